"""The model structures of a diagnosis: the fitted :class:`ModelFit`, the augmented model of the nominal
plant + effects written, loaded and compiled once per structure (:class:`LoopCache`), its free parameters and
bounds, its validation free run and the validation noise floor. Units: SI (s, m, N)."""
from __future__ import annotations

import dataclasses
import math
import re
import string
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import axis_kinematics
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.augmented import (AUGMENTED_CLASS, axis_prefix, load_augmented, load_structure,
                                                  load_written, write_axes_structure, write_structure)
from motiontwin.ident.diagnosis.bundle import Bundle, PlantInfo
from motiontwin.ident.diagnosis.noise import Process, noisy_simulator
from motiontwin.ident.diagnosis.plant_roles import PlantRoles
from motiontwin.ident.diagnosis.workers import map_jobs

FLOOR_REPLICATES = 5         # noise re-simulations for the validation noise floor
ESTIMATION_NFEV = 6           # free runs of each replicate's refit in estimation_rms


@dataclass
class ModelFit:
    """One model structure fitted on the training recording: the effects added to the nominal plant (several
    axes: each renamed for the axis ``axes`` names, :func:`on_axis`), the compiled loop, the fit and its bounds,
    and the validation free run (``val_rms`` [m] over every axis, ``val_axes`` per axis of several; the force
    channel's RMS, recorded minus simulated force [N], in ``val_force``, per axis of several in
    ``val_force_axes``; NaN for an unknown controller, whose observer does not simulate the recorded force)."""

    effects: list[effect_models.Effect]
    loop: outputerror.Loop
    fit: outputerror.Fit
    bounds: dict[str, tuple[float, float]]
    folder: Path | None = None
    val_rms: float = math.nan
    val_q: np.ndarray | None = None
    evidence: dict = field(default_factory=dict)
    axes: list[str] = field(default_factory=list)
    val_axes: dict[str, float] = field(default_factory=dict)
    start_cost: float = math.nan   # training cost of a candidate at its vanishing point (the model it extends)
    val_force: float = math.nan
    val_force_axes: dict[str, float] = field(default_factory=dict)
    val_force_error: np.ndarray | None = None   # recorded minus simulated force on validation [N], (n_axes, N)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    @property
    def placed(self) -> list[tuple[str, effect_models.Effect]]:
        """(axis, effect) pairs of a multi-axis structure."""
        return list(zip(self.axes, self.effects))

    def axis_rms(self, axis: str | None) -> float:
        """The validation RMS that decides on ``axis`` [m] (None: the one axis)."""
        return self.val_rms if axis is None else self.val_axes[axis]

    def axis_force_rms(self, axis: str | None) -> float:
        """The validation RMS of the force channel on ``axis`` [N] (None: the one axis)."""
        return self.val_force if axis is None else self.val_force_axes.get(axis, math.nan)

    @property
    def validated(self) -> bool:
        return not math.isnan(self.val_rms)


def _nominal_bounds(bundle: Bundle, prefix: str = "") -> tuple[list[str], dict[str, tuple[float, float]]]:
    """The nominal parameters the refit moves (``plant.free``, zero ones included, else every non-zero one)
    and their physical bounds: the plant's Modelica min/max (none where it declares none), never a window
    around the start value."""
    free, bounds = [], {}
    listed = bundle.plant.free
    for var in bundle.plant.model.parameters:
        value = float(bundle.start.get(var.name, var.start))
        if (listed is not None and var.name not in listed) or (listed is None and value == 0):
            continue
        free.append(prefix + var.name)
        bounds[prefix + var.name] = (float(var.min), float(var.max))
    return free, bounds


def evidence_key(name: str, axis: str | None) -> str:
    """An effect's entry in a structure's evidence: its name (several axes: ``name@axis``)."""
    return name if axis is None else f"{name}@{axis}"


def _log(progress, message: str) -> None:
    if progress:
        progress(message)


def _fmt(values: dict[str, float]) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in values.items())


