"""``diagnose(bundle_dir, out_dir)``: refit the nominal plant, test every candidate effect against the
noise-aware null reference, keep those that are significant and improve validation, write the augmented
Modelica model, its FMU and the report. Units: SI (s, m, N)."""
from __future__ import annotations

import concurrent.futures
import itertools
import math
import multiprocessing
import os
import shutil
import string
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np
from scipy import stats

from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import empirical
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident import outputerror
from motiontwin.ident import startvalues
from motiontwin.ident.plant_states import alias_state
from motiontwin.harness.recording import Recording
from motiontwin.ident.diagnosis.bundle import Bundle, BundleError
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, output_map

AUGMENTED_CLASS = effect_models.AUGMENTED_CLASS
VALIDATION_GAIN = evidence.VALIDATION_GAIN
MAX_EFFECTS = 3
BOOTSTRAP_COUNT = 30
SCREEN_NFEV = 4             # cheap fit of every candidate, to rank them
MAX_NFEV = 15               # full fit of the best-ranked candidates
FULL_FITS = 3
FLOOR_REPLICATES = 5         # noise re-simulations for the validation noise floor
MULTI_START = ("position_ripple", "resonance")   # nonlinear in a period/frequency: screen every start
EMPIRICAL_EFFECT = empirical.EMPIRICAL   # the data-driven term added after the catalogue (not in VOCABULARY)
_TOKENS = itertools.count()  # screening-job tokens (itertools.count is thread-safe in CPython)


@dataclass
class ModelFit:
    """One model structure fitted on the training recording."""

    effects: list[effect_models.Effect]
    loop: outputerror.Loop
    fit: outputerror.Fit
    bounds: dict[str, tuple[float, float]]
    folder: Path | None = None
    val_rms: float = math.nan
    val_q: np.ndarray | None = None
    evidence: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]


def _nominal_bounds(bundle: Bundle, prefix: str = "") -> tuple[list[str], dict[str, tuple[float, float]]]:
    """The nominal parameters the refit moves (``plant.free``, else every non-zero one), within a factor 5
    of their start and their Modelica min/max."""
    free, bounds = [], {}
    for var in bundle.plant.model.parameters:
        value = float(bundle.start.get(var.name, var.start))
        if value == 0 or (bundle.plant.free is not None and var.name not in bundle.plant.free):
            continue
        lo, hi = sorted((value / 5, value * 5))
        lo, hi = max(lo, var.min), min(hi, var.max)
        free.append(prefix + var.name)
        bounds[prefix + var.name] = (lo, hi)
    return free, bounds


def _log(progress, message: str) -> None:
    if progress:
        progress(message)


def nominal_start(bundle: Bundle, progress=None) -> dict[str, float]:
    """Start values of the nominal refit: the Modelica defaults, over them ``plant.parameters`` of the bundle,
    and for every other non-zero parameter that enters the plant's force linearly (mass, viscous
    friction, ...) the inverse-dynamics least-squares estimate on the training recording (kept when it has
    the default's sign), so that a 2 kg default never meets a 95 kg axis in a closed-loop free run."""
    model, plant = bundle.plant.model, bundle.plant
    values = {v.name: float(v.start) for v in model.parameters} | plant.parameters
    guess = [n for n, v in values.items() if n not in plant.parameters and v != 0]
    if alias_state(model, plant.output_name) != plant.position_state:
        _log(progress, "start values: the Modelica defaults and plant.parameters (the inverse-dynamics start "
                       "needs the output to be the position state itself)")
        return values
    estimate = startvalues.inverse_dynamics_start(model, bundle.train["q"], bundle.train["u"], bundle.controller.Ts,
                                                  plant.position_state, guess, values, input_name=plant.input_name)
    kept = {n: v for n, v in estimate.items() if v * values[n] > 0}
    if kept:
        _log(progress, f"start values from inverse dynamics: {_fmt(kept)} (defaults: "
                       f"{_fmt({n: values[n] for n in kept})})")
    return values | kept


def _moving_start(bundle: Bundle, prefix: str = "") -> dict[str, str]:
    """The velocity state starts at the slope of the first samples (a loop may be moving at t = 0)."""
    return {prefix + bundle.plant.velocity_state: "dq"}


def _divergence_hint(bundle: Bundle) -> str:
    return (f"Set start values in {bundle.directory / 'experiment.json'}, field \"plant.parameters\", e.g. "
            f"\"parameters\": {{\"m\": 95.0}}, or check the controller and the recorded signals' units.")


def fit_nominal(bundle: Bundle, progress=None) -> tuple[ModelFit, outputerror.Weights]:
    model = bundle.plant.model
    free, bounds = _nominal_bounds(bundle)
    values = dict(bundle.start)
    loop = outputerror.build_loop(model, bundle.controller, bundle.plant.output_name, free, values,
                                  bundle.train.time.size, input_name=bundle.plant.input_name,
                                  tracking=_moving_start(bundle))
    q0, u0 = outputerror.simulate(loop, bundle.train)
    startvalues.check_free_run(q0, bundle.train["q"], bundle.train.time,
                               f"the nominal closed loop ({bundle.plant.class_name} with the bundle's controller) on "
                               f"{bundle.recording_path('train')}", {n: values[n] for n in free},
                               _divergence_hint(bundle))
    ts = bundle.controller.Ts
    weights = outputerror.Weights(evidence.noise_level(bundle.train["q"] - q0, ts),
                                  evidence.noise_level(bundle.train["u"] - u0, ts))
    result = outputerror.fit(loop, bundle.train, weights, bounds, max_nfev=40)
    weights = outputerror.Weights(evidence.noise_level(bundle.train["q"] - result.q_sim, ts),
                                  evidence.noise_level(bundle.train["u"] - result.u_sim, ts))
    result = outputerror.fit(loop.with_values(result.values), bundle.train, weights, bounds, max_nfev=15)
    _log(progress, f"nominal refit: {_fmt(result.values)}; rms q {result.rms_q:.3g} m")
    return ModelFit([], loop.with_values(result.values), result, bounds), weights


