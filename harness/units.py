"""Unit strings of FMU variables and recordings: parsing into SI base-unit exponents and comparison.

Modelica/FMI unit strings ("m/s2", "N.s/m", "kg.m2") are compared by their exponents over the SI
base units, so "N" and "kg.m/s2" are the same unit; unparseable strings compare verbatim.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

_DERIVED_SI = {
    "N": {"kg": 1, "m": 1, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2},
    "W": {"kg": 1, "m": 2, "s": -3},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "Hz": {"s": -1},
}
_FACTOR = re.compile(r"^([A-Za-z_]+)(-?\d+)?$")

#: quantity -> unit string -> (SI unit, factor to SI). Spellings follow Modelica ("N.m", "um").
SCALES: dict[str, dict[str, tuple[str, float]]] = {
    "time": {"s": ("s", 1.0), "ms": ("s", 1e-3), "us": ("s", 1e-6)},
    "position": {
        "m": ("m", 1.0), "mm": ("m", 1e-3), "um": ("m", 1e-6), "nm": ("m", 1e-9),
        "rad": ("rad", 1.0), "mrad": ("rad", 1e-3), "urad": ("rad", 1e-6), "deg": ("rad", np.pi / 180),
    },
    "length": {"m": ("m", 1.0), "mm": ("m", 1e-3), "um": ("m", 1e-6), "nm": ("m", 1e-9)},
    "force": {
        "N": ("N", 1.0), "kN": ("N", 1e3), "mN": ("N", 1e-3),
        "N.m": ("N.m", 1.0), "Nm": ("N.m", 1.0), "kN.m": ("N.m", 1e3), "mN.m": ("N.m", 1e-3),
    },
}


def si_scale(unit: str) -> tuple[str, float] | None:
    """(SI unit, factor to SI) of a time, position or force unit of :data:`SCALES`, or of a rate of one
    (``"mm/s"`` -> ``("m/s", 1e-3)``, ``"deg/s2"``); None when the unit is not one of these."""
    unit = unit.strip()
    for table in SCALES.values():
        if unit in table:
            return table[unit]
    head, slash, tail = unit.partition("/")
    if slash and tail in ("s", "s2"):
        base = si_scale(head)
        if base is not None and base[0] != "s":
            return f"{base[0]}/{tail}", base[1]
    return None


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
