"""Parameters that end on a bound of their fit: found in the final structure, reported in diagnosis.json, the
report and the CLI line (a bound hit is never silent). Nominal bounds are physical (the plant's Modelica
min/max, :func:`structure._nominal_bounds`); an effect's bounds are those of its :class:`effect_base.Param`."""
from __future__ import annotations

import math

AT_BOUND_RTOL = 1e-6   # a value within this fraction of the bound's scale counts as on the bound
AT_BOUND_ATOL = 1e-15  # ... or this close to a bound at 0 (the fit starts strictly inside its bounds)


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


def structure_at_bound(structure) -> dict[str, dict]:
    """:func:`at_bound` of a fitted :class:`structure.ModelFit`."""
    return at_bound(structure.fit.values, structure.bounds, structure.loop.free)


def at_bound_text(entries: dict[str, dict]) -> str:
    """One phrase for the CLI line and the report ("" when no parameter is on a bound)."""
    return ", ".join(f"{name} = {e['value']:.4g} at its {e['bound']} bound {e['limit']:.4g}"
                     for name, e in entries.items())


def at_bound_markdown(entries: dict[str, dict]) -> list[str]:
    """The report's section on parameters at a bound (empty when there is none)."""
    if not entries:
        return []
    return ["## Parameters at a bound", "",
            f"These fitted parameters ended on a bound of their fit, so their values are limits, not estimates: "
            f"{at_bound_text(entries)}.", ""]
