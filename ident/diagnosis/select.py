"""Selection: the greedy forward loop over rounds. A screened effect is kept when its cost reduction beats the
parametric-bootstrap null reference and it lowers the validation RMS by the validation rule's margin; a
nested simpler effect is preferred unless the richer one earns its extra parameters; other structures that
fit as well are reported as equivalent explanations. Units: SI (s, m, N)."""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
from scipy import stats

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence, noise
from motiontwin.ident.diagnosis.bounds import WIDEN_ROUNDS, widened_effects
from motiontwin.ident.diagnosis.augmented import axis_prefix
from motiontwin.ident.diagnosis.axis_units import bundle_units
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.locate import AxisEvidence, axis_score, locate
from motiontwin.ident.diagnosis.screen import (MAX_NFEV, SCREEN_NFEV, _close_richer, candidates,
                                               fit_candidate, placed_structure,
                                               ranked_with_nested, refine, score_test, screen)
from motiontwin.ident.diagnosis.structure import (ModelFit, _log, _rms, build_structure, compiled, evidence_key,
                                                  validate_any)
from motiontwin.ident.diagnosis.workers import map_jobs

VALIDATION_GAIN = evidence.VALIDATION_GAIN
MAX_EFFECTS = 3
#: after an accepted effect, another round runs only when some axis's force residual still exceeds its noise
#: reference by this factor (the first round always screens, so a parameters-only bundle meets the null test)
NEXT_ROUND_SCORE = 1.5
BOOTSTRAP_COUNT = 30