def _fmt(values: dict[str, float]) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in values.items())


def _in_state_coordinates(rec: Recording, gain: float, offset: float) -> Recording:
    """``rec`` with the measured q replaced by the plant's position state (q - offset)/gain."""
    return Recording(rec.time, {**rec.columns, "q": (rec["q"] - offset) / gain}, rec.units, rec.meta)


def context(bundle: Bundle, nominal: ModelFit) -> effect_models.Context:
    """Recorded ranges and inverse-dynamics signals in the plant's state coordinates."""
    ts = bundle.controller.Ts
    plant = bundle.plant
    gain, offset = output_map(plant.model, plant.roles, nominal.fit.values)
    rec = _in_state_coordinates(bundle.train, gain, offset)
    inv = evidence.inverse_dynamics(rec, plant.model, nominal.fit.values, plant.position_state, plant.velocity_state,
                                    ts, _input_index(bundle))
    q = np.concatenate([rec["q"], _in_state_coordinates(bundle.validation, gain, offset)["q"]])
    v = inv.v if inv else np.gradient(rec["q"], ts)
    mass = _mass_equivalent(bundle, nominal.fit.values)
    ctx = effect_models.Context(ts, float(q.min()), float(q.max()), float(np.max(np.abs(v))) or 1e-3, mass,
                     position_gain=gain, u=bundle.train["u"],
                     duration=float(bundle.train.time[-1] - bundle.train.time[0]),
                     pole_pitch=_pitch_in_state_coordinates(plant.pole_pitch, gain))
    if inv is not None:
        ctx.x, ctx.v, ctx.a, ctx.force, ctx.udot = inv.x, inv.v, inv.a, inv.force, inv.udot
    ctx.resonance_guess = evidence.resonance_guesses(bundle.train["q"] - nominal.fit.q_sim, ts)
    return ctx


def _pitch_in_state_coordinates(pole_pitch: float | None, gain: float) -> float | None:
    """``plant.pole_pitch`` [m of the measured output] in units of the plant's position state."""
    return None if pole_pitch is None else pole_pitch / gain


def _mass_equivalent(bundle: Bundle, values: dict[str, float]) -> float:
    model = bundle.plant.model
    i_v = [s.name for s in model.states].index(bundle.plant.velocity_state)
    gain = ca.Function("g", [model.x, model.u, model.p], [ca.jacobian(model.dx[i_v], model.u[_input_index(bundle)])])
    p = np.array([values[s.name] for s in model.parameters])
    return float(1 / np.array(gain(np.zeros(model.x.numel()), np.zeros(model.u.numel()), p)).item())


def _input_index(bundle: Bundle) -> int:
    return [v.name for v in bundle.plant.model.inputs].index(bundle.plant.input_name)


@dataclass
class LoopCache:
    """Compiled closed loops of one diagnosis, by structure: the effect names, the number of samples, the
    RK4 substeps and whether the Jacobian is compiled. Parameter values are inputs of a compiled loop, so
    a structure is compiled once however often it is refitted, validated or re-screened."""

    loops: dict[tuple, outputerror.Loop] = field(default_factory=dict)
    models: dict[tuple[str, ...], object] = field(default_factory=dict)



