"""Screening: every candidate effect added to the current structure and fitted with a few Gauss-Newton steps
(forked worker processes), ranked by cost; the best ranked with their nested simpler (and close richer)
effects go on to the full fit. Units: SI (s, m, N)."""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from motiontwin.ident import outputerror, startvalues
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.augmented import axis_prefix
from motiontwin.ident.diagnosis.effect_base import vanishing_start
from motiontwin.ident.diagnosis.nominal import default_start
from motiontwin.ident.plant_states import position_from_output
from motiontwin.ident.diagnosis.structure import ModelFit, _log, build_axes, build_structure, on_axis
from motiontwin.ident.diagnosis.workers import map_jobs

SCREEN_NFEV = 4             # cheap fit of every candidate, to rank them
MAX_NFEV = 15               # full fit of the best-ranked candidates
FULL_FITS = 3
SCREEN_STARTS = 1           # data-driven starts fitted in the screening, besides the vanishing point
FULL_STARTS = 3             # ... and in a full fit
#: nonlinear in a period or a frequency: every start is screened
MULTI_START = ("position_ripple", "resonance", "encoder_error", "coulomb_friction")
#: smooth in their parameters at the vanishing point and the dearest to fit (stiff extra states, the most RK4
#: substeps): screened only when the score test (:func:`score_test`) beats their bootstrap null
SCORE_TESTED = ("time_delay",)


def fit_structure(bundle: Bundle, current: ModelFit, candidate: effect_models.Effect, ctx: effect_models.Context,
                  weights: outputerror.Weights, folder: Path, max_nfev: int = MAX_NFEV,
                  replacing: effect_models.Effect | None = None) -> ModelFit:
    """Fit the current structure plus ``candidate`` (in place of its effect ``replacing``, when given) from
    its vanishing point and its data-driven starts, these also with the nominal parameters from a joint
    inverse-dynamics estimate (:func:`_joint_start`) and at the plant's own start values (the missing effect
    may have pulled the nominal refit into a basin the candidate's fit does not leave). In place of a nested
    simpler effect the first start is the richer one at the simpler one's fitted values
    (``effects.NESTED_START``): the current model exactly, so the fit cannot end above it."""
    effects = ([candidate if e is replacing else e for e in current.effects] if replacing is not None
               else current.effects + [candidate])
    base = dict(current.fit.values) if current.effects else {"plant." + k: v for k, v in current.fit.values.items()}
    if replacing is not None:
        base = {k: v for k, v in base.items() if k not in {p.name for p in replacing.params}}
    starts = _starts(candidate, ctx)
    first = starts[1] if len(starts) > 1 else {}
    if replacing is not None and candidate.name in effect_models.NESTED_START:
        starts = [{**starts[0], **effect_models.NESTED_START[candidate.name](current.fit.values)}] + starts
    values = {**base, **{p.name: float(np.mean(p.bounds)) for p in candidate.params if not p.fitted}, **starts[0]}
    loop, bounds = build_structure(bundle, effects, values, folder, bundle.train.time.size,
                                   min_substeps=current.loop.substeps)
    joint = _joint_start(bundle, loop, candidate, {**values, **first})
    prior = {"plant." + k: v for k, v in default_start(bundle).items() if "plant." + k in loop.free}
    starts = starts + ([joint] if joint else []) + ([{**prior, **first}] if prior else [])
    best, start_cost = _best_fit(bundle, loop, bounds, weights, base, starts, max_nfev, candidate.name,
                                 current.fit.shift)
    return ModelFit(effects, loop.with_values(best.values), best, bounds, folder, start_cost=start_cost)


def _starts(candidate: effect_models.Effect, ctx: effect_models.Context) -> list[dict[str, float]]:
    """The candidate's starting points: first its vanishing point (the current model exactly), then its
    data-driven starts (the inverse-dynamics force residual projected on the effect's regressors, and several
    values of a parameter in which the cost is rough)."""
    data = candidate.initial(ctx)
    return [vanishing_start(candidate, data)] + data