def _moving_start(bundle: Bundle, prefix: str = "") -> dict[str, str]:
    """The velocity state starts at the slope of the first samples (a loop may be moving at t = 0)."""
    return {prefix + bundle.plant.velocity_state: "dq"}


@dataclass
class LoopCache:
    """Compiled closed loops of one diagnosis, by structure: the effect names, the number of samples, the
    RK4 substeps and whether the Jacobian is compiled. Parameter values are inputs of a compiled loop, so
    a structure is compiled once however often it is refitted, validated or re-screened."""

    loops: dict[tuple, outputerror.Loop] = field(default_factory=dict)
    models: dict[tuple[str, ...], object] = field(default_factory=dict)


def structure_parameters(model, effects: list[effect_models.Effect], free: list[str],
                         bounds: dict[str, tuple[float, float]], values: dict[str, float]
                         ) -> tuple[list[str], dict[str, tuple[float, float]], dict[str, float]]:
    """Free parameters and bounds of a structure (the nominal ones, then each effect's fitted ones) and the
    values of every parameter of its ``model`` (``values`` over the Modelica start values)."""
    free, bounds = list(free), dict(bounds)
    for effect in effects:
        for p in effect.params:
            if p.fitted:
                free.append(p.name)
                bounds[p.name] = p.bounds
    all_values = {v.name: float(v.start) for v in model.parameters}
    all_values.update({k: v for k, v in values.items() if k in all_values})
    return free, bounds, all_values


def start_states(bundle: Bundle, model: symbolic.SymbolicModel) -> dict[str, list[int] | None]:
    """``build_loop``'s ``initial_states`` and ``shift_states`` for the diagnosis's loops of ``model`` (the
    plant, or an augmented model whose plant states are prefixed "plant."): the states whose start the fits
    estimate (``outputerror.fit``'s ``estimate_start``), so that the loops differentiate the start of these only,
    one free run less per Jacobian for every other state. A known controller: its own state (priced by its
    relation; none on several axes). An unknown controller: the plant's position and velocity, the predictor's
    start, which the first noisy samples would fix with a transient of about 1 / (2 pi bandwidth) that a slow
    observer leaves long enough for an effect to take it up (a backlash named on a parameters-only bundle at
    3.3 Hz, docs/diagnose.md)."""
    if bundle.observer is not None:
        names = [v.name for v in model.states]
        prefix = "" if bundle.plant.position_state in names else "plant."
        plant = [names.index(prefix + s) for s in (bundle.plant.position_state, bundle.plant.velocity_state)]
        return {"initial_states": plant, "shift_states": plant}
    if bundle.multi_axis or bundle.controller is None:
        return {"initial_states": [], "shift_states": None}
    nx = model.x.numel()
    return {"initial_states": list(range(nx, nx + bundle.controller.n_states)), "shift_states": None}


def build_structure(bundle: Bundle, effects: list[effect_models.Effect], values: dict[str, float], folder: Path,
                    n_samples: int, with_jacobian: bool = True, min_substeps: int = 1,
                    substeps: int | None = None, only: tuple[str, ...] | None = None
                    ) -> tuple[outputerror.Loop, dict[str, tuple[float, float]]]:
    """Write and load the augmented model with ``effects`` and compile its loop (at least ``min_substeps``
    RK4 steps per sample, so that structures compared with each other share the integration accuracy).
    A structure already compiled with the same samples/substeps is reused from ``bundle.cache`` (one
    :class:`LoopCache` per diagnosis, so concurrent or repeated diagnoses share nothing). ``only``: the loop
    differentiates these free parameters alone and no start state (:func:`screen.score_test`'s effect columns)."""
    cache: LoopCache = bundle.cache
    names = tuple(e.name for e in effects)
    model = cache.models.get(names)
    if model is None:
        model = cache.models[names] = load_written(
            lambda where, written: write_structure(bundle.plant, effects, written, where),
            lambda where: load_augmented(where, AUGMENTED_CLASS), values, folder)
    free, bounds, all_values = structure_parameters(model, effects, *_nominal_bounds(bundle, "plant."), values)
    tracking = {s: "q" for e in effects for s in e.tracks_position} | _moving_start(bundle, "plant.")
    tracking.update({s: "u" for e in effects for s in e.tracks_force})
    min_substeps = max([min_substeps] + [e.min_substeps for e in effects])
    substeps = substeps or max(min_substeps, outputerror.stable_substeps(model, all_values, bundle.controller.sample_time))
    key = (names, n_samples, substeps, with_jacobian, only)
    if key not in cache.loops:
        starts = start_states(bundle, model)
        if only is not None:
            free, starts = [n for n in free if n in only], {**starts, "initial_states": []}
        cache.loops[key] = outputerror.build_loop(model, bundle.controller, "q",
                                                  free, all_values, n_samples, substeps=substeps, tracking=tracking,
                                                  with_jacobian=with_jacobian, **starts)
    return cache.loops[key].with_values(all_values), bounds


