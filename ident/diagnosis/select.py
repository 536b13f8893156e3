"""Selection: the greedy forward loop over rounds. A screened effect is kept when its cost reduction beats the
parametric-bootstrap null reference and it lowers the validation RMS by the validation rule's margin; a
nested simpler effect is preferred unless the richer one earns its extra parameters; other structures that
fit as well are reported as equivalent explanations. Units: SI (s, m, N)."""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import numpy as np
from scipy import stats

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.locate import locate
from motiontwin.ident.diagnosis.screen import (FULL_FITS, MAX_NFEV, SCREEN_NFEV, _close_richer, candidates,
                                               fit_candidate, placed_structure, ranked_with_nested, refine, screen)
from motiontwin.ident.diagnosis.structure import ModelFit, Structure, _log, build_structure, validate, validate_axes

VALIDATION_GAIN = evidence.VALIDATION_GAIN
MAX_EFFECTS = 3
BOOTSTRAP_COUNT = 30


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


#: after an accepted effect, another round runs only when some axis's force residual still exceeds its noise
#: reference by this factor (the first round always screens, so a parameters-only bundle meets the null test)
NEXT_ROUND_SCORE = 1.5


def _bootstrap_axes(bundle: Bundle, current: Structure, weights: outputerror.Weights, seed: int) -> np.ndarray:
    noisy = lambda n: outputerror.simulate(current.loop, bundle.train, current.fit.values, noise=n)  # noqa: E731
    return evidence.bootstrap_residuals(noisy, current.fit.q_sim, current.fit.u_sim, weights.sigma_q,
                                        weights.sigma_u, bundle.train.time.size, BOOTSTRAP_COUNT, seed=seed)


def select_axes(bundle: Bundle, nominal: Structure, weights: outputerror.Weights, work: Path,
           progress=None) -> tuple[Structure, list[dict], list[dict]]:
    """Greedy forward selection: locate the axis, screen the effects on it, keep the significant one that
    improves that axis's validation RMS; returns the final structure, the candidate log and the locations."""
    current = nominal
    log: list[dict] = []
    located: list[dict] = []
    used: dict[str, set[str]] = {a.output: set() for a in bundle.plant.axes}
    rounds = 0
    while len(current.effects) < MAX_EFFECTS:
        rounds += 1
        ranking = locate(bundle, current, weights, seed=100 + rounds)
        located.append({"round": rounds, "scores": {e.axis: e.score for e in ranking}})
        target = ranking[0]
        axis, ctx = target.axis, target.context
        scores = ", ".join(f"{e.axis} {e.score:.3g}" for e in ranking)
        if rounds > 1 and target.score < NEXT_ROUND_SCORE:
            _log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                                    f"none above {NEXT_ROUND_SCORE}, done")
            break
        _log(progress, f"round {rounds}: force residual / noise reference per axis: {scores}; "
                                f"screening {axis}")
        null = _bootstrap_axes(bundle, current, weights, rounds)
        base_gain = evidence.projected_gain(current.fit.jacobian, null)
        def fit_one(name: str, c: Structure = current, a: str = axis, x: effect_models.Context = ctx,
                    r: int = rounds) -> Structure:
            return fit_candidate(bundle, c, effect_models.VOCABULARY[name](x), a, x, weights, work / f"r{r}_{name}",
                                 SCREEN_NFEV)

        fits = screen(bundle, current, candidates(ctx, used[axis]), ctx, weights, work, progress, fit_one)
        screened = {name: placed_structure(bundle, current, name, axis, ctx, fit, substeps, work / f"r{rounds}_{name}")
                    for name, (fit, substeps) in fits.items()}
        order = sorted(screened, key=lambda n: screened[n].fit.cost)
        ranked = ranked_with_nested(order, screened)
        trials: dict[str, tuple[Structure, float, float, np.ndarray]] = {}
        for name in ranked:
            trial = refine_axes(bundle, screened[name], weights)
            placed = trial.effects[-1]
            gain = current.fit.cost - trial.fit.cost
            null_gain = evidence.projected_gain(trial.fit.jacobian, null) - base_gain
            threshold = evidence.null_threshold(null_gain, sum(p.fitted for p in placed.params))
            trials[name] = (trial, gain, threshold, null_gain)
            log.append({"round": rounds, "axis": axis, "effect": name, "cost_reduction": gain,
                        "null_threshold": threshold, "evidence_ratio": gain / threshold,
                        "parameters": {p.name: trial.fit.values[p.name] for p in placed.params}})
            _log(progress, f"  round {rounds} {name} on {axis}: cost -{gain:.4g}, null {threshold:.4g} "
                                    f"(x{gain / threshold:.2f})")
        if not current.val_rms:
            validate_axes(bundle, current, work / f"v{rounds}_current")
        chosen = None
        significant = sorted((n for n, t in trials.items() if t[1] > t[2]), key=lambda n: -trials[n][1])
        for name in significant:
            name = _simplest(name, trials, null, bundle, work, progress,
                                      check=lambda b, st, f, a=axis: _axis_validation(b, st, f, a))
            trial = trials[name][0]
            validate_axes(bundle, trial, work / f"v{rounds}_{name}")
            before, after = current.val_rms[axis], trial.val_rms[axis]
            ok = after < VALIDATION_GAIN * before
            _log(progress, f"  {name} on {axis}: validation rms {before:.4g} -> {after:.4g} "
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
    """The validation check of :func:`_simplest` on one axis: validate and return that axis's RMS."""
    validate_axes(bundle, structure, folder)
    return structure.val_rms[axis]


def refine_axes(bundle: Bundle, structure: Structure, weights: outputerror.Weights) -> Structure:
    """Continue the fit of a screened structure from its values (kept only when the cost falls)."""
    result = outputerror.fit(structure.loop, bundle.train, weights, structure.bounds, start=structure.fit.values,
                             max_nfev=MAX_NFEV)
    if result.cost >= structure.fit.cost:
        return structure
    return Structure(structure.effects, structure.axes, structure.loop.with_values(result.values), result,
                     structure.bounds, evidence=structure.evidence)
