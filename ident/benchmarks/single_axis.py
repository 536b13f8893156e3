"""Benchmark for the diagnosis: bundle generator (seeded truth co-simulations with concealed effects, encoder
quantisation and noise) and a runner that prints a confusion table, parameter errors, validation
improvement and runtime per case.

The truth of a case is a Modelica model of the project's library (``MotionTwin.Effects.*Joint``, or
``MotionTwin.Benchmarks.*`` where the library has none, e.g. two effects at once) built into an FMI 2.0 FMU
by :mod:`fmus.build`, and co-simulated by the harness :class:`~harness.master.Master` with

* the controller as the ``MotionTwin.Benchmarks.LoopController`` FMU (the library's
  ``DiscreteStateSpaceController`` with two states and inputs ``[r, q]``, ``method = "discrete"``) whose
  ``A, B, C, D`` parameters are the bundle's matrices, stepped every ``TS``;
* the plant stepped every ``TS / PLANT_SUBSTEPS`` by its own variable-step RODAS4 solver;
* the ``MotionTwin.Benchmarks.Encoder`` FMU between them: the controller reads the *measured* position,
  ``quantize(q + noise)`` (the rounding of :func:`harness.measurement.quantize`), the noise being a seeded
  external signal drawn with :func:`harness.measurement.add_noise`.

Every run starts at x = 0 with a pre-roll (a smooth move to the first reference position and a dwell) that is
cut off, so recordings start at rest. Recordings hold ``time, r, u, q, u_ext`` at the controller instants; the
nominal ``plant.mo`` is the rigid axis with mass and damping guesses 20-40 % off. Units: SI (s, m, N, kg).

    python -m motiontwin.ident.benchmarks.single_axis generate OUT_DIR [--set tuning|heldout] [--case NAME]
    python -m motiontwin.ident.benchmarks.single_axis run OUT_DIR [--set tuning|heldout]
    python -m motiontwin.ident.benchmarks.single_axis conceal OUT_DIR [--set ...] [--case NAME]
    python -m motiontwin.ident.benchmarks.single_axis verify OUT_DIR [--case coulomb_friction]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from motiontwin.harness.recording import atomic_write_texts, make_recording, write_recording
from motiontwin.ident.diagnosis.plant_roles import PlantRoles
from motiontwin.ident.benchmarks.truth import (CASES, NOISE, PLANT_CLASS, PLANT_FORMS, PLANT_SUBSTEPS, PLANT_TEXT,
                                               POLE_PITCH, RESOLUTION, TRUE_D, TRUE_M, TS, TruthPlant,
                                               controller_json, cosimulate, inertia_range, pid_controller, plant_form,
                                               reference, simulate_truth, truth_plant, with_preroll)

def write_bundle(folder: Path, case: str, seed: int, scale: float = 1.0, nominal_error: float | None = None,
                 durations: tuple[float, float] = (12.0, 6.0), noise_std: float = NOISE,
                 resolution: float = RESOLUTION, fmu_dir: Path | None = None, stroke: float = 0.1,
                 sweep_fraction: float = 0.25, form: str = "alias", engine: str = "fmu", mass: float = TRUE_M,
                 damping: float = TRUE_D, nominal: tuple[float, float] | None = None,
                 start_offset: float = 0.0, truth_model: TruthPlant | None = None) -> dict:
    """Write one bundle (experiment.json, plant.mo, train.csv, validation.csv) and its ``NAME.truth.json``
    next to it (true effects, truth model, concealment: max and RMS |q_truth - q_rigid| [m] and max |u_truth -
    u_rigid| [N] on the training run, the rigid axis at the true m, d driven by the same r, u_ext and noise).
    ``form``: how plant.mo is written, a key of :data:`PLANT_FORMS` (the same axis and nominal guesses);
    ``engine``: how the truth is computed, see :func:`simulate_truth`; ``mass``, ``damping``: the true rigid axis
    (the PID is tuned for ``mass``); ``nominal``: (m, d) of plant.mo instead of 20-50 % off the truth;
    ``start_offset`` [s]: the recordings start this long after the pre-roll (inside the first move, so the
    loop is already moving at t = 0); ``truth_model``: the truth instead of ``case``'s (the CasADi engine
    writes its effects as the diagnosis' augmented model; ``case`` then only names the bundle)."""
    written = PLANT_FORMS[form]
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    err = nominal_error if nominal_error is not None else rng.uniform(0.2, 0.5)
    m_nom = mass * (1 + err * rng.choice([-1, 1]))
    d_nom = damping * (1 + rng.uniform(0.2, 0.5) * rng.choice([-1, 1]))
    if nominal is not None:
        m_nom, d_nom = nominal
    plant = truth_model or truth_plant(case, scale, mass, damping)
    ctrl = pid_controller(mass=mass)
    skip = int(round(start_offset / TS))
    concealment = {}
    for part, duration in zip(("train", "validation"), durations):
        t, r, u_ext = reference(duration + skip * TS, rng, stroke, duration * sweep_fraction)
        noise_seed = int(rng.integers(2 ** 31))
        q, u, q_true = simulate_truth(case, t, r, u_ext, np.random.default_rng(noise_seed), scale,
                                      noise_std=noise_std, resolution=resolution, fmu_dir=fmu_dir,
                                      engine=engine, mass=mass, damping=damping, skip=skip, truth=truth_model)
        if part == "train":
            _, u_rigid, q_rigid = simulate_truth(case, t, r, u_ext, np.random.default_rng(noise_seed), scale,
                                                 with_effects=False, noise_std=noise_std, resolution=resolution,
                                                 fmu_dir=fmu_dir, engine=engine, mass=mass, damping=damping,
                                                 skip=skip)
            concealment = {"max_abs_m": float(np.max(np.abs(q_true - q_rigid))),
                           "rms_m": float(np.sqrt(np.mean((q_true - q_rigid) ** 2))),
                           "force_max_abs_N": float(np.max(np.abs(u - u_rigid)))}
            if plant.class_name.endswith("VariableInertiaJoint"):
                plant.effects[0]["contract"] = inertia_range(plant, q_true)
                plant.effects[0]["parameters"] = dict(plant.effects[0]["contract"])
        t, r, u_ext = t[skip:] - t[skip], r[skip:], u_ext[skip:]
        rec = make_recording(t, {"r": r, "u": u, "q": q, "u_ext": u_ext}, sample_time=TS, seed=seed,
                             excited="point-to-point moves, then a swept sine 20-600 Hz on u_ext",
                             metadata={"truth": plant.class_name, "noise_seed": noise_seed})
        write_recording(folder / f"{part}.csv", rec)
    experiment = {
        "plant": {"modelica": "plant.mo", "class": written.class_name, "input": written.input,
                  "output": written.output, **({"pole_pitch": POLE_PITCH} if case == "cogging" else {})},
        "controller": controller_json(ctrl),
        "recordings": {"train": "train.csv", "validation": "validation.csv"},
    }
    truth = {"case": case, "seed": seed, "scale": scale, "m": mass, "d": damping, "stroke": stroke,
             "plant_form": form, "mass_parameter": written.mass, "mass_scale": written.scale,
             "sweep_fraction": sweep_fraction,
             "truth_model": {"class": plant.class_name, "parameters": plant.parameters, "engine": engine,
                             "plant_step": TS / PLANT_SUBSTEPS, "encoder_resolution": resolution,
                             "noise_std": noise_std},
             "effects": plant.effects, "concealment": concealment}
    atomic_write_texts({
        folder / "plant.mo": written.text.format(a=float(round(m_nom, 3)) * written.scale,
                                                 b=float(round(d_nom, 3)) * written.scale),
        folder / "experiment.json": json.dumps(experiment, indent=2),
        folder.parent / f"{folder.name}.truth.json": json.dumps(truth, indent=2),
    })
    return truth


