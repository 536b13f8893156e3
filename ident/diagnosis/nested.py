"""After the rounds: the kept effects of the friction family (and backlash over resonance) judged again in their
nested forms with every other kept effect in the model (``effects.NESTED``), one axis or several. A round judges
a richer law against its simpler form before the later rounds' effects are in, so the answer can change once
they are: :func:`simplify_nested` then :func:`upgrade_nested`. Units: SI (s, m, N)."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.screen import MAX_NFEV, fit_candidate, fit_structure, refine
from motiontwin.ident.diagnosis.select import _unphysical, model_null
from motiontwin.ident.diagnosis.structure import (ModelFit, _log, build_axes, build_structure, evidence_key, on_axis,
                                                  validate_any)
from motiontwin.ident.diagnosis.workers import map_jobs


def _kept(final: ModelFit, ctx: effect_models.Context | None) -> list[tuple[str | None, effect_models.Effect,
                                                                          effect_models.Context]]:
    """(axis, kept effect, its axis's context) of a final structure; several axes: the context the round that
    kept the effect located (its evidence), one axis: ``ctx``."""
    if not final.axes:
        return [(None, e, ctx) for e in final.effects]
    return [(a, e, final.evidence.get(evidence_key(e.name, a), {}).get("context")) for a, e in final.placed]


def _in_place(bundle: Bundle, current: ModelFit, new: effect_models.Effect, old: effect_models.Effect,
              axis: str | None, ctx: effect_models.Context, weights: outputerror.Weights, folder: Path,
              progress=None) -> ModelFit | None:
    """``current`` with ``new`` fitted in place of its effect ``old`` (placed on ``axis`` of several); None, and
    logged, when the fit fails."""
    try:
        if axis is None:
            fitted = fit_structure(bundle, current, new, ctx, weights, folder, replacing=old)
        else:
            fitted = fit_candidate(bundle, current, new, axis, ctx, weights, folder, MAX_NFEV, replacing=old)
        return refine(bundle, fitted, weights)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        _log(progress, f"  {new.name} in place of {old.name}{'' if axis is None else f' on {axis}'}: fit failed "
                       f"({exc})")
        return None


def _side_by_side(bundle: Bundle, current: ModelFit, news: list[effect_models.Effect], old: effect_models.Effect,
                  axis: str | None, ctx: effect_models.Context, weights: outputerror.Weights, work: Path,
                  progress=None, fit: Callable[..., ModelFit | None] = _in_place) -> list[ModelFit | None]:
    """``fit`` (:func:`_in_place`, or another with its arguments) of each of ``news`` in place of ``old``, fitted
    side by side in the worker processes (:func:`workers.map_jobs`: a Hexapod or 4-DOF fit takes tens of seconds);
    each structure is rebuilt here at its fit (the compiled library is on disk), a failed fit logged here."""
    by_name = {e.name: e for e in news}

    def folder(name: str) -> Path:
        return work / f"upgrade_{evidence_key(name, axis)}"

    def job(name: str) -> tuple[outputerror.Fit, int] | str:
        failed: list[str] = []
        trial = fit(bundle, current, by_name[name], old, axis, ctx, weights, folder(name), failed.append)
        return failed[0] if trial is None else (trial.fit, trial.loop.substeps)

    out: list[ModelFit | None] = []
    for new, result in zip(news, map_jobs(job, list(by_name))):
        if isinstance(result, str):
            _log(progress, result)
            out.append(None)
            continue
        fitted, substeps = result
        if axis is None:
            effects = [new if e is old else e for e in current.effects]
            loop, bounds = build_structure(bundle, effects, fitted.values, folder(new.name), bundle.train.time.size,
                                           substeps=substeps)
            out.append(ModelFit(effects, loop.with_values(fitted.values), fitted, bounds, folder(new.name)))
            continue
        roles = next(a for a in bundle.plant.axes if a.output == axis)
        pairs = [(a, on_axis(new, roles, bundle.plant.model) if e is old else e) for a, e in current.placed]
        loop, bounds = build_axes(bundle, pairs, fitted.values, folder(new.name), bundle.train.time.size,
                                  min_substeps=substeps)
        out.append(ModelFit([e for _, e in pairs], loop.with_values(fitted.values), fitted, bounds, folder(new.name),
                            evidence=dict(current.evidence), axes=[a for a, _ in pairs]))
    return out


def _placed(trial: ModelFit, current: ModelFit, old: effect_models.Effect) -> effect_models.Effect:
    """The effect of ``trial`` that took the place of ``current``'s ``old``."""
    return trial.effects[next(k for k, e in enumerate(current.effects) if e is old)]


def _moved_evidence(trial: ModelFit, current: ModelFit, old: str, new: str, axis: str | None,
                    entries: dict) -> ModelFit:
    """``trial`` carrying ``current``'s evidence, the entry of the replaced effect ``old`` moved to ``new``
    with its validation figure after the change and ``entries`` (the rule that replaced it)."""
    before = evidence_key(old, axis)
    found = {**current.evidence.get(before, {}), "validation_rms_after": trial.axis_rms(axis), **entries}
    trial.evidence = {**{k: v for k, v in current.evidence.items() if k != before}, evidence_key(new, axis): found}
    return trial


def simplify_nested(bundle: Bundle, final: ModelFit, weights: outputerror.Weights,
                    ctx: effect_models.Context | None, work: Path, progress=None) -> ModelFit:
    """Each kept richer nested effect (``NESTED``) refitted in its simpler form with every other kept effect in
    the model; the simpler form replaces it when the richer one's extra parameters no longer beat their
    bootstrap null (drawn from the simpler model, :func:`select.model_null`). Why: a richer law judged before a
    later round's effect was in can take up part of it (a Stribeck hump standing in for part of a cogging
    force that the next round adds). The mirror of :func:`upgrade_nested`."""
    if len(final.effects) < 2:
        return final
    current = final
    for axis, rich, axis_ctx in _kept(final, ctx):
        if rich.name not in effect_models.NESTED or axis_ctx is None:
            continue
        simple = effect_models.VOCABULARY[effect_models.NESTED[rich.name]](axis_ctx)
        on = "" if axis is None else f" on {axis}"
        if not simple.applicable:
            continue
        trial = _in_place(bundle, current, simple, rich, axis, axis_ctx, weights,
                          work / f"simplify_{evidence_key(rich.name, axis)}", progress)
        if trial is None:
            continue
        extra = trial.fit.cost - current.fit.cost
        null = model_null(bundle, trial, weights, 98, progress)
        dof = sum(p.fitted for p in rich.params) - sum(p.fitted for p in simple.params)
        threshold = evidence.null_threshold(evidence.extension_null(current.fit.jacobian, trial.fit.jacobian, null),
                                            dof)
        kept = extra > threshold
        _log(progress, f"  {rich.name}{on} with the other effects in: extra {-extra:+.4g} over {simple.name}, null "
                       f"{threshold:.4g} ({'kept' if kept else f'{simple.name} in its place'})")
        if kept:
            continue
        validate_any(bundle, trial, work / f"v_simplify_{evidence_key(rich.name, axis)}")
        current = _moved_evidence(trial, current, rich.name, simple.name, axis, {
            "simplified_from": rich.name, "simplify_cost_increase": extra, "simplify_null_threshold": threshold,
            "rule": f"nested simpler form of {rich.name}: with the other effects in, the richer law's extra "
                    f"parameters no longer beat their null threshold ({extra:.4g} <= {threshold:.4g})"})
    return current


def upgrade_nested(bundle: Bundle, final: ModelFit, weights: outputerror.Weights,
                   ctx: effect_models.Context | None, work: Path, progress=None) -> ModelFit:
    """Each kept simpler effect tried in its richer nested forms (``NESTED``: Stribeck, asymmetric, LuGre,
    load-dependent or drifting friction in place of Coulomb; backlash in place of resonance) with every other
    kept effect in the model. A richer form replaces it when its extra parameters beat their own bootstrap null
    (process noise included), its values are that physics, and the validation fit on its axis is not worse: a
    second effect can hide the richer law in the round that found the simpler one (an offset taken up by the
    Coulomb level hides the Stribeck hump)."""
    if len(final.effects) < 2:
        return final
    current = final
    for axis, simple, axis_ctx in _kept(final, ctx):
        if simple.name not in effect_models.NESTED.values() or axis_ctx is None:
            continue
        richer = [e for e in (effect_models.VOCABULARY[r](axis_ctx) for r, s in effect_models.NESTED.items()
                              if s == simple.name) if e.applicable]
        if not richer:
            continue
        on = "" if axis is None else f" on {axis}"
        null = model_null(bundle, current, weights, 99, progress)
        base_gain = evidence.projected_gain(current.fit.jacobian, null)
        best = None
        for rich, trial in zip(richer, _side_by_side(bundle, current, richer, simple, axis, axis_ctx, weights,
                                                      work, progress)):
            if trial is None:
                continue
            extra = current.fit.cost - trial.fit.cost
            dof = sum(p.fitted for p in rich.params) - sum(p.fitted for p in simple.params)
            threshold = evidence.null_threshold(
                evidence.extension_null(trial.fit.jacobian, current.fit.jacobian, null, base_gain), dof)
            _log(progress, f"  {rich.name} in place of {simple.name}{on}: extra {-extra:+.4g}, null {threshold:.4g}")
            if extra > threshold and not _unphysical(trial, progress, _placed(trial, current, simple), axis) and \
                    (best is None or extra > best[1]):
                best = (trial, extra, threshold, rich)
        if best is None:
            continue
        trial, extra, threshold, rich = best
        validate_any(bundle, trial, work / f"v_upgrade_{evidence_key(rich.name, axis)}")
        if not current.validated:
            validate_any(bundle, current, work / "v_before_upgrade")
        kept = trial.axis_rms(axis) <= current.axis_rms(axis)
        _log(progress, f"  {rich.name} in place of {simple.name}{on}: validation rms {current.axis_rms(axis):.4g} -> "
                       f"{trial.axis_rms(axis):.4g} ({'kept' if kept else 'rejected'})")
        if not kept:
            continue
        current = _moved_evidence(trial, current, simple.name, rich.name, axis, {
            "upgraded_from": simple.name, "upgrade_cost_reduction": extra, "upgrade_null_threshold": threshold,
            "rule": f"richer nested form of {simple.name}: its extra parameters beat their null "
                    f"threshold ({extra:.4g} > {threshold:.4g}) once the other effects were in"})
    return current
