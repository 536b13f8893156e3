"""The front end's result: a Modelica class as a flat CasADi DAE, its scalar variables, and the error for a
source that cannot become one. Kept apart from the front end so that the model cache and the symbolic layer
use the types without importing pymoca's wrapper."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca


class ModelicaError(Exception):
    """A Modelica source cannot be turned into a model; the message names file, line and column."""


@dataclass
class Variable:
    """One scalar Modelica variable with the attributes the FMU and the identification need."""

    name: str
    symbol: ca.SX
    description: str = ""
    unit: str = ""
    start: Any = None  # float, or an SX expression of parameters
    min: float = -math.inf
    max: float = math.inf
    nominal: float | None = None


@dataclass
class FlatModel:
    """A Modelica class as a flat DAE ``residual(der_x, x, z, u, p, t) == 0`` in CasADi SX.

    ``states`` carry ``der_states`` in the same order; ``algebraics`` are the remaining unknowns.
    ``parameters`` have numeric values; ``calculated`` are parameters bound to expressions of
    other parameters (substituted into ``residual``, kept so they can be reported).
    """

    name: str
    description: str
    source: Path
    states: list[Variable]
    der_states: list[ca.SX]
    algebraics: list[Variable]
    inputs: list[Variable]
    parameters: list[Variable]
    calculated: list[tuple[Variable, ca.SX]]
    outputs: list[str]
    residual: ca.SX
    time: ca.SX
    annotation: dict[str, Any] = field(default_factory=dict)