def validate(bundle: Bundle, structure: ModelFit, folder: Path) -> None:
    """Free-run the fitted structure on the validation recording; sets ``val_rms`` and ``val_q``."""
    rec = bundle.validation
    if structure.effects or structure.folder is not None:
        loop, _ = build_structure(bundle, structure.effects, structure.fit.values, folder, rec.time.size,
                                  with_jacobian=False, min_substeps=structure.loop.substeps)
    else:
        model = bundle.plant.model
        loop = outputerror.build_loop(model, bundle.controller, bundle.plant.output_name, structure.loop.free,
                                      structure.fit.values, rec.time.size, with_jacobian=False,
                                      min_substeps=structure.loop.substeps, input_name=bundle.plant.input_name,
                                      tracking=_moving_start(bundle),
                                      shift_states=start_states(bundle, model)["shift_states"])
    q, u = outputerror.simulate(loop, rec, structure.fit.values,
                                shift=validation_shift(bundle, loop, structure.fit))
    structure.val_q = q
    structure.val_rms = _rms(rec["q"] - q)
    if bundle.observer is None:     # an unknown controller's observer does not simulate the recorded force
        error = outputerror.measured(loop, rec, "input") - u
        structure.val_force_error, structure.val_force = np.atleast_2d(error), _rms(error)


def _rms(err: np.ndarray) -> float:
    """RMS of ``err``; inf when the free run diverged."""
    return float(np.sqrt(np.mean(err ** 2))) if np.all(np.isfinite(err)) else math.inf


def validation_shift(bundle: Bundle, loop: outputerror.Loop, fit: outputerror.Fit) -> np.ndarray | None:
    """The controller's start state on the validation recording estimated as the refits estimate it on the
    training recording (both channels over the whole run and the controller's relation, weighted by the
    noise levels of ``fit``), so that neither run carries a start state fixed by its first noisy samples
    (issue 23); several axes from where the controller's relation on the validation recording puts it
    (:func:`outputerror.relation_shift`, also without ``fit.weights``). An unknown controller: the predictor's
    plant start, from both channels of the validation run as the refits estimate it on the training run."""
    start = outputerror.relation_shift(loop, bundle.validation) if loop.axes else None
    if fit.weights is None:
        return start
    return outputerror.start_shift(loop, bundle.validation, loop.values, fit.weights, start=start)


def validation_floor(loop: outputerror.Loop, bundle: Bundle, values: dict[str, float], sigma_q: float | np.ndarray,
                     count: int = FLOOR_REPLICATES, process: Process | None = None) -> float | np.ndarray:
    """RMS of measured minus free-run q that the fitted model itself leaves on the validation excitation
    [m]: :func:`floor_rms` on the validation recording. No model can bring the validation RMS below this
    floor, so the improvement is also reported above it."""
    return floor_rms(loop, bundle.validation, values, sigma_q, process, count)


