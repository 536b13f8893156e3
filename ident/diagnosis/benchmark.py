"""Benchmark for the diagnosis: bundle generator (seeded truth simulations with concealed effects,
encoder quantisation and noise) and a runner that prints a confusion table, parameter errors, validation
improvement and runtime per case.

The truth plant is the nominal linear-motor axis plus the case's effects with their true values, written as
Modelica by :mod:`ident.diagnosis.effects` and simulated in closed loop by :mod:`ident.diagnosis.simulate`
with 4x finer integration, the controller reading the noisy encoder. (To be replaced by co-simulated FMUs of
the library's higher-fidelity joints through the harness.) Units: SI (s, m, N, kg).

    python -m ident.diagnosis.benchmark generate OUT_DIR [--set tuning|heldout]
    python -m ident.diagnosis.benchmark run OUT_DIR [--set tuning|heldout]
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
import scipy.signal as sps

from harness.recording import make_recording, write_recording
from ident.diagnosis import effects as fx
from ident.diagnosis import simulate as sim
from ident.diagnosis.bundle import Controller

PLANT_CLASS = "LinearAxis"
PLANT_TEXT = '''model LinearAxis "Direct-drive linear axis: moving mass with viscous damping, m*der(v) = u - d*v"
  parameter Real m(unit = "kg", min = 1e-6) = {m!r} "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = {d!r} "Viscous damping";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity";
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = x;
end LinearAxis;
'''
TS = 5e-4
TRUE_M, TRUE_D = 2.0, 15.0
RESOLUTION = 5e-9          # encoder quantum [m]
NOISE = 10e-9              # encoder noise std [m]

# case name -> list of (effect, true parameter values in the effect's Modelica names)
CASES: dict[str, list[tuple[str, dict[str, float]]]] = {
    "params_only_a": [],
    "params_only_b": [],
    "gravity_offset": [("gravity_offset", {"gravity_F0": 1.5})],
    "coulomb_friction": [("coulomb_friction", {"coulomb_Fc": 0.15})],
    "asymmetric_friction": [("asymmetric_friction", {"asym_Fc_pos": 0.2, "asym_Fc_neg": 0.06})],
    "stribeck_friction": [("stribeck_friction", {"stribeck_Fc": 0.08, "stribeck_Fs": 0.25, "stribeck_vs": 0.004})],
    "position_ripple": [("position_ripple", {"ripple_a": 0.5, "ripple_b": 0.3, "ripple_period": 0.016})],
    "position_dependent_inertia": [("position_dependent_inertia", {"inertia_slope": 5.0})],
    "time_delay": [("time_delay", {"delay_T": 2e-4})],
    "resonance": [("resonance", {"resonance_m2": 0.1, "resonance_fa": 220.0, "resonance_zeta": 0.03})],
    "two_effects": [("gravity_offset", {"gravity_F0": 1.0}),
                    ("position_ripple", {"ripple_a": 0.4, "ripple_b": -0.2, "ripple_period": 0.012})],
}
SCALED = {"gravity_F0", "coulomb_Fc", "asym_Fc_pos", "asym_Fc_neg", "stribeck_Fc", "stribeck_Fs", "ripple_a",
          "ripple_b", "inertia_slope", "delay_T", "resonance_m2"}


def pid_controller(ts: float = TS, mass: float = TRUE_M, bandwidth: float = 60.0) -> Controller:
    """PID with filtered derivative on e = r - q, Tustin-discretised (scipy cont2discrete, bilinear)."""
    wc = 2 * math.pi * bandwidth
    kp, ti, td, n = mass * wc ** 2 / 3, 4 / wc, 1.5 / wc, 8.0
    num = [kp * ti * td * (1 + 1 / n), kp * (ti + td / n), kp]
    den = [ti * td / n, ti, 0.0]
    a, b, c, d, _ = sps.cont2discrete(sps.tf2ss(num, den), ts, method="bilinear")
    return Controller(ts, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([d, -d]))


def reference(duration: float, rng: np.random.Generator, stroke: float, sweep: float) -> tuple[np.ndarray, ...]:
    """Point-to-point moves (cosine velocity profile) with dwells, then a swept sine on u_ext at rest."""
    t = np.arange(int(round(duration / TS))) * TS
    r = np.zeros_like(t)
    u_ext = np.zeros_like(t)
    moving_end = duration - sweep
    pos, now = stroke * rng.uniform(0.3, 0.7), 0.3
    r[:] = pos
    while now < moving_end - 0.5:
        target = stroke * rng.uniform(0.05, 0.95)
        speed = rng.choice([0.003, 0.01, 0.05, 0.15]) * rng.uniform(0.7, 1.3)
        dur = max(0.08, min(1.5, 2 * abs(target - pos) / speed))
        dur = min(dur, moving_end - 0.2 - now)
        i0, i1 = int(now / TS), int((now + dur) / TS)
        s = (1 - np.cos(np.pi * np.linspace(0, 1, i1 - i0))) / 2
        r[i0:i1] = pos + (target - pos) * s
        r[i1:] = target
        pos = target
        now += dur + rng.uniform(0.1, 0.4)
    i_sweep = int(moving_end / TS)
    ts = t[i_sweep:] - t[i_sweep]
    f0, f1 = 20.0, 600.0
    phase = 2 * np.pi * f0 * sweep / np.log(f1 / f0) * (np.exp(ts / sweep * np.log(f1 / f0)) - 1)
    u_ext[i_sweep:] = 1.5 * np.sin(phase) * np.minimum(1, ts / 0.05)
    return t, r, u_ext


def truth_model(case: str, scale: float):
    """Augmented Modelica model of the truth (nominal axis at the true m, d plus the case's effects)."""
    folder = Path(tempfile.mkdtemp(prefix="mt-truth-"))
    ctx = fx.Context(TS, 0.0, 0.1, 0.2, TRUE_M)
    effects, values = [], {"plant.m": TRUE_M, "plant.d": TRUE_D}
    for name, params in CASES[case]:
        effect = fx.VOCABULARY[name](ctx)
        effects.append(effect)
        for p in effect.params:
            values[p.name] = float(np.mean(p.bounds))
        values.update({k: v * (scale if k in SCALED else 1.0) for k, v in params.items()})
    plant_text = PLANT_TEXT.format(m=TRUE_M, d=TRUE_D)
    fx.write_model(folder, plant_text, PLANT_CLASS, effects, values, {"m": TRUE_M, "d": TRUE_D}, "Truth")
    model = fx.load_augmented(folder, "Truth")
    tracking = {s: "q" for e in effects for s in e.tracks_position}
    tracking.update({s: "u" for e in effects for s in e.tracks_force})
    return model, values, tracking


def simulate_truth(case: str, t: np.ndarray, r: np.ndarray, u_ext: np.ndarray, rng: np.random.Generator,
                   scale: float, with_effects: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-loop truth with encoder noise fed back; returns measured q (quantised), u and the true q."""
    ctrl = pid_controller()
    model, values, tracking = truth_model(case if with_effects else "params_only_a", scale)
    pre = int(1.0 / TS)
    n = t.size + pre
    rr = np.concatenate([np.full(pre, r[0]), r])
    ue = np.concatenate([np.zeros(pre), u_ext])
    noise = rng.normal(0, NOISE, n)
    loop = sim.build_loop(model, ctrl, "plant.x", [], values, n, tracking=tracking, with_jacobian=False)
    fine = sim.build_loop(model, ctrl, "plant.x", [], values, n, substeps=4 * loop.substeps, tracking=tracking,
                          with_jacobian=False)
    rec = make_recording(np.arange(n) * TS, {"r": rr, "u": np.zeros(n), "q": np.full(n, r[0]), "u_ext": ue})
    q, u = sim.simulate(fine, rec, values, noise=noise)
    q_meas = np.round((q + noise) / RESOLUTION) * RESOLUTION
    return q_meas[pre:], u[pre:], q[pre:]


def write_bundle(folder: Path, case: str, seed: int, scale: float = 1.0, nominal_error: float | None = None,
                 durations: tuple[float, float] = (12.0, 6.0)) -> dict:
    """Write one bundle (experiment.json, plant.mo, train.csv, validation.csv) and its truth.json."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    err = nominal_error if nominal_error is not None else rng.uniform(0.2, 0.4)
    m_nom = TRUE_M * (1 + err * rng.choice([-1, 1]))
    d_nom = TRUE_D * (1 + rng.uniform(0.2, 0.4) * rng.choice([-1, 1]))
    plant_text = PLANT_TEXT.format(m=float(round(m_nom, 3)), d=float(round(d_nom, 3)))
    (folder / "plant.mo").write_text(plant_text, encoding="utf-8")
    ctrl = pid_controller()
    for part, duration in zip(("train", "validation"), durations):
        t, r, u_ext = reference(duration, rng, 0.1, duration / 4)
        q, u, _ = simulate_truth(case, t, r, u_ext, rng, scale)
        rec = make_recording(t, {"r": r, "u": u, "q": q, "u_ext": u_ext}, sample_time=TS, seed=seed,
                             excited="point-to-point moves, then a swept sine 20-600 Hz on u_ext")
        write_recording(folder / f"{part}.csv", rec)
    experiment = {
        "plant": {"modelica": "plant.mo", "class": PLANT_CLASS, "input": "u", "output": "q"},
        "controller": {"kind": "discrete_state_space", "Ts": TS, "inputs": ["r", "q"], "outputs": ["u"],
                       "A": ctrl.A.tolist(), "B": ctrl.B.tolist(), "C": ctrl.C.tolist(), "D": ctrl.D.tolist()},
        "recordings": {"train": "train.csv", "validation": "validation.csv"},
    }
    (folder / "experiment.json").write_text(json.dumps(experiment, indent=2), encoding="utf-8")
    truth = {"case": case, "seed": seed, "scale": scale, "m": TRUE_M, "d": TRUE_D,
             "effects": [{"name": n, "parameters": {k: v * (scale if k in SCALED else 1) for k, v in p.items()}}
                         for n, p in CASES[case]]}
    (folder.parent / f"{folder.name}.truth.json").write_text(json.dumps(truth, indent=2), encoding="utf-8")
    return truth


def concealment(case: str, seed: int, scale: float = 1.0) -> float:
    """Max |q_truth - q_without_effects| [m] over a training trajectory: how hidden the effect is."""
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


def generate(out: Path, which: str) -> None:
    for case, seed, scale in case_list(which):
        t0 = time.perf_counter()
        write_bundle(out / which / case, case, seed, scale)
        print(f"{which}/{case}: seed {seed}, scale {scale:.2f}, {time.perf_counter() - t0:.1f} s", flush=True)


def _main_value(name: str, params: dict[str, float]) -> tuple[str, float] | None:
    keys = {"gravity_offset": "F0", "coulomb_friction": "Fc", "asymmetric_friction": "Fc_pos",
            "stribeck_friction": "Fs", "position_ripple": "amplitude", "time_delay": "delay",
            "resonance": "frequency", "position_dependent_inertia": "mass_max"}
    key = keys[name]
    return (key, params[key]) if key in params else None


def _truth_contract(effect: dict) -> dict[str, float]:
    e = fx.VOCABULARY[effect["name"]](fx.Context(TS, 0.0, 0.1, 0.2, TRUE_M))
    values = {p.name: float(np.mean(p.bounds)) for p in e.params}
    values.update(effect["parameters"])
    values["plant.m"] = TRUE_M
    return e.contract(values, fx.Context(TS, 0.0, 0.1, 0.2, TRUE_M))


def run(out: Path, which: str, only: list[str] | None = None) -> int:
    from ident.diagnosis import diagnose

    names = list(fx.VOCABULARY)
    confusion = {n: {m: 0 for m in names + ["(none)"]} for n in names + ["(none)"]}
    rows = []
    for case, _, _ in case_list(which):
        if only and case not in only:
            continue
        bundle = out / which / case
        truth = json.loads((out / which / f"{case}.truth.json").read_text())
        t0 = time.perf_counter()
        doc = diagnose(bundle, out / "results" / which / case)
        seconds = time.perf_counter() - t0
        found = [e["name"] for e in doc["effects"]]
        true_names = [e["name"] for e in truth["effects"]]
        for tn in true_names:  # a true effect is found (diagonal) or missed (column "(none)")
            confusion[tn][tn if tn in found else "(none)"] += 1
        for fn in found:       # a found effect that is not in the truth is a false positive (row "(none)")
            if fn not in true_names:
                confusion["(none)"][fn] += 1
        if not true_names and not found:
            confusion["(none)"]["(none)"] += 1
        errors = []
        for effect in truth["effects"]:
            match = [e for e in doc["effects"] if e["name"] == effect["name"]]
            tv = _main_value(effect["name"], _truth_contract(effect))
            if match and tv:
                fv = match[0]["parameters"].get(tv[0])
                errors.append(f"{tv[0]} {fv:.4g}/{tv[1]:.4g} ({100 * (fv / tv[1] - 1):+.0f}%)")
        val = doc["validation"]
        ratio = val["augmented_rms"] / val["nominal_rms"]
        m_err = 100 * (doc["augmented_parameters"].get("m", math.nan) / TRUE_M - 1)
        rows.append((case, ",".join(true_names) or "-", ",".join(found) or "-", "; ".join(errors), m_err,
                     val["nominal_rms"], val["augmented_rms"], ratio, seconds))
        print(f"{case:28s} truth={rows[-1][1]:40s} found={rows[-1][2]:40s} {rows[-1][3]} m_err={m_err:+.1f}% "
              f"val {val['nominal_rms']:.3g}->{val['augmented_rms']:.3g} m (x{ratio:.2f}) {seconds:.0f} s",
              flush=True)
    print("\nconfusion (rows truth, columns found):")
    short = [n[:10] for n in names] + ["(none)"]
    print(" " * 28 + " ".join(f"{s:>10s}" for s in short))
    for tn in names + ["(none)"]:
        print(f"{tn:28s}" + " ".join(f"{confusion[tn][fn]:>10d}" for fn in names + ["(none)"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ident.diagnosis.benchmark")
    parser.add_argument("command", choices=["generate", "run", "conceal"])
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", default="tuning", choices=["tuning", "heldout"])
    parser.add_argument("--case", default=None)
    args = parser.parse_args(argv)
    if args.command == "generate":
        generate(args.out, args.set)
    elif args.command == "conceal":
        for case, seed, scale in case_list(args.set):
            if args.case in (None, case):
                print(f"{case}: max |q_truth - q_nominal| = {concealment(case, seed, scale) * 1e6:.2f} um")
    else:
        return run(args.out, args.set, [args.case] if args.case else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