def concealment(case: str, seed: int, scale: float = 1.0) -> float:
    """Max |q_truth - q_without_effects| [m] over a 12 s training trajectory: how hidden the effect is."""
    rng = np.random.default_rng(seed)
    t, r, u_ext = reference(12.0, rng, 0.1, 3.0)
    _, _, q1 = simulate_truth(case, t, r, u_ext, np.random.default_rng(0), scale)
    _, _, q0 = simulate_truth(case, t, r, u_ext, np.random.default_rng(0), scale, with_effects=False)
    return float(np.max(np.abs(q1 - q0)))


def case_list(which: str) -> list[tuple[str, int, float]]:
    """(case, seed, scale): the tuning set at scale 1; the held-out set with other seeds and magnitudes."""
    if which == "tuning":
        return [(c, 10 + i, 1.0) for i, c in enumerate(CASES)]
    rng = np.random.default_rng(2024)
    return [(c, 500 + i, float(rng.uniform(0.6, 1.5))) for i, c in enumerate(CASES)]


def trajectory(which: str, seed: int) -> dict[str, float]:
    """Stroke [m] and swept-sine share of a recording: fixed in the tuning set, drawn per case when held out."""
    if which == "tuning":
        return {"stroke": 0.1, "sweep_fraction": 0.25}
    rng = np.random.default_rng(seed + 7919)
    return {"stroke": float(rng.uniform(0.06, 0.14)), "sweep_fraction": float(rng.uniform(0.2, 0.35))}


