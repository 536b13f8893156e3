"""Where a nominal plant keeps its input, measured output, position and velocity, whatever its form.

The diagnosis adds effect forces to the plant's input and writes structural effects in terms of the
plant's position and velocity. A plant may be written in any form the front end accepts: the output may be
a state itself (``der(q) = v``), an algebraic alias of one (``q = x``) or an affine expression of one
(a gear ratio ``q = 0.002*phi``, a sensor offset ``q = s + offset``), with any state names. The roles are
found from the equations (the *derivative chain* of the output: the single state the output is affine in
is the position, the state equal to its derivative is the velocity) or named in the bundle
(``plant.position`` / ``plant.velocity``). Positions and velocities are in the plant's own state
coordinates; :func:`output_map` converts the measured output into them. An axis of a multi-axis plant may
instead have an output that is any differentiable expression of the states (a leg length L(pose)): its
position is that expression and its velocity the expression's time derivative (:func:`output_rate`,
:mod:`ident.diagnosis.axis_kinematics`). Units: those of the plant.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca

from motiontwin.fmus import symbolic
from motiontwin.ident.plant_states import output_expression, output_state, velocity_state

CHAIN = "derivative chain of the output"
NAMED = "bundle fields plant.position/plant.velocity"
EXPRESSION = "output expression of the states and its time derivative"


class PlantFormError(ValueError):
    """The plant's form is not supported; the message names the construct and the plant file's line."""


@dataclass(frozen=True)
class PlantRoles:
    """Names (in the plant class) of the driven input, the measured output, the position and velocity
    states, how they were found, and the other inputs with the values they are held at."""

    input: str
    output: str
    position: str
    velocity: str
    source: str = CHAIN
    held_inputs: dict[str, float] = field(default_factory=dict)

    @property
    def expression(self) -> bool:
        """The axis's position is its output expression (no single state), its velocity that expression's
        time derivative (:func:`output_rate`); axis coordinates are the output's own."""
        return self.source == EXPRESSION

    def describe(self) -> str:
        """One line for the progress output and the report."""
        if self.expression:
            return (f"plant input {self.input}, output {self.output}; position {self.output}(states), velocity "
                    f"its time derivative (from the {self.source})")
        return (f"plant input {self.input}, output {self.output}; position plant.{self.position}, "
                f"velocity plant.{self.velocity} (from the {self.source})")

    def as_dict(self) -> dict:
        return {"input": self.input, "output": self.output, "position": self.position,
                "velocity": self.velocity, "found_from": self.source, "held_inputs": dict(self.held_inputs)}


def declaration_line(text: str, name: str) -> int | None:
    """1-based line of the class or variable declaration of ``name`` (None when absent)."""
    short = re.escape(name.split(".")[-1])
    return _first_line(text, [rf"\b(model|block|class|package)\s+{short}\b",
                              rf"\b(input|output|Real|parameter)\b[^;]*\b{short}\b", rf"\b{short}\b"])


def equation_line(text: str, name: str, derivative: bool = False) -> int | None:
    """1-based line of the equation defining ``name`` (``name = ...`` or ``... = name``), or with
    ``derivative`` its derivative (``der(name) = ...``), else of its declaration."""
    short = re.escape(name)
    patterns = [rf"\bder\(\s*{short}\s*\)"] if derivative else [rf"^\s*{short}\s*=", rf"=\s*{short}\s*;"]
    return _first_line(text, patterns) or declaration_line(text, name)


def _first_line(text: str, patterns: list[str]) -> int | None:
    """First line (1-based) matching the first pattern that matches any line; strings are ignored."""
    lines = [re.sub(r'"[^"]*"', '""', line) for line in text.splitlines()]
    for pattern in patterns:
        for number, line in enumerate(lines, 1):
            if re.search(pattern, line):
                return number
    return None


def _where(path: Path, line: int | None) -> str:
    return f"{path}, line {line}" if line else str(path)


def output_rate(model: symbolic.SymbolicModel, output_name: str) -> tuple[ca.SX, ca.SX]:
    """The output ``h(x, p)`` and its time derivative ``dh/dx * der(x)`` (for a leg length by inverse
    kinematics: J(pose) times the pose rates), both free of inputs and time (position-level outputs)."""
    expr = output_expression(model, output_name)
    return expr, ca.jtimes(expr, model.x, model.dx)