def write_structure(bundle: Bundle, effects: list[effect_models.Effect], values: dict[str, float],
                    folder: Path) -> Path:
    """Write the self-contained Modelica folder of the nominal plant + ``effects`` at ``values``."""
    plant_values = {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")}
    return effect_models.write_model(folder, bundle.plant.text, bundle.plant.class_name, effects, values, plant_values,
                          AUGMENTED_CLASS, bundle.plant.roles)


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


def build_structure(bundle: Bundle, effects: list[effect_models.Effect], values: dict[str, float], folder: Path,
                    n_samples: int, with_jacobian: bool = True, min_substeps: int = 1,
                    substeps: int | None = None) -> tuple[outputerror.Loop, dict[str, tuple[float, float]]]:
    """Write and load the augmented model with ``effects`` and compile its loop (at least ``min_substeps``
    RK4 steps per sample, so that structures compared with each other share the integration accuracy).
    A structure already compiled with the same samples/substeps is reused from ``bundle.cache`` (one
    :class:`LoopCache` per diagnosis, so concurrent or repeated diagnoses share nothing)."""
    cache: LoopCache = bundle.cache
    names = tuple(e.name for e in effects)
    model = cache.models.get(names)
    if model is None:
        write_structure(bundle, effects, values, folder)
        model = cache.models[names] = effect_models.load_augmented(folder, AUGMENTED_CLASS)
    free, bounds, all_values = structure_parameters(model, effects, *_nominal_bounds(bundle, "plant."), values)
    tracking = {s: "q" for e in effects for s in e.tracks_position} | _moving_start(bundle, "plant.")
    tracking.update({s: "u" for e in effects for s in e.tracks_force})
    min_substeps = max([min_substeps] + [e.min_substeps for e in effects])
    substeps = substeps or max(min_substeps, outputerror.stable_substeps(model, all_values, bundle.controller.Ts))
    key = (names, n_samples, substeps, with_jacobian)
    if key not in cache.loops:
        cache.loops[key] = outputerror.build_loop(model, bundle.controller, "q",
                                                  free, all_values, n_samples, substeps=substeps, tracking=tracking,
                                                  with_jacobian=with_jacobian)
    return cache.loops[key].with_values(all_values), bounds


def fit_structure(bundle: Bundle, current: ModelFit, candidate: effect_models.Effect, ctx: effect_models.Context,
                  weights: outputerror.Weights, folder: Path, max_nfev: int = MAX_NFEV) -> ModelFit:
    """Fit the current structure plus ``candidate`` from each of the candidate's starting points."""
    effects = current.effects + [candidate]
    base = dict(current.fit.values) if current.effects else {"plant." + k: v for k, v in current.fit.values.items()}
    starts = candidate.initial(ctx)
    if max_nfev <= SCREEN_NFEV and candidate.name not in MULTI_START:
        starts = starts[:1]
    values = {**base, **{p.name: float(np.mean(p.bounds)) for p in candidate.params if not p.fitted}, **starts[0]}
    loop, bounds = build_structure(bundle, effects, values, folder, bundle.train.time.size,
                                   min_substeps=current.loop.substeps)
    best = None
    for start in starts:
        clipped = {k: float(np.clip(v, *bounds[k])) for k, v in start.items() if k in bounds}
        result = outputerror.fit(loop, bundle.train, weights, bounds, start={**base, **clipped}, max_nfev=max_nfev)
        if best is None or result.cost < best.cost:
            best = result
    return ModelFit(effects, loop.with_values(best.values), best, bounds, folder)


def refine(bundle: Bundle, structure: ModelFit, weights: outputerror.Weights, max_nfev: int = MAX_NFEV) -> ModelFit:
    """Continue the fit of an already compiled structure from its current values."""
    result = outputerror.fit(structure.loop, bundle.train, weights, structure.bounds, start=structure.fit.values,
                             max_nfev=max_nfev)
    if result.cost >= structure.fit.cost:
        return structure
    return ModelFit(structure.effects, structure.loop.with_values(result.values), result, structure.bounds,
                    structure.folder, evidence=structure.evidence)


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
                                      tracking=_moving_start(bundle))
    q, _ = outputerror.simulate(loop, rec, structure.fit.values)
    structure.val_q = q
    structure.val_rms = float(np.sqrt(np.mean((rec["q"] - q) ** 2))) if np.all(np.isfinite(q)) else math.inf


def select(bundle: Bundle, nominal: ModelFit, weights: outputerror.Weights, ctx: effect_models.Context, work: Path,
           progress=None) -> tuple[ModelFit, list[dict]]:
    """Greedy forward selection of effects with the bootstrap null reference and the validation check."""
    current = nominal
    log: list[dict] = []
    used_families: set[str] = set()
    rounds = 0
    shortlist = list(effect_models.VOCABULARY)
    while len(current.effects) < MAX_EFFECTS:
        rounds += 1
        if rounds > 1:  # recompile at the fitted values (integration accuracy) and converge the accepted
            # structure, so that no candidate is credited with leftover fit slack or integration error
            loop, bounds = build_structure(bundle, current.effects, current.fit.values, work / f"c{rounds}",
                                           bundle.train.time.size, min_substeps=current.loop.substeps)
            result = outputerror.fit(loop, bundle.train, weights, bounds, start=current.fit.values,
                                     max_nfev=4 * MAX_NFEV)
            current = ModelFit(current.effects, loop.with_values(result.values), result, bounds,
                               work / f"c{rounds}", evidence=current.evidence)
            validate(bundle, current, work / f"v{rounds}_refined")
        noisy = lambda n, c=current: outputerror.simulate(c.loop, bundle.train, c.fit.values, noise=n)  # noqa: E731
        null = evidence.bootstrap_residuals(noisy, current.fit.q_sim, current.fit.u_sim, weights.sigma_q,
                                            weights.sigma_u, bundle.train.time.size, BOOTSTRAP_COUNT, seed=rounds)
        base_gain = evidence.projected_gain(current.fit.jacobian, null)
        candidates = {n: factory(ctx) for n, factory in effect_models.VOCABULARY.items() if n in shortlist}
        names = [n for n, e in candidates.items() if e.applicable and e.family not in used_families]
        screened = screen(bundle, current, names, ctx, weights, work / f"r{rounds}", progress)
        order = sorted(screened, key=lambda n: screened[n][0].cost)
        shortlist = order[:FULL_FITS + 2]     # later rounds screen only the effects that ranked high here
        ranked = ranked_with_nested(order, screened)
        ranked += _close_richer(ranked, screened, current.fit.cost)
        trials: dict[str, tuple[ModelFit, float, float, np.ndarray]] = {}
        for name in ranked:
            t0 = time.perf_counter()
            result, substeps = screened[name]
            effects = current.effects + [effect_models.VOCABULARY[name](ctx)]
            loop, bounds = build_structure(bundle, effects, result.values, work / f"r{rounds}_{name}",
                                           bundle.train.time.size, substeps=substeps)
            trial = refine(bundle, ModelFit(effects, loop.with_values(result.values), result, bounds,
                                            work / f"r{rounds}_{name}"), weights)
            candidate = trial.effects[-1]
            gain = current.fit.cost - trial.fit.cost
            null_gain = evidence.projected_gain(trial.fit.jacobian, null) - base_gain
            dof = sum(p.fitted for p in candidate.params)
            threshold = evidence.null_threshold(null_gain, dof)
            trials[name] = (trial, gain, threshold, null_gain)
            log.append({"round": rounds, "effect": name, "cost_reduction": gain, "null_threshold": threshold,
                        "evidence_ratio": gain / threshold, "parameters": _effect_values(trial, candidate),
                        "seconds": round(time.perf_counter() - t0, 2)})
            _log(progress, f"  round {rounds} {name}: cost -{gain:.4g}, null {threshold:.4g} "
                           f"(x{gain / threshold:.2f}), {time.perf_counter() - t0:.1f} s")
        significant = sorted((n for n, t in trials.items() if t[1] > t[2]), key=lambda n: -trials[n][1])
        chosen = None
        for name in significant:
            name = _simplest(name, trials, null, bundle, work, progress)
            trial = trials[name][0]
            validate(bundle, trial, work / f"v{rounds}_{name}")
            if np.isnan(current.val_rms):
                validate(bundle, current, work / f"v{rounds}_current")
            ok = trial.val_rms < VALIDATION_GAIN * current.val_rms
            _log(progress, f"  {name}: validation rms {current.val_rms:.4g} -> {trial.val_rms:.4g} "
                           f"({'kept' if ok else 'rejected'})")
            for entry in log:
                if entry["round"] == rounds and entry["effect"] == name:
                    entry["validation_rms_before"], entry["validation_rms_after"] = current.val_rms, trial.val_rms
            if ok:
                chosen = trial
                break
        if chosen is None:
            break
        gain, threshold = trials[chosen.effects[-1].name][1:3]
        equivalents, rule = equivalent_explanations(bundle, chosen, trials, work / f"e{rounds}", progress)
        chosen.evidence = {**current.evidence, chosen.effects[-1].name: {
            "cost_reduction": gain, "null_threshold": threshold, "validation_rms_before": current.val_rms,
            "validation_rms_after": chosen.val_rms, "previous": current, "equivalents": equivalents,
            "rule": rule}}
        used_families.add(chosen.effects[-1].family)
        current = chosen
    return current, log