def generate(out: Path, which: str, only: list[str] | None = None) -> None:
    """Write every bundle of the set ``which`` (or the cases ``only``) into ``out/which/CASE`` (FMUs built
    into ``out/fmus``); a case's bundle does not depend on which others are written."""
    for case, seed, scale in case_list(which):
        if only and case not in only:
            continue
        t0 = time.perf_counter()
        shape = trajectory(which, seed)
        form = plant_form(which, seed)
        truth = write_bundle(out / which / case, case, seed, scale, fmu_dir=out / "fmus", form=form, **shape)
        print(f"{which}/{case}: seed {seed}, scale {scale:.2f}, plant form {form}, stroke {shape['stroke'] * 1e3:.0f} mm, "
              f"sweep {shape['sweep_fraction']:.2f}, truth {truth['truth_model']['class']}, "
              f"concealment {truth['concealment']['max_abs_m'] * 1e6:.2f} um "
              f"({truth['concealment']['force_max_abs_N']:.3g} N), {time.perf_counter() - t0:.1f} s",
              flush=True)


# -- verification against the CasADi simulation of the diagnosis' own augmented model ------------

def verify(case: str = "coulomb_friction", seed: int = 10, duration: float = 12.0,
           fmu_dir: Path | None = None) -> dict[str, float]:
    """Noise-free comparison of the co-simulated FMU truth with the CasADi closed-loop simulation of the
    same physics written as the diagnosis' augmented model (RK4, 32 substeps per sample), on the same
    drive including the pre-roll; returns max and RMS |q_fmu - q_casadi| [m] and the max |q| [m]."""
    from motiontwin.ident import outputerror
    from motiontwin.ident.diagnosis import augmented
    from motiontwin.ident.diagnosis import effects as effect_models

    plant = truth_plant(case)
    if plant.class_name.endswith("VariableInertiaJoint"):
        raise ValueError("position_dependent_inertia: the truth (cosine mass) has no exact CasADi counterpart")
    rng = np.random.default_rng(seed)
    t, r, u_ext = reference(duration, rng, 0.1, duration / 4)
    rr, ue, _ = with_preroll(r, u_ext)
    fmu = cosimulate(plant, rr, ue, np.zeros(rr.size), resolution=1e-15, fmu_dir=fmu_dir)

    ctx = effect_models.Context(TS, 0.0, 0.1, 0.2, TRUE_M)
    effects, values = [], {"plant.m": TRUE_M, "plant.d": TRUE_D}
    for true in plant.effects:
        effect = effect_models.VOCABULARY[true["name"]](ctx)
        effects.append(effect)
        values.update({p.name: float(np.mean(p.bounds)) for p in effect.params})
        values.update({k: v for k, v in true["parameters"].items() if k in {p.name for p in effect.params}})
    with tempfile.TemporaryDirectory(prefix="mt-verify-") as folder:
        augmented.write_model(Path(folder), PLANT_TEXT.format(m=TRUE_M, d=TRUE_D), PLANT_CLASS, effects, values,
                              {"m": TRUE_M, "d": TRUE_D}, "Truth", PlantRoles("u", "q", "x", "v"))
        model = augmented.load_augmented(Path(folder), "Truth")
    n = rr.size
    loop = outputerror.build_loop(model, pid_controller(), "plant.x", [], values, n, substeps=32, with_jacobian=False)
    rec = make_recording(np.arange(n) * TS, {"r": rr, "u": np.zeros(n), "q": np.zeros(n), "u_ext": ue})
    q_casadi, _ = outputerror.simulate(loop, rec, values)
    diff = fmu["q_true"] - q_casadi
    return {"max_abs_m": float(np.max(np.abs(diff))), "rms_m": float(np.sqrt(np.mean(diff ** 2))),
            "max_q_m": float(np.max(np.abs(q_casadi)))}


