"""After the rounds: each kept effect must still earn its place once the later rounds' effects are in (backward
elimination of the greedy forward selection). A round judges an effect before the later ones are in, so an
effect can stand in for part of a later one (on coupled axes, a constant force on one axis first taken up on its
neighbour through the coupling). Units: SI (s, m, N)."""
from __future__ import annotations

from pathlib import Path

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.screen import MAX_NFEV
from motiontwin.ident.diagnosis.select import model_null
from motiontwin.ident.diagnosis.structure import ModelFit, _log, build_axes, build_structure, evidence_key


def _without(bundle: Bundle, current: ModelFit, effect: effect_models.Effect, folder: Path,
             weights: outputerror.Weights) -> ModelFit:
    """``current`` without ``effect``, refitted from its values."""
    own = {p.name for p in effect.params}
    values = {k: v for k, v in current.fit.values.items() if k not in own}
    if current.axes:
        pairs = [(a, e) for a, e in current.placed if e is not effect]
        loop, bounds = build_axes(bundle, pairs, values, folder, bundle.train.time.size,
                                  min_substeps=current.loop.substeps)
        effects, axes = [e for _, e in pairs], [a for a, _ in pairs]
    else:
        effects, axes = [e for e in current.effects if e is not effect], []
        loop, bounds = build_structure(bundle, effects, values, folder, bundle.train.time.size,
                                       min_substeps=current.loop.substeps)
    result = outputerror.fit(loop, bundle.train, weights, bounds, start={**loop.values, **values}, max_nfev=MAX_NFEV,
                             estimate_start=True, shift=current.fit.shift)
    return ModelFit(effects, loop.with_values(result.values), result, bounds, folder, axes=axes)


def prune(bundle: Bundle, final: ModelFit, weights: outputerror.Weights, work: Path, progress=None) -> ModelFit:
    """Each kept effect (of two or more) removed and the rest refitted: when the cost it saves no longer beats
    its bootstrap null (drawn from the model without it, :func:`select.model_null`), it is dropped."""
    current = final
    for effect in list(final.effects):
        if len(current.effects) < 2:
            break
        k = next(i for i, e in enumerate(current.effects) if e is effect)
        axis = current.axes[k] if current.axes else None
        key = evidence_key(effect.name, axis)
        on = "" if axis is None else f" on {axis}"
        without = _without(bundle, current, effect, work / f"prune_{key}", weights)
        saved = without.fit.cost - current.fit.cost
        null = model_null(bundle, without, weights, 97, progress)
        threshold = evidence.null_threshold(evidence.extension_null(current.fit.jacobian, without.fit.jacobian, null),
                                            sum(p.fitted for p in effect.params))
        dropped = saved <= threshold
        _log(progress, f"  {effect.name}{on} with the other effects in: cost {-saved:+.4g} without it, null "
                       f"{threshold:.4g} ({'dropped' if dropped else 'kept'})")
        if dropped:
            without.evidence = {n: v for n, v in current.evidence.items() if n != key}
            current = without
    return current
