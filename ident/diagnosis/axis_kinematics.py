"""Axes whose output is an expression of the plant's states (a hexapod leg length L_i(pose) by inverse
kinematics): the axis's position is the output expression h(x, p), its velocity the time derivative
dh/dx * der(x) (J(pose) times the pose rates), its acceleration the derivative of that. An effect on such an
axis is a force along it subtracted from the axis's input; when the input is the axis's actuator force (a
leg force) that is the force mapped into the plant's coordinates through the Jacobian transpose.

The augmented Modelica model needs the position and velocity as explicit functions of the states (an
algebraic variable inside a friction law would make the equations nonlinear in their unknowns), so each is
written as a Modelica function generated from the CasADi expression (:func:`function_files`) and called with
the plant's states and parameters (:func:`substitutions`). The locate stage needs the opposite direction,
the states from the measured outputs (:func:`states_from_outputs`, Newton on h(x_P) = q). Units: the plant's.
"""
from __future__ import annotations

import re

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, PlantRoles, output_rate

_UNARY = {"NEG": "-({0})", "SQ": "({0})^2", "SQRT": "sqrt({0})", "SIN": "sin({0})", "COS": "cos({0})",
          "TAN": "tan({0})", "ASIN": "asin({0})", "ACOS": "acos({0})", "ATAN": "atan({0})", "EXP": "exp({0})",
          "LOG": "log({0})", "TANH": "tanh({0})", "SINH": "sinh({0})", "COSH": "cosh({0})", "FABS": "abs({0})",
          "SIGN": "sign({0})", "INV": "1/({0})", "TWICE": "2*({0})", "ASSIGN": "{0}", "FLOOR": "floor({0})",
          "CEIL": "ceil({0})"}
_BINARY = {"ADD": "{0} + {1}", "SUB": "{0} - ({1})", "MUL": "({0})*({1})", "DIV": "({0})/({1})",
           "POW": "({0})^({1})", "CONSTPOW": "({0})^({1})", "ATAN2": "atan2({0}, {1})", "FMIN": "min({0}, {1})",
           "FMAX": "max({0}, {1})", "HYPOT": "sqrt(({0})^2 + ({1})^2)"}
_OPS = {getattr(ca, f"OP_{k}"): v for k, v in {**_UNARY, **_BINARY}.items() if hasattr(ca, f"OP_{k}")}


def function_name(roles: PlantRoles, kind: str) -> str:
    """Modelica name of the generated function of axis ``roles`` (``kind``: position or velocity)."""
    return f"MTAxis_{re.sub(r'[^A-Za-z0-9_]', '_', roles.output)}_{kind}"


def _literal(value: float) -> str:
    text = repr(float(value))
    if text in ("inf", "-inf", "nan"):
        raise PlantFormError(f"constant {text} in an axis output expression")
    return f"({text})" if value < 0 else text


def modelica_function(name: str, fn: ca.Function, description: str, prefixes: tuple[str, ...] = ("x", "p")) -> str:
    """Source of a Modelica function computing the scalar output of ``fn`` (SX; its inputs vectors, by default
    the states and the parameters, whose formal arguments are named by ``prefixes``) instruction by
    instruction; raises :class:`PlantFormError` on an operation Modelica has no counterpart for here."""
    sizes = [fn.nnz_in(i) for i in range(fn.n_in())]
    formal = [[f"{prefixes[i]}{j + 1}" for j in range(n)] for i, n in enumerate(sizes)]
    body, work = [], [f"w{k}" for k in range(fn.sz_w())]
    for k in range(fn.n_instructions()):
        op, args, outs = fn.instruction_id(k), fn.instruction_input(k), fn.instruction_output(k)
        if op == ca.OP_INPUT:
            body.append(f"  w{outs[0]} := {formal[args[0]][args[1]]};")
        elif op == ca.OP_OUTPUT:
            body.append(f"  y := w{args[0]};")
        elif op == ca.OP_CONST:
            body.append(f"  w{outs[0]} := {_literal(fn.instruction_constant(k))};")
        elif op in _OPS:
            body.append(f"  w{outs[0]} := " + _OPS[op].format(*[f"w{a}" for a in args]) + ";")
        else:
            raise PlantFormError(f"operation {op} (casadi OP code) in the axis output expression has no "
                                 f"Modelica counterpart here")
    lines = [f'function {name} "{description}"']
    lines += [f"  input Real {n};" for names in formal for n in names]
    lines += ["  output Real y;", "protected"] + [f"  Real {w};" for w in work]
    lines += ["algorithm"] + body + [f"end {name};"]
    return "\n".join(lines) + "\n"


def kinematics(model: symbolic.SymbolicModel, roles: PlantRoles) -> ca.Function:
    """(x, p) -> (position, velocity) of an expression axis."""
    h, rate = output_rate(model, roles.output)
    return ca.Function("axis", [model.x, model.p], [h, rate])