# -- the runner ------------------------------------------------------------------------------------

#: the main parameter of each effect's contract, compared with the truth
MAIN_PARAMETER = {"gravity_offset": "F0", "coulomb_friction": "Fc", "asymmetric_friction": "Fc_pos",
                  "stribeck_friction": "Fs", "position_ripple": "amplitude", "time_delay": "delay",
                  "resonance": "frequency", "position_dependent_inertia": "mass_max", "backlash": "b",
                  "lugre_friction": "z0", "actuator_saturation": "Fmax", "cogging": "A1",
                  "load_dependent_friction": "mu", "friction_drift": "dFc"}
VOCABULARY = list(MAIN_PARAMETER)
UNEXPLAINED = "unexplained"    # the answer for a law outside the catalogue (row and column of the confusion table)


def _answer_names(effects: list[dict], unexplained: dict | None = None) -> list[str]:
    """Names in the confusion table: catalogue effects by name, laws outside the catalogue (truth) and an
    unexplained verdict (found, with or without a validated term) as "unexplained"."""
    names = [UNEXPLAINED if e.get("outside_catalogue") else e["name"] for e in effects]
    return names + ([UNEXPLAINED] if unexplained else [])


def _term_errors(truth_terms: dict[str, float], unexplained: dict | None) -> list[str]:
    """found/true coefficient of each true term of a law outside the catalogue (missing: "not found")."""
    found = ((unexplained or {}).get("empirical_term") or {}).get("coefficients", {})
    out = []
    for name, true_value in truth_terms.items():
        if name in found:
            out.append(f"{name} {found[name]:.4g}/{true_value:.4g} ({100 * (found[name] / true_value - 1):+.1f}%)")
        else:
            out.append(f"{name} not found")
    extra = [n for n in found if n not in truth_terms]
    return out + ([f"other terms {', '.join(extra)}"] if extra else [])