def find_roles(model: symbolic.SymbolicModel, text: str, path: Path, input_name: str, output_name: str,
               position: str | None = None, velocity: str | None = None, expression: bool = False) -> PlantRoles:
    """The roles of a plant (see the module docstring); raises :class:`PlantFormError` naming the construct
    and the line of ``path`` (whose source is ``text``) when the form is not supported.

    Parameters
    ----------
    model : the plant through the front end.
    text, path : the plant file's source and path (for the line numbers of errors).
    input_name, output_name : the driven input and the measured output.
    position, velocity : state names from the bundle, or None to find them from the derivative chain.
    expression : accept an output that is a nonlinear expression of several states (an axis of a multi-axis
        plant: a leg length of a pose), whose time derivative is then its velocity.

    Returns
    -------
    PlantRoles
    """
    names = [v.name for v in model.states]
    inputs = [v.name for v in model.inputs]
    if input_name not in inputs:
        raise PlantFormError(f"{path}: class {model.name} has no input {input_name!r} (inputs: {inputs})")
    held = {v.name: float(v.start) if isinstance(v.start, (int, float)) else 0.0
            for v in model.inputs if v.name != input_name}
    expr = output_expression(model, output_name)
    if expr is None:
        raise PlantFormError(f"{path}: class {model.name} has no output {output_name!r} "
                             f"(outputs: {model.state_outputs + [c.var.name for c in model.computed]})")
    for role, name in (("position", position), ("velocity", velocity)):
        if name is not None and name not in names:
            raise PlantFormError(f"{path}: plant.{role} names {name!r}, which is not a state of class "
                                 f"{model.name}; its states are {', '.join(names)}")
    where = _where(path, equation_line(text, output_name))
    if ca.depends_on(expr, model.u):
        raise PlantFormError(f"{where}: output {output_name} = {expr} depends on an input directly; the "
                             f"measured output must be a position (an expression of one state)")
    pos = names.index(position) if position is not None else output_state(model, output_name)
    if pos is None and expression and velocity is None:
        rate = output_rate(model, output_name)[1]
        if not ca.depends_on(expr, model.x) or ca.depends_on(rate, ca.vertcat(model.u, model.t)):
            raise PlantFormError(f"{where}: output {output_name} = {expr} is not a position-level expression of "
                                 f"the states (it depends on no state, or its time derivative depends on an "
                                 f"input); an axis output must be a function of the positions, such as a leg "
                                 f"length by inverse kinematics")
        return PlantRoles(input_name, output_name, "", "", EXPRESSION, held)
    if pos is None:
        raise PlantFormError(f"{where}: output {output_name} = {expr} is not affine in exactly one state, so "
                             f"its position state is not defined; write it as a state, an alias or an affine "
                             f"expression of one state, or name plant.position and plant.velocity in "
                             f"experiment.json")
    if not ca.depends_on(expr, model.x[pos]):
        raise PlantFormError(f"{where}: output {output_name} = {expr} does not depend on plant.position "
                             f"{names[pos]!r}")
    if velocity is not None:
        vel = names.index(velocity)
    else:
        vel = velocity_state(model, pos)
        if vel is None:
            line = equation_line(text, names[pos], derivative=True)
            raise PlantFormError(f"{_where(path, line)}: der({names[pos]}) = {model.dx[pos]} is not "
                                 f"a state of class {model.name}, so the velocity is not defined; write "
                                 f"der({names[pos]}) = <velocity state>, or name plant.velocity in "
                                 f"experiment.json")
    source = NAMED if position is not None or velocity is not None else CHAIN
    return PlantRoles(input_name, output_name, names[pos], names[vel], source, held)


def output_map(model: symbolic.SymbolicModel, roles: PlantRoles, values: dict[str, float]) -> tuple[float, float]:
    """(gain, offset) of the output as ``gain*position + offset`` at the parameter ``values`` and the other
    states at their start values; the measured output q corresponds to the position (q - offset)/gain.
    An expression axis is in its output's coordinates: (1, 0)."""
    if roles.expression:
        return 1.0, 0.0
    expr = output_expression(model, roles.output)
    i_pos = [v.name for v in model.states].index(roles.position)
    fn = ca.Function("h", [model.x, model.u, model.p], [expr, ca.jacobian(expr, model.x[i_pos])])
    p = [values[v.name] for v in model.parameters]
    x0 = ca.Function("x0", [model.p], [model.x0()])(p)
    x0[i_pos] = 0
    offset, gain = fn(x0, ca.DM.zeros(model.u.numel()), p)
    gain = float(gain)
    if gain == 0:
        raise PlantFormError(f"{model.flat.source}: output {roles.output} does not change with plant.position "
                             f"{roles.position!r} at the refitted parameters")
    return gain, float(offset)