def floor_rms(loop: outputerror.Loop, rec: Recording, values: dict[str, float], sigma_q: float | np.ndarray,
              process: Process | None = None, count: int = FLOOR_REPLICATES) -> float | np.ndarray:
    """RMS of ``rec``'s q minus the free run that a correct model leaves [m]: the model re-simulated with white
    encoder noise of the estimated level fed back through the controller and the process force noise
    ``process`` (:mod:`noise`) acting on the plant: the noise and its closed-loop echo, which no free-run
    simulation can predict. A multi-axis loop takes one encoder noise level and one process noise per axis (a
    tuple) and returns one floor per axis."""
    return floors(loop, rec, values, sigma_q, process, count)[0]


def floors(loop: outputerror.Loop, rec: Recording, values: dict[str, float], sigma_q: float | np.ndarray,
           process: Process | None = None, count: int = FLOOR_REPLICATES,
           force_noise: float = 0.0) -> tuple[float | np.ndarray, float | np.ndarray]:
    """The floors of both channels from the same replicates: :func:`floor_rms`, and that of the recorded force
    [N], the replicates' commanded force (the controller's answer to the encoder and process noise) plus white
    measurement noise of standard deviation ``force_noise`` (:func:`noise.force_measurement`)."""
    q_free, u_free = outputerror.simulate(loop, rec, values)
    simulate = noisy_simulator(loop, rec, values, process)
    rng = np.random.default_rng(0)
    power, force = [], []
    per_axis = np.ndim(sigma_q) > 0
    for _ in range(count):
        if per_axis:
            noise = rng.normal(0.0, 1.0, (np.size(sigma_q), rec.time.size)) * np.reshape(sigma_q, (-1, 1))
        else:
            noise = rng.normal(0.0, sigma_q, rec.time.size)
        q_noisy, u_noisy = simulate(noise, rng)
        power.append(np.mean((q_noisy + noise - q_free) ** 2, axis=-1))
        force.append(np.mean((u_noisy - u_free) ** 2, axis=-1) + force_noise ** 2)
    if per_axis:
        return np.sqrt(np.mean(power, axis=0)), np.sqrt(np.mean(force, axis=0))
    return float(np.sqrt(np.mean(power))), float(np.sqrt(np.mean(force)))