def explain_remainder(bundle: Bundle, final: ModelFit, weights: outputerror.Weights, ctx: effect_models.Context,
                      work: Path, progress=None) -> tuple[ModelFit, dict]:
    """After the catalogue: is there structure left that no named effect explains? The force residual of the
    final model (inverse dynamics of the augmented model itself, on the measured motion) is fitted by the
    sparse law of :mod:`empirical`; its terms are added to the augmented model as the effect
    ``empirical_force`` and refitted by output error with every other parameter. The structure is
    significant when the cost reduction beats the parametric-bootstrap null (dof = the term's fitted
    parameters), and the term is kept only when it also passes the validation rule, as a catalogue effect.

    Returns the final structure (with the empirical effect when kept) and the check: ``status`` is "none"
    (no term, or not significant), "unexplained" (a term validated: ``empirical_term``), "unexplained, no
    term validated" (significant, but the validation fit does not improve) or "not tested" (the final
    model has extra states, e.g. a delay or a resonance, so it has no two-state inverse dynamics), with
    ``where`` the axis, time windows, velocity/position ranges (measured units) and frequency band."""
    plant = bundle.plant
    if final.effects:
        model = bundle.cache.models[tuple(final.names)]
        prefix = "plant."
    else:
        model, prefix = plant.model, ""
    if model.x.numel() != 2:
        reason = (f"not tested: the final model has {model.x.numel()} states (effects "
                  f"{', '.join(final.names)}), and its force residual needs the two-state inverse dynamics")
        _log(progress, f"remaining structure {reason}")
        return final, {"status": "not tested", "reason": reason}
    values = {v.name: float(v.start) for v in model.parameters} | final.fit.values
    gain, offset = output_map(plant.model, plant.roles, {k[len(prefix):]: v for k, v in values.items()
                                                          if k.startswith(prefix)})
    rec = _in_state_coordinates(bundle.train, gain, offset)
    inputs = [v.name for v in model.inputs]
    inv = evidence.inverse_dynamics(rec, model, values, prefix + plant.position_state,
                                    prefix + plant.velocity_state, bundle.controller.Ts,
                                    inputs.index("u" if final.effects else plant.input_name), held_input=True)
    law = empirical.fit_empirical_force({"x": inv.x, "v": inv.v, "a": inv.a, "u": inv.u}, inv.force,
                                        library=empirical.residual_library())
    _log(progress, f"remaining force residual: {law.describe()}")
    law = empirical.without_parameter_terms(law)
    if not law.terms:
        return final, {"status": empirical.NONE, "reason": "no library function beyond the nominal parameters' own "
                                                   "explains the remaining force residual (cross-validated)"}
    signals = {"x": inv.x, "v": inv.v, "a": inv.a, "u": inv.u}
    regression = law
    for attempt in range(2):     # fit the regression's terms, drop those the output-error fit leaves small, refit
        if attempt:
            pruned = empirical.refitted(law, trial.fit.values, signals)
            if len(pruned.terms) in (0, len(law.terms)):
                break
            law = pruned
            _log(progress, f"  empirical term pruned after the output-error fit: {', '.join(law.names)}")
            for key in [k for k in bundle.cache.loops if EMPIRICAL_EFFECT in k[0]]:   # same name, new terms
                del bundle.cache.loops[key]
            bundle.cache.models = {k: m for k, m in bundle.cache.models.items() if EMPIRICAL_EFFECT not in k}
        effect = empirical.as_effect(law, ctx)
        try:
            trial = refine(bundle, fit_structure(bundle, final, effect, ctx, weights, work / f"empirical{attempt}"),
                           weights)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
            return final, {"status": empirical.NONE, "reason": f"the empirical term ({', '.join(law.names)}) could not "
                                                       f"be fitted by output error: {exc}"}
    noisy = lambda n: outputerror.simulate(final.loop, bundle.train, final.fit.values, noise=n)  # noqa: E731
    null = evidence.bootstrap_residuals(noisy, final.fit.q_sim, final.fit.u_sim, weights.sigma_q, weights.sigma_u,
                                        bundle.train.time.size, BOOTSTRAP_COUNT, seed=MAX_EFFECTS + 1)
    null_gain = evidence.projected_gain(trial.fit.jacobian, null) - evidence.projected_gain(final.fit.jacobian, null)
    dof = sum(p.fitted for p in effect.params)
    threshold = evidence.null_threshold(null_gain, dof)
    reduction = final.fit.cost - trial.fit.cost
    _log(progress, f"  empirical term: cost -{reduction:.4g}, null {threshold:.4g} (x{reduction / threshold:.2f})")
    if empirical.verdict(reduction, threshold, None, VALIDATION_GAIN) == empirical.NONE:
        return final, {"status": empirical.NONE, "reason": f"the empirical term ({', '.join(law.names)}) is not "
                                                           f"significant: cost reduction {reduction:.4g} <= null "
                                                           f"threshold {threshold:.4g}"}
    validate(bundle, trial, work / "v_empirical")
    if not math.isfinite(final.val_rms):
        validate(bundle, final, work / "v_before_empirical")
    status = empirical.verdict(reduction, threshold, trial.val_rms / final.val_rms, VALIDATION_GAIN)
    kept = status == empirical.UNEXPLAINED
    _log(progress, f"  empirical term: validation rms {final.val_rms:.4g} -> {trial.val_rms:.4g} "
                   f"({'kept' if kept else 'rejected'})")
    trial.evidence = dict(final.evidence)
    absorbed: list[str] = []
    for named in [e for e in trial.effects if kept and e.family != EMPIRICAL_EFFECT]:
        # a catalogue effect the empirical term now carries (Coulomb friction inside x*sign(v) + sign(v)):
        # dropped when removing it costs no more than its own null threshold and keeps the validation fit
        rest = [e for e in trial.effects if e is not named]
        start = {k: v for k, v in trial.fit.values.items() if k not in {q.name for q in named.params}}
        try:
            loop, bounds = build_structure(bundle, rest, start, work / f"without_{named.name}",
                                           bundle.train.time.size, min_substeps=trial.loop.substeps)
            result = outputerror.fit(loop, bundle.train, weights, bounds, start=start, max_nfev=MAX_NFEV)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            continue
        reduced = ModelFit(rest, loop.with_values(result.values), result, bounds, work / f"without_{named.name}")
        extra = result.cost - trial.fit.cost
        null_extra = evidence.projected_gain(trial.fit.jacobian, null) - evidence.projected_gain(result.jacobian, null)
        if extra > evidence.null_threshold(null_extra, sum(q.fitted for q in named.params)):
            continue
        validate(bundle, reduced, work / f"v_without_{named.name}")
        if not reduced.val_rms <= (2 - VALIDATION_GAIN) * trial.val_rms:
            continue
        _log(progress, f"  {named.name} is carried by the empirical term: without it cost +{extra:.4g}, "
                       f"validation {trial.val_rms:.4g} -> {reduced.val_rms:.4g} m (dropped)")
        reduced.evidence = {k: v for k, v in trial.evidence.items() if k != named.name}
        absorbed.append(named.name)
        trial = reduced
    where = empirical.locate_remainder((trial.fit.q_sim - final.fit.q_sim), bundle.train["q"] - final.fit.q_sim,
                                       bundle.train.time, inv.v * gain, bundle.train["q"], weights.sigma_q,
                                       bundle.controller.Ts)
    term = {"terms": law.names, "coefficients": effect.contract(trial.fit.values, ctx),
            "units": {name: empirical.TERM_UNITS.get(name, "") for name in law.names},
            "v_eps": (None if "empirical_v_eps" not in trial.fit.values
                      else trial.fit.values["empirical_v_eps"] * abs(gain)),
            "regression": {"terms": regression.names, "coefficients": [float(c) for c in regression.coefficients],
                           "threshold": regression.threshold, "cv_rms": regression.cv_rms,
                           "cv_rms_without": regression.cv_rms_zero},
            "modelica": string.Template(effect.equations[0]).substitute(
                x=f"plant.{plant.roles.position}", v=f"plant.{plant.roles.velocity}"),
            "validation_rms_before": final.val_rms, "validation_rms_after": trial.val_rms,
            "validation_gain": trial.val_rms / final.val_rms, "cost_reduction": reduction,
            "null_threshold": threshold, "fitted_parameters": dof, "absorbed_effects": absorbed}
    check = {"status": status,
             "axis": plant.output_name, **where, "empirical_term" if kept else "rejected_term": term}
    if not kept:
        return final, check
    trial.evidence = {**trial.evidence, EMPIRICAL_EFFECT: {
        "cost_reduction": reduction, "null_threshold": threshold, "validation_rms_before": final.val_rms,
        "validation_rms_after": trial.val_rms, "previous": final}}
    return trial, check


