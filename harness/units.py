"""Unit strings of FMU variables and recordings: parsing into SI base-unit exponents and comparison.

Modelica/FMI unit strings ("m/s2", "N.s/m", "kg.m2") are compared by their exponents over the SI
base units, so "N" and "kg.m/s2" are the same unit; unparseable strings compare verbatim.
"""

from __future__ import annotations

import re
from typing import Any

_DERIVED_SI = {
    "N": {"kg": 1, "m": 1, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2},
    "W": {"kg": 1, "m": 2, "s": -3},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "Hz": {"s": -1},
}
_FACTOR = re.compile(r"^([A-Za-z_]+)(-?\d+)?$")


def canonical_unit(unit: str) -> tuple[tuple[str, int], ...] | None:
    """Exponents of a Modelica unit string ("m/s2", "m.s-1", "N.s/m") over SI base units, or
    None when the string is not parseable (then it is compared verbatim)."""
    powers: dict[str, int] = {}
    for position, part in enumerate(unit.split("/")):
        sign = 1 if position == 0 else -1
        for factor in part.split("."):
            if factor in ("", "1"):
                continue
            match = _FACTOR.match(factor)
            if not match:
                return None
            name, exponent = match.group(1), int(match.group(2) or 1)
            for base, p in _DERIVED_SI.get(name, {name: 1}).items():
                powers[base] = powers.get(base, 0) + sign * exponent * p
    return tuple(sorted((k, v) for k, v in powers.items() if v != 0))


def units_compatible(a: str | None, b: str | None) -> bool:
    """True when either unit is undeclared or both denote the same SI unit."""
    if not a or not b:
        return True
    ca, cb = canonical_unit(a), canonical_unit(b)
    return a == b if ca is None or cb is None else ca == cb


def variable_unit(variable: Any) -> str | None:
    """The unit of an fmpy model variable, from the variable or its declared type."""
    if variable.unit:
        return variable.unit
    declared = getattr(variable, "declaredType", None)
    return getattr(declared, "unit", None) if declared is not None else None