def select(bundle: Bundle, nominal: ModelFit, weights: outputerror.Weights, ctx: effect_models.Context | None,
           work: Path, progress=None, owned: dict[str, str] | None = None) -> tuple[ModelFit, list[dict], list[dict]]:
    """Greedy forward selection of effects with the bootstrap null reference and the validation check, for one
    axis or several. Each round takes the axis to screen (several axes: the one whose force residual stands
    highest above its noise reference, :func:`locate.locate`; one axis: the only one, with ``ctx``), screens
    the vocabulary's effects on it, fully fits the best ranked with their nested simpler and close richer ones,
    keeps the first significant one (its nested simpler one unless the extra parameters earn their place) that
    lowers that axis's validation RMS by the validation rule's margin, and lists the structures that explain
    the data as well. Effects in ``owned`` (the plant refits the same physics as its own parameter,
    :func:`nominal.plant_physics`) are not offered. Returns the final structure, the candidate log and the
    per-round axis scores."""
    current = nominal
    log: list[dict] = []
    located: list[dict] = []
    used: dict[str | None, set[str]] = {}
    rounds = 0
    while len(current.effects) < MAX_EFFECTS:
        rounds += 1
        if rounds > 1 and not bundle.multi_axis:    # one axis: the round's score is that of the converged model
            current = _converged(bundle, current, weights, work, rounds)
        target = _round_axis(bundle, current, weights, rounds, located, progress)
        if target is False:
            break
        axis, ctx = (None, ctx) if target is None else (target.axis, target.context)
        on = "" if axis is None else f" on {axis}"
        if rounds > 1 and bundle.multi_axis:
            current = _converged(bundle, current, weights, work, rounds)
        null, base_gain = bootstrap_null(bundle, current, weights, seed=rounds, progress=progress)
        names = [n for n in candidates(ctx, used.setdefault(axis, set())) if n not in (owned or {})]

        def score(name: str, c: ModelFit = current, a: str | None = axis, x: effect_models.Context = ctx,
                  n: np.ndarray = null, g: np.ndarray = base_gain, r: int = rounds) -> tuple[bool, str]:
            return _score_passes(bundle, c, name, a, x, weights, n, g, work / f"s{r}_{name}")

        if axis is None:
            screened = screen(bundle, current, names, ctx, weights, work / f"r{rounds}", progress, score=score)
        else:
            def fit_one(name: str, c: ModelFit = current, a: str = axis, x: effect_models.Context = ctx,
                        r: int = rounds) -> ModelFit:
                return fit_candidate(bundle, c, effect_models.VOCABULARY[name](x), a, x, weights,
                                     work / f"r{r}_{name}", SCREEN_NFEV)

            screened = screen(bundle, current, names, ctx, weights, work, progress, fit_one, score)
        order = sorted(screened, key=lambda n: screened[n][0].cost)
        ranked = ranked_with_nested(order, screened)
        ranked += _close_richer(ranked, screened, current.fit.cost)
        trials: dict[str, tuple[ModelFit, float, float, np.ndarray]] = {}

        def refined(name: str, c: ModelFit = current, a: str | None = axis, x: effect_models.Context = ctx,
                    r: int = rounds) -> tuple[outputerror.Fit, float]:
            t0 = time.perf_counter()
            result, substeps = screened[name]
            trial = refine(bundle, _screened_structure(bundle, c, name, a, x, result, substeps, work / f"r{r}_{name}"),
                           weights)
            return trial.fit, time.perf_counter() - t0

        # the full fits are independent: in the screening's worker processes (several axes: 25-50 s each)
        for name, (result, seconds) in zip(ranked, map_jobs(refined, ranked)):
            t0 = time.perf_counter() - seconds
            trial = _screened_structure(bundle, current, name, axis, ctx, result, screened[name][1],
                                        work / f"r{rounds}_{name}")
            candidate = trial.effects[-1]
            gain = current.fit.cost - trial.fit.cost
            null_gain = evidence.extension_null(trial.fit.jacobian, current.fit.jacobian, null, base_gain)
            dof = sum(p.fitted for p in candidate.params)
            threshold = evidence.null_threshold(null_gain, dof)
            trials[name] = (trial, gain, threshold, null_gain)
            log.append({"round": rounds, **({} if axis is None else {"axis": axis}), "effect": name,
                        "cost_reduction": gain, "null_threshold": threshold, "evidence_ratio": gain / threshold,
                        "parameters": _effect_values(trial, candidate),
                        "seconds": round(time.perf_counter() - t0, 2)})
            _log(progress, f"  round {rounds} {name}{on}: cost {-gain:+.4g}, null {threshold:.4g} "
                           f"(x{gain / threshold:.2f}), {time.perf_counter() - t0:.1f} s")
        significant = sorted((n for n, t in trials.items() if t[1] > t[2] and not _unphysical(t[0], progress)),
                             key=lambda n: -trials[n][1])
        chosen, judged = None, set()
        for name in significant:
            name = _simplest(name, trials, null, bundle, work, progress, axis)
            if name in judged:      # the simplest form of several significant ones
                continue
            judged.add(name)
            trial = trials[name][0]
            validate_any(bundle, trial, work / f"v{rounds}_{name}")
            if not current.validated:
                validate_any(bundle, current, work / f"v{rounds}_current")
            before, after = current.axis_rms(axis), trial.axis_rms(axis)
            force_before, force_after = current.axis_force_rms(axis), trial.axis_force_rms(axis)
            ok = evidence.validation_accepts(before, after, force_before, force_after)
            forces = ("" if math.isnan(force_before) or math.isnan(force_after)     # no force channel to score
                      else f", force {force_before:.4g} -> {force_after:.4g}")
            quarters = _stroke_quarters(bundle, current, trial, axis)
            stroke = max(quarters, key=lambda b: b[2]) if quarters else None
            refused = ok and stroke is not None and stroke[2] > evidence.STROKE_RATIO
            _log(progress, f"  {name}{on}: validation rms {before:.4g} -> {after:.4g}{forces} "
                           f"({'kept' if ok and not refused else 'rejected'})")
            silent = None if ok else _unexercised(bundle, current, trial, weights, axis,
                                                  work / f"v{rounds}_{name}_vanished")
            if silent is not None:
                _log(progress, f"  {name}{on}: {evidence.silent_text(silent)}")
            if refused:
                ok = False
                unit = bundle_units(bundle, axis).position
                _log(progress, f"  {name}{on}: not reported as this physics, it lowers the validation force "
                               f"residual overall but raises its mean square x{stroke[2]:.3g} in the quarter of the "
                               f"recording between {stroke[0]:.4g} and {stroke[1]:.4g} {unit}: its law does not "
                               f"hold along the whole stroke")
            for entry in log:
                if entry["round"] == rounds and entry["effect"] == name:
                    entry["validation_rms_before"], entry["validation_rms_after"] = before, after
                    entry["validation_force_rms_before"] = force_before
                    entry["validation_force_rms_after"] = force_after
                    if silent is not None:
                        entry["not_exercised_by_validation"] = silent
                    if quarters:
                        entry["stroke_force_ratio"] = {"ratio": stroke[2], "position_range": list(stroke[:2]),
                                                       "quarters": [list(b) for b in quarters]}
            if ok:
                chosen = trial
                break
        if chosen is None:
            break
        name = chosen.effects[-1].name
        gain, threshold = trials[name][1:3]
        equivalents, rule = equivalent_explanations(bundle, chosen, trials, work / f"e{rounds}", progress, axis)
        found = {"cost_reduction": gain, "null_threshold": threshold,
                 "validation_rms_before": current.axis_rms(axis), "validation_rms_after": chosen.axis_rms(axis),
                 "validation_force_rms_before": current.axis_force_rms(axis),
                 "validation_force_rms_after": chosen.axis_force_rms(axis),
                 "previous": current, "equivalents": equivalents, "rule": rule}
        if axis is not None:
            found.update({"axis": axis, "score": target.score, "force_residual": target.force, "context": ctx,
                          "previous_q": current.fit.q_sim, "sigma_q": weights.sigma_q})
        chosen.evidence = {**current.evidence, evidence_key(name, axis): found}
        used[axis].add(chosen.effects[-1].family)
        current = chosen
    return current, log, located