#: screening jobs by token (the function fitting one candidate by name): forked workers inherit the table and
#: are sent only (token, name); every call adds its own token and removes it, so concurrent diagnoses do not collide
_SCREEN_JOBS: dict[int, tuple] = {}


def _screen_one(token: int, name: str) -> tuple[str, outputerror.Fit | None, int, float, str]:
    """Cheap fit of the current structure plus the effect ``name`` (run in a worker or in-process)."""
    fit_one = _SCREEN_JOBS[token]
    t0 = time.perf_counter()
    try:
        trial = fit_one(name)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return name, None, 0, time.perf_counter() - t0, str(exc)
    return name, trial.fit, trial.loop.substeps, time.perf_counter() - t0, ""


def screen_workers() -> int:
    """Processes for the candidate screening: ``MOTIONTWIN_DIAGNOSIS_WORKERS`` or the machine's cores
    (at most 4); 1 runs in-process, as does every diagnosis outside the main thread (forking a threaded
    process can deadlock). The results do not depend on it (each fit is deterministic)."""
    if threading.current_thread() is not threading.main_thread():
        return 1
    value = os.environ.get("MOTIONTWIN_DIAGNOSIS_WORKERS")
    count = int(value) if value and value.isdigit() else min(4, os.cpu_count() or 1)
    return max(1, count) if "fork" in multiprocessing.get_all_start_methods() else 1