def estimation_rms(train_loop: outputerror.Loop, train: Recording, fit: outputerror.Fit,
                   bounds: dict[str, tuple[float, float]], val_loop: outputerror.Loop, validation: Recording,
                   val_values: dict[str, float], weights: outputerror.Weights, process: Process | None = None,
                   count: int = FLOOR_REPLICATES, max_nfev: int = ESTIMATION_NFEV) -> tuple[float, float]:
    """RMS on the validation recording of the parameter error that the training noise leaves in a correct
    model (one axis), in the position [m] and in the recorded force [N]: the fitted model re-simulated with the
    estimated encoder and process noise on the training excitation, refitted from its values on each replicate
    (the same trust-region fit within the same bounds, ``max_nfev`` free runs), and the validation free run of
    each refit against the fitted model's. A parameter the training barely excites (a mass under little
    acceleration) is fitted to its noise; that error is no missing physics, and the floor verdict counts it. A
    refit, not a linearised step: it keeps the bounds and follows the nonlinear cost (stiff friction laws).
    NaN when no replicate's refit moved from the fitted values (a cost too rough there for the trust region) or
    most of them diverged: the error is unknown, not zero. Several axes: per axis (arrays; ``process`` a tuple, one
    per axis), the replicates simulated from the fit's controller start (:func:`outputerror.relation_shift`)."""
    n_ax = len(train_loop.channels)
    shape = (n_ax,) if train_loop.axes else ()
    if not train_loop.free:
        return np.zeros(shape)[()], np.zeros(shape)[()]
    # several axes: the replicates start from the fit's controller start, which no refit re-estimates
    simulate = noisy_simulator(train_loop, train, fit.values, process, fit.shift if train_loop.axes else None)
    q_val, u_val = outputerror.simulate(val_loop, validation, val_values)
    rng = np.random.default_rng(1)
    replicates = []      # drawn here, in one sequence: the same replicates for any worker count
    sigma_q = np.broadcast_to(np.asarray(weights.sigma_q, float), (n_ax,))
    for _ in range(count):
        encoder = (rng.normal(0.0, 1.0, (n_ax, train.time.size)) * sigma_q[:, None]).reshape((*shape, -1))
        q, u = simulate(encoder, rng)
        columns = {c: train[c] for c in train.columns}
        for k, sig in enumerate(train_loop.channels):
            columns.update({sig.output: np.reshape(q + encoder, (n_ax, -1))[k],
                            sig.input: np.reshape(u, (n_ax, -1))[k]})
        replicates.append(Recording(train.time, columns))

    def refit_one(index: str) -> tuple[bool, np.ndarray, np.ndarray]:
        """Whether the replicate's refit moved, and its validation run's mean square position and force
        differences from the fitted model's."""
        refit = outputerror.fit(train_loop, replicates[int(index)], weights, bounds, start=fit.values,
                                max_nfev=max_nfev)     # a replicate's noise-free force fixes its start exactly
        refitted = {k if k in val_values else "plant." + k: v for k, v in refit.values.items()}
        q_moved, u_moved = outputerror.simulate(val_loop, validation, {**val_values, **refitted})
        return (any(refit.values[k] != fit.values[k] for k in refit.values),
                np.mean((q_moved - q_val) ** 2, axis=-1), np.mean((u_moved - u_val) ** 2, axis=-1))

    outcomes = map_jobs(refit_one, [str(k) for k in range(count)])   # in the diagnosis' worker processes
    moved = any(m for m, _, _ in outcomes)
    shifts, forces = [s for _, s, _ in outcomes], [f for _, _, f in outcomes]
    if not moved:
        return np.full(shape, math.nan)[()], np.full(shape, math.nan)[()]
    shifts, forces = np.reshape(shifts, (count, n_ax)), np.reshape(forces, (count, n_ax))
    finite = np.all(np.isfinite(shifts) & np.isfinite(forces), axis=1)
    if finite.sum() < (count + 1) // 2:      # most replicates' refits diverged: no estimate
        return np.full(shape, math.nan)[()], np.full(shape, math.nan)[()]
    # a replicate whose refit left the stable region is an estimation error beyond any bound: it is counted as
    # the largest finite one, not dropped (dropping it would make the bound tighter the less stable the fit)
    shifts = np.where(finite[:, None], shifts, np.max(shifts[finite], axis=0))
    forces = np.where(finite[:, None], forces, np.max(forces[finite], axis=0))
    result = np.sqrt(np.mean(shifts, axis=0)), np.sqrt(np.mean(forces, axis=0))
    return (result[0], result[1]) if train_loop.axes else (float(result[0][0]), float(result[1][0]))


SANDWICH_DRAWS = 32          # parameter draws from the sandwich covariance in sandwich_rms


def sandwich_rms(train_loop: outputerror.Loop, fit: outputerror.Fit, bounds: dict[str, tuple[float, float]],
                 val_loop: outputerror.Loop, validation: Recording, val_values: dict[str, float],
                 count: int = SANDWICH_DRAWS) -> tuple[float, float]:
    """RMS on the validation recording (position [m], recorded force [N]) of the parameter error that the fit's
    own training residual implies: parameters drawn from the HAC (Newey-West) sandwich covariance of the fit
    (:func:`outputerror.statistics`, the start estimates marginalised, parameters on a bound held), within the
    bounds, and the validation free run of each against the fitted model's. One axis. Why: refits on noise
    replicates (:func:`estimation_rms`) only see the scatter that the loop they re-simulate gives the noise. With
    an unknown controller that loop is the predictor, not the real loop the recorded force answered the noise
    through, and on the held-out Coulomb case its replicates read 1.3e-5 m where the fitted parameters cost
    7.5e-5 against the truth's (why they spread less is a reading, not measured on its own: the observer holds
    each replicate near the recorded motion). The sandwich reads the scatter from the residual as it is (it also
    counts a model error as noise: an upper reading). NaN when the Jacobian does not determine the parameters."""
    if not train_loop.free:
        return 0.0, 0.0
    try:
        stats = outputerror.statistics(train_loop, fit, bounds)
    except (ValueError, np.linalg.LinAlgError):
        return math.nan, math.nan
    if stats.robust_covariance is None or not np.all(np.isfinite(stats.robust_covariance)):
        return math.nan, math.nan
    names = list(train_loop.free)
    keys = [n if n in val_values else "plant." + n for n in names]
    lo, hi = outputerror.bound_arrays(train_loop, bounds)
    q_val, u_val = outputerror.simulate(val_loop, validation, val_values)
    rng = np.random.default_rng(2)
    draws = rng.multivariate_normal(stats.estimate, stats.robust_covariance, count, method="eigh")
    power, force = [], []
    for theta in np.clip(draws, lo, hi):
        q, u = outputerror.simulate(val_loop, validation, {**val_values, **dict(zip(keys, map(float, theta)))})
        power.append(np.mean((q - q_val) ** 2))
        force.append(np.mean((u - u_val) ** 2))
    finite = np.isfinite(power) & np.isfinite(force)
    if finite.sum() < (count + 1) // 2:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(np.array(power)[finite]))), float(np.sqrt(np.mean(np.array(force)[finite])))


