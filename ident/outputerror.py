"""Output-error (simulation-error) refit of a Modelica plant's parameters against a recording, in CasADi.

The plant is the :class:`fmus.symbolic.SymbolicModel` the FMU is generated from, so the refit and the
FMU share one set of equations. Two set-ups:

* open loop: the plant input is the recorded input column, held over each sample (ZOH, as a
  co-simulation master sets it); the residual is measured minus simulated output;
* closed loop: a sampled linear controller (:class:`ident.controller.Controller`) reads r_k and the
  simulated output q_k (+ a measurement-noise input n_k, zero in a free run), applies
  u_k = C z_k + D [r_k; q_k + n_k] + u_ext_k over [t_k, t_k + Ts) and updates z_{k+1} = A z_k + B [r_k; q_k + n_k];
  the residual stacks the output and the force channels, each weighted by its noise level.

The plant is integrated over one sample by RK4 with ``substeps`` steps. One step function (CasADi SX) is
built once, with its forward-sensitivity step from algorithmic differentiation, so the residual Jacobian with
respect to the free parameters is exact instead of finite differences. Both are chained over the recording in
compiled C (:mod:`ident.chain`: CasADi-generated code + a model-agnostic loop, cached by source hash), or,
without a C compiler, with CasADi's ``mapaccum`` (same results, much slower on long recordings).

Shooting: single shooting is the default. For the stable or marginally stable loops of motion systems
(a joint is an integrator with damping; in closed loop the controller stabilises it) the free run stays
bounded for any parameter value inside the bounds, the Gauss-Newton iteration with exact AD Jacobians
converges in a few steps, and there are only n_free unknowns. Multiple shooting (:mod:`ident.multipleshooting`,
``identify(..., shooting="multiple")``) adds n_s unknowns and n_s continuity constraints per segment node,
solved by IPOPT on the same step function; it can pay off for unstable plants, whose free run from a poor
start diverges.

Parameter statistics: covariance = s^2 (J^T J)^-1 with J the weighted residual Jacobian at the optimum and
s^2 = weighted RSS / (rows - free parameters); exact for white output noise in open loop, too small when the
residual is coloured (closed loop, model error, filtered noise). ``robust_covariance`` of the statistics is
the HAC sandwich (J^T J)^-1 S (J^T J)^-1 with S the Newey-West long-run covariance of the per-sample scores
(:func:`ident.leastsquares.hac_covariance`), which holds for coloured residuals; both are printed.

Units: SI (s, m, N), those of the Modelica model.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import chain as native_chain
from motiontwin.ident import plant_states
from motiontwin.ident import startvalues
from motiontwin.ident.controller import Controller
from motiontwin.ident.leastsquares import (LeastSquaresResult, UnidentifiableError, check_identifiability,
                                          hac_covariance)
from motiontwin.ident.plant_states import output_state

__all__ = ["Signals", "Loop", "Weights", "Fit", "OutputErrorResult", "build_loop", "default_bounds",
           "simulate", "residuals", "fit", "statistics", "identify", "bound_arrays",
           "state_indices", "weighted_jacobian", "output_state", "initial_motion_states"]


_LOG = logging.getLogger(__name__)
JIT_OPTIONS = {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"]}}
CALL_INSTRUCTIONS = 400     # plant right-hand sides above this many SX instructions are called, not inlined


@dataclass(frozen=True)
class Signals:
    """Recording column names: plant output, plant input (the controller's output in closed loop),
    reference and additive input disturbance (closed loop; absent disturbance = zero)."""

    output: str = "q"
    input: str = "u"
    reference: str = "r"
    disturbance: str = "u_ext"


def axis_signals(input_name: str, output_name: str) -> Signals:
    """Column names of one axis of a multi-axis recording: ``r_<output>``, ``<input>``, ``<output>`` and
    ``u_ext_<input>`` (the plant's own input and output names are the recorded force and position)."""
    return Signals(output_name, input_name, f"r_{output_name}", f"u_ext_{input_name}")


@dataclass
class Loop:
    """A compiled free-run simulation (open loop, or closed with ``controller``) whose parameters ``free``
    are symbolic; the others are fixed values."""

    model: symbolic.SymbolicModel
    controller: Controller | None
    position_state: str                 # the plant output compared with the recording (a state or an output)
    free: list[str]
    values: dict[str, float]            # every plant parameter's current value (free ones: starting point)
    substeps: int
    n_samples: int
    sim: Callable = field(repr=False)   # (s0, W[3xN], theta, pfix) -> (Q[1xN], U[1xN])
    jac: Callable | None = field(repr=False)   # (s0, W, theta, pfix) -> (dQ/dtheta, dU/dtheta, dQ/ds0, dU/ds0)
    tracking: dict[str, str] = field(default_factory=dict)  # state -> "q" or "u": starts at q_0 or u_0
    signals: Signals = field(default_factory=Signals)
    ts: float = 0.0                     # sample period [s]
    step: ca.Function | None = field(default=None, repr=False)  # (s, w, theta, pfix) -> (s_next, q, u), one sample
    axes: tuple[Signals, ...] = ()      # multi-axis loop: one entry per axis (plant input/output = columns)

    @property
    def closed(self) -> bool:
        return self.controller is not None

    @property
    def channels(self) -> tuple[Signals, ...]:
        """The axes' column names; a single-axis loop has one channel, ``signals``."""
        return self.axes or (self.signals,)

    @property
    def fixed(self) -> list[str]:
        return [v.name for v in self.model.parameters if v.name not in self.free]

    def theta(self, values: dict[str, float] | None = None) -> np.ndarray:
        values = values or self.values
        return np.array([values[n] for n in self.free], dtype=float)

    def pfix(self) -> np.ndarray:
        return np.array([self.values[n] for n in self.fixed], dtype=float)

    def with_values(self, values: dict[str, float]) -> "Loop":
        merged = dict(self.values)
        merged.update(values)
        return Loop(self.model, self.controller, self.position_state, self.free, merged, self.substeps,
                    self.n_samples, self.sim, self.jac, self.tracking, self.signals, self.ts, self.step, self.axes)


def stable_substeps(model: symbolic.SymbolicModel, values: dict[str, float], ts: float,
                    minimum: int = 1, maximum: int = 64) -> int:
    """RK4 substeps per sample so that the fastest linearised plant mode stays well inside RK4's stability
    region (|lambda| h <= 1) at rest and at a moderate speed."""
    p = np.array([values[v.name] for v in model.parameters])
    jac_fn = ca.Function("a", [model.x, model.u, model.p], [ca.jacobian(model.dx, model.x)])
    worst = 0.0
    u0 = np.zeros(model.u.numel())
    for speed in (0.0, 1e-3, 0.05):
        x = np.zeros(model.x.numel())
        a = np.array(jac_fn(x + speed, u0, p))
        if np.all(np.isfinite(a)) and a.size:
            worst = max(worst, float(np.max(np.abs(np.linalg.eigvals(a)))))
    return int(min(maximum, max(minimum, math.ceil(worst * ts / 1.0))))


def default_bounds(model: symbolic.SymbolicModel, free: list[str]) -> dict[str, tuple[float, float]]:
    """Bounds of the free parameters from their Modelica ``min``/``max`` attributes (infinite when absent)."""
    by_name = {v.name: v for v in model.parameters}
    _check_names(model, free)
    return {n: (float(by_name[n].min), float(by_name[n].max)) for n in free}


def _check_names(model: symbolic.SymbolicModel, free: list[str]) -> None:
    names = [v.name for v in model.parameters]
    unknown = [n for n in free if n not in names]
    if unknown:
        calculated = {var.name for var, _ in model.flat.calculated}
        hint = [n for n in unknown if n in calculated]
        extra = f" ({', '.join(hint)}: calculated from other parameters, not free)" if hint else ""
        raise KeyError(f"{model.flat.source}: class {model.name} has no free parameter "
                       f"{', '.join(repr(n) for n in unknown)}{extra}; its parameters are {', '.join(names)}")


def _output_expression(model: symbolic.SymbolicModel, name: str) -> ca.SX:
    expr = plant_states.output_expression(model, name)
    if expr is None:
        states = [v.name for v in model.states]
        outputs = model.state_outputs + [c.var.name for c in model.computed if c.causality == "output"]
        raise KeyError(f"{model.flat.source}: class {model.name} has no state or output {name!r}; "
                       f"outputs: {', '.join(outputs)}; states: {', '.join(states)}")
    return expr


def _output_gain(model: symbolic.SymbolicModel, name: str, x0: np.ndarray, p: np.ndarray) -> float:
    """d(output ``name``)/d(the state it is affine in) at ``x0``: 1 when the output is a state itself (and when
    no single state carries it)."""
    if name in [v.name for v in model.states]:
        return 1.0
    i = output_state(model, name)
    if i is None:
        return 1.0
    expr = _output_expression(model, name)
    slope = float(ca.Function("g", [model.x, model.u, model.p], [ca.jacobian(expr, model.x[i])])(
        x0, np.zeros(model.u.numel()), p))
    return slope or 1.0


def _state_for_output(model: symbolic.SymbolicModel, name: str, x0: np.ndarray, p: np.ndarray,
                      target: float) -> np.ndarray:
    """``x0`` with the state the output ``name`` is affine in set so that the output equals ``target``."""
    i = output_state(model, name)
    if i is None:
        return x0
    expr = _output_expression(model, name)
    fn = ca.Function("h", [model.x, model.u, model.p], [expr, ca.jacobian(expr, model.x[i])])
    value, slope = (float(o) for o in fn(x0, np.zeros(model.u.numel()), p))
    x0 = x0.copy()
    if slope != 0:
        x0[i] += (target - value) / slope
    return x0


def initial_motion_states(model: symbolic.SymbolicModel, output: str) -> list[str]:
    """The states that fix where a recording starts: the state the output is affine in and, when its
    derivative is a state (der(x) = v), that velocity state too, so a loop already moving at t = 0 is not
    forced to start at rest."""
    i_pos = output_state(model, output)
    if i_pos is None:
        return []
    i_vel = plant_states.velocity_state(model, i_pos)
    return [model.states[i].name for i in (i_pos, i_vel) if i is not None]


def build_loop(model: symbolic.SymbolicModel, controller: Controller | None, position_state: str, free: list[str],
               values: dict[str, float], n_samples: int, substeps: int | None = None,
               tracking: dict[str, str] | None = None, with_jacobian: bool = True, min_substeps: int = 1,
               ts: float | None = None, input_name: str | None = None, signals: Signals = Signals(),
               jit: bool = False, native: bool | None = None, axes: list[Signals] | None = None,
               initial_sensitivity: bool = True) -> Loop:
    """Compile the free-run simulation of ``n_samples`` samples with the parameters ``free`` symbolic.

    controller: None for open loop (then ``ts`` [s] is required); position_state: the state or output
    compared with the recording; input_name: the plant input that is driven (default: the only one; other
    inputs stay at their start values); jit: compile the step functions to C (gcc) first, which pays
    off on long recordings (the chain then runs at C speed, minus CasADi's per-call overhead); only used by
    the CasADi chain. native: chain the samples in compiled C (:mod:`ident.chain`); None = when a C
    compiler is available, False = CasADi ``mapaccum`` chain.

    axes: a multi-axis loop (several inputs and outputs; :func:`axis_signals`): each entry's ``input`` and
    ``output`` are plant names (and recording columns); ``position_state`` and ``input_name`` are then
    ignored. The controller maps y = [r_1..r_n, q_1..q_n] to u = [u_1..u_n] (block-diagonal or
    multivariable); w = [r (n); u_ext (n); measurement noise (n)] per sample, and the step returns q and u
    with n entries each. initial_sensitivity: compile the sensitivities w.r.t. the initial state too (needed
    to estimate initial states, ``fit(..., estimate_initial=...)``); without them the Jacobian step of a
    large coupled plant is a fraction of the size (its d/ds0 blocks are then empty).
    """
    if ca.depends_on(model.dx, model.t):
        raise ValueError(f"{model.name}: time-varying plants are not supported by the output-error refit")
    if model.sampled:
        raise ValueError(f"{model.name} is a sampled model; the plant must be continuous")
    _check_names(model, free)
    if controller is None and not (ts and ts > 0):
        raise ValueError("open-loop simulation needs the sample period ts [s]")
    ts = float(controller.Ts if controller is not None else ts)
    names = [v.name for v in model.parameters]
    inputs = [v.name for v in model.inputs]
    if axes:
        driven, observed = [a.input for a in axes], [a.output for a in axes]
    else:
        if input_name is None:
            if len(inputs) != 1:
                raise ValueError(f"{model.name} has inputs {inputs}; name the driven one (input_name)")
            input_name = inputs[0]
        driven, observed = [input_name], [position_state]
    for name in driven:
        if name not in inputs:
            raise KeyError(f"{model.flat.source}: class {model.name} has no input {name!r}; inputs: {inputs}")
    n_ax = len(driven)
    if controller is not None:
        _check_controller_shape(controller, n_ax)
    values = {n: float(values.get(n, model.parameters[i].start)) for i, n in enumerate(names)}
    substeps = substeps or max(min_substeps, stable_substeps(model, values, ts))
    fixed = [n for n in names if n not in free]
    f = ca.Function("f", [model.x, model.u, model.p], [model.dx])
    # a large right-hand side (a coupled mechanism's mass-matrix solve) is called, not inlined, in every RK4
    # stage (MX graph): the step and its sensitivity step then compile from kilobytes instead of megabytes
    sym = ca.MX if f.n_instructions() > CALL_INSTRUCTIONS else ca.SX
    theta = sym.sym("theta", len(free))
    pfix = sym.sym("pfix", len(fixed))
    p_full = ca.vertcat(*[theta[free.index(n)] if n in free else pfix[fixed.index(n)] for n in names])
    q_expr = ca.vertcat(*[_output_expression(model, name) for name in observed])
    h_out = ca.Function("h", [model.x, model.u, model.p], [q_expr])
    nx = model.x.numel()
    nz = controller.n_states if controller is not None else 0
    s = sym.sym("s", nx + nz)
    w = sym.sym("w", 3 * n_ax)  # per axis, closed loop: r, u_ext, measurement noise; open loop: -, input, -
    x, z = s[:nx], s[nx:]
    held = [0.0 if v.start is None or not isinstance(v.start, (int, float)) else float(v.start) for v in model.inputs]
    k_in = [inputs.index(name) for name in driven]

    def plant_input(u_vec: ca.SX) -> ca.SX:
        return ca.vertcat(*[u_vec[k_in.index(i)] if i in k_in else held[i] for i in range(len(inputs))])

    if controller is None:
        u = w[n_ax:2 * n_ax]
        q = h_out(x, plant_input(u), p_full)
        z_next = z
    else:
        if ca.depends_on(q_expr, model.u):
            raise ValueError(f"{model.name}: output {', '.join(map(repr, observed))} depends on the input "
                             "directly; closing a sampled loop around it is an algebraic loop")
        q = h_out(x, plant_input(sym.zeros(n_ax)), p_full)
        y = ca.vertcat(w[:n_ax], q + w[2 * n_ax:])
        A, B, C, D = (ca.DM(m) for m in (controller.A, controller.B, controller.C, controller.D))
        u = (C @ z if nz else 0) + D @ y + w[n_ax:2 * n_ax]
        z_next = A @ z + B @ y if nz else z
    uvec = plant_input(u)
    h = ts / substeps
    xk = x
    for _ in range(substeps):
        k1 = f(xk, uvec, p_full)
        k2 = f(xk + h / 2 * k1, uvec, p_full)
        k3 = f(xk + h / 2 * k2, uvec, p_full)
        k4 = f(xk + h * k3, uvec, p_full)
        xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    s_next, out_k = ca.vertcat(xk, z_next), ca.vertcat(q, u)
    step = ca.Function("step", [s, w, theta, pfix], [ca.densify(s_next), ca.densify(q), ca.densify(u)])
    if not with_jacobian:
        aug, seed = None, None
    elif sym is ca.SX:
        aug, seed = _sensitivity_step(s, w, theta, pfix, s_next, out_k, initial_sensitivity)
    else:
        select_p = np.array([[1.0 if n == m else 0.0 for m in free] for n in names]).reshape(len(names), len(free))
        select_u = np.array([[1.0 if i == k else 0.0 for k in k_in] for i in range(len(inputs))])
        aug, seed = _called_sensitivity_step(model, observed, controller, plant_input, select_p, select_u, p_full,
                                             s, w, theta, pfix, substeps, ts, initial_sensitivity)
    pair = None
    if native or (native is None and native_chain.available()):
        try:
            pair = _native_pair(step, aug, seed, n_samples)
        except (RuntimeError, OSError) as exc:
            if native:
                raise
            _LOG.warning("compiled chain unavailable, using CasADi's mapaccum chain: %s", exc)
    sim, jac = pair or _casadi_pair(step, aug, seed, n_samples, JIT_OPTIONS if jit else {})
    return Loop(model, controller, observed[0], list(free), values, substeps, n_samples, sim, jac,
                dict(tracking or {}), signals if not axes else axes[0], ts, step, tuple(axes or ()))


def _check_controller_shape(controller: Controller, n_axes: int) -> None:
    """The controller must map [r_1..r_n, q_1..q_n] to n forces."""
    nz = controller.n_states
    shapes = {"B": (nz, 2 * n_axes), "C": (n_axes, nz), "D": (n_axes, 2 * n_axes)}
    for name, shape in shapes.items():
        got = np.shape(getattr(controller, name))
        if got != shape and not (np.size(getattr(controller, name)) == 0 and 0 in shape):
            raise ValueError(f"controller matrix {name} has shape {got}; a loop of {n_axes} axes needs {shape} "
                             f"(inputs r_1..r_n, q_1..q_n; outputs u_1..u_n)")


def _sensitivity_step(s: ca.SX, w: ca.SX, theta: ca.SX, pfix: ca.SX, s_next: ca.SX,
                      out_k: ca.SX, initial: bool = True) -> tuple[ca.Function, np.ndarray]:
    """The step augmented with forward sensitivities w.r.t. [theta; s0], propagated sample by sample with
    the step's AD Jacobians (S+ = ds+/ds S + [ds+/dtheta, 0]), and the initial seed vec([0, I]): one pass
    over the recording gives the whole residual Jacobian, at a cost of about (1 + n_theta + n_s) free runs.
    Without ``initial`` only the theta columns are propagated (seed 0) and the d/ds0 outputs are omitted."""
    ns, nth = s.numel(), theta.numel()
    n0 = ns if initial else 0
    sens = ca.SX.sym("S", ns, nth + n0)
    pad = ca.SX.zeros(ns, n0)
    s_sens = ca.jacobian(s_next, s) @ sens + ca.horzcat(ca.jacobian(s_next, theta), pad)
    n_out = out_k.numel() // 2      # q then u, one entry per axis
    o_sens = ca.jacobian(out_k, s) @ sens + ca.horzcat(ca.jacobian(out_k, theta), ca.SX.zeros(2 * n_out, n0))
    # per sample and channel: axis 0's row, then axis 1's, ... (see _channel_major)
    outs = [ca.vertcat(s_next, ca.vec(s_sens)), ca.vec(o_sens[:n_out, :nth].T), ca.vec(o_sens[n_out:, :nth].T)]
    if initial:
        outs += [ca.vec(o_sens[:n_out, nth:].T), ca.vec(o_sens[n_out:, nth:].T)]
    aug = ca.Function("sstep", [ca.vertcat(s, ca.vec(sens)), w, theta, pfix], [ca.densify(o) for o in outs])
    seed = np.hstack([np.zeros((ns, nth)), np.eye(ns)[:, :n0]]).ravel(order="F")
    return aug, seed


def _called_sensitivity_step(model: symbolic.SymbolicModel, observed: list[str], controller: Controller | None,
                             plant_input: Callable, select_p: np.ndarray, select_u: np.ndarray, p_full: ca.MX,
                             s: ca.MX, w: ca.MX, theta: ca.MX, pfix: ca.MX, substeps: int, ts: float,
                             initial: bool) -> tuple[ca.Function, np.ndarray]:
    """:func:`_sensitivity_step` for a large plant (MX graph): the variational equations of the same RK4
    step written out, with the plant's Jacobians [df/dx, df/du, df/dp] and [dh/dx, dh/du, dh/dp] as one
    called function each, so that the generated code holds each Jacobian once instead of one forward
    derivative per sensitivity direction inlined in every stage."""
    nx, ns, nth = model.x.numel(), s.numel(), theta.numel()
    nz, n_ax = ns - nx, len(observed)
    n0 = ns if initial else 0
    na = nth + n0
    dx_expr = model.dx
    q_expr = ca.vertcat(*[_output_expression(model, name) for name in observed])
    f_jac = ca.Function("f_jac", [model.x, model.u, model.p],
                        [dx_expr] + [ca.jacobian(dx_expr, v) for v in (model.x, model.u, model.p)])
    h_jac = ca.Function("h_jac", [model.x, model.u, model.p],
                        [q_expr] + [ca.jacobian(q_expr, v) for v in (model.x, model.u, model.p)])
    s_aug = ca.MX.sym("s_aug", ns * (1 + na))
    x, z = s_aug[:nx], s_aug[nx:ns]
    sens = ca.reshape(s_aug[ns:], ns, na)
    sx, sz = sens[:nx, :], sens[nx:, :]
    dp = ca.horzcat(ca.DM(select_p), ca.DM.zeros(select_p.shape[0], n0))      # d p / d [theta, s0]
    p_val = p_full       # an expression of theta and pfix, inputs of the augmented step too
    su = ca.DM(select_u)
    if controller is None:
        u, du = w[n_ax:2 * n_ax], ca.MX.zeros(n_ax, na)
        q, hx, hu, hp = h_jac(x, plant_input(u), p_val)
        dq = hx @ sx + hp @ dp
        z_next, dz = z, sz
    else:
        q, hx, hu, hp = h_jac(x, plant_input(ca.MX.zeros(n_ax)), p_val)
        dq = hx @ sx + hp @ dp
        y = ca.vertcat(w[:n_ax], q + w[2 * n_ax:])
        A, B, C, D = (ca.DM(m) for m in (controller.A, controller.B, controller.C, controller.D))
        u = (C @ z if nz else 0) + D @ y + w[n_ax:2 * n_ax]
        du = (C @ sz if nz else 0) + D[:, n_ax:] @ dq
        z_next = A @ z + B @ y if nz else z
        dz = A @ sz + B[:, n_ax:] @ dq if nz else sz
    uvec = plant_input(u)
    duvec = su @ du
    h = ts / substeps
    xk, sk = x, sx

    def stage(xs: ca.MX, dxs: ca.MX) -> tuple[ca.MX, ca.MX]:
        k, fx, fu, fp = f_jac(xs, uvec, p_val)
        return k, fx @ dxs + fu @ duvec + fp @ dp

    for _ in range(substeps):
        k1, d1 = stage(xk, sk)
        k2, d2 = stage(xk + h / 2 * k1, sk + h / 2 * d1)
        k3, d3 = stage(xk + h / 2 * k2, sk + h / 2 * d2)
        k4, d4 = stage(xk + h * k3, sk + h * d3)
        xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        sk = sk + h / 6 * (d1 + 2 * d2 + 2 * d3 + d4)
    s_sens = ca.vertcat(sk, dz)
    outs = [ca.vertcat(xk, z_next, ca.vec(s_sens)), ca.vec(dq[:, :nth].T), ca.vec(du[:, :nth].T)]
    if initial:
        outs += [ca.vec(dq[:, nth:].T), ca.vec(du[:, nth:].T)]
    aug = ca.Function("sstep", [s_aug, w, theta, pfix], [ca.densify(o) for o in outs])
    seed = np.hstack([np.zeros((ns, nth)), np.eye(ns)[:, :n0]]).ravel(order="F")
    return aug, seed


def _with_initial_blocks(blocks: list) -> tuple:
    """(dq, du, dq0, du0): empty d/ds0 blocks when the loop was compiled without them."""
    if len(blocks) == 4:
        return tuple(blocks)
    dq, du = (np.asarray(b) for b in blocks)
    return dq, du, np.zeros((dq.shape[0], 0)), np.zeros((du.shape[0], 0))


def _native_pair(step: ca.Function, aug: ca.Function | None, seed: np.ndarray | None,
                 n_samples: int) -> tuple[Callable, Callable | None]:
    """``sim`` and ``jac`` running the samples in compiled C."""
    chains = native_chain.native_chains([step] + ([aug] if aug is not None else []), n_samples)

    def sim(s0, W, th, pf) -> tuple[np.ndarray, np.ndarray]:
        q, u = chains[0](s0, W, th, pf)
        return q.T, u.T

    def jac(s0, W, th, pf) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return _with_initial_blocks(chains[1](np.concatenate([np.asarray(s0, float).ravel(), seed]), W, th, pf))

    return sim, (jac if aug is not None else None)


def _casadi_pair(step: ca.Function, aug: ca.Function | None, seed: np.ndarray | None, n_samples: int,
                 opts: dict) -> tuple[Callable, Callable | None]:
    """``sim`` and ``jac`` as CasADi ``mapaccum`` chains (the fallback without a C compiler)."""
    if opts:
        step = ca.Function("step", step.sx_in(), step.call(step.sx_in()), opts)
    n_in = [step.numel_in(i) for i in range(4)]
    s0, th, pf = ca.MX.sym("s0", n_in[0]), ca.MX.sym("th", n_in[2]), ca.MX.sym("pf", n_in[3])
    W = ca.MX.sym("W", n_in[1], n_samples)
    _, q_all, u_all = _chain(step, n_samples, s0, W, th, pf)
    # the output at sample k is read from the state at t_k, which the chain's output k holds
    sim = ca.Function("sim", [s0, W, th, pf], [q_all, u_all])
    if aug is None:
        return sim, None
    if opts:
        aug = ca.Function("sstep", aug.sx_in(), aug.call(aug.sx_in()), opts)
    blocks = _chain(aug, n_samples, ca.vertcat(s0, ca.DM(seed)), W, th, pf)[1:]
    simjac = ca.Function("simjac", [s0, W, th, pf], [b.T for b in blocks])
    return sim, lambda *args: _with_initial_blocks([np.array(b) for b in simjac(*args)])


def _chain(step: ca.Function, n_samples: int, s0: ca.MX, W: ca.MX, th: ca.MX, pf: ca.MX) -> list[ca.MX]:
    """``step`` applied ``n_samples`` times, the state accumulated, one column of W per sample."""
    return step.mapaccum("chain", n_samples, [0], [0])(s0, W, th, pf)


def _column(rec: Recording, name: str, optional: bool = False) -> np.ndarray:
    if name in rec.columns:
        return rec[name]
    if optional:
        return np.zeros_like(rec.time)
    raise KeyError(f"recording has no column {name!r}; columns: {', '.join(rec.columns)}")


def initial_state(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
                  initial: dict[str, float] | None = None) -> np.ndarray:
    """Start from the first recorded sample at rest: the output state (when the output is a state) = q_0, or
    the state an output expression is affine in (an alias, gear ratio or offset) such that the output = q_0,
    other plant states at their start values, tracked states at that position or u_0, states in ``initial`` at those
    values, and in closed loop the controller state giving the recorded force u_0 (least-norm solution of
    C z = u_0 - u_ext_0 - D y_0). Multi-axis: the same for every axis; a tracking signal may name its axis
    by output (``"dq:q3"``, ``"q:q3"``, ``"u:q3"``; without it, the first axis)."""
    values = values or loop.values
    model, ctrl = loop.model, loop.controller
    p = np.array([values[v.name] for v in model.parameters])
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    names = [v.name for v in model.states]
    positions: dict[str, float] = {}
    for sig in loop.channels:
        output = sig.output if loop.axes else loop.position_state
        q_rec = _column(rec, sig.output)
        if output in names:
            x0[names.index(output)] = q_rec[0]
            positions[sig.output] = q_rec[0]
        else:
            x0 = _state_for_output(model, output, x0, p, q_rec[0])
            i_pos = output_state(model, output)
            positions[sig.output] = q_rec[0] if i_pos is None else x0[i_pos]
    by_output = {sig.output: sig for sig in loop.channels}
    for state, tracked in loop.tracking.items():
        signal, _, axis = tracked.partition(":")
        sig = by_output[axis] if axis else loop.channels[0]
        output = sig.output if loop.axes else loop.position_state
        if signal == "dq":      # a velocity state: the slope of the first samples (a loop moving at t = 0)
            slope = startvalues.first_samples(_column(rec, sig.output), float(np.median(np.diff(rec.time))))[1]
            x0[names.index(state)] = slope / _output_gain(model, output, x0, p)
        else:
            x0[names.index(state)] = positions[sig.output] if signal == "q" else _column(rec, sig.input)[0]
    for state, value in (initial or {}).items():
        x0[names.index(state)] = value
    if ctrl is None or not ctrl.n_states:
        return np.concatenate([x0, np.zeros(ctrl.n_states if ctrl is not None else 0)])
    refs = np.array([_column(rec, sig.reference) for sig in loop.channels])
    meas = np.array([_column(rec, sig.output) for sig in loop.channels])
    forces = np.array([_column(rec, sig.input) - _column(rec, sig.disturbance, True) for sig in loop.channels])
    if any(t.partition(":")[0] == "dq" for t in loop.tracking.values()):   # moving at t = 0: the controller
        count = min(rec.time.size, max(20, 4 * ctrl.n_states))            # state from its first outputs
        y = np.vstack([refs[:, :count], meas[:, :count]]).T
        return np.concatenate([x0, startvalues.controller_state(ctrl.A, ctrl.B, ctrl.C, ctrl.D, y,
                                                                forces[:, :count].T)])
    y0 = np.concatenate([refs[:, 0], meas[:, 0]])
    target = forces[:, 0] - ctrl.D @ y0
    z0 = np.linalg.pinv(ctrl.C) @ np.atleast_1d(target)
    return np.concatenate([x0, z0])


def drive(rec: Recording, noise: np.ndarray | None = None, signals: Signals | tuple[Signals, ...] = Signals(),
          closed: bool = True) -> np.ndarray:
    """The 3n x N input matrix of a recording (n axes, ``signals`` one per axis): closed loop
    [r; u_ext; measurement noise], open loop [0; input; 0], each block one row per axis."""
    channels = (signals,) if isinstance(signals, Signals) else tuple(signals)
    n = rec.time.size
    zeros = np.zeros((len(channels), n))
    if noise is not None:
        noise = np.asarray(noise, float).reshape(len(channels), n)
    if not closed:
        return np.vstack([zeros, [_column(rec, sig.input) for sig in channels], zeros])
    return np.vstack([[_column(rec, sig.reference) for sig in channels],
                      [_column(rec, sig.disturbance, True) for sig in channels],
                      zeros if noise is None else noise])


def _shaped(loop: Loop, values: np.ndarray) -> np.ndarray:
    """Simulated outputs (axes x N) as the caller sees them: 1-D for a single-axis loop."""
    values = np.asarray(values, float).reshape(len(loop.channels), -1)
    return values if loop.axes else values.ravel()


def measured(loop: Loop, rec: Recording, kind: str) -> np.ndarray:
    """The recorded outputs (``kind="output"``) or forces (``"input"``) of the loop's axes, shaped as
    :func:`simulate` returns them."""
    return _shaped(loop, np.array([_column(rec, getattr(sig, kind)) for sig in loop.channels]))


def simulate(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
             noise: np.ndarray | None = None,
             initial: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Free-run simulation along ``rec`` (plant states in ``initial`` start there); returns simulated
    (output, input) at the sample instants: 1-D arrays, or (axes x samples) for a multi-axis loop (whose
    ``noise`` is axes x samples too)."""
    values = {**loop.values, **(values or {})}
    if rec.time.size != loop.n_samples:
        raise ValueError(f"loop compiled for {loop.n_samples} samples, recording has {rec.time.size}")
    pf = np.array([values[n] for n in loop.fixed])
    q, u = loop.sim(initial_state(loop, rec, values, initial), drive(rec, noise, loop.channels, loop.closed),
                    loop.theta(values), pf)
    return _shaped(loop, np.array(q)), _shaped(loop, np.array(u))


@dataclass
class Fit:
    """Result of an output-error refit."""

    values: dict[str, float]     # all plant parameters after the fit
    cost: float                  # weighted sum of squares (output channel, and force channel in closed loop)
    rms_q: float                 # RMS of measured minus simulated output
    q_sim: np.ndarray
    u_sim: np.ndarray
    jacobian: np.ndarray         # weighted residual Jacobian w.r.t. the free parameters (then the estimated
                                 # initial states) at the optimum
    success: bool
    nfev: int = 0                # residual evaluations (free runs) of the optimiser
    initial: dict[str, float] = field(default_factory=dict)   # estimated initial plant states
    residual: np.ndarray | None = None   # weighted residual at the optimum, rows as ``jacobian`` (for the HAC std)


@dataclass
class Weights:
    """Noise levels used to weight the residual channels: sigma_q [output unit], sigma_u [N]
    (sigma_u is unused in open loop, where the input is given); a multi-axis loop takes one level per axis
    (arrays), so each axis's output and force channel is weighted by its own noise."""

    sigma_q: float | np.ndarray
    sigma_u: float | np.ndarray = 1.0


def _weighted(meas: np.ndarray, sim: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
    """(meas - sim) / sigma, channel-major (axis 0's samples, then axis 1's, ...)."""
    diff = np.asarray(meas) - np.asarray(sim)
    if diff.ndim == 2:
        diff = diff / np.reshape(np.asarray(sigma, float), (-1, 1))
        return diff.ravel()
    return diff / sigma


def _channel_major(sens: np.ndarray, n_axes: int) -> np.ndarray:
    """Chained sensitivities (samples x (axes * columns)) as rows channel-major: (axes * samples) x columns."""
    sens = np.asarray(sens)
    if n_axes == 1:
        return sens
    n = sens.shape[0]
    if sens.shape[1] == 0:
        return np.zeros((n_axes * n, 0))
    return sens.reshape(n, n_axes, -1).transpose(1, 0, 2).reshape(n_axes * n, -1)


def residuals(loop: Loop, rec: Recording, values: dict[str, float], weights: Weights,
              noise: np.ndarray | None = None, q_meas: np.ndarray | None = None,
              u_meas: np.ndarray | None = None,
              initial: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted residual vector [(q_meas - q_sim)/sigma_q; (u_meas - u_sim)/sigma_u (closed loop only)] and
    the simulation."""
    q, u = simulate(loop, rec, values, noise, initial)
    qm = measured(loop, rec, "output") if q_meas is None else q_meas
    if not loop.closed:
        return _weighted(qm, q, weights.sigma_q), q, u
    um = measured(loop, rec, "input") if u_meas is None else u_meas
    return np.concatenate([_weighted(qm, q, weights.sigma_q), _weighted(um, u, weights.sigma_u)]), q, u


def _interior(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``theta`` clipped strictly inside [lo, hi] (scipy's TRF starts from an interior point)."""
    eps = 1e-9 * np.maximum(np.abs(theta), 1e-12)
    lo_f, hi_f = np.where(np.isfinite(lo), lo, 0.0), np.where(np.isfinite(hi), hi, 0.0)
    lo_in = np.where(np.isfinite(lo), lo_f + np.maximum(eps, 1e-12 * np.abs(lo_f)), -np.inf)
    hi_in = np.where(np.isfinite(hi), hi_f - np.maximum(eps, 1e-12 * np.abs(hi_f)), np.inf)
    return np.minimum(np.maximum(theta, lo_in), hi_in)


def bound_arrays(loop: Loop, bounds: dict[str, tuple[float, float]] | None) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of ``loop.free`` (``bounds`` over the Modelica min/max); empty ones raise."""
    names = loop.free
    bounds = {**default_bounds(loop.model, names), **(bounds or {})}
    lo = np.array([bounds[n][0] for n in names], dtype=float)
    hi = np.array([bounds[n][1] for n in names], dtype=float)
    bad = [n for n, a, b in zip(names, lo, hi) if not a < b]
    if bad:
        raise ValueError(f"empty bounds for {', '.join(f'{n} {bounds[n]}' for n in bad)}")
    return lo, hi


def state_indices(loop: Loop, names: list[str] | tuple[str, ...]) -> list[int]:
    """Indices of the plant states ``names`` in the loop state (unknown names raise)."""
    state_names = [v.name for v in loop.model.states]
    unknown = [n for n in names if n not in state_names]
    if unknown:
        raise KeyError(f"{loop.model.name} has no state {unknown}; states: {', '.join(state_names)}")
    return [state_names.index(n) for n in names]


def weighted_jacobian(loop: Loop, s0: np.ndarray, W: np.ndarray, theta: np.ndarray, pf: np.ndarray,
                      idx: list[int], weights: Weights) -> np.ndarray:
    """Jacobian of the weighted residual of the free run from ``s0`` w.r.t. [theta, s0[idx]]."""
    n_ax = len(loop.channels)
    jq, ju, jq0, ju0 = (_channel_major(m, n_ax) for m in loop.jac(s0, W, theta, pf))
    rows = loop.n_samples

    def scaled(block: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
        return block / np.repeat(np.broadcast_to(np.asarray(sigma, float), (n_ax,)), rows)[:, None]

    j = -scaled(np.hstack([jq, jq0[:, idx]]), weights.sigma_q)
    if loop.closed:
        j = np.vstack([j, -scaled(np.hstack([ju, ju0[:, idx]]), weights.sigma_u)])
    return j


def fit(loop: Loop, rec: Recording, weights: Weights, bounds: dict[str, tuple[float, float]] | None = None,
        start: dict[str, float] | None = None, max_nfev: int = 40,
        q_meas: np.ndarray | None = None, u_meas: np.ndarray | None = None,
        estimate_initial: list[str] | tuple[str, ...] = (), initial: dict[str, float] | None = None) -> Fit:
    """Output-error least squares of ``loop.free`` within ``bounds`` (default: the Modelica min/max), by
    scipy's trust-region reflective method with the CasADi Jacobian. The initial values of the plant states
    ``estimate_initial`` are estimated too (unbounded), e.g. the position, which the first noisy sample
    would otherwise fix with an error that the integrator carries through the whole run. ``initial``: known
    initial values of plant states (e.g. a run that starts at rest at a known position)."""
    known = dict(initial or {})
    values = {**loop.values, **(start or {})}
    names = loop.free
    lo, hi = bound_arrays(loop, bounds)
    idx = state_indices(loop, estimate_initial)
    n_th = len(names)
    theta0 = _interior(loop.theta(values), lo, hi)
    base = initial_state(loop, rec, values, known)
    x_init0 = base[idx]
    scale = np.concatenate([np.maximum(np.abs(theta0), 1e-12), np.ones(len(idx))])
    lo_all = np.concatenate([lo, np.full(len(idx), -np.inf)])
    hi_all = np.concatenate([hi, np.full(len(idx), np.inf)])
    s0_cache: dict[bytes, np.ndarray] = {}
    qm = measured(loop, rec, "output") if q_meas is None else q_meas
    um = (measured(loop, rec, "input") if u_meas is None else u_meas) if loop.closed else None
    W = drive(rec, signals=loop.channels, closed=loop.closed)
    pf = np.array([values[n] for n in loop.fixed])

    def split(xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        full = xs * scale
        return full[:n_th], full[n_th:]

    def state(theta: np.ndarray, x_init: np.ndarray) -> np.ndarray:
        key = theta.tobytes() + x_init.tobytes()
        if key not in s0_cache:
            s0_cache.clear()
            s0_cache[key] = initial_state(loop, rec, {**values, **dict(zip(names, theta))},
                                          {**known, **dict(zip(estimate_initial, x_init))})
        return s0_cache[key]

    def res(xs: np.ndarray) -> np.ndarray:
        theta, x_init = split(xs)
        q, u = loop.sim(state(theta, x_init), W, theta, pf)
        r = _weighted(qm, _shaped(loop, np.array(q)), weights.sigma_q)
        if loop.closed:
            r = np.concatenate([r, _weighted(um, _shaped(loop, np.array(u)), weights.sigma_u)])
        return np.where(np.isfinite(r), r, 1e12)

    def jac(xs: np.ndarray) -> np.ndarray:
        theta, x_init = split(xs)
        j = weighted_jacobian(loop, state(theta, x_init), W, theta, pf, idx, weights) * scale
        return np.where(np.isfinite(j), j, 0.0)

    nfev = 0
    x_start = np.concatenate([theta0, x_init0]) / scale
    if x_start.size:
        if loop.jac is None:
            raise ValueError("the loop was compiled without its Jacobian (with_jacobian=False)")
        from scipy.optimize import least_squares  # here: importing scipy.optimize takes about a second

        sol = least_squares(res, x_start, jac=jac, bounds=(lo_all / scale, hi_all / scale), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)
        xs = sol.x
        success = bool(sol.success or sol.status == 0)
        nfev = int(sol.nfev)
    else:
        xs = x_start
        success = True
    theta, x_init = split(xs)
    final = {**values, **dict(zip(names, map(float, theta)))}
    initial = dict(zip(estimate_initial, map(float, x_init)))
    r, q, u = residuals(loop, rec, final, weights, q_meas=qm, u_meas=um, initial={**known, **initial})
    j = jac(xs) / scale if xs.size else np.zeros((r.size, 0))
    cost = float(r @ r) if np.all(np.isfinite(r)) else math.inf
    rms = float(np.sqrt(np.mean((qm - q) ** 2))) if np.all(np.isfinite(q)) else math.inf
    return Fit(final, cost, rms, q, u, j, success, nfev, initial, r)


def statistics(loop: Loop, result: Fit) -> LeastSquaresResult:
    """Estimate, covariance s^2 (J^T J)^-1, std and correlation of the free parameters at the optimum, and the
    HAC (Newey-West) sandwich covariance that holds for coloured residuals (closed loop, model error).

    Raises :class:`ident.leastsquares.UnidentifiableError` naming the parameters the recording does not
    determine (a rank-deficient Jacobian)."""
    j = result.jacobian
    names = loop.free + [f"{n}(t0)" for n in result.initial]
    report = check_identifiability(j, names)
    if not report.identifiable:
        raise UnidentifiableError(report.message(), report.unidentifiable, report.null_directions)
    dof = j.shape[0] - j.shape[1]
    factor = result.cost / dof if dof > 0 else float("nan")
    col = np.linalg.norm(j, axis=0)
    jn = j / col
    n_th = len(loop.free)
    bread = np.linalg.inv(jn.T @ jn) / np.outer(col, col)
    cov = (bread * factor)[:n_th, :n_th]
    sv = np.linalg.svd(j[:, :n_th], compute_uv=False)
    robust, lags = None, None
    if result.residual is not None and np.all(np.isfinite(result.residual)):
        channels = j.shape[0] // loop.n_samples   # rows are channel-major: output samples, then force samples
        by_sample = j.reshape(channels, loop.n_samples, -1).transpose(1, 0, 2).reshape(j.shape)
        residual = np.asarray(result.residual).reshape(channels, loop.n_samples).T.ravel()
        full, lags = hac_covariance(by_sample, residual, rows_per_sample=channels, bread=bread)
        robust = full[:n_th, :n_th]
    return LeastSquaresResult(loop.theta(result.values), cov, list(loop.free), result.cost, dof, False,
                              float(sv[0] / sv[-1]), robust, lags)


@dataclass
class OutputErrorResult:
    """An output-error identification: the compiled loop, the fit and the parameter statistics."""

    loop: Loop
    fit: Fit
    weights: Weights
    statistics: LeastSquaresResult


def _rms_weight(residual: np.ndarray) -> float:
    rms = float(np.sqrt(np.mean(residual ** 2)))
    return rms if rms > 0 and math.isfinite(rms) else 1.0


def identify(model: symbolic.SymbolicModel, rec: Recording, free: list[str], controller: Controller | None = None,
             signals: Signals = Signals(), bounds: dict[str, tuple[float, float]] | None = None,
             start: dict[str, float] | None = None, substeps: int | None = None,
             tracking: dict[str, str] | None = None, max_nfev: int = 50,
             input_name: str | None = None, estimate_initial: list[str] | None = None,
             shooting: str = "single", segments: int = 4, auto_start: bool = False,
             initial: str = "rest") -> OutputErrorResult:
    """Refit ``free`` parameters of ``model`` (values of the others: ``start`` or the Modelica start values)
    so that its free run reproduces ``rec``; closed loop when ``controller`` is given.

    The recording must be sampled uniformly (at the controller period in closed loop). Each channel is
    weighted by the RMS of its residual after a first fit, then the fit is repeated. ``estimate_initial``:
    plant states whose initial value is estimated too (default: :func:`initial_motion_states`: the state the
    output is affine in (the output state itself, or the state behind an alias, gear ratio or offset) and its
    velocity state).
    ``input_name``: the driven plant input (default: the one named like the input column, else the only one).
    ``shooting``: "single" (:func:`fit`, ``max_nfev`` free runs per fit) or "multiple"
    (:func:`ident.multipleshooting.fit` over ``segments`` segments, IPOPT). ``auto_start``: free parameters
    not in ``start`` that enter the inverse dynamics linearly start from its least-squares estimate
    (:func:`ident.startvalues.inverse_dynamics_start`). A free run that diverges from the start values raises
    :class:`ident.startvalues.DivergenceError` naming the values and what to set. ``initial``: "rest" (the
    velocity state starts at its start value) or "samples" (at the slope of the first samples, for a loop
    already moving at t = 0); both are then estimated with ``estimate_initial``."""
    if initial not in ("rest", "samples"):
        raise ValueError(f"initial must be 'rest' or 'samples', not {initial!r}")
    if not free:
        raise ValueError("name at least one free parameter")
    if shooting not in ("single", "multiple"):
        raise ValueError(f"shooting must be 'single' or 'multiple', not {shooting!r}")
    _check_names(model, free)
    needed = [signals.output, signals.input] + ([signals.reference] if controller is not None else [])
    missing = [c for c in needed if c not in rec.columns]
    if missing:
        raise KeyError(f"recording has no column {', '.join(repr(c) for c in missing)} "
                       f"(columns: {', '.join(rec.columns)})")
    steps = np.diff(rec.time)
    ts = float(np.median(steps)) if controller is None else controller.Ts
    bad = np.flatnonzero(np.abs(steps - ts) > 1e-3 * ts)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"recording row {i + 3}, column 'time': step {steps[i]:.9g} s differs from the sample "
                         f"period {ts:.9g} s (the refit needs uniform sampling at the controller's instants)")
    values = {v.name: float(v.start) for v in model.parameters}
    values.update(start or {})
    if input_name is None and signals.input in [v.name for v in model.inputs]:
        input_name = signals.input
    if auto_start:
        guess = [n for n in free if n not in (start or {})]
        position = plant_states.alias_state(model, signals.output)
        if position is not None:
            values.update(startvalues.inverse_dynamics_start(model, rec[signals.output], rec[signals.input], ts,
                                                             position, guess, values, bounds, input_name))
    i_pos = output_state(model, signals.output)
    i_vel = None if i_pos is None else plant_states.velocity_state(model, i_pos)
    if initial == "samples" and i_vel is not None:
        tracking = {model.states[i_vel].name: "dq", **(tracking or {})}
    loop = build_loop(model, controller, signals.output, list(free), values, rec.time.size, substeps=substeps,
                      tracking=tracking, ts=ts, input_name=input_name, signals=signals)
    q0, u0 = simulate(loop, rec)
    qm = rec[signals.output]
    startvalues.check_free_run(q0, qm, rec.time, f"the {'closed' if loop.closed else 'open'}-loop free run of "
                               f"{model.name} on the recording", {n: values[n] for n in free},
                               "Give start values: --set NAME=VALUE or --values FILE (identify oe), or start=.")
    weights = Weights(_rms_weight(qm - q0), _rms_weight(rec[signals.input] - u0) if loop.closed else 1.0)
    if estimate_initial is None:
        estimate_initial = initial_motion_states(model, signals.output)
    if shooting == "multiple":
        from motiontwin.ident import multipleshooting

        def refit(lp: Loop, w: Weights) -> Fit:
            return multipleshooting.fit(lp, rec, w, segments, bounds, estimate_initial=estimate_initial)
    else:
        def refit(lp: Loop, w: Weights) -> Fit:
            return fit(lp, rec, w, bounds, max_nfev=max_nfev, estimate_initial=estimate_initial)
    result = refit(loop, weights)
    weights = Weights(_rms_weight(qm - result.q_sim),
                      _rms_weight(rec[signals.input] - result.u_sim) if loop.closed else 1.0)
    result = refit(loop.with_values(result.values), weights)
    loop = loop.with_values(result.values)
    return OutputErrorResult(loop, result, weights, statistics(loop, result))
