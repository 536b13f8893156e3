"""The unexplained stage after the catalogue: the force residual of the final model fitted by a sparse
empirical law, added to the augmented model and kept only when significant and validated. Units: SI."""
from __future__ import annotations

import math
import string
from pathlib import Path

import numpy as np

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import empirical
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.axis_units import bundle_units
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.locate import force_residual, locate
from motiontwin.ident.diagnosis.screen import MAX_NFEV, fit_candidate, fit_structure, refine
from motiontwin.ident.diagnosis.select import MAX_EFFECTS, NEXT_ROUND_SCORE, VALIDATION_GAIN, model_null
from motiontwin.ident.diagnosis.structure import ModelFit, _log, build_structure, validate, validate_axes

EMPIRICAL_EFFECT = empirical.EMPIRICAL   # the data-driven term added after the catalogue (not in VOCABULARY)


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
    model's acceleration does not respond to its input directly), with ``where`` the axis, time windows,
    velocity/position ranges (measured units) and frequency band. The states a measurement does not give
    (delay, load, bristle, drift states) come from the final model's free run (:func:`locate.free_run_states`)."""
    plant = bundle.plant
    inv, gain, _ = force_residual(bundle, final)
    if inv is None:
        reason = (f"not tested: the final model's acceleration (effects {', '.join(final.names) or 'none'}) does "
                  f"not respond to its force input directly, so its force residual has no gain to divide by")
        _log(progress, f"remaining structure {reason}")
        return final, {"status": "not tested", "reason": reason}
    law = empirical.fit_empirical_force({"x": inv.x, "v": inv.v, "a": inv.a, "u": inv.u}, inv.force,
                                        library=empirical.residual_library())
    _log(progress, f"remaining force residual: {law.describe(bundle_units(bundle))}")
    law = empirical.without_parameter_terms(law)
    if not law.terms:
        return final, {"status": empirical.NONE, "reason": "no library function beyond the nominal parameters' own "
                                                   "explains the remaining force residual (cross-validated)"}
    signals = {"x": inv.x, "v": inv.v, "a": inv.a, "u": inv.u}
    regression = law
    trial: ModelFit | None = None
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
    dof = sum(p.fitted for p in effect.params)
    null, reduction, threshold = _null_test(bundle, final, trial, weights, dof)
    _log(progress, f"  empirical term: cost {-reduction:+.4g}, null {threshold:.4g} (x{reduction / threshold:.2f})")
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
            result = outputerror.fit(loop, bundle.train, weights, bounds, start=start, max_nfev=MAX_NFEV,
                                     estimate_start=True, shift=trial.fit.shift)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            continue
        reduced = ModelFit(rest, loop.with_values(result.values), result, bounds, work / f"without_{named.name}")
        extra = result.cost - trial.fit.cost
        null_extra = evidence.extension_null(trial.fit.jacobian, result.jacobian, null)
        if extra > evidence.null_threshold(null_extra, sum(q.fitted for q in named.params)):
            continue
        validate(bundle, reduced, work / f"v_without_{named.name}")
        if not reduced.val_rms <= (2 - VALIDATION_GAIN) * trial.val_rms:
            continue
        _log(progress, f"  {named.name} is carried by the empirical term: without it cost +{extra:.4g}, "
                       f"validation {trial.val_rms:.4g} -> {reduced.val_rms:.4g} "
                       f"{bundle_units(bundle).position} (dropped)")
        reduced.evidence = {k: v for k, v in trial.evidence.items() if k != named.name}
        absorbed.append(named.name)
        trial = reduced
    where = empirical.locate_remainder(trial.fit.q_sim - final.fit.q_sim if kept else inv.force,
                                       bundle.train["q"] - final.fit.q_sim, bundle.train.time, inv.v * gain,
                                       bundle.train["q"], weights.sigma_q, bundle.controller.sample_time)
    term = {"terms": law.names, "coefficients": effect.contract(trial.fit.values, ctx),
            "units": {name: bundle_units(bundle).si(empirical.TERM_UNITS.get(name, "")) for name in law.names},
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


def _null_test(bundle: Bundle, final: ModelFit, trial: ModelFit, weights: outputerror.Weights,
               dof: int) -> tuple[np.ndarray, float, float]:
    """The parametric-bootstrap null residuals of the final model (seeded after the selection's rounds), the
    empirical term's cost reduction and its 99.9 % null threshold for ``dof`` fitted parameters."""
    null = model_null(bundle, final, weights, MAX_EFFECTS + 1)
    null_gain = evidence.extension_null(trial.fit.jacobian, final.fit.jacobian, null)
    return null, final.fit.cost - trial.fit.cost, evidence.null_threshold(null_gain, dof)


def explain_remainder_axes(bundle: Bundle, final: ModelFit, weights: outputerror.Weights, work: Path,
                           progress=None) -> tuple[ModelFit, dict]:
    """The unexplained stage on several axes: the axis whose force residual beyond the final model stands
    highest above its noise reference (:func:`locate.locate`) is the one asked; nothing is tested when none
    reaches ``NEXT_ROUND_SCORE``. Its force residual is fitted by the sparse law, the law placed on that axis as
    the effect ``empirical_force`` and refitted by output error with every other parameter, and kept as for one
    axis: significant beyond the bootstrap null and lowering that axis's validation RMS by the validation
    rule's margin. Returns the final structure and the check (``status``, ``axis``, where, the term)."""
    target = locate(bundle, final, weights, seed=100 + MAX_EFFECTS + 1)[0]
    axis, ctx = target.axis, target.context
    if target.score < NEXT_ROUND_SCORE:
        reason = (f"no axis's force residual reaches {NEXT_ROUND_SCORE} times its noise reference (highest: "
                  f"{axis}, {target.score:.3g})")
        _log(progress, f"remaining structure: none ({reason})")
        return final, {"status": empirical.NONE, "reason": reason}
    signals = {"x": ctx.x, "v": ctx.v, "a": ctx.a, "u": ctx.u}
    law = empirical.fit_empirical_force(signals, target.force, library=empirical.residual_library())
    _log(progress, f"remaining force residual on {axis}: {law.describe(bundle_units(bundle, axis))}")
    law = empirical.without_parameter_terms(law)
    if not law.terms:
        return final, {"status": empirical.NONE, "reason": f"no library function beyond the nominal parameters' "
                                                           f"own explains the force residual of {axis}"}
    effect = empirical.as_effect(law, ctx)
    try:
        trial = refine(bundle, fit_candidate(bundle, final, effect, axis, ctx, weights, work / "empirical", MAX_NFEV),
                       weights)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return final, {"status": empirical.NONE, "reason": f"the empirical term ({', '.join(law.names)}) on {axis} "
                                                           f"could not be fitted by output error: {exc}"}
    dof = sum(p.fitted for p in effect.params)
    _, reduction, threshold = _null_test(bundle, final, trial, weights, dof)
    _log(progress, f"  empirical term on {axis}: cost {-reduction:+.4g}, null {threshold:.4g} "
                   f"(x{reduction / threshold:.2f})")
    if empirical.verdict(reduction, threshold, None, VALIDATION_GAIN) == empirical.NONE:
        return final, {"status": empirical.NONE, "reason": f"the empirical term ({', '.join(law.names)}) on {axis} "
                                                           f"is not significant: cost reduction {reduction:.4g} <= "
                                                           f"null threshold {threshold:.4g}"}
    validate_axes(bundle, trial, work / "v_empirical")
    if not final.val_axes:
        validate_axes(bundle, final, work / "v_before_empirical")
    before, after = final.val_axes[axis], trial.val_axes[axis]
    status = empirical.verdict(reduction, threshold, after / before, VALIDATION_GAIN)
    kept = status == empirical.UNEXPLAINED
    _log(progress, f"  empirical term on {axis}: validation rms {before:.4g} -> {after:.4g} "
                   f"({'kept' if kept else 'rejected'})")
    k = [a.output for a in bundle.plant.axes].index(axis)
    where = empirical.locate_remainder(trial.fit.q_sim[k] - final.fit.q_sim[k] if kept else target.force,
                                       bundle.train[axis] - final.fit.q_sim[k], bundle.train.time,
                                       ctx.v * ctx.position_gain, bundle.train[axis],
                                       float(np.atleast_1d(weights.sigma_q)[k]), bundle.controller.sample_time)
    placed = trial.effects[-1]
    term = {"terms": law.names, "coefficients": placed.contract(trial.fit.values, ctx),
            "units": {name: bundle_units(bundle, axis).si(empirical.TERM_UNITS.get(name, "")) for name in law.names},
            "modelica": placed.equations[0], "validation_rms_before": before, "validation_rms_after": after,
            "validation_gain": after / before, "cost_reduction": reduction, "null_threshold": threshold,
            "fitted_parameters": dof}
    check = {"status": status, "axis": axis, **where, "empirical_term" if kept else "rejected_term": term}
    if not kept:
        return final, check
    trial.evidence = {**final.evidence, f"{EMPIRICAL_EFFECT}@{axis}": {
        "axis": axis, "cost_reduction": reduction, "null_threshold": threshold, "validation_rms_before": before,
        "validation_rms_after": after, "previous": final}}
    return trial, check