def on_axis(effect: effect_models.Effect, roles: PlantRoles,
            model: symbolic.SymbolicModel | None = None) -> effect_models.Effect:
    """``effect`` acting on the axis ``roles``: its parameters and variables prefixed by the axis output
    (``q3_coulomb_Fc``), ``$x``/``$v`` the axis's position and velocity states (an expression axis: the
    generated functions of the plant ``model``'s states, :mod:`axis_kinematics`), ``u`` (the commanded force
    in an equation) the axis's input; the initialiser and the contract keep the effect's own names."""
    prefix = axis_prefix(roles.output)
    names = [p.name for p in effect.params] + re.findall(r"\bReal\s+(\w+)", effect.declarations)
    pattern = re.compile(r"(?<![\w.])(" + "|".join(map(re.escape, names)) + r"|u)\b") if names else None
    if roles.expression and model is None:
        raise ValueError(f"axis {roles.output} is an output expression: on_axis needs the plant model")
    kinematics = axis_kinematics.substitutions(model, roles)

    def rename(text: str) -> str:
        if pattern is not None:
            text = pattern.sub(lambda m: roles.input if m.group(1) == "u" else prefix + m.group(1), text)
        if roles.expression:
            text = text.replace("der($v)", "$a")
        return string.Template(text).safe_substitute(kinematics)

    def initial(ctx: effect_models.Context) -> list[dict[str, float]]:
        return [{prefix + k: v for k, v in start.items()} for start in effect.initial(ctx)]

    def contract(values: dict[str, float], ctx: effect_models.Context) -> dict[str, float]:
        own = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
        return effect.contract({**values, **own}, ctx)

    params = [dataclasses.replace(p, name=prefix + p.name) for p in effect.params]
    return dataclasses.replace(effect, params=params, declarations=rename(effect.declarations),
                               force=rename(effect.force), sensor=rename(effect.sensor),
                               equations=[rename(e) for e in effect.equations],
                               initial=initial, contract=contract,
                               tracks_position=[prefix + s for s in effect.tracks_position],
                               tracks_force=[prefix + s for s in effect.tracks_force])


def axes_signals(plant: PlantInfo) -> list[outputerror.Signals]:
    """The recording columns of every axis."""
    return [outputerror.axis_signals(a.input, a.output) for a in plant.axes]


def _tracking(bundle: Bundle, effects: list[tuple[str, effect_models.Effect]]) -> dict[str, str]:
    """Velocity states start at the slope of the first samples (expression axes: the plant's start state);
    effect states at the axis's position/force."""
    tracking = {f"plant.{a.velocity}": f"dq:{a.output}" for a in bundle.plant.axes if not a.expression}
    for axis, e in effects:
        tracking.update({s: f"q:{axis}" for s in e.tracks_position})
        tracking.update({s: f"u:{axis}" for s in e.tracks_force})
    return tracking