def _joint_start(bundle: Bundle, loop: outputerror.Loop, candidate: effect_models.Effect,
                 values: dict[str, float]) -> dict[str, float]:
    """The nominal parameters and the candidate's together from inverse dynamics of the augmented model (least
    squares of those entering the force linearly; the others keep ``values``). A missing effect distorts
    the nominal refit (a Coulomb friction taken up by a mass a tenth of the true one, a local minimum the
    output-error fit of the candidate does not leave); this start is free of that distortion. Empty when
    the augmented model has extra states or its output is not affine in the position state (q = x, a gear
    ratio, an offset)."""
    model = loop.model
    position = "plant." + bundle.plant.position_state
    found = position_from_output(model, "q", values, bundle.train["q"]) if model.x.numel() == 2 else None
    if found is None or found[0] != position:
        return {}
    free = [n for n in loop.free if n.startswith("plant.")] + [p.name for p in candidate.params if p.fitted]
    try:
        estimate = startvalues.inverse_dynamics_start(model, found[1], bundle.train["u"],
                                                      bundle.controller.sample_time, position, free, values, input_name="u")
    except (ValueError, np.linalg.LinAlgError, RuntimeError):
        return {}
    return {**{p.name: values[p.name] for p in candidate.params if p.fitted and p.name in values}, **estimate}


def _start_cost(bundle: Bundle, loop: outputerror.Loop, weights: outputerror.Weights,
                values: dict[str, float], shift: np.ndarray | None = None) -> float:
    """The training cost of ``loop`` at ``values`` with the controller start ``shift`` (one free run, no fit)."""
    r, _, _ = outputerror.residuals(loop, bundle.train, values, weights, shift=shift)
    return outputerror.squared_norm(r)


def _best_fit(bundle: Bundle, loop: outputerror.Loop, bounds: dict[str, tuple[float, float]],
              weights: outputerror.Weights, base: dict[str, float], starts: list[dict[str, float]],
              max_nfev: int, name: str = "", shift: np.ndarray | None = None) -> tuple[outputerror.Fit, float]:
    """The lowest-cost fit of ``loop`` from ``base`` with the vanishing start (``starts[0]``) and the
    lowest-cost data-driven starts over it (each clipped into its bounds): ``SCREEN_STARTS`` of them in a
    screening fit (every one for ``MULTI_START`` effects), ``FULL_STARTS`` in a full fit. Returns the fit
    and the cost at the vanishing start. The trust-region fit accepts only descent, so no fit ends above the
    cost of its start. ``shift``: the current model's controller start (where every fit's estimate starts).
    A start whose fit raises is passed over; the first error is raised when none is left."""
    points = [{**base, **{k: float(np.clip(v, *bounds[k])) for k, v in start.items() if k in bounds}}
              for start in starts]
    costs = [_start_cost(bundle, loop, weights, point, shift) for point in points]
    data = sorted(range(1, len(points)), key=lambda k: costs[k])
    count = len(data) if name in MULTI_START else SCREEN_STARTS if max_nfev <= SCREEN_NFEV else FULL_STARTS
    best, failure = None, None
    for k in [0] + data[:count]:
        try:
            result = outputerror.fit(loop, bundle.train, weights, bounds, start=points[k], max_nfev=max_nfev,
                                     estimate_start=True, shift=shift)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:   # this start's loop cannot be
            failure = failure or exc                                       # fitted: the other starts still count
            continue
        if best is None or result.cost < best.cost:
            best = result
    if best is None:
        raise failure
    return best, costs[0]


def refine(bundle: Bundle, structure: ModelFit, weights: outputerror.Weights, max_nfev: int = MAX_NFEV) -> ModelFit:
    """Continue the fit of an already compiled structure from its current values."""
    result = outputerror.fit(structure.loop, bundle.train, weights, structure.bounds, start=structure.fit.values,
                             max_nfev=max_nfev, estimate_start=True,
                             shift=structure.fit.shift)
    if result.cost >= structure.fit.cost:
        return structure
    return ModelFit(structure.effects, structure.loop.with_values(result.values), result, structure.bounds,
                    structure.folder, evidence=structure.evidence, axes=structure.axes)


class Screened(NamedTuple):
    """One candidate's screening, as a worker returns it."""

    name: str
    fit: outputerror.Fit | None   # None: not screened (``error`` says why, or its score test failed)
    substeps: int                 # RK4 substeps per sample of its loop
    seconds: float
    error: str = ""               # why the fit failed
    start_cost: float = math.nan  # the cost at its vanishing start
    note: str = ""                # its score test's progress line


