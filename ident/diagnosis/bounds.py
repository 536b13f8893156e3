"""Parameters that end on a bound of their fit: found in the final structure, reported in diagnosis.json, the
report and the CLI line (a bound hit is never silent). Nominal bounds are physical (the plant's Modelica
min/max, :func:`structure._nominal_bounds`); an effect's bounds are those of its :class:`effect_base.Param`,
whose sides are physical (:func:`physical_sides`) or search ranges, which :func:`widened_effects` widens when
the fit ends on them (the refit is :func:`select.widen_search_bounds`)."""
from __future__ import annotations

import dataclasses
import math

from motiontwin.ident.diagnosis.effect_base import Effect, Param

AT_BOUND_RTOL = 1e-6   # a value within this fraction of the bound's scale counts as on the bound
AT_BOUND_ATOL = 1e-15  # ... or this close to a bound at 0 (the fit starts strictly inside its bounds)
WIDEN_FACTOR = 10.0    # a search limit the fit ends on moves this factor away from zero (or towards it)
WIDEN_ROUNDS = 2       # refits with widened search limits at most


def _strip(name: str) -> str:
    return name[len("plant."):] if name.startswith("plant.") else name


def at_bound(values: dict[str, float], bounds: dict[str, tuple[float, float]], free: list[str]) -> dict[str, dict]:
    """The fitted parameters of ``free`` that sit on a finite bound: name (without ``plant.``) -> value, side
    ("lower"/"upper") and the bound's value."""
    found = {}
    for name in free:
        if name not in bounds:
            continue
        value = float(values[name])
        for side, limit in zip(("lower", "upper"), bounds[name]):
            if not math.isfinite(limit):
                continue
            span = bounds[name][1] - bounds[name][0]
            scale = max(abs(limit), abs(value), abs(span) if math.isfinite(span) else 0.0, 1e-300)
            if abs(value - limit) <= AT_BOUND_RTOL * scale + AT_BOUND_ATOL:
                found[_strip(name)] = {"value": value, "bound": side, "limit": float(limit)}
    return found


def physical_sides(param: Param) -> tuple[bool, bool]:
    """Which sides (lower, upper) of ``param``'s bounds are physical, never widened: a limit at 0 (a sign
    constraint), an infinite one, the effect's vanishing point ``zero``, or one the effect marks
    (``Param.physical``: a mass kept positive, the RK4 resolution of a state)."""
    lower, upper = (bool(marked) or limit == 0 or not math.isfinite(limit) or limit == param.zero
                    for marked, limit in zip(param.physical, param.bounds))
    return lower, upper


def widened_limits(bounds: tuple[float, float], hit: set[str], physical: tuple[bool, bool],
                   factor: float = WIDEN_FACTOR) -> tuple[float, float]:
    """``bounds`` with each hit ("lower"/"upper") non-physical side moved ``factor`` away: outwards by the
    factor in magnitude, or towards zero when the side faces zero (a positive lower limit divided by it), so
    that a limit never crosses 0 and a positive parameter stays positive."""
    lo, hi = bounds
    if "lower" in hit and not physical[0]:
        lo = lo / factor if lo > 0 else lo * factor
    if "upper" in hit and not physical[1]:
        hi = hi * factor if hi > 0 else hi / factor
    return lo, hi


def widened_effects(structure) -> tuple[list[Effect], dict[str, tuple[float, float]]]:
    """The effects of a fitted :class:`structure.ModelFit` with every parameter that ends on a search limit
    (:func:`physical_sides`) widened (:func:`widened_limits`; ``Param.searched`` keeps the default range),
    and the new bounds by parameter name (empty: nothing to widen)."""
    hits = structure_at_bound(structure)
    changed: dict[str, tuple[float, float]] = {}
    effects = []
    for effect in structure.effects:
        params = []
        for p in effect.params:
            hit = {e["bound"] for name, e in hits.items() if name == p.name} if p.fitted else set()
            new = widened_limits(p.bounds, hit, physical_sides(p)) if hit else p.bounds
            if new != p.bounds:
                changed[p.name] = new
                p = dataclasses.replace(p, bounds=new, searched=p.searched or p.bounds)
            params.append(p)
        effects.append(dataclasses.replace(effect, params=params))
    return effects, changed


def bounds_widened(structure) -> dict[str, dict]:
    """The search limits widened in a fitted structure: name -> side, default limit, widened limit and the
    fitted value (diagnosis.json ``bounds_widened``)."""
    out = {}
    for p in (p for e in structure.effects for p in e.params if p.searched is not None):
        for side, old, new in zip(("lower", "upper"), p.searched, p.bounds):
            if old != new:
                out[p.name] = {"bound": side, "from": float(old), "to": float(new),
                               "value": float(structure.fit.values[p.name])}
    return out


def structure_at_bound(structure) -> dict[str, dict]:
    """:func:`at_bound` of a fitted :class:`structure.ModelFit`; a widened limit names its default
    (``widened_from``)."""
    found = at_bound(structure.fit.values, structure.bounds, structure.loop.free)
    searched = {p.name: p.searched for e in structure.effects for p in e.params if p.searched is not None}
    for name, entry in found.items():
        if name in searched:
            old = searched[name][0 if entry["bound"] == "lower" else 1]
            if old != entry["limit"]:
                entry["widened_from"] = float(old)
    return found


def at_bound_text(entries: dict[str, dict]) -> str:
    """One phrase for the CLI line and the report ("" when no parameter is on a bound)."""
    return ", ".join(f"{name} = {e['value']:.4g} at its {e['bound']} bound {e['limit']:.4g}"
                     + (f" (widened from {e['widened_from']:.4g})" if "widened_from" in e else "")
                     for name, e in entries.items())


def at_bound_markdown(entries: dict[str, dict], widened: dict[str, dict] | None = None) -> list[str]:
    """The report's section on parameters at a bound and on widened search limits (empty when neither)."""
    left = {n: w for n, w in (widened or {}).items() if n not in entries}
    if not entries and not left:
        return []
    lines = ["## Parameters at a bound" if entries else "## Widened search limits", ""]
    if entries:
        lines += [f"These fitted parameters ended on a bound of their fit, so their values are limits, not "
                  f"estimates: {at_bound_text(entries)}.", ""]
    if left:
        moved = ", ".join(f"{n} = {w['value']:.4g} (its {w['bound']} search limit widened from {w['from']:.4g} "
                          f"to {w['to']:.4g})" for n, w in left.items())
        lines += [f"These fitted parameters ended on a search limit of their effect and were refitted with it "
                  f"widened; they now lie inside: {moved}.", ""]
    return lines