def _axes_cache(bundle: Bundle) -> dict:
    if bundle.cache is None:
        bundle.cache = LoopCache()
    return bundle.cache


def build_axes(bundle: Bundle, effects: list[tuple[str, effect_models.Effect]], values: dict[str, float],
               folder: Path, n_samples: int, with_jacobian: bool = True, min_substeps: int = 1,
               only: tuple[str, ...] | None = None) -> tuple[outputerror.Loop, dict[str, tuple[float, float]]]:
    """Write, load and compile the multi-axis loop of the nominal plant + ``effects`` (cached by structure;
    ``only``: as :func:`build_structure`'s)."""
    cache = _axes_cache(bundle)
    names = tuple(f"{e.name}@{axis}" for axis, e in effects)
    model = cache.models.get(names)
    if model is None:
        model = cache.models[names] = load_written(
            lambda where, written: write_axes_structure(bundle.plant, effects, written, where), load_structure,
            values, folder)
    free, bounds, all_values = structure_parameters(model, [e for _, e in effects], *bundle.nominal_free, values)
    substeps = max(min_substeps, outputerror.stable_substeps(model, all_values, bundle.controller.sample_time))
    key = ("axes",) + (names, n_samples, substeps, with_jacobian, only)
    if key not in cache.loops:
        free = free if only is None else [n for n in free if n in only]
        cache.loops[key] = outputerror.build_loop(model, bundle.controller, bundle.plant.axes[0].output, free,
                                                  all_values, n_samples, substeps=substeps,
                                                  tracking=_tracking(bundle, effects), with_jacobian=with_jacobian,
                                                  axes=axes_signals(bundle.plant), initial_states=())
    return cache.loops[key].with_values(all_values), bounds


def per_axis_rms(bundle: Bundle, rec: Recording, q: np.ndarray, column: str = "output") -> dict[str, float]:
    """RMS of measured minus simulated output per axis [m] (inf when the run diverged), by output name;
    ``column`` "input": of the force channel [N], ``q`` then the simulated forces."""
    return {a.output: _rms(rec[getattr(a, column)] - q[k]) for k, a in enumerate(bundle.plant.axes)}


def validate_axes(bundle: Bundle, structure: ModelFit, folder: Path) -> None:
    """Free-run the fitted structure on the validation recording: per-axis RMS in ``val_axes``, over every
    axis in ``val_rms``."""
    loop, _ = build_axes(bundle, structure.placed, structure.fit.values, folder, bundle.validation.time.size,
                         with_jacobian=False, min_substeps=structure.loop.substeps)
    q, u = outputerror.simulate(loop, bundle.validation, structure.fit.values,
                                shift=validation_shift(bundle, loop, structure.fit))
    structure.val_q = q
    structure.val_axes = per_axis_rms(bundle, bundle.validation, q)
    structure.val_force_axes = per_axis_rms(bundle, bundle.validation, u, "input")
    structure.val_force_error = np.array([bundle.validation[a.input] - u[k] for k, a in enumerate(bundle.plant.axes)])
    structure.val_rms = _rms(np.array([bundle.validation[a.output] - q[k] for k, a in enumerate(bundle.plant.axes)]))


def validate_any(bundle: Bundle, structure: ModelFit, folder: Path) -> None:
    """:func:`validate` (one axis) or :func:`validate_axes` (several)."""
    (validate_axes if bundle.multi_axis else validate)(bundle, structure, folder)


def compiled(bundle: Bundle, structure: ModelFit, folder: Path) -> tuple[outputerror.Loop, dict]:
    """The training loop of ``structure`` recompiled at its fitted values (the RK4 substeps they need)."""
    if bundle.multi_axis:
        return build_axes(bundle, structure.placed, structure.fit.values, folder, bundle.train.time.size,
                          min_substeps=structure.loop.substeps)
    return build_structure(bundle, structure.effects, structure.fit.values, folder, bundle.train.time.size,
                           min_substeps=structure.loop.substeps)