def _screen_one(fit_one: Callable[[str], ModelFit], name: str, score: Callable[[str], tuple[bool, str]] | None
                ) -> Screened:
    """Cheap fit of the current structure plus the effect ``name`` (run in a worker or in-process), after its
    score test for an effect in ``SCORE_TESTED`` when ``score`` is given (name -> (passes, progress line))."""
    t0 = time.perf_counter()
    note = ""
    if score is not None and name in SCORE_TESTED:
        passes, note = score(name)
        if not passes:
            return Screened(name, None, 0, time.perf_counter() - t0, note=note)
    try:
        trial = fit_one(name)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return Screened(name, None, 0, time.perf_counter() - t0, error=str(exc), note=note)
    return Screened(name, trial.fit, trial.loop.substeps, time.perf_counter() - t0, start_cost=trial.start_cost,
                    note=note)


def screen(bundle: Bundle, current: ModelFit, names: list[str], ctx: effect_models.Context,
           weights: outputerror.Weights, folder: Path, progress=None,
           fit_one: Callable[[str], ModelFit] | None = None,
           score: Callable[[str], tuple[bool, str]] | None = None) -> dict[str, tuple[outputerror.Fit, int]]:
    """Screen every candidate effect with a few Gauss-Newton steps, in parallel processes
    (:func:`map_jobs`): name -> (fit, RK4 substeps of its loop). ``fit_one``: the
    cheap fit of one candidate by name (default: :func:`fit_structure` with ``SCREEN_NFEV``; the multi-axis
    diagnosis places the effect on its located axis). ``score``: the score test of an effect in
    ``SCORE_TESTED`` (name -> (passes, progress line)), run in the same worker before its fit, which follows
    only when it passes (the test of the 4-DOF bundle's delay takes 30 s: beside the other screenings, not
    before them)."""
    if fit_one is None:
        def fit_one(name: str) -> ModelFit:
            return fit_structure(bundle, current, effect_models.VOCABULARY[name](ctx), ctx, weights, folder / name,
                                 SCREEN_NFEV)
    out: dict[str, tuple[outputerror.Fit, int]] = {}
    for one in map_jobs(lambda name: _screen_one(fit_one, name, score), names):
        if one.note:
            _log(progress, one.note)
        if one.error:
            _log(progress, f"  {one.name}: fit failed ({one.error})")
        if one.fit is None:
            continue
        out[one.name] = (one.fit, one.substeps)
        _log(progress, f"  screen {one.name}: cost {one.fit.cost - current.fit.cost:+.4g} ({one.seconds:.1f} s)")
        defect = screening_defect(current.fit.cost, one.start_cost, one.fit.cost,
                                  (current.loop.substeps, one.substeps))
        if defect:
            _log(progress, f"  defect: {one.name} {defect}")
    return out


VANISHING_RTOL = 1e-6   # a candidate at its vanishing point reproduces the current cost within this (RK4 substeps)
INTEGRATION_RTOL = 1e-3   # ... or within this when it is integrated with other RK4 substeps than the model


def screening_defect(current: float, start: float, end: float, substeps: tuple[int, int] = (1, 1)) -> str:
    """What went wrong in one candidate's screening ("" if nothing): it ended above its vanishing start, or
    that start does not reproduce the model it extends (``current``), so the search could end worse.
    ``substeps``: the RK4 substeps per sample of the model and of the candidate; where they differ the line
    says so, since the two free runs then differ by their integration too (the time delay's Pade states take
    14 substeps, a model 1-3). A start within ``INTEGRATION_RTOL`` of the cost of a model integrated with
    other substeps is that integration's difference, not a defect (a near-discontinuous friction law fitted on
    a real axis takes 64 substeps where its model took 26: 7.6e-5 of the cost)."""
    if end > start:
        return f"ended above its start (cost {end - current:+.4g}, at its vanishing point {start - current:+.4g})"
    if substeps[0] != substeps[1] and start - current <= INTEGRATION_RTOL * abs(current):
        return ""
    if not start <= current + VANISHING_RTOL * abs(current):
        share = f", {(start - current) / abs(current):.2g} of it" if current else ""
        finer = (f"; integrated with {substeps[1]} RK4 substeps per sample, the model with {substeps[0]}"
                 if substeps[0] != substeps[1] else "")
        return (f"at its vanishing point does not reproduce the model it extends (cost {start - current:+.4g}"
                f"{share}{finer}), ended at {end - current:+.4g}")
    return ""


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