def screen(bundle: Bundle, current: ModelFit, names: list[str], ctx: effect_models.Context,
           weights: outputerror.Weights, folder: Path, progress=None,
           fit_one: Callable[[str], ModelFit] | None = None) -> dict[str, tuple[outputerror.Fit, int]]:
    """Screen every candidate effect with a few Gauss-Newton steps, in parallel processes (forked, so
    they share the bundle and the current fit): name -> (fit, RK4 substeps of its loop). ``fit_one``: the
    cheap fit of one candidate by name (default: :func:`fit_structure` with ``SCREEN_NFEV``; the multi-axis
    diagnosis places the effect on its located axis)."""
    if fit_one is None:
        def fit_one(name: str) -> ModelFit:
            return fit_structure(bundle, current, effect_models.VOCABULARY[name](ctx), ctx, weights, folder / name,
                                 SCREEN_NFEV)
    token = next(_TOKENS)
    _SCREEN_JOBS[token] = fit_one
    workers = min(screen_workers(), len(names))
    try:
        if workers > 1:
            with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) \
                    as pool:
                results = list(pool.map(_screen_one, [token] * len(names), names))
        else:
            results = [_screen_one(token, name) for name in names]
    finally:
        del _SCREEN_JOBS[token]
    out: dict[str, tuple[outputerror.Fit, int]] = {}
    for name, result, substeps, seconds, error in results:
        if result is None:
            _log(progress, f"  {name}: fit failed ({error})")
            continue
        out[name] = (result, substeps)
        _log(progress, f"  screen {name}: cost -{current.fit.cost - result.cost:.4g} ({seconds:.1f} s)")
    return out


def ranked_with_nested(order: list[str], screened: dict) -> list[str]:
    """The FULL_FITS best-screened effects and the screened simpler effect each nests (``NESTED``), so that
    the parsimony rule can compare them."""
    ranked = order[:FULL_FITS]
    for name in list(ranked):
        simple = effect_models.NESTED.get(name)
        if simple in screened and simple not in ranked:
            ranked.append(simple)
    return ranked


NESTED_SCREEN_SHARE = 0.9   # a richer effect screened within 10 % of its ranked simpler one's gain is fitted too


def _close_richer(ranked: list[str], screened: dict, cost: float) -> list[str]:
    """Richer effects (``NESTED``) of a ranked simpler one whose screening gain is at least
    NESTED_SCREEN_SHARE of the simpler one's: a few steps do not converge their extra parameters (a drift
    time constant, a load coefficient), so the screening cannot tell them from the simpler effect."""
    return [rich for rich, simple in effect_models.NESTED.items()
            if simple in ranked and rich in screened and rich not in ranked
            and cost - screened[rich][0].cost >= NESTED_SCREEN_SHARE * (cost - screened[simple][0].cost) > 0]


def _validation_rms(bundle: Bundle, structure: ModelFit, folder: Path) -> float:
    validate(bundle, structure, folder)
    return structure.val_rms


def _simplest(name: str, trials: dict, null: np.ndarray, bundle: Bundle, work: Path, progress,
              check: Callable[[Bundle, ModelFit, Path], float] = _validation_rms) -> str:
    """Prefer the nested simpler effect (``NESTED``: coulomb in the richer frictions, resonance in backlash)
    unless the extra parameters beat their own null reference and improve the validation fit by the same
    margin as any effect (``check``: validates a structure and returns the validation RMS that decides, e.g.
    one axis's)."""
    simple = effect_models.NESTED.get(name)
    if simple not in trials or trials[simple][1] <= trials[simple][2]:
        return name
    rich, small = trials[name], trials[simple]
    extra = rich[1] - small[1]
    null_extra = (evidence.projected_gain(rich[0].fit.jacobian, null)
                  - evidence.projected_gain(small[0].fit.jacobian, null))
    dof = sum(p.fitted for p in rich[0].effects[-1].params) - sum(p.fitted for p in small[0].effects[-1].params)
    threshold = evidence.null_threshold(null_extra, dof)
    if extra <= threshold:
        return simple
    rich_rms = check(bundle, rich[0], work / f"n_{name}")
    small_rms = check(bundle, small[0], work / f"n_{simple}")
    _log(progress, f"  {name} vs {simple}: extra -{extra:.4g}, null {threshold:.4g}, validation "
                   f"{rich_rms:.4g} vs {small_rms:.4g}")
    return name if rich_rms < VALIDATION_GAIN * small_rms else simple


