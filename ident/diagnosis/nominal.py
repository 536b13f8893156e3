"""The first stage: the plant form checked against every candidate effect, start values of the nominal
parameters (Modelica defaults, ``plant.parameters``, inverse dynamics) and the closed-loop nominal refit.
Units: SI (s, m, N)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

from motiontwin.ident import observer, outputerror, startvalues
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.augmented import AUGMENTED_CLASS, check_buildable
from motiontwin.ident.diagnosis.axis_units import bundle_units
from motiontwin.ident.diagnosis.bounds import at_bound, at_bound_text
from motiontwin.ident.diagnosis.bundle import Bundle, BundleError
from motiontwin.ident.diagnosis.locate import _mass_equivalent, _needed_force, _pitch_in_state_coordinates, _states_from
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, output_map
from motiontwin.ident.diagnosis.structure import (LoopCache, ModelFit, _fmt, _log, _moving_start, _nominal_bounds,
                                                  build_axes, start_states)
from motiontwin.ident.plant_states import position_from_output

SAME_PHYSICS = 0.9    # |cosine| between a plant parameter's force and an effect's force shape: the same physics


def _divergence_hint(bundle: Bundle) -> str:
    return (f"Set start values in {bundle.directory / 'experiment.json'}, field \"plant.parameters\", e.g. "
            f"\"parameters\": {{\"m\": 95.0}}, or check the controller and the recorded signals' units.")


def nominal_start(bundle: Bundle, progress=None) -> dict[str, float]:
    """Start values of the nominal refit: the Modelica defaults, over them ``plant.parameters`` of the bundle,
    and for every parameter the refit moves (those listed in ``plant.free``, zero ones included, e.g. Fc, F0 of a
    PrismaticAxis; without the list, every other non-zero one) that enters the plant's force linearly (mass,
    viscous friction, ...) the inverse-dynamics
    least-squares estimate on the training recording (kept when it has the default's sign, or the default is
    zero), so that a 2 kg default never meets a 95 kg axis in a closed-loop free run."""
    model, plant = bundle.plant.model, bundle.plant
    values = default_start(bundle)
    listed = plant.free or []
    guess = [n for n, v in values.items() if n not in plant.parameters and (n in listed if listed else v != 0)]
    found = position_from_output(model, plant.output_name, values, bundle.train["q"])
    if found is None or found[0] != plant.position_state:
        _log(progress, "start values: the Modelica defaults and plant.parameters (the inverse-dynamics start "
                       "needs the output to be an affine function of the position state: q = x, a gear ratio, "
                       "an offset)")
        return values
    estimate = startvalues.inverse_dynamics_start(model, found[1], bundle.train["u"], bundle.controller.sample_time,
                                                  plant.position_state, guess, values, input_name=plant.input_name)
    kept = {n: v for n, v in estimate.items() if v * values[n] > 0 or (values[n] == 0 and v != 0)}
    if kept:
        _log(progress, f"start values from inverse dynamics: {_fmt(kept)} (defaults: "
                       f"{_fmt({n: values[n] for n in kept})})")
    return values | kept


def default_start(bundle: Bundle) -> dict[str, float]:
    """The Modelica defaults of the plant's parameters with ``plant.parameters`` of the bundle over them."""
    return {v.name: float(v.start) for v in bundle.plant.model.parameters} | bundle.plant.parameters


def _free_run_rms(loop: outputerror.Loop, bundle: Bundle) -> float:
    """RMS of the nominal loop's free run against the training q (inf when it diverges)."""
    q0, _ = outputerror.simulate(loop, bundle.train)
    with np.errstate(over="ignore", invalid="ignore"):
        rms = float(np.sqrt(np.mean((q0 - bundle.train["q"]) ** 2)))
    return rms if np.isfinite(rms) else math.inf


