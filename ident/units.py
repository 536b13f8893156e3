"""Unit checks of recordings before identification: declared units, explicit conversion, plausibility.

A recording (harness.recording) declares the unit of every column in its sidecar. Identification needs
SI: time in s, positions in m (linear) or rad (rotary), forces in N (linear) or N.m (rotary).
:func:`checked_columns` refuses a column whose declared unit is not of the needed kind, naming the
column, the declared unit and the expected one; a unit of the right kind but another scale (mm, um,
deg, kN, ms, ...) is converted, and the conversion is reported in ``notes`` (never silent).
A wrong *declaration* of the right kind (positions in mm declared m) cannot be seen from the string,
so :func:`check_motion` and :func:`check_inertia` test the converted data against generous physical
ranges of motion systems (PLAUSIBLE) and against an optional a-priori value, and raise
:class:`UnitError` naming the column.

Units: SI (s, m, rad, N, N.m, kg, kg.m2).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motiontwin.harness.recording import Recording, RecordingError
from motiontwin.harness.units import SCALES

__all__ = [
    "UnitError",
    "SCALES",
    "PLAUSIBLE",
    "CheckedColumns",
    "checked_columns",
    "check_motion",
    "check_inertia",
]


class UnitError(RecordingError):
    """A column's declared unit is wrong for the identification, or the data are implausible in it."""


_EXPECTED = {"time": "s", "position": "m or rad", "length": "m", "force": "N or N.m"}
_ROTARY = {"m": False, "rad": True, "N": False, "N.m": True}

#: Generous ranges of precision motion systems (linear: m, m/s, m/s^2, kg; rotary: rad, rad/s,
#: rad/s^2, kg.m2). Data outside them almost always means a mis-declared unit.
PLAUSIBLE = {
    "linear": {"span": 20.0, "speed": 20.0, "acceleration": 2e3, "inertia": (1e-3, 1e5)},
    "rotary": {"span": 1e4, "speed": 2e3, "acceleration": 1e6, "inertia": (1e-9, 1e5)},
}


@dataclass(frozen=True)
class CheckedColumns:
    """Columns converted to SI: time [s], values (name -> array), units (name -> SI unit),
    notes (one line per conversion or assumption made, to be shown to the user)."""

    time: np.ndarray
    values: dict[str, np.ndarray]
    units: dict[str, str]
    notes: list[str] = field(default_factory=list)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    @property
    def sample_rate(self) -> float:
        """[Hz] from the median time step."""
        return 1.0 / float(np.median(np.diff(self.time)))

    def rotary(self, name: str) -> bool:
        """True when column ``name`` is an angle [rad] or a torque [N.m]."""
        return _ROTARY[self.units[name]]


def _convert(rec: Recording, name: str, quantity: str, source: str, assumed: str) -> tuple[np.ndarray, str, str]:
    """(SI values, SI unit, note or '') of one column; UnitError if its unit is not of ``quantity``."""
    declared = (rec.units.get(name) or "").strip()
    if not declared:
        si = assumed
        return np.asarray(rec[name], dtype=float), si, f"{source}: column {name!r} declares no unit; assumed {si}"
    scales = SCALES[quantity]
    if declared not in scales:
        known = ", ".join(scales)
        raise UnitError(
            f"{source}: column {name!r} is declared in {declared!r}, but a {quantity} in {_EXPECTED[quantity]} "
            f"is expected (convertible units: {known}); fix 'units' in the sidecar or choose another column"
        )
    si, factor = scales[declared]
    values = np.asarray(rec[name], dtype=float) * factor
    note = "" if factor == 1.0 and declared == si else (
        f"{source}: column {name!r} converted from {declared} to {si} (x {factor:.10g})")
    return values, si, note