def _fitted_count(structure: ModelFit) -> int:
    return len(structure.loop.free)


def equivalent_explanations(bundle: Bundle, chosen: ModelFit, trials: dict, work: Path,
                            progress=None) -> tuple[list[dict], str]:
    """Other structures of the same round that explain the data as well as ``chosen``: significant, a
    training cost within the 99.9 % chi-square band of noise for the parameter-count difference (the cost is
    noise-weighted, so a correct model's differences are chi-square distributed), and a validation RMS within
    the validation rule's 10 %. Returns them (name, parameters, costs, AIC = cost + 2 k) and the rule that
    picked ``chosen``: parsimony (fewer fitted parameters; nested simpler effect) or, at equal counts, the
    information criterion."""
    name = chosen.effects[-1].name
    k_chosen = _fitted_count(chosen)
    aic_chosen = chosen.fit.cost + 2 * k_chosen
    found = []
    for other, (trial, gain, threshold, _) in trials.items():
        if other == name or gain <= threshold:
            continue
        k = _fitted_count(trial)
        band = stats.chi2.ppf(evidence.NULL_QUANTILE, max(abs(k - k_chosen), 1))
        if abs(trial.fit.cost - chosen.fit.cost) > band:
            continue
        if not math.isfinite(trial.val_rms):
            validate(bundle, trial, work / other)
        if not abs(trial.val_rms - chosen.val_rms) <= (1 - VALIDATION_GAIN) * chosen.val_rms:
            continue
        effect = trial.effects[-1]
        found.append({"name": other, "parameters": _effect_values(trial, effect),
                      "units": {p.name: p.unit for p in effect.params},
                      "train_cost": trial.fit.cost, "chosen_train_cost": chosen.fit.cost,
                      "validation_rms": trial.val_rms, "chosen_validation_rms": chosen.val_rms,
                      "fitted_parameters": k, "chosen_fitted_parameters": k_chosen,
                      "aic": trial.fit.cost + 2 * k, "chosen_aic": aic_chosen})
        _log(progress, f"  {other} explains the data as well as {name} (train cost {trial.fit.cost:.4g} vs "
                       f"{chosen.fit.cost:.4g}, validation {trial.val_rms:.4g} vs {chosen.val_rms:.4g} m)")
    if not found:
        return [], ""
    fewer = all(e["fitted_parameters"] > k_chosen for e in found)
    if fewer:
        rule = (f"parsimony: {name} has the fewest fitted parameters ({k_chosen}) of the structures that fit "
                f"within noise on training and validation data")
    else:
        rule = (f"information criterion: {name} has AIC = cost + 2k = {aic_chosen:.4g}, the others "
                + ", ".join(f"{e['name']} {e['aic']:.4g}" for e in found)
                + " (the cost reduction decides among structures of equal size)")
    return found, rule


def _effect_values(structure: ModelFit, effect: effect_models.Effect) -> dict[str, float]:
    return {p.name: structure.fit.values[p.name] for p in effect.params}


def validation_floor(loop: outputerror.Loop, bundle: Bundle, values: dict[str, float], sigma_q: float | np.ndarray,
                     count: int = FLOOR_REPLICATES) -> float | np.ndarray:
    """RMS of measured minus free-run q that the fitted model itself leaves on the validation excitation
    [m]: the model is re-simulated with white encoder noise of the estimated level fed back through the
    controller (the noise and its closed-loop echo, which no free-run simulation can predict). No model
    can bring the validation RMS below this floor, so the improvement is also reported above it.
    A multi-axis loop takes one noise level per axis and returns one floor per axis."""
    rec = bundle.validation
    q_free, _ = outputerror.simulate(loop, rec, values)
    rng = np.random.default_rng(0)
    power = []
    per_axis = np.ndim(sigma_q) > 0
    for _ in range(count):
        if per_axis:
            noise = rng.normal(0.0, 1.0, (np.size(sigma_q), rec.time.size)) * np.reshape(sigma_q, (-1, 1))
        else:
            noise = rng.normal(0.0, sigma_q, rec.time.size)
        q_noisy, _ = outputerror.simulate(loop, rec, values, noise=noise)
        power.append(np.mean((q_noisy + noise - q_free) ** 2, axis=-1))
    return np.sqrt(np.mean(power, axis=0)) if per_axis else float(np.sqrt(np.mean(power)))


def check_plant_form(bundle: Bundle, folder: Path) -> None:
    """Build every candidate effect's augmented model on the bundle's plant before any fitting (raises
    :class:`BundleError` naming the construct and the plant file's line)."""
    plant, ts = bundle.plant, bundle.controller.Ts
    values = {v.name: float(v.start) for v in plant.model.parameters}
    try:
        gain, offset = output_map(plant.model, plant.roles, values)
        x = (np.concatenate([bundle.train["q"], bundle.validation["q"]]) - offset) / gain
        v_max = float(np.max(np.abs(np.gradient(x, ts)))) or 1e-3
        ctx = effect_models.Context(ts, float(x.min()), float(x.max()), v_max, _mass_equivalent(bundle, values),
                         position_gain=gain, pole_pitch=_pitch_in_state_coordinates(plant.pole_pitch, gain))
        effect_models.check_buildable(folder, plant.text, plant.source, plant.class_name, plant.roles, ctx,
                                      AUGMENTED_CLASS)
    except PlantFormError as exc:
        raise BundleError(str(exc)) from None


