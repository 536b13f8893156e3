"""The one symbolic model: a flat Modelica DAE turned into explicit CasADi functions.

The same :class:`SymbolicModel` feeds the C code generator (the FMU runs exactly these
expressions) and identification (simulation, sensitivities, optimisation in ``ident/``).

Continuous models: the residual must be linear in ``[der(x); z]`` (mass-matrix form such as
``M(q)*der(v) = f(q, v, u)`` is fine); it is solved symbolically for the derivatives ``dx`` and the
algebraic variables ``z``.

Sampled models (class annotation ``__motiontwin(sampled(period=Ts, method="tustin"))``): a linear
continuous law ``der(x) = A x + B u, y = C x + D u`` (A..D may depend on parameters) executed as a
sampled-data system. It is Tustin-discretised at the period ``Ts``:
``Phi = (I - A Ts/2)^-1, Ad = Phi (I + A Ts/2), Bd = Phi B Ts, Cd = C Phi, Dd = D + C Phi B Ts/2``
(the realisation scipy's ``cont2discrete(method="bilinear")`` uses), the output held between samples.
With ``method="discrete"`` the law's matrices are taken as the discrete-time ones,
``x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k]`` (Modelica.Blocks.Discrete.StateSpace): the front end
has no ``sample``/``pre``, so ``der(x)`` stands for the next sample's state in such a class.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import casadi as ca

from motiontwin.fmus.frontend import FlatModel, ModelicaError, Variable

Causality = Literal["output", "local", "calculatedParameter"]


@dataclass
class Computed:
    """A variable computed from states, inputs and parameters (an output, a local or a calculated parameter)."""

    var: Variable
    expr: ca.SX
    causality: Causality


@dataclass
class SymbolicModel:
    """Explicit form of a Modelica class. Vectors are SX column vectors; units are the Modelica ones."""

    flat: FlatModel
    x: ca.SX
    u: ca.SX
    p: ca.SX
    t: ca.SX
    dx: ca.SX                     # continuous models: der(x) as a function of (t, x, u, p)
    computed: list[Computed]      # continuous models: y block; sampled models: held outputs
    state_outputs: list[str]      # names of states that are also outputs
    ts_index: int = -1            # sampled models: index of the sample period in p
    Ad: ca.SX | None = None
    Bd: ca.SX | None = None
    Cd: ca.SX | None = None
    Dd: ca.SX | None = None

    @property
    def name(self) -> str:
        return self.flat.name

    @property
    def sampled(self) -> bool:
        return self.ts_index >= 0

    @property
    def states(self) -> list[Variable]:
        return self.flat.states

    @property
    def inputs(self) -> list[Variable]:
        return self.flat.inputs

    @property
    def parameters(self) -> list[Variable]:
        return self.flat.parameters

    @property
    def y(self) -> ca.SX:
        return ca.vertcat(*[c.expr for c in self.computed]) if self.computed else ca.SX(0, 1)

    def parameter_values(self) -> list[float]:
        return [float(v.start) for v in self.parameters]

    def with_start_values(self, values: dict[str, float]) -> "SymbolicModel":
        """A copy whose parameters, states or inputs start at ``values`` (what write-back compiles in)."""
        known = {v.name: v for v in self.parameters + self.states + self.inputs}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise KeyError(f"{self.name} has no parameter, state or input named {', '.join(unknown)}")
        flat = replace(self.flat,
                       parameters=[replace(v, start=float(values.get(v.name, v.start))) for v in self.parameters],
                       states=[replace(v, start=float(values[v.name]) if v.name in values else v.start)
                               for v in self.states],
                       inputs=[replace(v, start=float(values[v.name]) if v.name in values else v.start)
                               for v in self.inputs])
        return replace(self, flat=flat)

    def x0(self) -> ca.SX:
        """Initial states as expressions of the parameters (start values; 0 where none is given)."""
        starts = [v.start if v.start is not None else 0.0 for v in self.states]
        return ca.vertcat(*[ca.SX(s) if not isinstance(s, ca.SX) else s for s in starts]) if starts else ca.SX(0, 1)

    def functions(self) -> dict[str, ca.Function]:
        """The CasADi functions of the runtime contract (fmus/runtime/mt_model.h), by name."""
        x, u, p, t = self.x, self.u, self.p, self.t
        if self.sampled:  # discrete states start at their (numeric) start values, held in the descriptor
            z = ca.SX.sym("z", x.numel())
            return {"sample": ca.Function("sample", [z, u, p], [self.Ad @ z + self.Bd @ u,
                                                                 self.Cd @ z + self.Dd @ u])}
        fns = {"x0": ca.Function("x0", [p], [self.x0()])}
        y = self.y
        fns["ode"] = ca.Function("ode", [t, x, u, p], [self.dx])
        fns["out"] = ca.Function("out", [t, x, u, p], [y])
        fns["jac"] = ca.Function("jacobian", [t, x, u, p], [ca.densify(ca.jacobian(ca.vertcat(self.dx, y), ca.vertcat(x, u)))])
        fns["dfdt"] = ca.Function("dfdt", [t, x, u, p], [ca.densify(ca.jacobian(self.dx, t))])
        return fns


def build(flat: FlatModel) -> SymbolicModel:
    """Turn a :class:`FlatModel` into explicit form (continuous, or Tustin-sampled when annotated)."""
    x = ca.vertcat(*[v.symbol for v in flat.states]) if flat.states else ca.SX(0, 1)
    dx_sym = ca.vertcat(*flat.der_states) if flat.der_states else ca.SX(0, 1)
    z = ca.vertcat(*[v.symbol for v in flat.algebraics]) if flat.algebraics else ca.SX(0, 1)
    u = ca.vertcat(*[v.symbol for v in flat.inputs]) if flat.inputs else ca.SX(0, 1)
    p = ca.vertcat(*[v.symbol for v in flat.parameters]) if flat.parameters else ca.SX(0, 1)
    unknowns = ca.vertcat(dx_sym, z)
    res = flat.residual
    where = f"{flat.source}: class {flat.name}"
    if res.numel() != unknowns.numel():
        raise ModelicaError(f"{where}: {res.numel()} equations for {unknowns.numel()} unknowns "
                            f"({x.numel()} state derivatives, {z.numel()} algebraic variables)")
    jac = ca.jacobian(res, unknowns)
    if ca.depends_on(jac, unknowns):
        rows = [i for i in range(res.numel()) if ca.depends_on(ca.jacobian(res[i], unknowns), unknowns)]
        raise ModelicaError(f"{where}: equations {', '.join(str(r + 1) for r in rows)} are nonlinear in the "
                            "derivatives/algebraic variables; write them in linear (mass-matrix) form")
    offset = ca.substitute(res, unknowns, ca.SX.zeros(unknowns.numel()))
    if ca.sprank(jac) < unknowns.numel():
        names = [str(s) for s in ca.vertsplit(unknowns)]
        raise ModelicaError(f"{where}: the equations cannot be solved for {', '.join(names)} (structurally "
                            "singular: an algebraic constraint between states needs index reduction, which the "
                            "front end does not do; write the model in minimal coordinates)")
    solution = _solve_linear(jac, -offset)
    dx = solution[: x.numel()]
    zsol = solution[x.numel():]
    outputs = set(flat.outputs)
    computed = [Computed(v, zsol[i], "output" if v.name in outputs else "local") for i, v in enumerate(flat.algebraics)]
    computed += [Computed(var, expr, "calculatedParameter") for var, expr in flat.calculated]
    state_outputs = [v.name for v in flat.states if v.name in outputs]
    model = SymbolicModel(flat, x, u, p, flat.time, dx, computed, state_outputs)
    sampled = flat.annotation.get("sampled")
    if sampled:
        _discretise(model, sampled if isinstance(sampled, dict) else {}, where)
    return model


def _solve_linear(jac: ca.SX, rhs: ca.SX) -> ca.SX:
    """Solve ``jac * w = rhs`` symbolically, exploiting a diagonal structure when there is one."""
    n = jac.size1()
    if n == 0:
        return ca.SX(0, 1)
    if jac.sparsity().is_diag():
        return rhs / ca.diag(jac)
    return ca.solve(jac, rhs)


def _discretise(model: SymbolicModel, spec: dict, where: str) -> None:
    """Tustin discretisation of a linear continuous law (see the module docstring)."""
    method = str(spec.get("method", "tustin")).strip('"')
    if method not in ("tustin", "discrete"):
        raise ModelicaError(f"{where}: sampled(method={method!r}) is not supported; use \"tustin\" or \"discrete\"")
    period = str(spec.get("period", "Ts"))
    names = [v.name for v in model.parameters]
    if period not in names:
        raise ModelicaError(f"{where}: sampled(period={period}) must name a parameter of the class")
    model.computed = [c for c in model.computed if c.causality != "calculatedParameter"]  # substituted already
    x, u = model.x, model.u
    y = model.y
    if model.state_outputs:
        raise ModelicaError(f"{where}: a sampled model's outputs must be algebraic variables, not states "
                            f"({', '.join(model.state_outputs)})")
    A, B = ca.jacobian(model.dx, x), ca.jacobian(model.dx, u)
    C, D = ca.jacobian(y, x), ca.jacobian(y, u)
    xu = ca.vertcat(x, u)
    if any(ca.depends_on(M, xu) for M in (A, B, C, D) if M.numel()) or ca.depends_on(model.dx, model.t) \
            or ca.depends_on(y, model.t):
        raise ModelicaError(f"{where}: a sampled model must be linear and time-invariant in its states and inputs")
    bias = ca.simplify(ca.substitute(ca.vertcat(model.dx, y), xu, ca.SX.zeros(xu.numel())))
    if not bias.is_zero():
        raise ModelicaError(f"{where}: a sampled model must be linear (no constant terms) in states and inputs")
    model.ts_index = names.index(period)
    if method == "discrete":  # the law's matrices are the discrete ones: x[k+1] = A x[k] + B u[k]
        model.Ad, model.Bd, model.Cd, model.Dd = A, B, C, D
        return
    ts = model.p[model.ts_index]
    n = x.numel()
    eye = ca.SX.eye(n)
    lhs = eye - A * ts / 2
    phi_b = ca.solve(lhs, B) if n else ca.SX(0, u.numel())
    phi_a = ca.solve(lhs, eye + A * ts / 2) if n else ca.SX(0, 0)
    c_phi = ca.solve(lhs.T, C.T).T if n else ca.SX(y.numel(), 0)
    model.Ad, model.Bd = phi_a, phi_b * ts
    model.Cd, model.Dd = c_phi, D + c_phi @ B * ts / 2