def fit_nominal(bundle: Bundle, progress=None) -> tuple[ModelFit, outputerror.Weights]:
    """Refit the nominal parameters in closed loop from ``bundle.start`` (replaced by the Modelica defaults when
    those free-run closer to the recording, so the report's start column stays true) and estimate the noise."""
    model = bundle.plant.model
    free, bounds = _nominal_bounds(bundle)

    def loop_at(values: dict[str, float], min_substeps: int = 1) -> outputerror.Loop:
        return outputerror.build_loop(model, bundle.controller, bundle.plant.output_name, free, values,
                                      bundle.train.time.size, input_name=bundle.plant.input_name,
                                      tracking=_moving_start(bundle), min_substeps=min_substeps,
                                      **start_states(bundle, model))

    values = dict(bundle.start)
    loop = loop_at(values)
    defaults = default_start(bundle)
    if any(values[n] != defaults[n] for n in free):   # an inverse-dynamics start must free-run better
        estimated, plain = _free_run_rms(loop, bundle), _free_run_rms(loop_at(defaults), bundle)
        if plain < estimated:
            _log(progress, f"start values: the defaults free-run closer to the recording (rms q {plain:.3g}) than "
                           f"the inverse-dynamics estimate ({estimated:.3g}); the refit starts from the defaults")
            values = bundle.start = defaults
            loop = loop_at(values)
    q0, u0 = outputerror.simulate(loop, bundle.train)
    startvalues.check_free_run(q0, bundle.train["q"], bundle.train.time,
                               f"the nominal closed loop ({bundle.plant.class_name} with the bundle's controller) on "
                               f"{bundle.recording_path('train')}", {n: values[n] for n in free},
                               _divergence_hint(bundle))
    ts = bundle.controller.sample_time
    weights = outputerror.Weights(evidence.noise_level(bundle.train["q"] - q0, ts),
                                  evidence.noise_level(bundle.train["u"] - u0, ts))
    result = outputerror.fit(loop, bundle.train, weights, bounds, max_nfev=40,
                             estimate_start=True)
    weights = outputerror.Weights(evidence.noise_level(bundle.train["q"] - result.q_sim, ts),
                                  evidence.noise_level(bundle.train["u"] - result.u_sim, ts))
    loop, result = _refit_as_fine_as_needed(bundle, loop, result, weights, bounds, loop_at, progress)
    _log(progress, f"nominal refit: {_fmt(result.values)}; rms q {result.rms_q:.3g} {bundle_units(bundle).position}")
    hit = at_bound_text(at_bound(result.values, bounds, free))
    if hit:
        _log(progress, f"nominal refit: at bound: {hit}")
    return ModelFit([], loop.with_values(result.values), result, bounds), weights


def fit_observer(bundle: Bundle, nominal: ModelFit, weights: outputerror.Weights, progress=None
                 ) -> tuple[ModelFit, outputerror.Weights]:
    """Unknown controller: the observer fitted with the refitted nominal plant (:func:`observer.fitted_with_plant`:
    its mass the plant's own, in place of the recording's inverse-dynamics estimate, which the encoder noise can
    halve; its bandwidth by prediction error), then the nominal refitted under it when it moved (one
    alternation: the optimum is set by the force and encoder noise, which the plant's refit does not move).
    Every fit after it estimates the predictor's start (:func:`start_states`), so that a slow observer's start
    transient is not left for an effect to explain. The pair is kept only when it predicts the training
    recording one step ahead at least as well as the nominal under the observer it started with (the
    criterion the bandwidth was fitted by): a nominal that misses a large effect can give the observer a
    wrong mass, and its refit under the fixed gains can then drift toward a mass that lets the predictor follow
    the encoder (the held-out LuGre bundle: 1.2 kg, then 0.003 kg against 6.3). Returned as they were for a
    known controller or an observer the bundle gives."""
    if bundle.observer is None:
        return nominal, weights
    kept = bundle.observer, bundle.controller, bundle.cache, bundle.start
    before, model, train = bundle.observer, bundle.plant.model, bundle.train
    roles = (bundle.plant.output_name, bundle.plant.input_name, outputerror.Signals())

    def one_step(values: dict[str, float], trial: observer.Observer) -> float:
        return observer.one_step_rms(model, values, train, trial, *roles)

    bundle.observer = observer.fitted_with_plant(before, model, dict(nominal.loop.values), train, *roles)
    _log(progress, f"observer mass {bundle.observer.mass:.4g} from {bundle.observer.mass_from}, bandwidth "
                   f"{bundle.observer.bandwidth_hz:.4g} Hz, {bundle.observer.bandwidth_from}")
    if (bundle.observer.bandwidth_hz, bundle.observer.mass) == (before.bandwidth_hz, before.mass):
        return nominal, weights
    bundle.controller = bundle.observer.controller()
    bundle.cache = LoopCache()
    refitted, refitted_weights = fit_nominal(bundle, progress)
    started, ended = one_step(dict(nominal.loop.values), before), one_step(dict(refitted.loop.values), bundle.observer)
    if ended <= started:
        return refitted, refitted_weights
    _log(progress, f"observer: the refit under it predicts one step ahead worse ({ended:.4g} against {started:.4g} "
                   f"under the observer it started with); the start observer and nominal are kept")
    bundle.observer, bundle.controller, bundle.cache, bundle.start = kept
    return nominal, weights