def run(bundle: Bundle, work: Path, progress=None) -> dict:
    """The whole diagnosis in ``work``; returns what the report needs."""
    t0 = time.perf_counter()
    bundle.cache = LoopCache()
    _log(progress, bundle.plant.roles.describe())
    check_plant_form(bundle, work / "check")
    _log(progress, f"every candidate effect's augmented model builds ({time.perf_counter() - t0:.1f} s)")
    bundle.start = nominal_start(bundle, progress)
    nominal, weights = fit_nominal(bundle, progress)
    validate(bundle, nominal, work / "v_nominal")
    startvalues.check_free_run(nominal.val_q, bundle.validation["q"], bundle.validation.time,
                               f"the refitted nominal closed loop on {bundle.recording_path('validation')}",
                               {k: v for k, v in nominal.fit.values.items() if k in nominal.loop.free},
                               _divergence_hint(bundle))
    ctx = context(bundle, nominal)
    final, log = select(bundle, nominal, weights, ctx, work / "trials", progress)
    final, remainder = explain_remainder(bundle, final, weights, ctx, work / "remainder", progress)
    model_dir = work / "final_model"
    values = dict(final.fit.values)
    if not final.effects:
        values = {"plant." + k: v for k, v in values.items()}
    names = tuple(e.name for e in final.effects)
    bundle.cache.models.pop(names, None)   # the final model at the fitted values (Diagnosis.write writes it again)
    loop, _ = build_structure(bundle, final.effects, values, model_dir, bundle.validation.time.size,
                              with_jacobian=False, min_substeps=final.loop.substeps)
    written = bundle.cache.models[names]
    q_aug, u_aug = outputerror.simulate(loop, bundle.validation, values)
    floor = validation_floor(loop, bundle, values, weights.sigma_q)
    _log(progress, f"diagnosis done in {time.perf_counter() - t0:.1f} s")
    return {"bundle": bundle, "nominal": nominal, "final": final, "weights": weights, "context": ctx,
            "log": log, "augmented_values": values, "q_augmented": q_aug, "u_augmented": u_aug,
            "remainder": remainder,
            "augmented_model": written, "validation_floor": floor, "seconds": time.perf_counter() - t0}


@dataclass
class Diagnosis:
    """The outcome of a diagnosis: the effects found, the refitted parameters and the validation fit.

    ``effects``: names of the catalogue effects added to the nominal model (empty: only its parameters were
    off, or what is missing is unexplained); ``parameters``: every parameter of the augmented model (plant
    ones without the ``plant.`` prefix) [SI]; ``nominal_parameters``: the refitted nominal plant;
    ``validation``: validation RMS of both [m] and the noise floor [m]; ``unexplained``: None, or where a
    significant residual structure no catalogue effect explains sits and the empirical term that explains it
    (``status`` "unexplained", ``empirical_term``) or the one that failed validation ("unexplained, no term
    validated", ``rejected_term``), as in diagnosis.json; ``result``: everything the report uses.
    :meth:`write` writes the report and the FMU."""

    effects: list[str]
    parameters: dict[str, float]
    nominal_parameters: dict[str, float]
    validation: dict[str, float]
    result: dict = field(repr=False)
    unexplained: dict | None = None

    @classmethod
    def from_result(cls, result: dict) -> "Diagnosis":
        strip = {k[len("plant."):] if k.startswith("plant.") else k: float(v)
                 for k, v in result["augmented_values"].items()}
        val_q = result["bundle"].validation["q"]
        augmented = float(np.sqrt(np.mean((val_q - result["q_augmented"]) ** 2)))
        remainder = result.get("remainder") or {}
        unexplained = remainder if remainder.get("status", "").startswith("unexplained") else None
        return cls([e.name for e in result["final"].effects if e.family != EMPIRICAL_EFFECT], strip,
                   {k: float(v) for k, v in result["nominal"].fit.values.items()},
                   {"nominal_rms": float(result["nominal"].val_rms), "augmented_rms": augmented,
                    "noise_floor_rms": float(result["validation_floor"])}, result, unexplained)

    def write(self, folder: str | os.PathLike) -> dict:
        """Write diagnosis.json, validation_prediction.csv, report.md (+ PNGs), the augmented Modelica model
        and its FMU into ``folder`` (staged beside it, then moved in); returns the diagnosis.json document."""
        from motiontwin.ident.diagnosis import report

        out = Path(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
        result = self.result
        with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}.work-") as tmp:
            staging = Path(tmp) / "out"
            write_structure(result["bundle"], result["final"].effects, result["augmented_values"],
                            staging / "augmented_model")
            document = report.write_all(result, staging, out)
            _publish(staging, out)
        return document


def _publish(staging: Path, out: Path) -> None:
    """Move every staged file into ``out`` (created if needed) with os.replace."""
    out.mkdir(parents=True, exist_ok=True)
    for src in sorted(staging.rglob("*")):
        if src.is_dir():
            continue
        target = out / src.relative_to(staging)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, target)
    shutil.rmtree(staging, ignore_errors=True)