def checked_columns(rec: Recording, quantities: dict[str, str], *, source: str = "recording") -> CheckedColumns:
    """Check and convert the columns an identification uses.

    quantities: column name -> 'position', 'length' (linear only) or 'force' (time is always checked).
    Positions and forces
    must agree (m with N, rad with N.m). A column without a declared unit is taken as SI of the kind
    its partner has (m/N if none declares one), and a note says so.
    """
    unknown = sorted(set(quantities.values()) - {"position", "length", "force"})
    if unknown:
        raise ValueError(f"quantities must be 'position', 'length' or 'force', got {unknown}")
    notes: list[str] = []
    time, _, note = _convert(rec, "time", "time", source, "s")
    notes += [note] if note else []
    declared_rotary = {_ROTARY[SCALES[q][u][0]] for n, q in quantities.items()
                       if (u := (rec.units.get(n) or "").strip()) in SCALES[q]}
    rotary = declared_rotary == {True}
    values, units = {}, {}
    for name, quantity in quantities.items():
        assumed = {"position": "rad" if rotary else "m", "length": "m", "force": "N.m" if rotary else "N"}[quantity]
        values[name], units[name], note = _convert(rec, name, quantity, source, assumed)
        notes += [note] if note else []
    kinds = {name: _ROTARY[unit] for name, unit in units.items()}
    if len(set(kinds.values())) > 1:
        listing = ", ".join(f"{name!r} in {units[name]}" for name in units)
        raise UnitError(
            f"{source}: columns {listing} mix linear and rotary units; a linear axis needs m and N, "
            "a rotary one rad and N.m"
        )
    return CheckedColumns(time, values, units, notes)


def check_motion(columns: CheckedColumns, name: str, *, source: str = "recording",
                 velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
    """Raise UnitError if position column ``name`` spans, or moves faster or harder, than PLAUSIBLE allows.

    ``velocity``/``acceleration`` (SI): filtered derivatives if the caller has them; otherwise they are
    taken by central differences of the recorded position (noise makes these upper estimates, so the
    acceleration is only checked when given).
    """
    q = columns[name]
    unit = columns.units[name]
    limits = PLAUSIBLE["rotary" if columns.rotary(name) else "linear"]
    if velocity is None:
        velocity = np.gradient(q, columns.time)
    found = {"span": float(np.ptp(q)), "speed": float(np.max(np.abs(velocity)))}
    if acceleration is not None:
        found["acceleration"] = float(np.max(np.abs(acceleration)))
    rates = {"span": unit, "speed": f"{unit}/s", "acceleration": f"{unit}/s2"}
    excess = [key for key, value in found.items() if value > limits[key]]
    if excess:
        listing = ", ".join(f"{key} {found[key]:.4g} {rates[key]} (plausible <= {limits[key]:.4g})" for key in excess)
        raise UnitError(
            f"{source}: column {name!r} declared in {unit} has an implausible {listing}; were the positions "
            f"recorded in a smaller unit (e.g. mm or deg)? Declare the recorded unit in the sidecar"
        )


def check_inertia(value: float, parameter: str, column: str, rotary: bool, *, source: str = "recording",
                  nominal: float | None = None, factor: float = 10.0) -> None:
    """Raise UnitError if a fitted mass/inertia [kg or kg.m2] is negative, outside PLAUSIBLE, or (with
    ``nominal``) more than ``factor`` away from the a-priori value; the message names the position column
    whose unit scales the estimate (positions k times too large give an inertia k times too small)."""
    unit = "kg.m2" if rotary else "kg"
    low, high = PLAUSIBLE["rotary" if rotary else "linear"]["inertia"]
    if nominal is not None:
        low, high = abs(nominal) / factor, abs(nominal) * factor
        reason = f"more than {factor:g}x away from the a-priori {abs(nominal):.4g} {unit}"
    else:
        reason = f"outside the plausible range {low:.3g}..{high:.3g} {unit}"
    if not value > 0:
        reason = "not positive"
    elif low <= value <= high:
        return
    raise UnitError(
        f"{source}: fitted {parameter} = {value:.4g} {unit} is {reason}; check the declared unit of column "
        f"{column!r} (a position recorded in mm but declared m makes {parameter} 1000x too small) "
        "and that the experiment excites the motion"
    )