REFINE_SUBSTEPS = 3     # nominal refits on a finer loop at most, when the refitted values need more RK4 substeps


def _refit_as_fine_as_needed(bundle: Bundle, loop: outputerror.Loop, result: outputerror.Fit,
                             weights: outputerror.Weights, bounds: dict[str, tuple[float, float]],
                             rebuilt: Callable[[dict[str, float], int], outputerror.Loop],
                             progress=None) -> tuple[outputerror.Loop, outputerror.Fit]:
    """The nominal's second refit (15 free runs from ``result``), on ``rebuilt(values, substeps)`` when the
    refitted values need more RK4 substeps than ``loop`` has, up to ``REFINE_SUBSTEPS`` times. Why: the
    substeps are chosen at the start values, and a refit to faster dynamics (a mass 60x lighter than the truth
    on the held-out LuGre case) was integrated with too few, so every structure built from it (at the substeps
    its values need) differed from it at its vanishing point (2e-4 of the cost) and the refit could use the
    integration error."""
    ts = bundle.controller.sample_time
    for _ in range(REFINE_SUBSTEPS):
        values = loop.with_values(result.values).values
        needed = outputerror.stable_substeps(loop.model, values, ts)
        finer = loop if needed <= loop.substeps else rebuilt(values, needed)
        if finer is not loop:
            _log(progress, f"nominal refit: {needed} RK4 substeps per sample at the refitted values "
                           f"(were {loop.substeps})")
        result = outputerror.fit(finer.with_values(result.values), bundle.train, weights, bounds, max_nfev=15,
                                 estimate_start=True, shift=result.shift)
        if finer is loop:
            break
        loop = finer
    return loop, result


def check_plant_form(bundle: Bundle, folder: Path) -> None:
    """Build every candidate effect's augmented model on the bundle's plant before any fitting (raises
    :class:`BundleError` naming the construct and the plant file's line)."""
    plant, ts = bundle.plant, bundle.controller.sample_time
    values = {v.name: float(v.start) for v in plant.model.parameters}
    try:
        gain, offset = output_map(plant.model, plant.roles, values)
        x = (np.concatenate([bundle.train["q"], bundle.validation["q"]]) - offset) / gain
        v_max = float(np.max(np.abs(np.gradient(x, ts)))) or 1e-3
        ctx = effect_models.Context(ts, float(x.min()), float(x.max()), v_max, _mass_equivalent(bundle, values),
                         position_gain=gain, pole_pitch=_pitch_in_state_coordinates(plant.pole_pitch, gain))
        check_buildable(folder, plant.text, plant.source, plant.class_name, plant.roles, ctx, AUGMENTED_CLASS)
    except PlantFormError as exc:
        raise BundleError(str(exc)) from None


def nominal_free(bundle: Bundle) -> tuple[list[str], dict[str, tuple[float, float]]]:
    """The nominal parameters refitted: non-zero ones that enter the inverse-dynamics force linearly
    (masses, viscous friction, gravity), within their physical bounds as in the single-axis refit; geometry
    (lengths, offsets), which enters nonlinearly, stays at its value."""
    free, bounds = _nominal_bounds(bundle, "plant.")
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


def _noise_weights(bundle: Bundle, loop: outputerror.Loop, q: np.ndarray, u: np.ndarray) -> outputerror.Weights:
    ts = bundle.controller.sample_time
    qm, um = outputerror.measured(loop, bundle.train, "output"), outputerror.measured(loop, bundle.train, "input")
    return outputerror.Weights(np.array([evidence.noise_level(qm[k] - q[k], ts) for k in range(len(qm))]),
                               np.array([evidence.noise_level(um[k] - u[k], ts) for k in range(len(um))]))


