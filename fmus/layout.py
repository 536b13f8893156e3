"""Value references and FMI attributes of every variable of a model, decided in one place.

The block order is the contract of ``fmus/runtime/mt_model.h``: vr 0 is time, then states x,
derivatives dx, inputs u, computed variables y, held sampled outputs yd, discrete states z,
parameters p. The C descriptor (codegen) and modelDescription.xml (description) both read
this table, so they cannot disagree.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca

from motiontwin.fmus.symbolic import SymbolicModel

BLOCKS = ("x", "dx", "u", "y", "yd", "z", "p")


@dataclass
class FmuVariable:
    """One FMU variable (all are Float64)."""

    vr: int
    name: str
    block: str
    causality: str
    variability: str
    initial: str | None
    start: float | None
    description: str = ""
    unit: str = ""
    min: float = -math.inf
    max: float = math.inf
    nominal: float | None = None
    derivative_of: int | None = None  # vr of the state this is the derivative of
    dependencies: list[int] | None = field(default=None)  # vrs of x/u an output depends on; None: all


@dataclass
class Layout:
    variables: list[FmuVariable]   # vr order, starting with time at vr 0
    sizes: dict[str, int]

    def block(self, name: str) -> list[FmuVariable]:
        return [v for v in self.variables if v.block == name]

    def by_name(self, name: str) -> FmuVariable:
        for v in self.variables:
            if v.name == name:
                return v
        raise KeyError(name)


def layout(model: SymbolicModel) -> Layout:
    """Assign value references and FMI attributes to every variable of ``model``."""
    vars_: list[FmuVariable] = [FmuVariable(0, "time", "time", "independent", "continuous", None, None,
                                            "simulation time", "s")]
    outputs = set(model.flat.outputs)

    def add(block: str, **kw: object) -> FmuVariable:
        var = FmuVariable(vr=len(vars_), block=block, **kw)  # type: ignore[arg-type]
        vars_.append(var)
        return var

    def start_of(v, default: float | None = 0.0) -> tuple[str, float | None]:
        if v.start is None:
            return "exact", default
        if isinstance(v.start, ca.SX):
            if v.start.is_constant():
                return "exact", float(ca.DM(v.start))
            return "calculated", None
        return "exact", float(v.start)

    sampled = model.sampled
    dep_x, dep_u = _dependencies(model)
    state_vrs: list[int] = []
    if not sampled:
        for v in model.states:
            initial, start = start_of(v)
            var = add("x", name=v.name, causality="output" if v.name in outputs else "local",
                      variability="continuous", initial=initial, start=start, description=v.description,
                      unit=v.unit, min=v.min, max=v.max, nominal=v.nominal)
            state_vrs.append(var.vr)
        for i, v in enumerate(model.states):
            add("dx", name=f"der({v.name})", causality="local", variability="continuous", initial="calculated",
                start=None, description=f"derivative of {v.name}", unit=_derivative_unit(v.unit),
                derivative_of=state_vrs[i])
    nx = len(state_vrs)
    input_vrs = []
    for v in model.inputs:
        _, start = start_of(v)
        var = add("u", name=v.name, causality="input", variability="discrete" if sampled else "continuous",
                  initial=None, start=start, description=v.description, unit=v.unit, min=v.min, max=v.max,
                  nominal=v.nominal)
        input_vrs.append(var.vr)
    block_y = "yd" if sampled else "y"
    for k, c in enumerate(model.computed):
        deps = None
        if not sampled and c.causality == "output":
            deps = [state_vrs[j] for j in dep_x[nx + k]] + [input_vrs[j] for j in dep_u[nx + k]]
        add(block_y, name=c.var.name, causality=c.causality,
            variability="fixed" if c.causality == "calculatedParameter" else ("discrete" if sampled else "continuous"),
            initial="calculated", start=None, description=c.var.description, unit=c.var.unit,
            min=c.var.min, max=c.var.max, nominal=c.var.nominal, dependencies=deps)
    if sampled:
        for v in model.states:
            initial, start = start_of(v)
            add("z", name=v.name, causality="local", variability="discrete", initial="exact",
                start=start if start is not None else 0.0, description=v.description, unit=v.unit)
    for v in model.parameters:
        _, start = start_of(v)
        add("p", name=v.name, causality="parameter", variability="fixed", initial="exact", start=start,
            description=v.description, unit=v.unit, min=v.min, max=v.max, nominal=v.nominal)
    for v in vars_:
        if v.block == "x" and v.causality == "output":
            v.dependencies = [v.vr]
    sizes = {b: sum(1 for v in vars_ if v.block == b) for b in BLOCKS}
    return Layout(vars_, sizes)


def _dependencies(model: SymbolicModel) -> tuple[list[list[int]], list[list[int]]]:
    """Structural dependencies of [dx; y] on x and on u, from the Jacobian's sparsity."""
    if model.sampled:
        return [], []
    f = ca.vertcat(model.dx, model.y)
    jx = ca.jacobian(f, model.x).sparsity()
    ju = ca.jacobian(f, model.u).sparsity()
    rows_x: list[list[int]] = [[] for _ in range(f.numel())]
    rows_u: list[list[int]] = [[] for _ in range(f.numel())]
    for r, c in zip(*jx.get_triplet()):
        rows_x[r].append(c)
    for r, c in zip(*ju.get_triplet()):
        rows_u[r].append(c)
    return [sorted(r) for r in rows_x], [sorted(r) for r in rows_u]


def _derivative_unit(unit: str) -> str:
    """Unit of a time derivative in Modelica unit syntax: m -> m/s, m/s -> m/s2, 1 -> s-1."""
    if not unit:
        return ""
    if unit == "1":
        return "s-1"
    if "/" not in unit:
        return f"{unit}/s"
    num, den = unit.rsplit("/", 1)
    if den == "s":
        return f"{num}/s2"
    if den.startswith("s") and den[1:].isdigit():
        return f"{num}/s{int(den[1:]) + 1}"
    return f"{num}/({den}.s)"