def run(out: Path, which: str, only: list[str] | None = None) -> int:
    """Diagnose every bundle of the set and print one line per case and the confusion table."""
    from motiontwin.ident.diagnosis import diagnose_bundle

    names = VOCABULARY + [UNEXPLAINED]
    confusion = {n: {m: 0 for m in names + ["(none)"]} for n in names + ["(none)"]}
    for case, _, _ in case_list(which):
        if only and case not in only:
            continue
        bundle = out / which / case
        truth = json.loads((out / which / f"{case}.truth.json").read_text())
        t0 = time.perf_counter()
        doc = diagnose_bundle(bundle, out / "results" / which / case)
        seconds = time.perf_counter() - t0
        found = _answer_names(doc["effects"], doc.get("unexplained"))
        true_names = _answer_names(truth["effects"])
        for tn in true_names:  # a true effect is found (diagonal) or missed (column "(none)")
            confusion[tn][tn if tn in found else "(none)"] += 1
        for fn in found:       # a found effect that is not in the truth is a false positive (row "(none)")
            if fn not in true_names:
                confusion["(none)"][fn] += 1
        if not true_names and not found:
            confusion["(none)"]["(none)"] += 1
        errors = []
        for effect in truth["effects"]:
            if effect.get("outside_catalogue"):
                errors += _term_errors(effect["contract"], doc.get("unexplained"))
                continue
            match = [e for e in doc["effects"] if e["name"] == effect["name"]]
            key = MAIN_PARAMETER[effect["name"]]
            true_value = effect["contract"].get(key)
            if match and true_value:
                fv = match[0]["parameters"].get(key)
                errors.append(f"{key} {fv:.4g}/{true_value:.4g} ({100 * (fv / true_value - 1):+.0f}%)")
        val = doc["validation"]
        ratio = val["augmented_rms"] / val["nominal_rms"]
        mass = doc["augmented_parameters"].get(truth.get("mass_parameter", "m"), math.nan)
        m_err = 100 * (mass / truth.get("mass_scale", 1.0) / TRUE_M - 1)
        truth_text, found_text = ",".join(true_names) or "-", ",".join(found) or "-"
        if doc.get("unexplained"):
            found_text += f" [{doc['unexplained']['status']}]"
        print(f"{case:28s} truth={truth_text:40s} found={found_text:40s} {'; '.join(errors)} m_err={m_err:+.1f}% "
              f"val {val['nominal_rms']:.3g}->{val['augmented_rms']:.3g} m (x{ratio:.2f}) {seconds:.0f} s",
              flush=True)
    print("\nconfusion (rows truth, columns found):")
    short = [n[:10] for n in names] + ["(none)"]
    print(" " * 28 + " ".join(f"{s:>10s}" for s in short))
    for tn in names + ["(none)"]:
        print(f"{tn:28s}" + " ".join(f"{confusion[tn][fn]:>10d}" for fn in names + ["(none)"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m motiontwin.ident.benchmarks.single_axis")
    parser.add_argument("command", choices=["generate", "run", "conceal", "verify"])
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", default="tuning", choices=["tuning", "heldout"])
    parser.add_argument("--case", default=None, help="one case, or several separated by commas (generate, run)")
    args = parser.parse_args(argv)
    cases = args.case.split(",") if args.case else None
    if args.command == "generate":
        generate(args.out, args.set, cases)
    elif args.command == "conceal":
        for case, seed, scale in case_list(args.set):
            if args.case in (None, case):
                print(f"{case}: max |q_truth - q_nominal| = {concealment(case, seed, scale) * 1e6:.2f} um")
    elif args.command == "verify":
        case = args.case or "coulomb_friction"
        t0 = time.perf_counter()
        res = verify(case, fmu_dir=args.out / "fmus")
        print(f"{case}: noise-free FMU co-simulation vs CasADi (RK4, Ts/32): max |dq| = {res['max_abs_m']:.3g} m, "
              f"RMS {res['rms_m']:.3g} m (max |q| {res['max_q_m']:.3g} m; encoder noise {NOISE:g} m, "
              f"quantum {RESOLUTION:g} m), {time.perf_counter() - t0:.1f} s")
    else:
        return run(args.out, args.set, cases)
    return 0


if __name__ == "__main__":
    sys.exit(main())
