"""Multi-axis mismatch diagnosis: a plant with several force inputs and position outputs (a coupled parallel
mechanism in actuator coordinates) under a per-axis or multivariable sampled controller.

The flow is the single-axis one (:mod:`ident.diagnosis.pipeline`) with one more question, *which axis*:

1. refit the nominal parameters that enter the force linearly (masses, viscous friction, gravity; geometry
   stays fixed) in closed loop, every axis's output and force channel weighted by its own noise level;
2. locate the axis: the per-axis inverse-dynamics force residual u_k - (force the nominal model needs for
   the measured motion on axis k), i.e. G^-1 (a_model(x, u) - a_measured) with G = d(acceleration)/du,
   decouples the mechanism (friction on joint 3 moves every actuator but leaves a force residual only on
   joint 3). Each axis's residual RMS is compared with what the refitted model itself leaves when it is
   re-simulated with white encoder noise (the same differentiation of the same noise level); the axis with the
   largest ratio is screened, and where on it (time windows, velocity/position range, frequency) is reported;
3. screen the vocabulary's effects on that axis only (its force subtracted from that axis's input, written in
   that axis's position and velocity states), refit the best ranked, keep one only when it beats the
   parametric-bootstrap null reference (:mod:`ident.diagnosis.evidence`) and lowers that axis's validation
   RMS by the validation rule's margin (``pipeline.VALIDATION_GAIN``); repeat on the axis located next.

Units: SI (s, m, N).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import string
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.build import MODELICA_DIR
from motiontwin.harness.recording import Recording
from motiontwin.ident import outputerror, startvalues
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence, pipeline
from motiontwin.ident.diagnosis.bundle import Bundle, PlantInfo
from motiontwin.ident.diagnosis.plant_roles import PlantRoles, output_map

AUGMENTED_CLASS = pipeline.AUGMENTED_CLASS
LOCATE_REPLICATES = 2       # noise re-simulations for each axis's reference force-residual level
#: after an accepted effect, another round runs only when some axis's force residual still exceeds its noise
#: reference by this factor (the first round always screens, so a parameters-only bundle meets the null test)
NEXT_ROUND_SCORE = 1.5
#: effects that replace the applied input (an input delay) are not offered per axis yet
PER_AXIS_EXCLUDED = ("time_delay",)


@dataclass
class Structure:
    """One multi-axis model structure fitted on the training recording: effects with the axis each acts on."""

    effects: list[effect_models.Effect]   # each renamed for its axis (:func:`on_axis`)
    axes: list[str]                       # the axis (output name) of each effect
    loop: outputerror.Loop
    fit: outputerror.Fit
    bounds: dict[str, tuple[float, float]]
    val_rms: dict[str, float] = field(default_factory=dict)    # per axis [m]
    val_q: np.ndarray | None = None
    evidence: dict = field(default_factory=dict)

    @property
    def placed(self) -> list[tuple[str, effect_models.Effect]]:
        """(axis, effect) pairs."""
        return list(zip(self.axes, self.effects))


def _prefix(axis: str) -> str:
    return f"{axis}_"


def on_axis(effect: effect_models.Effect, roles: PlantRoles) -> effect_models.Effect:
    """``effect`` acting on the axis ``roles``: its parameters and variables prefixed by the axis output
    (``q3_coulomb_Fc``), ``$x``/``$v`` the axis's position and velocity states, ``u`` (the commanded force
    in an equation) the axis's input; the initialiser and the contract keep the effect's own names."""
    prefix = _prefix(roles.output)
    names = [p.name for p in effect.params] + re.findall(r"\bReal\s+(\w+)", effect.declarations)
    pattern = re.compile(r"(?<![\w.])(" + "|".join(map(re.escape, names)) + r"|u)\b") if names else None

    def rename(text: str) -> str:
        if pattern is not None:
            text = pattern.sub(lambda m: roles.input if m.group(1) == "u" else prefix + m.group(1), text)
        return string.Template(text).safe_substitute(x=f"plant.{roles.position}", v=f"plant.{roles.velocity}")

    def initial(ctx: effect_models.Context) -> list[dict[str, float]]:
        return [{prefix + k: v for k, v in start.items()} for start in effect.initial(ctx)]

    def contract(values: dict[str, float], ctx: effect_models.Context) -> dict[str, float]:
        own = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
        return effect.contract({**values, **own}, ctx)

    params = [dataclasses.replace(p, name=prefix + p.name) for p in effect.params]
    return dataclasses.replace(effect, params=params, declarations=rename(effect.declarations),
                               force=rename(effect.force), equations=[rename(e) for e in effect.equations],
                               initial=initial, contract=contract,
                               tracks_position=[prefix + s for s in effect.tracks_position],
                               tracks_force=[prefix + s for s in effect.tracks_force])


def modelica_text(plant: PlantInfo, effects: list[tuple[str, effect_models.Effect]], values: dict[str, float],
                  plant_values: dict[str, float]) -> str:
    """Source of the augmented class: the nominal class as ``plant``, one input and output per axis (the
    plant's own names), every effect's force subtracted from its axis's input."""
    mods = ", ".join(f"{k} = {float(v)!r}" for k, v in plant_values.items())
    listed = ", ".join(f"{e.name} on {axis}" for axis, e in effects) or "no effect"
    lines = [f'model {AUGMENTED_CLASS} "{plant.class_name} augmented by the diagnosis with: {listed}"']
    lines += [f'  input Real {a.input}(unit = "N") "Commanded force of axis {a.output}";' for a in plant.axes]
    lines += [f'  output Real {a.output}(unit = "m") "Measured position of axis {a.output}";' for a in plant.axes]
    lines.append(f'  {plant.class_name} plant({mods}) "Nominal plant, refitted";')
    body = "".join(effect_models._decl(e.params, values) + e.declarations for _, e in effects)
    if body:
        lines.append(body.rstrip("\n"))
    lines.append("equation")
    for a in plant.axes:
        mine = [e for axis, e in effects if axis == a.output]
        delay = next((e for e in mine if e.delays_input), None)
        applied = f"{a.input} - {_prefix(a.output)}delay_a" if delay else a.input
        forces = "".join(f" - ({e.force})" for e in mine if e.force)
        lines.append(f"  plant.{a.input} = {applied}{forces};")
    lines.extend(f"  plant.{name} = {value!r};" for name, value in plant.axes[0].held_inputs.items())
    lines.extend(f"  {eq};" for _, e in effects for eq in e.equations)
    lines.extend(f"  {a.output} = plant.{a.output};" for a in plant.axes)
    lines.append(f"end {AUGMENTED_CLASS};")
    return "\n".join(lines) + "\n"


def write_structure(plant: PlantInfo, effects: list[tuple[str, effect_models.Effect]], values: dict[str, float],
                    folder: Path) -> Path:
    """Write the plant file and the augmented class into ``folder`` (the MotionTwin library is loaded from
    the project's Modelica folder, so a library plant may use other library classes)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plant.mo").write_text(plant.text, encoding="utf-8")
    plant_values = {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")}
    path = folder / f"{AUGMENTED_CLASS}.mo"
    path.write_text(modelica_text(plant, effects, values, plant_values), encoding="utf-8")
    return path


def write_product(plant: PlantInfo, final: "Structure", staging: Path) -> Path:
    """Write the final augmented model into ``staging/augmented_model`` with the MotionTwin library copied
    beside it (self-contained: it loads without the project's library path), and its FMI 2.0 FMU (ME + CS)
    with the fitted start values into ``staging/fmu``; returns the FMU's path relative to ``staging``."""
    from motiontwin.fmus.build import build_fmu

    folder = staging / "augmented_model"
    write_structure(plant, final.placed, final.fit.values, folder)
    shutil.copytree(MODELICA_DIR / "MotionTwin", folder / "MotionTwin", ignore=shutil.ignore_patterns("__pycache__"))
    model = symbolic.build(frontend.load(folder, AUGMENTED_CLASS))
    known = {v.name for v in model.parameters}
    built = build_fmu(model, staging / "fmu", "2.0",
                      start_values={k: v for k, v in final.fit.values.items() if k in known})
    return built.path.relative_to(staging)


def load_structure(folder: Path) -> symbolic.SymbolicModel:
    """The augmented model written by :func:`write_structure`, through the project's front end."""
    return symbolic.build(frontend.load(folder, AUGMENTED_CLASS, (MODELICA_DIR,)))


def axes_signals(plant: PlantInfo) -> list[outputerror.Signals]:
    """The recording columns of every axis."""
    return [outputerror.axis_signals(a.input, a.output) for a in plant.axes]


def _tracking(bundle: Bundle, effects: list[tuple[str, effect_models.Effect]]) -> dict[str, str]:
    """Velocity states start at the slope of the first samples; effect states at the axis's position/force."""
    tracking = {f"plant.{a.velocity}": f"dq:{a.output}" for a in bundle.plant.axes}
    for axis, e in effects:
        tracking.update({s: f"q:{axis}" for s in e.tracks_position})
        tracking.update({s: f"u:{axis}" for s in e.tracks_force})
    return tracking


def nominal_free(bundle: Bundle) -> tuple[list[str], dict[str, tuple[float, float]]]:
    """The nominal parameters refitted: non-zero ones that enter the inverse-dynamics force linearly
    (masses, viscous friction, gravity), bounded to a factor 5 around the start as in the single-axis
    refit; geometry (lengths, offsets), which enters nonlinearly, stays at its value."""
    free, bounds = pipeline._nominal_bounds(bundle, "plant.")
    model = bundle.plant.model
    values = dict(bundle.start)
    rng = np.random.default_rng(1)
    x, _, _ = _states_from(bundle, bundle.train, values)
    idx = rng.choice(x.shape[1], size=min(50, x.shape[1]), replace=False)
    a = rng.normal(0.0, 1.0, (len(bundle.plant.axes), idx.size))
    linear = []
    for name in free:
        plain = name[len("plant."):]
        forces = []
        for factor in (0.5, 1.0, 1.5):
            trial = {**values, plain: values[plain] * factor}
            forces.append(_needed_force(model, bundle, trial, x[:, idx], a))
        curvature = np.max(np.abs(forces[0] - 2 * forces[1] + forces[2]))
        scale = np.max(np.abs(forces[2] - forces[0])) or 1.0
        if scale > 0 and curvature <= 1e-6 * scale and np.max(np.abs(forces[2] - forces[0])) > 0:
            linear.append(name)
    return linear, {n: bounds[n] for n in linear}


def _acceleration_map(model: symbolic.SymbolicModel, bundle: Bundle) -> ca.Function:
    """(x, u, p) -> (velocity-state derivatives, their Jacobian w.r.t. the axes' inputs)."""
    names = [s.name for s in model.states]
    inputs = [v.name for v in model.inputs]
    i_v = [names.index(a.velocity) for a in bundle.plant.axes]
    k_u = [inputs.index(a.input) for a in bundle.plant.axes]
    acc = ca.vertcat(*[model.dx[i] for i in i_v])
    u_axes = ca.vertcat(*[model.u[k] for k in k_u])
    return ca.Function("acc", [model.x, model.u, model.p], [acc, ca.jacobian(acc, model.u)[:, k_u]
                                                               if u_axes.numel() else acc])


def _states_from(bundle: Bundle, rec: Recording, values: dict[str, float],
                 fc: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plant state trajectory (positions and velocities from the filtered outputs, other states at their
    start), accelerations and filtered forces of every axis, in state coordinates."""
    model = bundle.plant.model
    ts = bundle.controller.Ts
    fs = 1 / ts
    fc = fc or min(0.1 * fs, 150.0)
    names = [s.name for s in model.states]
    p = np.array([values[v.name] for v in model.parameters])
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    x = np.tile(x0[:, None], (1, rec.time.size))
    acc, forces = [], []
    for a in bundle.plant.axes:
        gain, offset = output_map(model, a, values)
        pos, vel, accel = startvalues.mirror_derivatives((rec[a.output] - offset) / gain, fs, fc)
        x[names.index(a.position)], x[names.index(a.velocity)] = pos, vel
        acc.append(accel)
        forces.append(startvalues.mirror_derivatives(rec[a.input], fs, fc)[0])
    return x, np.array(acc), np.array(forces)


def _needed_force(model: symbolic.SymbolicModel, bundle: Bundle, values: dict[str, float], x: np.ndarray,
                  acc: np.ndarray) -> np.ndarray:
    """Force each axis needs for the motion (x, acc) under the model at ``values`` (axes x samples)."""
    fn = _acceleration_map(model, bundle)
    p = np.array([values[v.name] for v in model.parameters])
    u = np.zeros((model.u.numel(), x.shape[1]))
    a0, gain = fn.map(x.shape[1])(x, u, p)
    n = len(bundle.plant.axes)
    a0 = np.array(a0)
    gain = np.array(gain).reshape(n, x.shape[1], n).transpose(1, 0, 2)   # map: blocks side by side
    return np.linalg.solve(gain, (acc - a0).T[:, :, None])[:, :, 0].T


@dataclass
class AxisEvidence:
    """The located residual of one axis: the force residual [N] and its reference level from noise."""

    axis: str
    force: np.ndarray
    score: float          # RMS of the force residual / RMS a correct model leaves with the same noise
    context: effect_models.Context


def force_residuals(bundle: Bundle, rec: Recording, values: dict[str, float]) -> np.ndarray:
    """Per-axis inverse-dynamics force residual u_k - (force the nominal model needs) [N], axes x samples."""
    plain = {k[len("plant."):] if k.startswith("plant.") else k: v for k, v in values.items()}
    plain = {v.name: plain.get(v.name, float(v.start)) for v in bundle.plant.model.parameters}
    x, acc, forces = _states_from(bundle, rec, plain)
    return forces - _needed_force(bundle.plant.model, bundle, plain, x, acc)


def locate(bundle: Bundle, current: Structure, weights: outputerror.Weights, seed: int) -> list[AxisEvidence]:
    """Every axis's force residual beyond the one the fitted model's own noise-free free run leaves through the
    same filters (the derivative filter's error on a fast excitation, common to model and data), and its
    ratio to the level that the fitted model re-simulated with white encoder noise leaves (same filters,
    same noise level per axis), best first."""
    rec = bundle.train

    def simulated(noise: np.ndarray | None) -> np.ndarray:
        q, u = outputerror.simulate(current.loop, rec, current.fit.values, noise=noise)
        columns = dict(rec.columns)
        for k, a in enumerate(bundle.plant.axes):
            columns[a.output], columns[a.input] = q[k] + (0.0 if noise is None else noise[k]), u[k]
        return force_residuals(bundle, Recording(rec.time, columns, rec.units, rec.meta), current.fit.values)

    model_own = simulated(None)
    residual = force_residuals(bundle, rec, current.fit.values) - model_own
    rng = np.random.default_rng(seed)
    reference = np.zeros(len(bundle.plant.axes))
    sigma = np.reshape(np.asarray(weights.sigma_q, float), (-1, 1))
    for _ in range(LOCATE_REPLICATES):
        noise = rng.normal(0.0, 1.0, residual.shape) * sigma
        reference += np.mean((simulated(noise) - model_own) ** 2, axis=1)
    reference = np.sqrt(reference / LOCATE_REPLICATES)
    found = []
    for k, a in enumerate(bundle.plant.axes):
        score = float(np.sqrt(np.mean(residual[k] ** 2)) / max(reference[k], 1e-300))
        found.append(AxisEvidence(a.output, residual[k], score, axis_context(bundle, current, k, residual[k])))
    return sorted(found, key=lambda e: -e.score)


def axis_context(bundle: Bundle, current: Structure, k: int, force: np.ndarray) -> effect_models.Context:
    """Recorded ranges and inverse-dynamics signals of axis ``k`` in its state coordinates."""
    ts = bundle.controller.Ts
    roles = bundle.plant.axes[k]
    model = bundle.plant.model
    plain = {v.name: current.fit.values.get("plant." + v.name, float(v.start)) for v in model.parameters}
    gain, offset = output_map(model, roles, plain)
    x, acc, forces = _states_from(bundle, bundle.train, plain)
    names = [s.name for s in model.states]
    pos, vel = x[names.index(roles.position)], x[names.index(roles.velocity)]
    q_all = (np.concatenate([bundle.train[roles.output], bundle.validation[roles.output]]) - offset) / gain
    fn = _acceleration_map(model, bundle)
    p = np.array([plain[v.name] for v in model.parameters])
    _, g = fn(x[:, 0], np.zeros(model.u.numel()), p)
    mass = float(np.linalg.inv(np.array(g))[k, k])
    ctx = effect_models.Context(ts, float(q_all.min()), float(q_all.max()), float(np.max(np.abs(vel))) or 1e-3,
                                mass, position_gain=gain, u=bundle.train[roles.input],
                                duration=float(bundle.train.time[-1] - bundle.train.time[0]))
    ctx.x, ctx.v, ctx.a, ctx.force = pos, vel, acc[k], force
    ctx.udot = np.gradient(forces[k], ts)
    q_sim = current.fit.q_sim[k]
    ctx.resonance_guess = evidence.resonance_guesses(bundle.train[roles.output] - q_sim, ts)
    return ctx


def _models(bundle: Bundle) -> dict:
    if bundle.cache is None:
        bundle.cache = pipeline.LoopCache()
    return bundle.cache


def build(bundle: Bundle, effects: list[tuple[str, effect_models.Effect]], values: dict[str, float], folder: Path,
          n_samples: int, with_jacobian: bool = True,
          min_substeps: int = 1) -> tuple[outputerror.Loop, dict[str, tuple[float, float]]]:
    """Write, load and compile the multi-axis loop of the nominal plant + ``effects`` (cached by structure)."""
    cache = _models(bundle)
    names = tuple(f"{e.name}@{axis}" for axis, e in effects)
    model = cache.models.get(names)
    if model is None:
        write_structure(bundle.plant, effects, values, folder)
        model = cache.models[names] = load_structure(folder)
    free, bounds, all_values = pipeline.structure_parameters(model, [e for _, e in effects], *bundle.nominal_free,
                                                             values)
    substeps = max(min_substeps, outputerror.stable_substeps(model, all_values, bundle.controller.Ts))
    key = ("axes",) + (names, n_samples, substeps, with_jacobian)
    if key not in cache.loops:
        cache.loops[key] = outputerror.build_loop(model, bundle.controller, bundle.plant.axes[0].output, free,
                                                  all_values, n_samples, substeps=substeps,
                                                  tracking=_tracking(bundle, effects), with_jacobian=with_jacobian,
                                                  axes=axes_signals(bundle.plant), initial_sensitivity=False)
    return cache.loops[key].with_values(all_values), bounds


def per_axis_rms(bundle: Bundle, rec: Recording, q: np.ndarray) -> dict[str, float]:
    """RMS of measured minus simulated output per axis [m] (inf when the run diverged)."""
    out = {}
    for k, a in enumerate(bundle.plant.axes):
        err = rec[a.output] - q[k]
        out[a.output] = float(np.sqrt(np.mean(err ** 2))) if np.all(np.isfinite(err)) else math.inf
    return out


def validate(bundle: Bundle, structure: Structure, folder: Path) -> None:
    """Free-run the fitted structure on the validation recording: per-axis RMS in ``val_rms``."""
    loop, _ = build(bundle, structure.placed, structure.fit.values, folder, bundle.validation.time.size,
                    with_jacobian=False, min_substeps=structure.loop.substeps)
    q, _ = outputerror.simulate(loop, bundle.validation, structure.fit.values)
    structure.val_q = q
    structure.val_rms = per_axis_rms(bundle, bundle.validation, q)


def _noise_weights(bundle: Bundle, loop: outputerror.Loop, q: np.ndarray, u: np.ndarray) -> outputerror.Weights:
    ts = bundle.controller.Ts
    qm, um = outputerror.measured(loop, bundle.train, "output"), outputerror.measured(loop, bundle.train, "input")
    return outputerror.Weights(np.array([evidence.noise_level(qm[k] - q[k], ts) for k in range(len(qm))]),
                               np.array([evidence.noise_level(um[k] - u[k], ts) for k in range(len(um))]))


def fit_nominal(bundle: Bundle, work: Path, progress=None) -> tuple[Structure, outputerror.Weights]:
    """Closed-loop refit of the nominal parameters on every axis at once."""
    values = {"plant." + k: v for k, v in bundle.start.items()}
    loop, bounds = build(bundle, [], values, work, bundle.train.time.size)
    q0, u0 = outputerror.simulate(loop, bundle.train)
    for k, a in enumerate(bundle.plant.axes):
        startvalues.check_free_run(q0[k], bundle.train[a.output], bundle.train.time,
                                   f"the nominal closed loop ({bundle.plant.class_name} with the bundle's controller) "
                                   f"on {bundle.recording_path('train')}, axis {a.output}",
                                   {n: loop.values[n] for n in loop.free}, pipeline._divergence_hint(bundle))
    weights = _noise_weights(bundle, loop, q0, u0)
    result = outputerror.fit(loop, bundle.train, weights, bounds, max_nfev=40)
    weights = _noise_weights(bundle, loop, result.q_sim, result.u_sim)
    result = outputerror.fit(loop.with_values(result.values), bundle.train, weights, bounds, max_nfev=15)
    pipeline._log(progress, f"nominal refit ({', '.join(loop.free)}): "
                            f"{pipeline._fmt({k: result.values[k] for k in loop.free})}; rms q {result.rms_q:.3g} m")
    return Structure([], [], loop.with_values(result.values), result, bounds), weights


def fit_candidate(bundle: Bundle, current: Structure, effect: effect_models.Effect, axis: str,
                  ctx: effect_models.Context, weights: outputerror.Weights, folder: Path,
                  max_nfev: int) -> Structure:
    """The current structure plus ``effect`` on ``axis``, fitted from each of its starting points."""
    roles = next(a for a in bundle.plant.axes if a.output == axis)
    placed = on_axis(effect, roles)
    effects = current.placed + [(axis, placed)]
    starts = placed.initial(ctx)
    if max_nfev <= pipeline.SCREEN_NFEV and effect.name not in pipeline.MULTI_START:
        starts = starts[:1]
    base = dict(current.fit.values)
    values = {**base, **{p.name: float(np.mean(p.bounds)) for p in placed.params if not p.fitted}, **starts[0]}
    loop, bounds = build(bundle, effects, values, folder, bundle.train.time.size, min_substeps=current.loop.substeps)
    best = None
    for start in starts:
        clipped = {k: float(np.clip(v, *bounds[k])) for k, v in start.items() if k in bounds}
        result = outputerror.fit(loop, bundle.train, weights, bounds, start={**loop.values, **base, **clipped},
                                 max_nfev=max_nfev)
        if best is None or result.cost < best.cost:
            best = result
    return Structure(current.effects + [placed], current.axes + [axis], loop.with_values(best.values), best, bounds,
                     evidence=dict(current.evidence))


def placed_structure(bundle: Bundle, current: Structure, name: str, axis: str, ctx: effect_models.Context,
                     fit: outputerror.Fit, substeps: int, folder: Path) -> Structure:
    """The structure of a screened candidate (its loop rebuilt here: the compiled library is on disk)."""
    roles = next(a for a in bundle.plant.axes if a.output == axis)
    placed = on_axis(effect_models.VOCABULARY[name](ctx), roles)
    loop, bounds = build(bundle, current.placed + [(axis, placed)], fit.values, folder, bundle.train.time.size,
                         min_substeps=substeps)
    return Structure(current.effects + [placed], current.axes + [axis], loop.with_values(fit.values), fit, bounds,
                     evidence=dict(current.evidence))


def _bootstrap(bundle: Bundle, current: Structure, weights: outputerror.Weights, seed: int) -> np.ndarray:
    noisy = lambda n: outputerror.simulate(current.loop, bundle.train, current.fit.values, noise=n)  # noqa: E731
    return evidence.bootstrap_residuals(noisy, current.fit.q_sim, current.fit.u_sim, weights.sigma_q,
                                        weights.sigma_u, bundle.train.time.size, pipeline.BOOTSTRAP_COUNT, seed=seed)


def candidates(ctx: effect_models.Context, used: set[str]) -> list[str]:
    """The vocabulary's effects offered on an axis (one per family and axis)."""
    offered = {n: factory(ctx) for n, factory in effect_models.VOCABULARY.items() if n not in PER_AXIS_EXCLUDED}
    return [n for n, e in offered.items() if e.applicable and e.family not in used]


def select(bundle: Bundle, nominal: Structure, weights: outputerror.Weights, work: Path,
           progress=None) -> tuple[Structure, list[dict], list[dict]]:
    """Greedy forward selection: locate the axis, screen the effects on it, keep the significant one that
    improves that axis's validation RMS; returns the final structure, the candidate log and the locations."""
    current = nominal
    log: list[dict] = []
    located: list[dict] = []
    used: dict[str, set[str]] = {a.output: set() for a in bundle.plant.axes}
    rounds = 0
    while len(current.effects) < pipeline.MAX_EFFECTS:
        rounds += 1
        ranking = locate(bundle, current, weights, seed=100 + rounds)
        located.append({"round": rounds, "scores": {e.axis: e.score for e in ranking}})
        target = ranking[0]
        axis, ctx = target.axis, target.context
        scores = ", ".join(f"{e.axis} {e.score:.3g}" for e in ranking)
        if rounds > 1 and target.score < NEXT_ROUND_SCORE:
            pipeline._log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                                    f"none above {NEXT_ROUND_SCORE}, done")
            break
        pipeline._log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                                f"screening {axis}")
        null = _bootstrap(bundle, current, weights, rounds)
        base_gain = evidence.projected_gain(current.fit.jacobian, null)
        def fit_one(name: str, c: Structure = current, a: str = axis, x: effect_models.Context = ctx,
                    r: int = rounds) -> Structure:
            return fit_candidate(bundle, c, effect_models.VOCABULARY[name](x), a, x, weights, work / f"r{r}_{name}",
                                 pipeline.SCREEN_NFEV)

        fits = pipeline.screen(bundle, current, candidates(ctx, used[axis]), ctx, weights, work, progress, fit_one)
        screened = {name: placed_structure(bundle, current, name, axis, ctx, fit, substeps, work / f"r{rounds}_{name}")
                    for name, (fit, substeps) in fits.items()}
        order = sorted(screened, key=lambda n: screened[n].fit.cost)
        ranked = pipeline.ranked_with_nested(order, screened)
        trials: dict[str, tuple[Structure, float, float, np.ndarray]] = {}
        for name in ranked:
            trial = refine(bundle, screened[name], weights)
            placed = trial.effects[-1]
            gain = current.fit.cost - trial.fit.cost
            null_gain = evidence.projected_gain(trial.fit.jacobian, null) - base_gain
            threshold = evidence.null_threshold(null_gain, sum(p.fitted for p in placed.params))
            trials[name] = (trial, gain, threshold, null_gain)
            log.append({"round": rounds, "axis": axis, "effect": name, "cost_reduction": gain,
                        "null_threshold": threshold, "evidence_ratio": gain / threshold,
                        "parameters": {p.name: trial.fit.values[p.name] for p in placed.params}})
            pipeline._log(progress, f"  round {rounds} {name} on {axis}: cost -{gain:.4g}, null {threshold:.4g} "
                                    f"(x{gain / threshold:.2f})")
        if not current.val_rms:
            validate(bundle, current, work / f"v{rounds}_current")
        chosen = None
        significant = sorted((n for n, t in trials.items() if t[1] > t[2]), key=lambda n: -trials[n][1])
        for name in significant:
            name = pipeline._simplest(name, trials, null, bundle, work, progress,
                                      check=lambda b, st, f, a=axis: _axis_validation(b, st, f, a))
            trial = trials[name][0]
            validate(bundle, trial, work / f"v{rounds}_{name}")
            before, after = current.val_rms[axis], trial.val_rms[axis]
            ok = after < pipeline.VALIDATION_GAIN * before
            pipeline._log(progress, f"  {name} on {axis}: validation rms {before:.4g} -> {after:.4g} "
                                    f"({'kept' if ok else 'rejected'})")
            for entry in log:
                if entry["round"] == rounds and entry["effect"] == name:
                    entry["validation_rms_before"], entry["validation_rms_after"] = before, after
            if ok:
                chosen = trial
                break
        if chosen is None:
            break
        name = chosen.effects[-1].name
        gain, threshold = trials[name][1:3]
        chosen.evidence[f"{name}@{axis}"] = {
            "axis": axis, "cost_reduction": gain, "null_threshold": threshold,
            "validation_rms_before": current.val_rms[axis], "validation_rms_after": chosen.val_rms[axis],
            "score": target.score, "force_residual": target.force, "context": ctx, "previous_q": current.fit.q_sim,
            "sigma_q": weights.sigma_q}
        used[axis].add(chosen.effects[-1].family)
        current = chosen
    return current, log, located


def _axis_validation(bundle: Bundle, structure: Structure, folder: Path, axis: str) -> float:
    """The validation check of :func:`pipeline._simplest` on one axis: validate and return that axis's RMS."""
    validate(bundle, structure, folder)
    return structure.val_rms[axis]


def refine(bundle: Bundle, structure: Structure, weights: outputerror.Weights) -> Structure:
    """Continue the fit of a screened structure from its values (kept only when the cost falls)."""
    result = outputerror.fit(structure.loop, bundle.train, weights, structure.bounds, start=structure.fit.values,
                             max_nfev=pipeline.MAX_NFEV)
    if result.cost >= structure.fit.cost:
        return structure
    return Structure(structure.effects, structure.axes, structure.loop.with_values(result.values), result,
                     structure.bounds, evidence=structure.evidence)


def run(bundle: Bundle, work: Path, progress=None) -> dict:
    """The whole multi-axis diagnosis in ``work``; returns what the report needs."""
    t0 = time.perf_counter()
    bundle.cache = pipeline.LoopCache()
    for roles in bundle.plant.axes:
        pipeline._log(progress, roles.describe())
    bundle.start = {v.name: float(v.start) for v in bundle.plant.model.parameters} | bundle.plant.parameters
    bundle.nominal_free = nominal_free(bundle)
    nominal, weights = fit_nominal(bundle, work / "nominal", progress)
    validate(bundle, nominal, work / "v_nominal")
    for a in bundle.plant.axes:
        k = [x.output for x in bundle.plant.axes].index(a.output)
        startvalues.check_free_run(nominal.val_q[k], bundle.validation[a.output], bundle.validation.time,
                                   f"the refitted nominal closed loop on {bundle.recording_path('validation')}, "
                                   f"axis {a.output}", {n: nominal.fit.values[n] for n in nominal.loop.free},
                                   pipeline._divergence_hint(bundle))
    final, log, located = select(bundle, nominal, weights, work / "trials", progress)
    if not final.val_rms:
        validate(bundle, final, work / "v_final")
    loop, _ = build(bundle, final.placed, final.fit.values, work / "final", bundle.validation.time.size,
                    with_jacobian=False, min_substeps=final.loop.substeps)
    floor = pipeline.validation_floor(loop, bundle, final.fit.values, weights.sigma_q)
    pipeline._log(progress, f"diagnosis done in {time.perf_counter() - t0:.1f} s")
    return {"bundle": bundle, "nominal": nominal, "final": final, "weights": weights, "log": log,
            "located": located, "validation_floor": floor, "seconds": time.perf_counter() - t0}


def _strip(values: dict[str, float]) -> dict[str, float]:
    return {k[len("plant."):] if k.startswith("plant.") else k: float(v) for k, v in values.items()}


def _effect_entry(bundle: Bundle, final: Structure, axis: str, effect: effect_models.Effect) -> dict:
    from motiontwin.ident.diagnosis import report

    info = final.evidence[f"{effect.name}@{axis}"]
    ctx = info["context"]
    params = effect.contract(final.fit.values, ctx)
    k = [a.output for a in bundle.plant.axes].index(axis)
    ts = bundle.controller.Ts
    location = evidence.locate(info["force_residual"], ctx.v, ctx.x * ctx.position_gain, ts)
    sigma = max(float(np.atleast_1d(info["sigma_q"])[k]), 1e-15)
    previous = info["previous_q"][k]
    location["time_windows"] = evidence.flagged_windows(bundle.train[axis] - previous, bundle.train.time,
                                                        sigma, ts)[:10]
    ratio = info["cost_reduction"] / info["null_threshold"]
    text = (f"{effect.explanation} Located on axis {axis}: its inverse-dynamics force residual is "
            f"{info['score']:.3g} times what a correct model leaves with the same encoder noise. Adding the effect "
            f"there lowers the noise-weighted output-error cost by {info['cost_reduction']:.4g}, {ratio:.1f} times "
            f"the 99.9 % bootstrap level, and the validation RMS of {axis} falls from "
            f"{info['validation_rms_before']:.3g} m to {info['validation_rms_after']:.3g} m.")
    return {"name": effect.name, "axis": axis, "parameters": {n: float(v) for n, v in params.items()},
            "units": {n: report.CONTRACT_UNITS.get(n, "") for n in params},
            "location": location, "location_text": report.location_text(location), "explanation": text,
            "evidence": {n: info[n] for n in ("cost_reduction", "null_threshold", "validation_rms_before",
                                              "validation_rms_after", "score")}}


@dataclass
class MultiAxisDiagnosis:
    """The outcome of a multi-axis diagnosis (the fields of :class:`pipeline.Diagnosis`, plus ``axes``:
    the axis of each effect, and ``validation["per_axis"]``)."""

    effects: list[str]
    axes: list[str]
    parameters: dict[str, float]
    nominal_parameters: dict[str, float]
    validation: dict
    result: dict = field(repr=False)

    @classmethod
    def from_result(cls, result: dict) -> "MultiAxisDiagnosis":
        bundle, nominal, final = result["bundle"], result["nominal"], result["final"]
        floor = np.atleast_1d(result["validation_floor"])
        per_axis = {a.output: {"nominal_rms": nominal.val_rms[a.output], "augmented_rms": final.val_rms[a.output],
                               "noise_floor_rms": float(floor[k] if floor.size > 1 else floor[0])}
                    for k, a in enumerate(bundle.plant.axes)}
        rec = bundle.validation

        def overall(q: np.ndarray) -> float:
            err = np.array([rec[a.output] - q[k] for k, a in enumerate(bundle.plant.axes)])
            return float(np.sqrt(np.mean(err ** 2)))

        validation = {"nominal_rms": overall(nominal.val_q), "augmented_rms": overall(final.val_q),
                      "noise_floor_rms": float(np.sqrt(np.mean(floor ** 2))), "per_axis": per_axis}
        return cls([e.name for e in final.effects], list(final.axes),
                   _strip(final.fit.values), _strip(nominal.fit.values), validation, result)

    def document(self, out: Path) -> dict:
        """diagnosis.json's content."""
        from motiontwin.ident.diagnosis import report

        result = self.result
        bundle, final = result["bundle"], result["final"]
        entries = [_effect_entry(bundle, final, axis, e) for axis, e in final.placed]
        return report._jsonable({
            "effects": entries, "validation": self.validation, "nominal_parameters": self.nominal_parameters,
            "augmented_parameters": self.parameters,
            "augmented_model": str(out / "augmented_model" / f"{AUGMENTED_CLASS}.mo"), "augmented_fmu": None,
            "noise": {"sigma_q": dict(zip([a.output for a in bundle.plant.axes],
                                          np.atleast_1d(result["weights"].sigma_q).tolist())),
                      "sigma_u": dict(zip([a.output for a in bundle.plant.axes],
                                          np.atleast_1d(result["weights"].sigma_u).tolist()))},
            "location": result["located"], "candidates": result["log"],
            "nominal_free": list(bundle.nominal_free[0]), "runtime_s": round(result["seconds"], 2),
            "plant_roles": {a.output: a.as_dict() for a in bundle.plant.axes}})

    def write(self, folder: str | os.PathLike) -> dict:
        """Write diagnosis.json, validation_prediction.csv, report.md/html and the augmented Modelica model
        into ``folder`` (staged beside it, then moved in); returns the diagnosis.json document."""
        from motiontwin.ident.diagnosis import report

        out = Path(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
        result = self.result
        bundle = result["bundle"]
        doc = self.document(out)
        with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}.work-") as tmp:
            staging = Path(tmp) / "out"
            doc["augmented_fmu"] = str(out / write_product(bundle.plant, result["final"], staging))
            rec = bundle.validation
            names = [a.output for a in bundle.plant.axes]
            table = np.column_stack([rec.time] + [np.column_stack([rec[n], result["nominal"].val_q[k],
                                                                   result["final"].val_q[k]])
                                                  for k, n in enumerate(names)])
            header = ",".join(["time"] + [f"{n}_{kind}" for n in names for kind in ("measured", "nominal",
                                                                                    "augmented")])
            np.savetxt(staging / "validation_prediction.csv", table, delimiter=",", fmt="%.17g", header=header,
                       comments="")
            (staging / "diagnosis.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")
            markdown = report_markdown(doc, bundle)
            (staging / "report.md").write_text(markdown, encoding="utf-8")
            (staging / "report.html").write_text(report.html_from_markdown(markdown), encoding="utf-8")
            pipeline._publish(staging, out)
        return doc


def report_markdown(doc: dict, bundle: Bundle) -> str:
    """report.md of a multi-axis diagnosis: effects by axis, per-axis validation, where it was located."""
    lines = [f"# Mismatch diagnosis: {bundle.plant.class_name}, {len(bundle.plant.axes)} axes", ""]
    if doc["effects"]:
        lines.append("## Effects found")
        for e in doc["effects"]:
            params = ", ".join(f"{k} = {v:.4g} {e['units'].get(k, '')}".rstrip() for k, v in e["parameters"].items())
            lines += ["", f"### {e['name']} on axis {e['axis']}", "", f"Parameters: {params}.", "",
                      e["explanation"], "", e["location_text"]]
    else:
        lines += ["## No effect found", "", "Only the nominal parameters were off: no candidate effect on the "
                  "located axes beat the bootstrap null reference and improved validation."]
    lines += ["", "## Validation RMS per axis", "", "| axis | nominal [m] | augmented [m] | noise floor [m] |",
              "|---|---|---|---|"]
    for axis, v in doc["validation"]["per_axis"].items():
        lines.append(f"| {axis} | {v['nominal_rms']:.3g} | {v['augmented_rms']:.3g} | {v['noise_floor_rms']:.3g} |")
    lines += ["", "## Location (force residual / noise reference per axis, each round)", ""]
    for entry in doc["location"]:
        lines.append(f"- round {entry['round']}: " + ", ".join(f"{k} {v:.3g}" for k, v in entry["scores"].items()))
    lines += ["", "## Parameters", "", "| parameter | nominal refit | augmented refit |", "|---|---|---|"]
    for name, value in doc["augmented_parameters"].items():
        nominal = doc["nominal_parameters"].get(name)
        lines.append(f"| {name} | {'' if nominal is None else f'{nominal:.6g}'} | {value:.6g} |")
    lines += ["", f"Augmented Modelica model: `{doc['augmented_model']}` (self-contained: the MotionTwin library "
              f"is copied beside it); its FMU (FMI 2.0, ME + CS, the fitted start values): `{doc['augmented_fmu']}`. "
              f"Runtime {doc['runtime_s']} s.", ""]
    return "\n".join(lines)