def function_files(model: symbolic.SymbolicModel, axes: list[PlantRoles]) -> dict[str, str]:
    """File name -> source of the position, velocity and acceleration functions of every expression axis (the
    acceleration takes the state derivatives too: dh_dot/dx * der(x))."""
    files = {}
    for roles in axes:
        if not roles.expression:
            continue
        fn = kinematics(model, roles)
        for i, kind in enumerate(("position", "velocity")):
            name = function_name(roles, kind)
            single = ca.Function(name, [model.x, model.p], [fn.call([model.x, model.p])[i]])
            files[f"{name}.mo"] = modelica_function(name, single, f"The {kind} of axis {roles.output} "
                                                    f"(generated from the plant's output expression)")
        name = function_name(roles, "acceleration")
        xdot = ca.SX.sym("xdot", model.x.numel())
        acc = ca.Function(name, [model.x, xdot, model.p], [ca.jtimes(output_rate(model, roles.output)[1], model.x, xdot)])
        files[f"{name}.mo"] = modelica_function(name, acc, f"The acceleration of axis {roles.output} from the "
                                                f"states and their derivatives (generated from the plant's output "
                                                f"expression)", ("x", "d", "p"))
    return files


def substitutions(model: symbolic.SymbolicModel | None, roles: PlantRoles) -> dict[str, str]:
    """What an effect's ``$x`` and ``$v`` (and, on an expression axis, ``der($v)``, written ``$a`` there) become
    on axis ``roles`` in the augmented model. An expression axis's acceleration is its own generated function
    of the states' derivatives: the front end's der() of a function call would differentiate the parameter
    arguments too (undeclared der(plant.rP) on the Hexapod)."""
    if not roles.expression:
        return {"x": f"plant.{roles.position}", "v": f"plant.{roles.velocity}"}
    args = ", ".join(f"plant.{v.name}" for v in model.states + model.parameters)
    out = {key: f"{function_name(roles, kind)}({args})" for key, kind in (("x", "position"), ("v", "velocity"))}
    rates = ", ".join(f"der(plant.{v.name})" for v in model.states)
    params = ", ".join(f"plant.{v.name}" for v in model.parameters)
    states = ", ".join(f"plant.{v.name}" for v in model.states)
    out["a"] = f"{function_name(roles, 'acceleration')}({states}, {rates}, {params})"
    return out


def axis_acceleration(model: symbolic.SymbolicModel, roles: PlantRoles) -> ca.SX:
    """The axis's acceleration as an expression of (x, u, p): d/dt of the velocity (an expression axis) or the
    velocity state's derivative."""
    if not roles.expression:
        return model.dx[[s.name for s in model.states].index(roles.velocity)]
    _, rate = output_rate(model, roles.output)
    return ca.jtimes(rate, model.x, model.dx)


def states_from_outputs(model: symbolic.SymbolicModel, axes: list[PlantRoles], values: np.ndarray,
                        q: np.ndarray, qdot: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Plant states (states x samples) whose axis outputs are ``q`` and their rates ``qdot`` (axes x samples):
    the position-level states (those the outputs depend on) by Newton's method from the start state, the
    velocity-level states (the others the rates depend on) from the rates, which are affine in them; the
    remaining states stay at their start. Needs as many axes as position-level and as velocity-level states."""
    h = ca.vertcat(*[output_rate(model, a.output)[0] for a in axes])
    rate = ca.vertcat(*[output_rate(model, a.output)[1] for a in axes])
    n_x = model.x.numel()
    pos = [i for i in range(n_x) if ca.depends_on(h, model.x[i])]
    vel = [i for i in range(n_x) if i not in pos and ca.depends_on(rate, model.x[i])]
    if len(pos) != len(axes) or len(vel) != len(axes):
        raise PlantFormError(f"the {len(axes)} axis outputs depend on {len(pos)} position-level and their rates "
                             f"on {len(vel)} velocity-level states; the states are found from the outputs only "
                             f"when both equal the number of axes")
    x_p, x_v = model.x[pos], model.x[vel]
    fn = ca.Function("ik", [model.x, model.p], [h, ca.jacobian(h, x_p), ca.substitute(rate, x_v, 0 * x_v),
                                                ca.jacobian(rate, x_v)])
    n = q.shape[1]
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(values)).ravel()
    x = np.tile(x0[:, None], (1, n))
    batch = fn.map(n)
    for _ in range(iterations):
        val, jac, _, _ = (np.array(m) for m in batch(x, values))
        jac = jac.reshape(len(axes), n, len(pos)).transpose(1, 0, 2)
        step = np.linalg.solve(jac, (val - q).T[:, :, None])[:, :, 0].T
        x[pos] -= step
        if np.max(np.abs(step)) < 1e-13 * max(1.0, float(np.max(np.abs(x[pos])))):
            break
    _, _, offset, gain = (np.array(m) for m in batch(x, values))
    gain = gain.reshape(len(axes), n, len(vel)).transpose(1, 0, 2)
    x[vel] = np.linalg.solve(gain, (qdot - offset).T[:, :, None])[:, :, 0].T
    return x
