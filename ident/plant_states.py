"""Which states of a plant model carry its measured position and its velocity, read from the equations.

One place for the question the output-error refit, the start values and the diagnosis all ask: the output is
a state, an alias of one (``q = x``) or an affine expression of one (a gear ratio, a sensor offset); the
velocity is the state the position's derivative equals (``der(x) = v``).
"""
from __future__ import annotations

import weakref
from typing import Callable

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic

__all__ = ["output_expression", "output_state", "position_from_output", "velocity_state", "per_model",
           "start_state"]

_PER_MODEL: dict[int, tuple[weakref.ref, dict]] = {}    # id(model) -> (the model, what was derived by key)


def per_model(model: symbolic.SymbolicModel, key: object, build: Callable[[], object]) -> object:
    """``build()`` once per model and ``key``, then kept as long as the model lives: what every fit evaluation
    derives from the model's equations (which state carries an output, the start-state function) is the same
    each time. A model's equations are not changed after it is built (:meth:`symbolic.SymbolicModel.with_start_values`
    makes a new one)."""
    entry = _PER_MODEL.get(id(model))
    if entry is None or entry[0]() is not model:
        entry = (weakref.ref(model, lambda _, k=id(model): _PER_MODEL.pop(k, None)), {})
        _PER_MODEL[id(model)] = entry
    if key not in entry[1]:
        entry[1][key] = build()
    return entry[1][key]


def start_state(model: symbolic.SymbolicModel, p: np.ndarray) -> np.ndarray:
    """The model's start state at the parameter vector ``p`` (in ``model.parameters`` order); the function is
    built once per model."""
    fn = per_model(model, "start", lambda: ca.Function("x0", [model.p], [model.x0()]))
    return np.array(fn(p), float).ravel()


def output_expression(model: symbolic.SymbolicModel, name: str) -> ca.SX | None:
    """Output or state ``name`` as an expression of states, inputs and parameters (None when there is none)."""
    names = [v.name for v in model.states]
    if name in names:
        return model.x[names.index(name)]
    found = [c.expr for c in model.computed if c.var.name == name and c.causality != "calculatedParameter"]
    return found[0] if found else None


def output_state(model: symbolic.SymbolicModel, name: str, affine: bool = True) -> int | None:
    """Index of the state the output ``name`` is affine in when it depends on exactly one state and on no
    input (a position state, an alias, a gear ratio or an offset of one), else None. ``affine=False``: also
    when the output is nonlinear in that one state (a position read with a sensor error periodic in it)."""
    return per_model(model, ("output_state", name, affine), lambda: _output_state(model, name, affine))


def _output_state(model: symbolic.SymbolicModel, name: str, affine: bool) -> int | None:
    expr = output_expression(model, name)
    if expr is None or ca.depends_on(expr, model.u):
        return None
    hits = [i for i in range(model.x.numel()) if ca.depends_on(expr, model.x[i])]
    if len(hits) != 1 or (affine and ca.depends_on(ca.jacobian(expr, model.x[hits[0]]), model.x)):
        return None
    return hits[0]


def position_from_output(model: symbolic.SymbolicModel, name: str, values: dict[str, float],
                         measured: np.ndarray) -> tuple[str, np.ndarray] | None:
    """The state the output ``name`` is affine in (``q = x``, a gear ratio ``q = g x``, an offset ``q = x + c``;
    g and c constant in the states, evaluated at the parameter ``values``, the others at their start values)
    and its trajectory ``(measured - c) / g``; None for any other output or g = 0."""
    i = output_state(model, name)
    if i is None:
        return None
    def affine() -> ca.Function:
        expr = output_expression(model, name)
        return ca.Function("affine", [model.p], [ca.jacobian(expr, model.x[i]),
                                                 ca.substitute(expr, model.x, ca.DM.zeros(model.x.numel()))])

    fn = per_model(model, ("affine_output", name), affine)
    p = np.array([values.get(v.name, float(v.start)) for v in model.parameters], float)
    gain, offset = (float(value) for value in fn(p))
    if gain == 0 or not np.isfinite(gain) or not np.isfinite(offset):
        return None
    return model.states[i].name, (np.asarray(measured, float) - offset) / gain


def velocity_state(model: symbolic.SymbolicModel, position: int) -> int | None:
    """Index of the state v with der(x[position]) = v, or None."""
    rate = model.dx[position]
    return next((i for i in range(model.x.numel()) if i != position and ca.is_equal(rate, model.x[i], 2)), None)
