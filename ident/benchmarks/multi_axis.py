"""Multi-axis benchmark for the diagnosis: bundle generator (the coupled 4-DOF Cheung and Hung manipulator in
actuator coordinates with a concealed effect on one or two actuators, co-simulated as library FMUs) and a
runner that prints the (axis, effect) confusion table, parameter errors, per-axis validation RMS and the
runtime per bundle against the 300 s budget.

The truth of a case is ``MotionTwin.Benchmarks.CheungEffects``: the library's ``MotionTwin.Plants.CheungManipulator``
(library parameter values) with, on every actuator, an opposing force built from the ``MotionTwin.Effects``
functions (offset + Stribeck/Coulomb friction + position ripple), zero except on the case's axes. It is built
into an FMI 2.0 FMU by :mod:`fmus.build` and co-simulated by the harness with one ``LoopController`` FMU and one
``Encoder`` FMU per axis (:func:`benchmarks.truth.loop_system`): each axis has its own PID
(:func:`benchmark.pid_controller`, its integral holding gravity) tuned for that actuator's effective mass at
the rest pose at :data:`BANDWIDTH`, a quantised encoder and its own seeded sensor noise. Every axis follows the
single-axis benchmark's reference (:func:`benchmark.reference`: point-to-point moves, then a swept sine on its
input disturbance) shifted to move within +-STROKE/2 of the paper's start pose, after the single-axis pre-roll
from rest at that pose; the forward kinematics and the Table 1 actuator ranges are checked on every sample.

The bundle's nominal plant is the same library class with the slider mass ``m_s`` and the viscous friction
``c_v`` 20-40 % off (``plant.parameters``). Units: SI (s, m, N, kg).

    python -m motiontwin.ident.benchmarks.multi_axis generate OUT_DIR [--set tuning|heldout] [--case NAME]
    python -m motiontwin.ident.benchmarks.multi_axis run OUT_DIR [--set tuning|heldout] [--case NAME]
    python -m motiontwin.ident.benchmarks.multi_axis score OUT_DIR [--set ...]   # re-score OUT_DIR/results
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from motiontwin.fmus import build
from motiontwin.harness import kinematics, measurement
from motiontwin.harness.recording import atomic_write_texts, make_recording, write_recording
from motiontwin.ident.benchmarks import single_axis as single
from motiontwin.ident.benchmarks.truth import V_EPS, cosimulate_axes, loop_axes
from motiontwin.ident.diagnosis.bundle import Controller

TS = single.TS
BANDWIDTH = 60.0            # Hz, closed-loop design bandwidth of every axis' PID
STROKE = 0.02               # m, every actuator moves within +-STROKE/2 of its start position
EFFECT_SCALE = 0.5          # the single-axis effect sizes (made for a 2 kg axis) times this: ~0.8 kg actuators
BUDGET_S = 300.0            # s, diagnosis wall time of one 4-DOF bundle of 10 s at 2 kHz on 2 cores
DURATIONS = (10.0, 5.0)     # s, training and validation recordings


@dataclass(frozen=True)
class AxisPlant:
    """A multi-axis plant of the benchmark: the library class (the bundle's nominal plant), the truth class
    that adds the effect forces, its axes as (input, output, position state, velocity state) and the
    parameters the nominal gets wrong."""

    library_class: str
    truth_class: str
    axes: tuple[tuple[str, str, str, str], ...]
    nominal_parameters: tuple[str, ...]

    @property
    def ports(self) -> list[tuple[str, str]]:
        return [(a[0], a[1]) for a in self.axes]

    @property
    def outputs(self) -> list[str]:
        return [a[1] for a in self.axes]


CHEUNG = AxisPlant("MotionTwin.Plants.CheungManipulator", "MotionTwin.Benchmarks.CheungEffects",
                   (("u1", "q1", "d1", "v1"), ("u3", "q3", "d3", "v3"), ("u5", "q5", "d5", "v5"),
                    ("u7", "q7", "d7", "v7")), ("m_s", "c_v"))

CASES = ["params_only_a", "params_only_b", "gravity_offset", "coulomb_friction", "stribeck_friction",
         "position_ripple", "two_axes"]
TUNING_AXES = {"gravity_offset": ["q3"], "coulomb_friction": ["q5"], "stribeck_friction": ["q1"],
               "position_ripple": ["q7"], "two_axes": ["q1", "q5"]}
# truth-class parameter (per axis, suffix _<actuator number>) of each single-axis library parameter
EFFECT_PARAMETERS = ("F0", "Fc", "Fs", "vs", "A", "period", "phase")


def effect_names(case: str) -> list[str]:
    """The single-axis effects of a case, one per affected axis (the two-axes case: Coulomb, then ripple)."""
    if case.startswith("params_only"):
        return []
    if case == "two_axes":
        return ["coulomb_friction", "position_ripple"]
    if case not in CASES:
        raise KeyError(f"unknown multi-axis benchmark case {case!r}; cases: {', '.join(CASES)}")
    return [case]


def _suffix(output: str) -> str:
    """The actuator number an axis' truth parameters carry: "q5" -> "5"."""
    return re.sub(r"^\D+", "", output)


def truth_parameters(case: str, axes: list[str], scale: float,
                     plant: AxisPlant = CHEUNG) -> tuple[dict[str, float], list[dict]]:
    """Truth-class parameter values and the true effects (name, axis, parameters, contract) of ``case`` with
    its effects on ``axes``: each effect is the single-axis benchmark's (:func:`benchmark.truth_plant`) at
    ``scale * EFFECT_SCALE``, its library parameters moved onto that axis (Coulomb friction: Fs = Fc)."""
    names = effect_names(case)
    if len(axes) != len(names) or len(set(axes)) != len(axes) or not set(axes) <= set(plant.outputs):
        raise ValueError(f"case {case!r} needs {len(names)} different axes among {', '.join(plant.outputs)}, "
                         f"got {axes}")
    parameters: dict[str, float] = {"v_eps": V_EPS}
    effects = []
    for name, axis in zip(names, axes):
        plant = single.truth_plant(name, scale * EFFECT_SCALE)
        values = {k: v for k, v in plant.parameters.items() if k in EFFECT_PARAMETERS}
        if "Fc" in values:
            values.setdefault("Fs", values["Fc"])
        parameters.update({f"{k}_{_suffix(axis)}": float(v) for k, v in values.items()})
        effects += [{**effect, "axis": axis} for effect in plant.effects]
    return parameters, effects


def case_list(which: str) -> list[tuple[str, int, float, list[str]]]:
    """(case, seed, scale, axes): the tuning set at scale 1 on fixed axes; the held-out set with its own seeds,
    magnitudes and axes."""
    if which == "tuning":
        return [(c, 30 + i, 1.0, TUNING_AXES.get(c, [])) for i, c in enumerate(CASES)]
    if which != "heldout":
        raise ValueError(f"set must be 'tuning' or 'heldout', not {which!r}")
    rng = np.random.default_rng(4096)
    cases = []
    for i, c in enumerate(CASES):
        scale = float(rng.uniform(0.6, 1.5))
        axes = [str(a) for a in rng.choice(CHEUNG.outputs, size=len(effect_names(c)), replace=False)]
        cases.append((c, 700 + i, scale, axes))
    return cases


# -- the plant at rest, the controllers and the workspace -------------------------------------------

def rest_state(plant: AxisPlant = CHEUNG) -> tuple[np.ndarray, np.ndarray]:
    """Start positions of the axes (the library class' state start values) [m] and the effective mass of each
    actuator there, diag(M) with M^-1 = d(d2q/dt2)/du = (dq/dx)(df/dx)(df/du) at rest [kg]."""
    model = build.load_model(plant.library_class)
    p = model.parameter_values()
    x0 = np.array(model.functions()["x0"](p)).ravel()
    u0 = np.zeros(model.u.numel())
    outputs = [c.var.name for c in model.computed]
    rows = [outputs.index(o) for o in plant.outputs]
    jac = ca.Function("rest_jacobians", [model.x, model.u, model.p],
                      [ca.jacobian(model.y, model.x), ca.jacobian(model.dx, model.x), ca.jacobian(model.dx, model.u)])
    cx, fx, fu = (np.array(m) for m in jac(x0, u0, p))
    inputs = [v.name for v in model.inputs]
    cols = [inputs.index(i) for i, _ in plant.ports]
    acc_per_force = (cx @ fx @ fu)[np.ix_(rows, cols)]
    start = np.array(model.functions()["out"](0.0, x0, u0, p)).ravel()[rows]
    return start, np.diag(np.linalg.inv(acc_per_force))


def controllers(masses: np.ndarray) -> list[Controller]:
    """One PID per axis, tuned for that axis' effective mass at :data:`BANDWIDTH`."""
    return [single.pid_controller(mass=float(m), bandwidth=BANDWIDTH) for m in masses]


def check_workspace(q: np.ndarray, what: str) -> None:
    """Refuse positions (n, 4) [m] outside the Table 1 actuator ranges or where the forward kinematics has
    no real solution (the linkage cannot be assembled)."""
    pose = np.array([kinematics.cheung_forward(row) for row in q])
    if not np.all(np.isfinite(pose)) or not all(kinematics.cheung_in_range(row) for row in q):
        bad = int(np.argmax([not (np.all(np.isfinite(p)) and kinematics.cheung_in_range(row))
                             for p, row in zip(pose, q)]))
        raise ValueError(f"{what}: sample {bad} leaves the 4-DOF workspace (d = {q[bad].tolist()} m)")


def references(duration: float, rng: np.random.Generator, start: np.ndarray,
               sweep_fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time and (n, axes) reference and input disturbance: per axis the single-axis reference
    (:func:`benchmark.reference`) over STROKE, centred on that axis' start position."""
    cols = [single.reference(duration, rng, STROKE, duration * sweep_fraction) for _ in start]
    t = cols[0][0]
    r = np.column_stack([s + c[1] - STROKE / 2 for s, c in zip(start, cols)])
    u_ext = np.column_stack([c[2] for c in cols])
    return t, r, u_ext


def simulate(parameters: dict[str, float], r: np.ndarray, u_ext: np.ndarray, noise_seeds: list[int],
             ctrls: list[Controller], start: np.ndarray, fmu_dir: Path | None = None,
             noise_std: float = single.NOISE, resolution: float = single.RESOLUTION,
             plant: AxisPlant = CHEUNG) -> dict[str, np.ndarray]:
    """Closed-loop truth with the truth class at ``parameters``, pre-roll from rest at ``start`` cut off; every
    axis' sensor noise drawn from its own seed; the true positions are checked against the workspace, pre-roll
    included. Returns (n, axes) arrays r, u, q (measured), u_ext, q_true."""
    cols = [single.with_preroll(r[:, j], u_ext[:, j], float(start[j])) for j in range(r.shape[1])]
    pre = cols[0][2]
    rr, ue = np.column_stack([c[0] for c in cols]), np.column_stack([c[1] for c in cols])
    noise = np.column_stack([measurement.add_noise(np.zeros(rr.shape[0]), noise_std, np.random.default_rng(s))
                             for s in noise_seeds])
    out = cosimulate_axes(plant.truth_class, parameters, loop_axes(plant.ports), ctrls, rr, ue, noise,
                                 resolution, fmu_dir)
    check_workspace(out["q_true"], f"{plant.truth_class} run (pre-roll included)")
    return {k: v[pre:] for k, v in out.items() if k != "time"}


# -- bundles ------------------------------------------------------------------------------------------

def _nominal(rng: np.random.Generator, plant: AxisPlant) -> tuple[dict[str, float], dict[str, float]]:
    """True library values and the nominal guesses 20-40 % off (random sign) of the plant's parameters."""
    model = build.load_model(plant.library_class)
    true = {v.name: float(v.start) for v in model.parameters if v.name in plant.nominal_parameters}
    guess = {k: float(round(v * (1 + rng.uniform(0.2, 0.4) * rng.choice([-1, 1])), 4)) for k, v in true.items()}
    return true, guess


def write_bundle(folder: Path, case: str, seed: int, scale: float, axes: list[str],
                 durations: tuple[float, float] = DURATIONS, fmu_dir: Path | None = None,
                 sweep_fraction: float = 0.25, plant: AxisPlant = CHEUNG) -> dict:
    """Write one multi-axis bundle (experiment.json, train.csv, validation.csv) and ``NAME.truth.json`` next to
    it: true effects with their axes, truth model, nominal errors and, per axis, the concealment on the
    training run (max and RMS |q_truth - q_rigid| [m], max |u_truth - u_rigid| [N], the rigid truth driven by
    the same references, disturbances and noise; max |r - q_truth| [m], the tracking error)."""
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    truth_values, effects = truth_parameters(case, axes, scale, plant)
    true_nominal, guess = _nominal(rng, plant)
    start, masses = rest_state(plant)
    ctrls = controllers(masses)
    outputs = plant.outputs
    concealment: dict[str, dict[str, float]] = {}
    recordings = {}
    for part, duration in zip(("train", "validation"), durations):
        t, r, u_ext = references(duration, rng, start, sweep_fraction)
        check_workspace(r, f"{case} {part} reference")
        seeds = [int(s) for s in rng.integers(2 ** 31, size=len(outputs))]
        out = simulate(truth_values, r, u_ext, seeds, ctrls, start, fmu_dir, plant=plant)
        if part == "train":
            rigid = simulate({}, r, u_ext, seeds, ctrls, start, fmu_dir, plant=plant)
            dq, du = out["q_true"] - rigid["q_true"], out["u"] - rigid["u"]
            concealment = {o: {"max_abs_m": float(np.max(np.abs(dq[:, j]))),
                               "rms_m": float(np.sqrt(np.mean(dq[:, j] ** 2))),
                               "force_max_abs_N": float(np.max(np.abs(du[:, j]))),
                               "tracking_max_abs_m": float(np.max(np.abs(r[:, j] - out["q_true"][:, j])))}
                           for j, o in enumerate(outputs)}
        columns = {}
        for j, (inp, o) in enumerate(plant.ports):
            columns.update({f"r_{o}": r[:, j], inp: out["u"][:, j], o: out["q"][:, j], f"u_ext_{inp}": u_ext[:, j]})
        recordings[part] = make_recording(
            t, columns, units={k: "m" if k.startswith("r_") or k in outputs else "N" for k in columns},
            sample_time=TS, seed=seed, excited="per axis: point-to-point moves, then a swept sine 20-600 Hz on u_ext",
            metadata={"truth": plant.truth_class, "noise_seeds": seeds})
    experiment = {
        "plant": {"class": plant.library_class,
                  "axes": [{"input": i, "output": o, "position": x, "velocity": v} for i, o, x, v in plant.axes],
                  "parameters": guess, "free": sorted(guess)},
        "controller": {"kind": "per_axis", "axes": [single.controller_json(c) for c in ctrls]},
        "recordings": {"train": "train.csv", "validation": "validation.csv"},
    }
    truth = {"case": case, "seed": seed, "scale": scale, "axes": axes, "stroke": STROKE,
             "sweep_fraction": sweep_fraction, "bandwidth_hz": BANDWIDTH,
             "effective_mass": dict(zip(outputs, masses.tolist())), "start": dict(zip(outputs, start.tolist())),
             "nominal": {"true": true_nominal, "guess": guess},
             "truth_model": {"class": plant.truth_class, "parameters": truth_values, "engine": "fmu",
                             "plant_step": TS / single.PLANT_SUBSTEPS, "encoder_resolution": single.RESOLUTION,
                             "noise_std": single.NOISE},
             "effects": effects, "concealment": concealment}
    folder.mkdir(parents=True, exist_ok=True)
    for part, rec in recordings.items():
        write_recording(folder / f"{part}.csv", rec)
    atomic_write_texts({folder / "experiment.json": json.dumps(experiment, indent=2),
                        folder.parent / f"{folder.name}.truth.json": json.dumps(truth, indent=2)})
    return truth


def generate(out: Path, which: str, only: str | None = None, durations: tuple[float, float] = DURATIONS) -> None:
    """Write every bundle of the set into ``out/which/CASE`` (FMUs built into ``out/fmus``), one line each."""
    for case, seed, scale, axes in case_list(which):
        if only not in (None, case):
            continue
        t0 = time.perf_counter()
        truth = write_bundle(out / which / case, case, seed, scale, axes, durations, fmu_dir=out / "fmus")
        hidden = ", ".join(f"{a} {c['max_abs_m'] * 1e6:.2f} um/{c['force_max_abs_N']:.3g} N"
                           f"/{c['tracking_max_abs_m'] * 1e6:.0f} um" for a, c in truth["concealment"].items())
        print(f"{which}/{case}: seed {seed}, scale {scale:.2f}, axes {','.join(axes) or '-'}, "
              f"effects {','.join(e['name'] for e in truth['effects']) or '-'}; max |q - q_rigid|/|u - u_rigid|/|r - q|: "
              f"{hidden}; {time.perf_counter() - t0:.1f} s", flush=True)


# -- the runner ------------------------------------------------------------------------------------

UNEXPLAINED = "unexplained"


def found_effects(doc: dict) -> list[tuple[str, str]]:
    """(axis, name) of every effect a diagnosis.json names; an entry labelled empirical, or named
    "unexplained", and the verdict's ``unexplained`` entry (a validated empirical term, or "unexplained, no
    term validated") count as "unexplained" on its axis (axis "?" when the entry has none)."""
    found = []
    for e in doc.get("effects", []):
        name = UNEXPLAINED if e.get("empirical") or e.get("name") == UNEXPLAINED else e["name"]
        found.append((str(e.get("axis", "?")), name))
    verdict = doc.get("unexplained")
    if verdict and not any(name == UNEXPLAINED for _, name in found):
        found.append((str(verdict.get("axis", "?")), UNEXPLAINED))
    return found


def score(doc: dict, truth: dict) -> dict:
    """Compare one diagnosis.json with its truth: per true effect the outcome (the effect's name when found
    on its axis, "wrong axis" when found on another one, what was found on its axis instead, or "(none)"),
    the unmatched findings (false positives), the main parameter's relative error, the slider mass error
    and the per-axis validation RMS nominal -> augmented."""
    found = found_effects(doc)
    used: set[int] = set()
    outcomes, errors = [], {}
    for effect in truth["effects"]:
        axis, name = effect["axis"], effect["name"]
        hit = next((i for i, f in enumerate(found) if f == (axis, name) and i not in used), None)
        if hit is None:
            elsewhere = next((i for i, f in enumerate(found) if f[1] == name and i not in used), None)
            on_axis = next((i for i, f in enumerate(found) if f[0] == axis and i not in used), None)
            hit = elsewhere if elsewhere is not None else on_axis
            outcome = "wrong axis" if elsewhere is not None else (found[on_axis][1] if on_axis is not None
                                                                   else "(none)")
        else:
            outcome = name
            key = single.MAIN_PARAMETER[name]
            true_value = effect["contract"].get(key)
            value = doc["effects"][hit]["parameters"].get(key)
            if true_value and value is not None:
                errors[f"{axis}:{key}"] = value / true_value - 1
        if hit is not None:
            used.add(hit)
        outcomes.append((name, outcome))
    false_positives = [found[i][1] for i in range(len(found)) if i not in used]
    params = doc.get("augmented_parameters", {})
    mass_errors = {k: params[p] / v - 1 for k, v in truth["nominal"]["true"].items()
                   for p in (k, f"plant.{k}") if p in params}
    per_axis = doc.get("validation", {}).get("per_axis", {})
    return {"outcomes": outcomes, "false_positives": false_positives, "parameter_errors": errors,
            "nominal_errors": mass_errors,
            "validation": {a: (v["nominal_rms"], v["augmented_rms"]) for a, v in per_axis.items()}}


def confusion_table(scores: list[dict]) -> tuple[list[str], list[str], dict[str, dict[str, int]]]:
    """Rows: true effect names and "(none)" (parameters-only bundles, false positives); columns: found
    names, "unexplained", "wrong axis" and "(none)"; counts over the bundles. The names are the single-axis
    vocabulary and any other name a diagnosis reports (new candidates)."""
    reported = [n for s in scores for n in [o for _, o in s["outcomes"]] + s["false_positives"]]
    extra = {UNEXPLAINED, "wrong axis", "(none)"}
    names = list(dict.fromkeys(list(single.MAIN_PARAMETER) + [n for n in reported if n not in extra]))
    rows, cols = names + ["(none)"], names + [UNEXPLAINED, "wrong axis", "(none)"]
    table = {r: {c: 0 for c in cols} for r in rows}
    for s in scores:
        for name, outcome in s["outcomes"]:
            table[name][outcome] += 1
        for name in s["false_positives"]:
            table["(none)"][name] += 1
        if not s["outcomes"] and not s["false_positives"]:
            table["(none)"]["(none)"] += 1
    return rows, cols, table


def format_line(case: str, truth: dict, s: dict, wall: float, cpu: float | None) -> str:
    """One printed line per bundle: truth, outcome, errors, per-axis validation and time vs the budget."""
    true_text = ",".join(f"{e['axis']}:{e['name']}" for e in truth["effects"]) or "-"
    found_text = ",".join(f"{n}->{o}" for n, o in s["outcomes"]) or "-"
    extra = ",".join(s["false_positives"])
    errs = " ".join(f"{k} {100 * v:+.0f}%" for k, v in {**s["parameter_errors"], **s["nominal_errors"]}.items())
    val = " ".join(f"{a} {_gain(n, g)}" for a, (n, g) in s["validation"].items())
    budget = "ok" if wall <= BUDGET_S else "OVER"
    cpu_text = "-" if cpu is None else f"{cpu:.0f} s"
    return (f"{case:18s} truth={true_text:40s} outcome={found_text:40s} extra={extra or '-'} {errs} "
            f"val[m] {val} wall {wall:.0f} s cpu {cpu_text} ({budget} vs {BUDGET_S:.0f} s)")


def _gain(nominal: float | None, augmented: float | None) -> str:
    """Validation RMS nominal -> augmented and their ratio; a diverged (None) fit says so."""
    if nominal is None or augmented is None:
        return f"{nominal}->{augmented} (diverged)"
    return f"{nominal:.3g}->{augmented:.3g} (x{augmented / nominal:.2f})" if nominal else f"0->{augmented:.3g}"


def print_confusion(scores: list[dict]) -> str:
    """The confusion table as text (rows truth, columns found)."""
    rows, cols, table = confusion_table(scores)
    lines = ["confusion (rows truth, columns found on the true axis):",
             " " * 20 + " ".join(f"{c[:11]:>11s}" for c in cols)]
    lines += [f"{r[:20]:20s}" + " ".join(f"{table[r][c]:>11d}" for c in cols) for r in rows]
    return "\n".join(lines)


def run(out: Path, which: str, only: str | None = None, diagnose: bool = True) -> int:
    """Diagnose every bundle of the set with ``diagnose_bundle`` into ``out/results/SET/CASE`` (or, with
    ``diagnose=False``, score the diagnosis.json files already there, timed by their ``runtime_s``); print one
    line per bundle and the confusion table. A bundle whose diagnosis fails or is missing is reported and left
    out of the table; exit code 1 then."""
    from motiontwin.ident.diagnosis import diagnose_bundle

    scores, failed = [], 0
    for case, _, _, _ in case_list(which):
        if only not in (None, case):
            continue
        result = out / "results" / which / case
        wall0, cpu0 = time.perf_counter(), _cpu_seconds()
        try:
            truth = json.loads((out / which / f"{case}.truth.json").read_text())
            if diagnose:
                doc = diagnose_bundle(out / which / case, result)
                wall, cpu = time.perf_counter() - wall0, _cpu_seconds() - cpu0
            else:
                doc = json.loads((result / "diagnosis.json").read_text())
                wall, cpu = float(doc.get("runtime_s", math.nan)), None
        except Exception as exc:  # a failing bundle must not hide the others' results
            print(f"{case:18s} diagnosis failed: {type(exc).__name__}: {exc}", flush=True)
            failed += 1
            continue
        s = score(doc, truth)
        scores.append(s)
        print(format_line(case, truth, s, wall, cpu), flush=True)
    print("\n" + print_confusion(scores))
    return 1 if failed else 0


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children [s]."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m motiontwin.ident.benchmarks.multi_axis")
    parser.add_argument("command", choices=["generate", "run", "score"],
                        help="generate bundles; run: diagnose and score them; score: score existing results")
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", default="tuning", choices=["tuning", "heldout"])
    parser.add_argument("--case", default=None, choices=CASES)
    args = parser.parse_args(argv)
    if args.command == "generate":
        generate(args.out, args.set, args.case)
        return 0
    return run(args.out, args.set, args.case, diagnose=args.command == "run")


if __name__ == "__main__":
    sys.exit(main())