def _converged(bundle: Bundle, current: ModelFit, weights: outputerror.Weights, work: Path, rounds: int) -> ModelFit:
    """The accepted structure recompiled at its fitted values (integration accuracy) and converged, so that no
    later candidate is credited with leftover fit slack or integration error (and the final model is not left
    with it when no round follows); validated."""
    folder = work / f"c{rounds}"
    loop, bounds = compiled(bundle, current, folder)
    result = outputerror.fit(loop, bundle.train, weights, bounds, start=current.fit.values, max_nfev=4 * MAX_NFEV,
                             estimate_start=True, shift=current.fit.shift)
    converged = ModelFit(current.effects, loop.with_values(result.values), result, bounds, folder,
                         evidence=current.evidence, axes=current.axes)
    validate_any(bundle, converged, work / f"v{rounds}_refined")
    return converged


def bootstrap_null(bundle: Bundle, current: ModelFit, weights: outputerror.Weights, seed: int, progress=None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The round's bootstrap null reference (:func:`model_null`) and its projection on the current model's own
    Jacobian (:func:`evidence.projected_gain`), against which every candidate's extension is measured
    (:func:`evidence.extension_null`)."""
    null = model_null(bundle, current, weights, seed, progress)
    return null, evidence.projected_gain(current.fit.jacobian, null)


def model_null(bundle: Bundle, model: ModelFit, weights: outputerror.Weights, seed: int, progress=None
               ) -> np.ndarray:
    """``BOOTSTRAP_COUNT`` weighted residual replicates of ``model`` re-simulated with the estimated encoder and
    process noise (:func:`evidence.bootstrap_residuals`), scaled to leave no more cost than the model leaves on
    the training recording (:func:`evidence.consistent_null`; logged when they are)."""
    noisy = noise.noisy_simulator(model.loop, bundle.train, model.fit.values, bundle.process_noise, model.fit.shift)
    null = evidence.bootstrap_residuals(noisy, model.fit.q_sim, model.fit.u_sim, weights.sigma_q,
                                        weights.sigma_u, bundle.train.time.size, BOOTSTRAP_COUNT, seed=seed)
    null, factor = evidence.consistent_null(null, model.fit.cost)
    if factor < 1:
        _log(progress, f"  bootstrap null scaled x{factor:.3g}: the noise re-simulated through this model leaves "
                       f"{1 / factor:.3g} times the cost it leaves on the data")
    return null


def _score_passes(bundle: Bundle, current: ModelFit, name: str, axis: str | None, ctx: effect_models.Context,
                  weights: outputerror.Weights, null: np.ndarray, base_gain: np.ndarray, folder: Path
                  ) -> tuple[bool, str]:
    """Whether ``name`` goes on to the screening, and the progress line that says why: its score test
    (:func:`screen.score_test`) predicts a cost reduction above the 99.9 % level of its own extension's
    bootstrap null, the level its full fit must beat too (or the test cannot be evaluated: a non-finite
    Jacobian). Run in a screening worker: the line is logged by the main process."""
    t0 = time.perf_counter()
    predicted, jac, dof = score_test(bundle, current, name, axis, ctx, weights, folder)
    on = "" if axis is None else f" on {axis}"
    if not (math.isfinite(predicted) and np.all(np.isfinite(jac))):
        return True, f"  score test {name}{on}: not finite (a free run that diverges), screened"
    threshold = evidence.null_threshold(evidence.extension_null(jac, current.fit.jacobian, null, base_gain), dof)
    passes = predicted > threshold
    return passes, (f"  score test {name}{on}: predicted cost {0.0 - predicted:+.4g}, null {threshold:.4g} "
                    f"({'screened' if passes else 'not screened'}, {time.perf_counter() - t0:.1f} s)")


def widen_search_bounds(bundle: Bundle, final: ModelFit, weights: outputerror.Weights, work: Path,
                        progress=None, rounds: int = WIDEN_ROUNDS) -> ModelFit:
    """The chosen structure refitted with every effect parameter that ended on a search limit of its effect
    (not a physical one, :func:`bounds.physical_sides`) given that limit widened (:func:`bounds.widened_effects`),
    up to ``rounds`` times, from the fitted values on the same compiled loop: only descent beyond the solver's own
    tolerance is accepted (less is round-off: a LuGre level on its vanishing point leaves its Stribeck parameters
    flat, they wander to their limits, and widening them lowered the cost by 1.6e-11 of it), so the result never
    has a higher training cost than ``final``, and only a validation run no worse than before (``final``
    is validated first when it was not; on the held-out friction-bump case a Coulomb velocity scale widened 10x
    lowered the training cost and broke the validation run). One axis or several."""
    current = final
    for k in range(rounds):
        effects, changed = widened_effects(current)
        if not changed:
            break
        if math.isnan(current.val_rms):      # not validated yet: the comparison below needs its figure
            validate_any(bundle, current, work / f"v_before{k + 1}")
        trial = ModelFit(effects, current.loop, current.fit, {**current.bounds, **changed}, current.folder,
                         evidence=current.evidence, axes=current.axes)
        refit = refine(bundle, trial, weights, 2 * MAX_NFEV)
        what = ", ".join(f"{n} {current.bounds[n]} -> {b}" for n, b in changed.items())
        if refit is trial or current.fit.cost - refit.fit.cost <= outputerror.TOLERANCE * current.fit.cost:
            _log(progress, f"search limits widened ({what}): the refit did not lower the training cost beyond the "
                           f"solver's own tolerance; the fit stays as it was")
            break
        _log(progress, f"search limits widened ({what}): training cost {current.fit.cost:.6g} -> "
                       f"{refit.fit.cost:.6g}")
        validate_any(bundle, refit, work / f"v_widened{k + 1}")
        if not math.isfinite(refit.val_rms) or refit.val_rms > current.val_rms:
            _log(progress, f"  the widened fit's validation RMS {refit.val_rms:.4g} exceeds the fit's own "
                           f"{current.val_rms:.4g} (the widened law does not carry over): it stays as it was")
            break
        current = refit
    return current


def _unexercised(bundle: Bundle, current: ModelFit, trial: ModelFit, weights: outputerror.Weights,
                 axis: str | None, folder: Path) -> dict | None:
    """What the validation rule cannot judge: a significant effect that it rejects but that the validation
    recording does not exercise (at its vanishing point, the other parameters kept, the validation run changes
    by less than ``evidence.SILENT_SHARE`` of its RMS in position and force, and the validation RMS is no worse
    with it), with its cost reduction in each half of the training recording (where on training its evidence
    lies); None otherwise. Such an effect stays out of the model (nothing confirms it) and is reported as not
    confirmed. Why: a current limit that only the training's largest force demand reaches (the audit
    current-limit case: x127 over the null on one 28 ms event, the validation's forces below half the limit)."""
    zero = {p.name: float(p.zero) for p in trial.effects[-1].params if p.zero is not None}
    before, after = current.axis_rms(axis), trial.axis_rms(axis)
    force_before, force_after = current.axis_force_rms(axis), trial.axis_force_rms(axis)
    if not zero or not after <= before or force_after > force_before:
        return None
    fit = dataclasses.replace(trial.fit, values={**trial.fit.values, **zero})
    vanished = ModelFit(trial.effects, trial.loop, fit, trial.bounds, trial.folder, axes=trial.axes)
    validate_any(bundle, vanished, folder)
    k = 0 if axis is None else [a.output for a in bundle.plant.axes].index(axis)
    change_q = _rms(np.atleast_2d(trial.val_q)[k] - np.atleast_2d(vanished.val_q)[k]) / after
    change_u = 0.0
    if trial.val_force_error is not None and vanished.val_force_error is not None:
        change_u = _rms(trial.val_force_error[k] - vanished.val_force_error[k]) / force_after
    if not max(change_q, change_u) < evidence.SILENT_SHARE:
        return None
    halves = evidence.half_gains(outputerror.measured(trial.loop, bundle.train, "output"),
                                 outputerror.measured(trial.loop, bundle.train, "input"),
                                 (current.fit.q_sim, current.fit.u_sim), (trial.fit.q_sim, trial.fit.u_sim),
                                 weights, with_force=bundle.observer is None)
    return {"validation_change": [change_q, change_u], "training_halves": halves}


def _stroke_quarters(bundle: Bundle, before: ModelFit, after: ModelFit, axis: str | None
                     ) -> list[tuple[float, float, float]]:
    """Per quarter of the validation recording by position on ``axis``: how ``after`` changes the force
    residual over ``before`` (:func:`evidence.stroke_ratios`); empty without a simulated force channel."""
    if before.val_force_error is None or after.val_force_error is None:
        return []
    k = 0 if axis is None else [a.output for a in bundle.plant.axes].index(axis)
    position = bundle.validation["q" if axis is None else axis]
    return evidence.stroke_ratios(position, before.val_force_error[k], after.val_force_error[k])


def _unphysical(trial: ModelFit, progress, effect: effect_models.Effect | None = None,
                axis: str | None = None) -> bool:
    """True (and logged) when the fitted values of ``effect`` (default: the trial's last, placed on its axis
    when the trial has axes, :func:`structure.on_axis`; given, placed on ``axis`` when that is given) are not
    the physics it names."""
    if effect is None and trial.axes:
        axis = trial.axes[-1]
    effect = effect or trial.effects[-1]
    if effect.unphysical is None:
        return False
    prefix = axis_prefix(axis) if axis is not None else ""
    reason = effect.unphysical({p.name[len(prefix):]: trial.fit.values[p.name] for p in effect.params})
    if reason:
        _log(progress, f"  {effect.name}: not reported as this physics, {reason}")
    return bool(reason)


def _round_axis(bundle: Bundle, current: ModelFit, weights: outputerror.Weights, rounds: int, located: list[dict],
                progress) -> AxisEvidence | None | bool:
    """The axis a round screens: None for one axis; for several the located one (its scores appended to
    ``located``); or False when after the first round no axis's force residual reaches ``NEXT_ROUND_SCORE``
    times its noise reference (one axis: :func:`locate.axis_score`; with an unknown controller too: the data's
    force residual is inverse dynamics on the measured motion and force, which the observer does not touch, and
    the model's own and noisy runs are its predictor's, with the force it applied)."""
    if not bundle.multi_axis:
        if rounds == 1:
            return None
        score = axis_score(bundle, current, weights, seed=100 + rounds)
        located.append({"round": rounds, "scores": {bundle.plant.output_name: score}})
        done = score < NEXT_ROUND_SCORE
        _log(progress, f"round {rounds}: force residual / noise reference {score:.3g}"
                       f"{f'; below {NEXT_ROUND_SCORE}, done' if done else ''}")
        return False if done else None
    ranking = locate(bundle, current, weights, seed=100 + rounds)
    located.append({"round": rounds, "scores": {e.axis: e.score for e in ranking}})
    scores = ", ".join(f"{e.axis} {e.score:.3g}" for e in ranking)
    if rounds > 1 and ranking[0].score < NEXT_ROUND_SCORE:
        _log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                       f"none above {NEXT_ROUND_SCORE}, done")
        return False
    _log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                   f"screening {ranking[0].axis}")
    return ranking[0]


