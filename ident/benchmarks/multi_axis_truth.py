"""Cheap multi-axis bundles whose truth is simulated by CasADi: the diagnosis' own augmented model with the
true effects on their axes (the ``MotionTwin.Effects`` force laws through the project's front end), RK4
with 8 substeps per sample, white encoder noise fed back through the controller, no quantisation. The
multi-axis counterpart of ``benchmarks.truth.casadi_truth``, for the decision tests and the budget benchmark until
the FMU-truth generator exists. Units: SI (s, m, N).
"""
from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from motiontwin.harness.recording import atomic_write_texts, make_recording, write_recording
from motiontwin.ident import outputerror
from motiontwin.ident.controller import Controller
from motiontwin.ident.benchmarks import single_axis as benchmark
from motiontwin.ident.benchmarks.independent_laws import coloured_noise
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import empirical
from motiontwin.ident.diagnosis import structure
from motiontwin.ident.diagnosis.bundle import read_axes_controller, read_axes_plant
from motiontwin.ident.diagnosis.plant_roles import output_rate

#: a small coupled plant for tests and examples: two carriages with inertial (mc) and elastic (kc) coupling
COUPLED2_TEXT = '''model Coupled2 "Two carriages with inertial and elastic coupling"
  parameter Real m1(unit = "kg", min = 1e-6) = 2.0 "Mass of carriage 1";
  parameter Real m2(unit = "kg", min = 1e-6) = 3.0 "Mass of carriage 2";
  parameter Real mc(unit = "kg", min = 0) = 0.6 "Inertial coupling";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping of each carriage";
  parameter Real kc(unit = "N/m", min = 0) = 2000 "Coupling spring";
  input Real u1(unit = "N");
  input Real u2(unit = "N");
  output Real q1(unit = "m");
  output Real q2(unit = "m");
  Real x1(unit = "m", start = 0.01, fixed = true);
  Real x2(unit = "m", start = 0.02, fixed = true);
  Real v1(unit = "m/s", start = 0, fixed = true);
  Real v2(unit = "m/s", start = 0, fixed = true);
equation
  der(x1) = v1;
  der(x2) = v2;
  m1*der(v1) + mc*der(v2) = u1 - d*v1 - kc*(x1 - x2);
  mc*der(v1) + m2*der(v2) = u2 - d*v2 - kc*(x2 - x1);
  q1 = x1;
  q2 = x2;
end Coupled2;
'''
COUPLED2_AXES = [{"input": "u1", "output": "q1"}, {"input": "u2", "output": "q2"}]
CHEUNG_AXES = [{"input": f"u{k}", "output": f"q{k}"} for k in (1, 3, 5, 7)]
#: the Hexapod in leg coordinates: leg forces in, leg lengths (inverse kinematics of the pose states) out
HEXAPOD_AXES = [{"input": f"tau{j}", "output": f"L{j}"} for j in range(1, 7)]
#: the Hexapod's refitted parameters in the examples: the platform mass and the legs' viscous friction (its
#: Coulomb friction, gravity and geometry are known), so that a concealed leg friction stays concealed
HEXAPOD_FREE = ["mE"] + [f"cv{j}" for j in range(1, 7)]
#: the process force noise of the ``_process`` examples: white, first-order coloured [N] and its time constant [s]
EXAMPLE_PROCESS = (0.05, 0.05, 0.05)
PREROLL = 0.5            # s at the first reference before the recording starts (integrators settle)
SUBSTEPS = 8


def quadratic_drag(ctx: effect_models.Context) -> effect_models.Effect:
    """A force outside the catalogue: drag c*v*|v| (the parameter ``empirical_c1`` [N s^2/m^2])."""
    drag = next(term for term in empirical.default_library() if term.name == "v*|v|")
    return empirical.as_effect(empirical.EmpiricalForce([drag], np.array([1.0]), 0.0, 0.0, 0.0, 1e-3), ctx)


#: truth effects outside the vocabulary, by name
OUTSIDE = {"quadratic_drag": quadratic_drag}


@dataclass
class TrueEffect:
    """An effect of the truth: vocabulary (or ``OUTSIDE``) name, axis (output name), parameters (the effect's own
    names)."""

    name: str
    axis: str
    parameters: dict[str, float]


def pid_document(ts: float, mass: float, bandwidth: float) -> dict:
    """The single-axis benchmark's PID (:func:`benchmark.pid_controller`) as its experiment.json object."""
    return benchmark.controller_json(benchmark.pid_controller(ts, mass, bandwidth))


