"""The units an axis of a diagnosis is reported in: a linear axis in m, N, kg (shown in mm, mm/s and um), a
rotary one in rad, N.m, kg.m2 (shown in deg, deg/s and urad). An axis is rotary when the recording's position
column is in rad after the bundle's conversion to SI (ident.units; an undeclared column is taken as m) or the
plant output's Modelica unit is rad. The effects' contracts are written in linear units (CONTRACT_UNITS of
:mod:`ident.diagnosis.report`); :meth:`AxisUnits.si` maps them to the axis's kind.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from motiontwin.fmus.symbolic import SymbolicModel

if TYPE_CHECKING:
    from motiontwin.ident.diagnosis.bundle import Bundle

_ROTARY_FACTORS = {"N": "N.m", "kg": "kg.m2", "m": "rad", "m2": "rad2", "m3": "rad3"}


@dataclass(frozen=True)
class AxisUnits:
    """SI units of one axis and the scales its positions, velocities and residuals are shown in."""

    rotary: bool = False

    @property
    def position(self) -> str:
        return "rad" if self.rotary else "m"

    @property
    def force(self) -> str:
        return "N.m" if self.rotary else "N"

    def si(self, linear_unit: str) -> str:
        """``linear_unit`` (an effect contract's unit, written for a linear axis) for this axis's kind: each
        factor of a product or quotient mapped (N -> N.m, kg -> kg.m2, m2 -> rad2: "N.s2/m2" -> "N.m.s2/rad2")."""
        if not self.rotary:
            return linear_unit
        return re.sub(r"[A-Za-z]+\d*", lambda m: _ROTARY_FACTORS.get(m.group(0), m.group(0)), linear_unit)

    @property
    def shown_position(self) -> tuple[float, str]:
        """(factor, unit) positions are shown in: mm, or deg."""
        return (180 / math.pi, "deg") if self.rotary else (1e3, "mm")

    @property
    def shown_velocity(self) -> tuple[float, str]:
        factor, unit = self.shown_position
        return factor, f"{unit}/s"

    def shown_residual(self, peak: float = 0.0) -> tuple[float, str]:
        """(factor, unit) position residuals whose largest magnitude is ``peak`` are shown in: um (urad), or mm
        (mrad) from 10 mm (10 mrad) on, so that a real axis's large errors read as numbers, not 500000 um."""
        if np.isfinite(peak) and peak >= 1e-2:
            return 1e3, ("mrad" if self.rotary else "mm")
        return 1e6, ("urad" if self.rotary else "um")

    def as_dict(self) -> dict[str, str]:
        return {"position": self.position, "velocity": self.si("m/s"), "force": self.force,
                "mass": self.si("kg")}


def axis_units(recording_unit: str | None, model: SymbolicModel | None = None,
               output: str | None = None) -> AxisUnits:
    """The units of an axis whose position column is in ``recording_unit`` (after conversion to SI) and whose
    plant output is ``output`` of ``model``."""
    plant_unit = ""
    if model is not None and output is not None:
        flat = model.flat
        variables = [*flat.states, *flat.algebraics, *flat.inputs]
        plant_unit = next((v.unit for v in variables if v.name == output and v.unit), "")
    return AxisUnits(rotary="rad" in (recording_unit, plant_unit))


def bundle_units(bundle: "Bundle", axis: str | None = None) -> AxisUnits:
    """The units of a single-axis bundle (``axis`` None: column q) or of the axis with output ``axis``."""
    column, output = ("q", bundle.plant.output_name) if axis is None else (axis, axis)
    return axis_units(bundle.train.units.get(column), bundle.plant.model, output)