def fit_candidate(bundle: Bundle, current: ModelFit, effect: effect_models.Effect, axis: str,
                  ctx: effect_models.Context, weights: outputerror.Weights, folder: Path,
                  max_nfev: int, replacing: effect_models.Effect | None = None) -> ModelFit:
    """The current structure plus ``effect`` on ``axis`` (in place of the placed effect ``replacing``, when
    given: first from the richer effect at the simpler one's fitted values, ``effects.NESTED_START``, as
    :func:`fit_structure`), fitted from each of its starting points."""
    roles = next(a for a in bundle.plant.axes if a.output == axis)
    placed = on_axis(effect, roles, bundle.plant.model)
    starts = _starts(placed, ctx)
    base = dict(current.fit.values)
    if replacing is None:
        pairs = current.placed + [(axis, placed)]
    else:
        pairs = [(a, placed if e is replacing else e) for a, e in current.placed]
        base = {k: v for k, v in base.items() if k not in {p.name for p in replacing.params}}
        prefix = axis_prefix(axis)
        if effect.name in effect_models.NESTED_START:
            own = {k[len(prefix):]: v for k, v in current.fit.values.items() if k.startswith(prefix)}
            nested = effect_models.NESTED_START[effect.name](own)
            starts = [{**starts[0], **{prefix + k: v for k, v in nested.items()}}] + starts
    values = {**base, **{p.name: float(np.mean(p.bounds)) for p in placed.params if not p.fitted}, **starts[0]}
    loop, bounds = build_axes(bundle, pairs, values, folder, bundle.train.time.size,
                              min_substeps=current.loop.substeps)
    best, start_cost = _best_fit(bundle, loop, bounds, weights, {**loop.values, **base}, starts, max_nfev,
                                 effect.name, current.fit.shift)
    return ModelFit([e for _, e in pairs], loop.with_values(best.values), best, bounds, folder,
                    evidence=dict(current.evidence), axes=[a for a, _ in pairs], start_cost=start_cost)


def score_test(bundle: Bundle, current: ModelFit, name: str, axis: str | None, ctx: effect_models.Context,
               weights: outputerror.Weights, folder: Path) -> tuple[float, np.ndarray, int]:
    """The score (Lagrange-multiplier) test of ``name`` on the current structure (on ``axis`` of several): the
    cost reduction that one Gauss-Newton step from the effect's vanishing point predicts from the effect's
    parameters (that point's weighted residual projected on the extended model's Jacobian there, less its
    projection on the same Jacobian without the effect's columns: the step of the other parameters alone, which
    the fit's controller-start prior prices and this projection does not, is not credited to it), the extended
    Jacobian (for the bootstrap null of the same extension) and the effect's fitted parameter count. One
    Jacobian at one point, where a screening fit takes several Jacobians from two starts: for an effect smooth in
    its parameters at the vanishing point, a reduction this test does not predict no fit finds near it either.

    At the vanishing point the extended model is the current one exactly (the effect acts by nothing), so the
    residual and every other column are the current fit's own (:func:`_extended_at_vanishing_point`): only the
    effect's columns are computed, by a loop that differentiates nothing else."""
    effect = effect_models.VOCABULARY[name](ctx)
    if axis is not None:
        effect = on_axis(effect, next(a for a in bundle.plant.axes if a.output == axis), bundle.plant.model)
    start = vanishing_start(effect, effect.initial(ctx))
    fixed = {p.name: float(np.mean(p.bounds)) for p in effect.params if not p.fitted}
    own = tuple(p.name for p in effect.params if p.fitted)
    if axis is None:
        base = dict(current.fit.values) if current.effects else {"plant." + k: v for k, v in current.fit.values.items()}
        loop, bounds = build_structure(bundle, current.effects + [effect], {**base, **fixed, **start}, folder,
                                       bundle.train.time.size, min_substeps=current.loop.substeps, only=own)
    else:
        base = dict(current.fit.values)
        loop, bounds = build_axes(bundle, current.placed + [(axis, effect)], {**base, **fixed, **start}, folder,
                                  bundle.train.time.size, min_substeps=current.loop.substeps, only=own)
        base = {**loop.values, **base}
    point = {**base, **{k: float(np.clip(v, *bounds[k])) for k, v in start.items() if k in bounds}}
    residual, jacobian, columns = _extended_at_vanishing_point(bundle, current, loop, point, weights)
    if not (np.all(np.isfinite(jacobian)) and np.all(np.isfinite(residual))):
        return math.nan, jacobian, len(columns)
    without = np.delete(jacobian, list(columns.values()), axis=1)
    lowest_without = float(residual @ residual - evidence.projected_gain(without, residual[None, :])[0])
    lowest = _quadratic_minimum(jacobian, residual, columns, point, bounds)
    return lowest_without - lowest, jacobian, sum(p.fitted for p in effect.params)