def _screened_structure(bundle: Bundle, current: ModelFit, name: str, axis: str | None,
                        ctx: effect_models.Context, result: outputerror.Fit, substeps: int,
                        folder: Path) -> ModelFit:
    """The structure of a screened candidate at its screening fit (its loop compiled here)."""
    if axis is not None:
        return placed_structure(bundle, current, name, axis, ctx, result, substeps, folder)
    effects = current.effects + [effect_models.VOCABULARY[name](ctx)]
    loop, bounds = build_structure(bundle, effects, result.values, folder, bundle.train.time.size, substeps=substeps)
    return ModelFit(effects, loop.with_values(result.values), result, bounds, folder)


def _validation_rms(bundle: Bundle, structure: ModelFit, folder: Path, axis: str | None = None) -> float:
    """Validate ``structure`` and return the RMS that decides on ``axis`` (None: the one axis)."""
    validate_any(bundle, structure, folder)
    return structure.axis_rms(axis)


def _simplest(name: str, trials: dict, null: np.ndarray, bundle: Bundle, work: Path, progress,
              axis: str | None = None) -> str:
    """Prefer the nested simpler effect (``NESTED``: coulomb in the richer frictions, resonance in backlash)
    unless the extra parameters beat their own null reference (with the process noise estimated from the
    data, :mod:`noise`) and do not worsen the validation fit (on ``axis``). The richer effect does not need
    the 10 % validation margin of a new effect: near the floor no model gains 10 %, and its significance on
    the training data is the evidence for its extra parameters."""
    simple = effect_models.NESTED.get(name)
    if simple not in trials or trials[simple][1] <= trials[simple][2]:
        return name
    rich, small = trials[name], trials[simple]
    extra = rich[1] - small[1]
    null_extra = evidence.extension_null(rich[0].fit.jacobian, small[0].fit.jacobian, null)
    dof = sum(p.fitted for p in rich[0].effects[-1].params) - sum(p.fitted for p in small[0].effects[-1].params)
    threshold = evidence.null_threshold(null_extra, dof)
    if extra <= threshold:
        return simple
    rich_rms = _validation_rms(bundle, rich[0], work / f"n_{name}", axis)
    small_rms = _validation_rms(bundle, small[0], work / f"n_{simple}", axis)
    _log(progress, f"  {name} vs {simple}: extra {-extra:+.4g}, null {threshold:.4g}, validation "
                   f"{rich_rms:.4g} vs {small_rms:.4g}")
    return name if rich_rms <= small_rms else simple