def references(outputs: list[str], centres: dict[str, float], duration: float, ts: float, stroke: float,
               rng: np.random.Generator) -> np.ndarray:
    """Smooth point-to-point moves of every axis (cosine profiles, independent targets and durations), so
    that each axis moves in both directions at several speeds: axes x samples."""
    n = int(round(duration / ts))
    out = np.zeros((len(outputs), n))
    for k, name in enumerate(outputs):
        pos, now = centres[name], 0.1
        r = np.full(n, pos)
        while now < duration - 0.3:
            target = centres[name] + stroke * rng.uniform(-0.5, 0.5)
            dur = min(rng.uniform(0.15, 0.6), duration - 0.1 - now)
            i0, i1 = int(now / ts), int((now + dur) / ts)
            s = (1 - np.cos(np.pi * np.linspace(0, 1, max(i1 - i0, 1)))) / 2
            r[i0:i1] = pos + (target - pos) * s
            r[i1:] = target
            pos = target
            now += dur + rng.uniform(0.05, 0.2)
        out[k] = r
    return out


def write_bundle(folder: Path, plant_doc: dict, controller_doc: dict, effects: list[TrueEffect],
                 train_s: float, validation_s: float, seed: int, noise_std: float = 1e-8,
                 stroke: float = 0.004, plant_text: str | None = None,
                 true_parameters: dict[str, float] | None = None,
                 process: tuple[float, float, float] = (0.0, 0.0, 0.05)) -> dict:
    """Write a multi-axis bundle (experiment.json, train.csv, validation.csv, truth.json) into ``folder``;
    returns the truth document. ``plant_doc``: experiment.json's plant object (with ``axes``; its
    ``parameters`` are the diagnosis' start values, not the truth's); with ``plant_text`` it is written as
    plant.mo. ``true_parameters``: the truth's plant parameters (default: the Modelica values). ``process``:
    force noise on every axis's plant input, held over each sample and not in the recorded force (white
    standard deviation, first-order coloured standard deviation [N], its time constant [s])."""
    folder.mkdir(parents=True, exist_ok=True)
    if plant_text is not None:
        (folder / "plant.mo").write_text(plant_text, encoding="utf-8")
        plant_doc = {**plant_doc, "modelica": "plant.mo"}
    plant = read_axes_plant(plant_doc, folder, "truth plant")
    ctrl: Controller = read_axes_controller(controller_doc, "truth controller", plant.axes)
    ts = ctrl.Ts
    values = {"plant." + v.name: float(v.start) for v in plant.model.parameters}
    values.update({"plant." + k: float(v) for k, v in (true_parameters or {}).items()})
    p = np.array([values["plant." + v.name] for v in plant.model.parameters])
    x0 = np.array(ca.Function("x0", [plant.model.p], [plant.model.x0()])(p)).ravel()
    names = [s.name for s in plant.model.states]
    out = ca.Function("y", [plant.model.x, plant.model.p], [ca.vertcat(*[output_rate(plant.model, a.output)[0]
                                                                           for a in plant.axes])])
    at_start = np.array(out(x0, p)).ravel()
    centres = {a.output: float(at_start[k] if a.expression else x0[names.index(a.position)])
               for k, a in enumerate(plant.axes)}
    placed = []
    ctx = effect_models.Context(ts, -1.0, 1.0, 0.2, 1.0)
    for true in effects:
        roles = next(a for a in plant.axes if a.output == true.axis)
        factory = effect_models.VOCABULARY.get(true.name) or OUTSIDE[true.name]
        effect = structure.on_axis(factory(ctx), roles, plant.model)
        placed.append((true.axis, effect))
        values.update({p.name: float(np.mean(p.bounds)) for p in effect.params})
        values.update({augmented.axis_prefix(true.axis) + k: float(v) for k, v in true.parameters.items()})
    rng = np.random.default_rng(seed)
    outputs = [a.output for a in plant.axes]
    with tempfile.TemporaryDirectory(prefix="mt-truth-") as tmp:
        augmented.write_axes_structure(plant, placed, values, Path(tmp))
        model = augmented.load_structure(Path(tmp))
    signals = structure.axes_signals(plant)
    pre = int(round(PREROLL / ts))
    parts = {}
    for part, duration in (("train", train_s), ("validation", validation_s)):
        r = references(outputs, centres, duration, ts, stroke, rng)
        r = np.hstack([np.repeat(r[:, :1], pre, axis=1), r])
        n = r.shape[1]
        columns = {}
        for k, sig in enumerate(signals):
            columns.update({sig.reference: r[k], sig.input: np.zeros(n), sig.output: np.full(n, r[k, 0])})
        rec = make_recording(np.arange(n) * ts, columns)
        loop = outputerror.build_loop(model, ctrl, outputs[0], [], values, n, substeps=SUBSTEPS,
                                      with_jacobian=False, axes=signals)
        noise = rng.normal(0.0, noise_std, (len(outputs), n))
        force = np.array([process[0] * rng.standard_normal(n)
                          + (coloured_noise(n, process[1], process[2], ts, rng) if process[1] else 0.0)
                          for _ in outputs])
        if np.any(force):
            rec = make_recording(rec.time, {**rec.columns, **{sig.disturbance: force[k]
                                                              for k, sig in enumerate(signals)}})
        q, u = outputerror.simulate(loop, rec, values, noise=noise)
        u = u - force       # the recorded force is the controller's command
        if part == "validation":    # what no model can predict: the recording against the noise-free truth
            clean, _ = outputerror.simulate(loop, make_recording(rec.time, columns), values)
            floor = np.sqrt(np.mean((q[:, pre:] + noise[:, pre:] - clean[:, pre:]) ** 2, axis=1))
        data = {}
        for k, sig in enumerate(signals):
            data.update({sig.reference: r[k, pre:], sig.input: u[k, pre:], sig.output: q[k, pre:] + noise[k, pre:]})
        forces = {sig.input for sig in signals}
        parts[part] = make_recording(np.arange(n - pre) * ts, data, {c: ("N" if c in forces else "m") for c in data})
    for part, rec in parts.items():
        write_recording(folder / f"{part}.csv", rec)
    experiment = {"plant": plant_doc, "controller": controller_doc,
                  "recordings": {"train": "train.csv", "validation": "validation.csv"}}
    truth = {"effects": [{"name": e.name, "axis": e.axis, "parameters": e.parameters} for e in effects],
             "plant_parameters": {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")},
             "noise_std": noise_std, "process_noise": dict(zip(("white", "coloured", "tau"), process)), "seed": seed,
             "floor_rms": dict(zip(outputs, floor.tolist()))}
    atomic_write_texts({folder / "experiment.json": json.dumps(experiment, indent=1),
                        folder / "truth.json": json.dumps(truth, indent=1)})
    return truth


def example(folder: Path, case: str, train_s: float, validation_s: float, ts: float = 5e-4) -> dict:
    """Write one of the example bundles: ``coupled2_coulomb_q2`` (Coulomb friction 0.3 N on q2 of the coupled
    two-carriage plant, start values m1 = 2.3 kg and d = 8 N.s/m against the true 2 and 10),
    ``coupled2_params_only`` (the same without the friction) or ``cheung_coulomb_q5`` (Coulomb friction 0.5 N
    on q5 of the CheungManipulator library class, c_v starting at 4 against the true 5),
    ``hexapod_coulomb_L3`` (the library Hexapod in leg coordinates whose leg 3 has 15 N more Coulomb friction
    than the nominal model's Table II value: the plant's own friction law, not the diagnosis' effect code;
    mE starting at 11.5 kg against the true 10.2) or ``hexapod_params_only`` (the same without the extra
    friction). Hexapod cases take ``ts`` = 1e-3 (1 kHz). The two-carriage cases with the suffix ``_process``
    (``coupled2_coulomb_q2_process``, ``coupled2_params_only_process``) add ``EXAMPLE_PROCESS`` force noise to
    both carriages."""
    if case.startswith("coupled2"):
        controller = {"kind": "per_axis", "axes": [pid_document(ts, 2.0, 60.0), pid_document(ts, 3.0, 60.0)]}
        plant = {"class": "Coupled2", "axes": COUPLED2_AXES, "parameters": {"m1": 2.3, "d": 8.0}}
        process = EXAMPLE_PROCESS if case.endswith("_process") else (0.0, 0.0, 0.05)
        effects = ([TrueEffect("coulomb_friction", "q2", {"coulomb_Fc": 0.3, "coulomb_v_eps": 1e-4})]
                   if case.removesuffix("_process") == "coupled2_coulomb_q2" else [])
        return write_bundle(folder, plant, controller, effects, train_s, validation_s, seed=3,
                            plant_text=COUPLED2_TEXT, process=process)
    if case == "cheung_coulomb_q5":
        controller = {"kind": "per_axis", "axes": [pid_document(ts, 1.2, 40.0) for _ in CHEUNG_AXES]}
        plant = {"class": "MotionTwin.Plants.CheungManipulator", "axes": CHEUNG_AXES, "parameters": {"c_v": 4.0}}
        effect = TrueEffect("coulomb_friction", "q5", {"coulomb_Fc": 0.5, "coulomb_v_eps": 1e-4})
        return write_bundle(folder, plant, controller, [effect], train_s, validation_s, seed=16)
    if case.startswith("hexapod"):
        controller = {"kind": "per_axis", "axes": [pid_document(ts, 33.0, 10.0) for _ in HEXAPOD_AXES]}
        plant = {"class": "MotionTwin.Plants.Hexapod", "axes": HEXAPOD_AXES, "parameters": {"mE": 11.5},
                 "free": HEXAPOD_FREE}
        extra = {"rc3": 20.1528 + 15.0} if case == "hexapod_coulomb_L3" else {}
        return write_bundle(folder, plant, controller, [], train_s, validation_s, seed=24, stroke=0.006,
                            true_parameters=extra)
    raise ValueError(f"unknown example {case!r}; known: coupled2_coulomb_q2, coupled2_params_only (each also with "
                     f"_process), cheung_coulomb_q5, hexapod_coulomb_L3, hexapod_params_only")