def _extended_at_vanishing_point(bundle: Bundle, current: ModelFit, loop: outputerror.Loop, point: dict[str, float],
                                 weights: outputerror.Weights) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """The weighted residual and Jacobian of the current structure extended by an effect at its vanishing point
    ``point``, and the effect's columns (name -> column): the current fit's residual and Jacobian (its parameters,
    then the start states it estimated) beside the effect's columns from ``loop``, which differentiates the
    effect's parameters only (``build_structure``'s ``only``), from the same start state. Why: the effect's
    states make its loop the dearest of the screening (a delay's Pade states need 14 RK4 substeps per sample),
    and differentiating it by every parameter again only recomputed the current fit's columns (14 columns of the
    4-DOF plant: 18 s of its screening's CPU)."""
    fit = current.fit
    rec = bundle.train
    if fit.residual is None or fit.weights is None or not fit.weights.same_as(weights):
        fit = outputerror.fit(current.loop, rec, weights, current.bounds, start=fit.values, max_nfev=1,
                              estimate_start=True, shift=fit.shift)     # the current columns under ``weights``
    values = {**loop.values, **point}
    s0 = outputerror.initial_state(loop, rec, values, None, fit.shift)
    drive = outputerror.drive(rec, signals=loop.channels, closed=loop.closed)
    pf = np.array([values[n] for n in loop.fixed])
    own = outputerror.weighted_jacobian(loop, s0, drive, loop.theta(values), pf, [], weights)
    offset = fit.jacobian.shape[1]
    return fit.residual, np.hstack([fit.jacobian, own]), {n: offset + k for k, n in enumerate(loop.free)}


def _quadratic_minimum(jac: np.ndarray, residual: np.ndarray, columns: dict[str, int], point: dict[str, float],
                       bounds: dict[str, tuple[float, float]]) -> float:
    """The lowest cost of the Gauss-Newton model |r + J d|^2 from ``point``, where the effect's parameters
    (``columns``: name -> column of ``jac``) that the free step would take out of their bounds stay put."""
    step = -np.linalg.lstsq(jac, residual, rcond=None)[0]
    held = [k for name, k in columns.items()
            if (point[name] <= bounds[name][0] and step[k] < 0) or (point[name] >= bounds[name][1] and step[k] > 0)]
    rest = np.delete(jac, held, axis=1)
    return float(residual @ residual - evidence.projected_gain(rest, residual[None, :])[0])


def placed_structure(bundle: Bundle, current: ModelFit, name: str, axis: str, ctx: effect_models.Context,
                     fit: outputerror.Fit, substeps: int, folder: Path) -> ModelFit:
    """The structure of a screened candidate (its loop rebuilt here: the compiled library is on disk)."""
    roles = next(a for a in bundle.plant.axes if a.output == axis)
    placed = on_axis(effect_models.VOCABULARY[name](ctx), roles, bundle.plant.model)
    loop, bounds = build_axes(bundle, current.placed + [(axis, placed)], fit.values, folder, bundle.train.time.size,
                              min_substeps=substeps)
    return ModelFit(current.effects + [placed], loop.with_values(fit.values), fit, bounds, folder,
                    evidence=dict(current.evidence), axes=current.axes + [axis])


def candidates(ctx: effect_models.Context, used: set[str]) -> list[str]:
    """The vocabulary's effects offered on an axis (one per family and axis)."""
    offered = {n: factory(ctx) for n, factory in effect_models.VOCABULARY.items()}
    return [n for n, e in offered.items() if e.applicable and e.family not in used]