def _fitted_count(structure: ModelFit) -> int:
    return len(structure.loop.free)


def equivalent_explanations(bundle: Bundle, chosen: ModelFit, trials: dict, work: Path, progress=None,
                            axis: str | None = None) -> tuple[list[dict], str]:
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
        if not trial.validated:
            validate_any(bundle, trial, work / other)
        if not abs(trial.axis_rms(axis) - chosen.axis_rms(axis)) <= (1 - VALIDATION_GAIN) * chosen.axis_rms(axis):
            continue
        effect = trial.effects[-1]
        found.append({"name": other, "parameters": _effect_values(trial, effect),
                      "units": {p.name: p.unit for p in effect.params},
                      "train_cost": trial.fit.cost, "chosen_train_cost": chosen.fit.cost,
                      "validation_rms": trial.axis_rms(axis), "chosen_validation_rms": chosen.axis_rms(axis),
                      "fitted_parameters": k, "chosen_fitted_parameters": k_chosen,
                      "aic": trial.fit.cost + 2 * k, "chosen_aic": aic_chosen})
        _log(progress, f"  {other} explains the data as well as {name} (train cost {trial.fit.cost:.4g} vs "
                       f"{chosen.fit.cost:.4g}, validation {trial.axis_rms(axis):.4g} vs "
                       f"{chosen.axis_rms(axis):.4g} {bundle_units(bundle, axis).position})")
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