def fit_nominal_axes(bundle: Bundle, work: Path, progress=None) -> tuple[ModelFit, outputerror.Weights]:
    """Closed-loop refit of the nominal parameters on every axis at once."""
    values = {"plant." + k: v for k, v in bundle.start.items()}
    loop, bounds = build_axes(bundle, [], values, work, bundle.train.time.size)
    q0, u0 = outputerror.simulate(loop, bundle.train)
    for k, a in enumerate(bundle.plant.axes):
        startvalues.check_free_run(q0[k], bundle.train[a.output], bundle.train.time,
                                   f"the nominal closed loop ({bundle.plant.class_name} with the bundle's controller) "
                                   f"on {bundle.recording_path('train')}, axis {a.output}",
                                   {n: loop.values[n] for n in loop.free}, _divergence_hint(bundle))
    weights = _noise_weights(bundle, loop, q0, u0)
    start = outputerror.relation_shift(loop, bundle.train) if bundle.observer is None else None
    result = outputerror.fit(loop, bundle.train, weights, bounds, max_nfev=40,
                             estimate_start=True, shift=start)
    weights = _noise_weights(bundle, loop, result.q_sim, result.u_sim)
    loop, result = _refit_as_fine_as_needed(
        bundle, loop, result, weights, bounds,
        lambda values, n: build_axes(bundle, [], values, work, bundle.train.time.size, min_substeps=n)[0], progress)
    _log(progress, f"nominal refit ({', '.join(loop.free)}): "
                   f"{_fmt({k: result.values[k] for k in loop.free})}; rms q {result.rms_q:.3g} "
                   f"(each axis in its unit)")
    return ModelFit([], loop.with_values(result.values), result, bounds), weights


def plant_physics(bundle: Bundle, nominal: ModelFit, ctx: effect_models.Context) -> dict[str, str]:
    """Catalogue effects whose force the plant already has as a refitted parameter (effect -> parameter): the
    force the parameter adds along the recorded motion (:func:`parameter_forces`) points the same way as the
    effect's force shape (``Effect.regressor``), so the effect would add the same physics a second time. Of
    several such parameters the closest (largest |cosine|) is named, whatever their order in the plant."""
    forces = parameter_forces(bundle, nominal, ctx)
    owned = {}
    for effect, factory in effect_models.VOCABULARY.items():
        shape = factory(ctx).regressor
        if shape is None or not forces:
            continue
        r = shape(ctx, ctx.x, ctx.v)
        cosine = {name: _cosine(r, push) for name, push in forces.items()}
        best = max(cosine, key=cosine.get)
        if cosine[best] > SAME_PHYSICS:
            owned[effect] = best
    return owned


def parameter_forces(bundle: Bundle, nominal: ModelFit, ctx: effect_models.Context) -> dict[str, np.ndarray]:
    """d u_needed / d p of every refitted nominal parameter along the training run's filtered states (``ctx``):
    the force each parameter adds, u_needed being the force the plant's equations need for the filtered
    acceleration (exact for a plant affine in its input; a PrismaticAxis gives a, v, tanh(v/v_eps), 1). At
    u = 0 instead, a mass would push the plant's other forces over itself (a constant on a loaded axis: an
    offset taken for the mass's). Empty for a multi-axis plant or without the inverse-dynamics signals."""
    plant = bundle.plant
    if bundle.multi_axis or ctx.x is None or ctx.v is None or ctx.a is None or not nominal.loop.free:
        return {}
    model = plant.model
    names, inputs = [s.name for s in model.states], [v.name for v in model.inputs]
    params = [v.name for v in model.parameters]
    i_v, k_u = names.index(plant.velocity_state), inputs.index(plant.input_name)
    acc = model.dx[i_v]
    fn = ca.Function("push", [model.x, model.u, model.p],
                     [acc, ca.jacobian(acc, model.u)[k_u], ca.jacobian(acc, model.p)]).map(ctx.x.size)
    p = np.array([nominal.fit.values.get(n, 0.0) for n in params])
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    x = np.tile(x0[:, None], (1, ctx.x.size))
    x[names.index(plant.position_state)], x[i_v] = ctx.x, ctx.v
    u = np.zeros((model.u.numel(), ctx.x.size))
    acc0, gain, _ = fn(x, u, p)
    u[k_u] = (ctx.a - np.array(acc0).ravel()) / np.array(gain).ravel()
    _, gain, dp = fn(x, u, p)
    dp = -np.array(dp).reshape(ctx.x.size, len(params)).T / np.array(gain).ravel()
    return {name: dp[params.index(name)] for name in nominal.loop.free}


def _cosine(a: np.ndarray, b: np.ndarray) -> float:
    """|cosine| between two vectors (0 when one is zero)."""
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return abs(float(a @ b)) / norm if norm > 0 else 0.0
