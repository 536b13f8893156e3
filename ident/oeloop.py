"""The closed loop of a Modelica plant and a sampled controller as compiled CasADi functions (the output-error
refit's model, :mod:`ident.outputerror`): the recording's signals, :class:`Loop` and :func:`build_loop` (RK4
substeps, forward-sensitivity step, chained in compiled C or CasADi's ``mapaccum``). Units: those of the
Modelica model (SI)."""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.ident import chain as native_chain
from motiontwin.ident import plant_states
from motiontwin.ident.controller import Controller
from motiontwin.ident.plant_states import output_state, per_model

_LOG = logging.getLogger("motiontwin.ident.outputerror")
JIT_OPTIONS = {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"]}}
CALL_INSTRUCTIONS = 400     # plant right-hand sides above this many SX instructions are called, not inlined
#: a step whose written-out form would exceed this many instructions (right-hand side x 4 RK4 stages x substeps)
#: is one substep function chained in a loop instead (:func:`_substep_chain`): written out, a stiff LuGre bristle
#: state's 25-100 substeps gave 1-11 MB of C on which gcc spent 100-175 s each (the KUKA robot test: 800 s of
#: compiling on a cold cache). Measured on the two real-recording tests, cold / warm cache: 300 -> KUKA 73 / 47 s,
#: servo 48 / 15 s; 4000 -> 95 / 52 s, 131 / 18 s; written out (before) -> 600+ / 68 s, 146 / 18 s
INLINE_STEP_INSTRUCTIONS = 300


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
    initial_states: tuple[int, ...] = ()  # the states (indices into [x; z]) whose dQ/ds0, dU/ds0 columns jac gives
    shift_states: tuple[int, ...] | None = None   # the states a start ``shift`` moves; None: the controller's

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
                    self.n_samples, self.sim, self.jac, self.tracking, self.signals, self.ts, self.step, self.axes,
                    self.initial_states, self.shift_states)


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
    i, fn = _output_function(model, name)
    if i is None:
        return 1.0
    slope = float(fn(x0, np.zeros(model.u.numel()), p)[1])
    return slope or 1.0


def _output_function(model: symbolic.SymbolicModel, name: str) -> tuple[int | None, ca.Function | None]:
    """The state the output ``name`` is carried by (None: no single state) and the function (x, u, p) -> (output,
    its derivative in that state)."""
    def build() -> tuple[int | None, ca.Function | None]:
        i = output_state(model, name, affine=False)
        if i is None:
            return None, None
        expr = _output_expression(model, name)
        return i, ca.Function("h", [model.x, model.u, model.p], [expr, ca.jacobian(expr, model.x[i])])
    return per_model(model, ("output_function", name), build)


NEWTON_STEPS = 20      # most Newton steps for the state of an output nonlinear in it (one when affine)


def _state_for_output(model: symbolic.SymbolicModel, name: str, x0: np.ndarray, p: np.ndarray,
                      target: float) -> np.ndarray:
    """``x0`` with the state the output ``name`` depends on set so that the output equals ``target``: one
    Newton step when the output is affine in it, until the step vanishes when not (a position read with a
    small sensor error periodic in it: the step shrinks by the error's slope, about 1e-2, each time)."""
    i, fn = _output_function(model, name)
    if i is None:
        return x0
    x0 = x0.copy()
    for _ in range(NEWTON_STEPS):
        value, slope = (float(o) for o in fn(x0, np.zeros(model.u.numel()), p))
        step = (target - value) / slope if slope != 0 else 0.0
        x0[i] += step
        if abs(step) <= 1e-14 * max(1.0, abs(x0[i])):
            break
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
               initial_states: Sequence[int] | None = None, shift_states: Sequence[int] | None = None) -> Loop:
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
    with n entries each. initial_states: the states (indices into [x; z], the controller's after the plant's)
    whose initial values the Jacobian differentiates (needed to estimate them, ``fit(..., estimate_initial=...,
    estimate_start=...)``); None: every state. Each costs about one free run per Jacobian: a diagnosis
    estimates only the start shift's, a large coupled plant none (its d/ds0 blocks are then empty).
    shift_states: the states (indices into [x; z]) that a start ``shift`` moves
    (:func:`ident.loopstart.initial_state`, ``fit(..., estimate_start=True)``); None: the controller's. An
    unknown controller's predictor gives the plant's position and velocity: its observer's state holds no
    load, and the plant's start is what the first noisy samples fix badly.
    """
    if ca.depends_on(model.dx, model.t):
        raise ValueError(f"{model.name}: time-varying plants are not supported by the output-error refit")
    if model.sampled:
        raise ValueError(f"{model.name} is a sampled model; the plant must be continuous")
    _check_names(model, free)
    if controller is None and not (ts and ts > 0):
        raise ValueError("open-loop simulation needs the sample period ts [s]")
    ts = float(controller.sample_time if controller is not None else ts)
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
    ticks = controller.ticks if controller is not None else 1
    substeps = ticks * -(-substeps // ticks)      # whole RK4 substeps per controller update
    fixed = [n for n in names if n not in free]
    f = ca.Function("f", [model.x, model.u, model.p], [model.dx])
    # a large right-hand side (a coupled mechanism's mass-matrix solve) is called, not inlined, in every RK4
    # stage (MX graph), and a step of many substeps chains one substep (:data:`INLINE_STEP_INSTRUCTIONS`): the
    # step and its sensitivity step then compile from kilobytes instead of megabytes
    large = f.n_instructions() > CALL_INSTRUCTIONS
    sym = ca.MX if large or 4 * substeps * f.n_instructions() > INLINE_STEP_INSTRUCTIONS else ca.SX
    theta = sym.sym("theta", len(free))
    gains = controller.entries() if controller is not None else np.zeros(0)
    pfix = sym.sym("pfix", len(fixed) + gains.size)     # the fixed parameters, then the controller's entries
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

    if controller is not None and ca.depends_on(q_expr, model.u):
        raise ValueError(f"{model.name}: output {', '.join(map(repr, observed))} depends on the input "
                         "directly; closing a sampled loop around it is an algebraic loop")
    h = ts / substeps
    if controller is not None:
        A, B, C, D = controller.symbolic(pfix[len(fixed):])
    xk, zk = x, z
    for tick in range(ticks):       # a controller faster than the recording updates ticks times per sample
        if controller is None:
            u_tick = w[n_ax:2 * n_ax]
            q_tick = h_out(xk, plant_input(u_tick), p_full)
        else:
            q_tick = h_out(xk, plant_input(sym.zeros(n_ax)), p_full)
            y = ca.vertcat(w[:n_ax], q_tick + w[2 * n_ax:])
            u_tick = (C @ zk if nz else 0) + D @ y + w[n_ax:2 * n_ax]
            zk = A @ zk + B @ y if nz else zk
        if tick == 0:               # recorded: the position and force at the sample instant
            q, u = q_tick, u_tick
        uvec = plant_input(u_tick)
        if sym is ca.MX:            # one called RK4 substep, chained in a loop (not unrolled) in the generated C
            xk = _substep_chain(f, ca.MX if large else ca.SX, nx, uvec.numel(), p_full.numel(), h,
                                substeps // ticks)(xk, uvec, p_full)
        else:
            for _ in range(substeps // ticks):
                xk = _rk4(f, xk, uvec, p_full, h)
    s_next, out_k = ca.vertcat(xk, zk), ca.vertcat(q, u)
    step = ca.Function("step", [s, w, theta, pfix], [ca.densify(s_next), ca.densify(q), ca.densify(u)])
    columns = list(range(nx + nz)) if initial_states is None else [int(i) for i in initial_states]
    if any(not 0 <= i < nx + nz for i in columns):
        raise ValueError(f"initial_states {columns}: the loop has {nx + nz} states")
    if not with_jacobian:
        aug, seed = None, None
    elif sym is ca.SX:
        aug, seed = _sensitivity_step(s, w, theta, pfix, s_next, out_k, columns)
    else:
        select_p = np.array([[1.0 if n == m else 0.0 for m in free] for n in names]).reshape(len(names), len(free))
        select_u = np.array([[1.0 if i == k else 0.0 for k in k_in] for i in range(len(inputs))])
        aug, seed = _called_sensitivity_step(model, observed, controller, plant_input, select_p, select_u, p_full,
                                             s, w, theta, pfix, substeps, ts, columns, large)
    pair = None
    if native or (native is None and native_chain.available()):
        try:
            pair = _native_pair(step, aug, seed, n_samples)
        except (RuntimeError, OSError) as exc:
            if native:
                raise
            _LOG.warning("compiled chain unavailable, using CasADi's mapaccum chain: %s", exc)
    sim, jac = pair or _casadi_pair(step, aug, seed, n_samples, JIT_OPTIONS if jit else {})
    sim, jac = _with_gains(sim, gains), (_with_gains(jac, gains) if jac else None)
    step = _step_with_gains(step, gains)
    return Loop(model, controller, observed[0], list(free), values, substeps, n_samples, sim, jac,
                dict(tracking or {}), signals if not axes else axes[0], ts, step, tuple(axes or ()), tuple(columns),
                None if shift_states is None else tuple(int(i) for i in shift_states))


def _with_gains(run: Callable, gains: np.ndarray) -> Callable:
    """``run(s0, W, theta, pfix)`` of the chain whose last ``pfix`` entries are the controller's ``gains``."""
    if not gains.size:
        return run

    def bound(s0, W, theta, pfix):
        return run(s0, W, theta, np.concatenate([np.asarray(pfix, dtype=float).ravel(), gains]))
    return bound


def _step_with_gains(step: ca.Function, gains: np.ndarray) -> ca.Function:
    """``step(s, w, theta, pfix)`` with the controller's ``gains`` appended to ``pfix``: the one-sample step with
    the loop's documented inputs."""
    if not gains.size:
        return step
    sym = ca.SX if step.is_a("SXFunction") else ca.MX
    args = [sym.sym(step.name_in(i), step.sparsity_in(i)) for i in range(3)]
    pfix = sym.sym("pfix", step.numel_in(3) - gains.size)
    return ca.Function("step", [*args, pfix], step.call([*args, ca.vertcat(pfix, gains)], True))


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
                      out_k: ca.SX, initial: list[int]) -> tuple[ca.Function, np.ndarray]:
    """The step augmented with forward sensitivities w.r.t. [theta; s0[initial]], propagated sample by sample
    with the step's AD Jacobians (S+ = ds+/ds S + [ds+/dtheta, 0]), and the initial seed vec([0, I[:, initial]]):
    one pass over the recording gives the whole residual Jacobian, at a cost of about (1 + n_theta +
    len(initial)) free runs. Without ``initial`` states the d/ds0 outputs are omitted."""
    ns, nth = s.numel(), theta.numel()
    n0 = len(initial)
    sens = ca.SX.sym("S", ns, nth + n0)
    pad = ca.SX.zeros(ns, n0)
    s_sens = ca.jacobian(s_next, s) @ sens + ca.horzcat(ca.jacobian(s_next, theta), pad)
    n_out = out_k.numel() // 2      # q then u, one entry per axis
    o_sens = ca.jacobian(out_k, s) @ sens + ca.horzcat(ca.jacobian(out_k, theta), ca.SX.zeros(2 * n_out, n0))
    # per sample and channel: axis 0's row, then axis 1's, ... (see _channel_major)
    outs = [ca.vertcat(s_next, ca.vec(s_sens)), ca.vec(o_sens[:n_out, :nth].T), ca.vec(o_sens[n_out:, :nth].T)]
    if n0:
        outs += [ca.vec(o_sens[:n_out, nth:].T), ca.vec(o_sens[n_out:, nth:].T)]
    aug = ca.Function("sstep", [ca.vertcat(s, ca.vec(sens)), w, theta, pfix], [ca.densify(o) for o in outs])
    seed = np.hstack([np.zeros((ns, nth)), np.eye(ns)[:, initial]]).ravel(order="F")
    return aug, seed


def _called_sensitivity_step(model: symbolic.SymbolicModel, observed: list[str], controller: Controller | None,
                             plant_input: Callable, select_p: np.ndarray, select_u: np.ndarray, p_full: ca.MX,
                             s: ca.MX, w: ca.MX, theta: ca.MX, pfix: ca.MX, substeps: int, ts: float,
                             initial: list[int], large: bool = True) -> tuple[ca.Function, np.ndarray]:
    """:func:`_sensitivity_step` for a large plant or a step of many substeps (MX graph): the variational
    equations of the same RK4 step, one substep chained (:func:`_sensitivity_substep_chain`), with the plant's
    derivatives as called functions for a large plant (``large``; :func:`_plant_derivatives`), so that the
    generated code holds them once instead of one forward derivative per sensitivity direction inlined in every
    stage, and inlined in the substep for a small one."""
    nx, ns, nth = model.x.numel(), s.numel(), theta.numel()
    nz, n_ax = ns - nx, len(observed)
    n0 = len(initial)
    na = nth + n0
    dp = np.hstack([select_p, np.zeros((select_p.shape[0], n0))])      # d p / d [theta, s0]
    slope, measure = _plant_derivatives(model, observed, dp)
    s_aug = ca.MX.sym("s_aug", ns * (1 + na))
    x, z = s_aug[:nx], s_aug[nx:ns]
    sens = ca.reshape(s_aug[ns:], ns, na)
    sx, sz = sens[:nx, :], sens[nx:, :]
    p_val = p_full       # an expression of theta and pfix, inputs of the augmented step too
    su = ca.DM(select_u)
    ticks = controller.ticks if controller is not None else 1
    h = ts / substeps
    if controller is not None:
        A, B, C, D = controller.symbolic(pfix[pfix.numel() - controller.entries().size:])
    xk, sk, zk, dzk = x, sx, z, sz
    for tick in range(ticks):       # a controller faster than the recording, as in build_loop's step
        if controller is None:
            u_tick, du_tick = w[n_ax:2 * n_ax], ca.MX.zeros(n_ax, na)
            q_tick, dq_tick = measure(xk, plant_input(u_tick), p_val, sk)
        else:
            q_tick, dq_tick = measure(xk, plant_input(ca.MX.zeros(n_ax)), p_val, sk)
            y = ca.vertcat(w[:n_ax], q_tick + w[2 * n_ax:])
            u_tick = (C @ zk if nz else 0) + D @ y + w[n_ax:2 * n_ax]
            du_tick = (C @ dzk if nz else 0) + D[:, n_ax:] @ dq_tick
            zk, dzk = (A @ zk + B @ y, A @ dzk + B[:, n_ax:] @ dq_tick) if nz else (zk, dzk)
        if tick == 0:
            dq, du = dq_tick, du_tick
        uvec, duvec = plant_input(u_tick), su @ du_tick
        xk, sk = _sensitivity_substep_chain(slope, ca.MX if large else ca.SX, nx, na, uvec.numel(), p_val.numel(),
                                            h, substeps // ticks)(xk, sk, uvec, duvec, p_val)
    s_sens = ca.vertcat(sk, dzk)
    outs = [ca.vertcat(xk, zk, ca.vec(s_sens)), ca.vec(dq[:, :nth].T), ca.vec(du[:, :nth].T)]
    if n0:
        outs += [ca.vec(dq[:, nth:].T), ca.vec(du[:, nth:].T)]
    aug = ca.Function("sstep", [s_aug, w, theta, pfix], [ca.densify(o) for o in outs])
    seed = np.hstack([np.zeros((ns, nth)), np.eye(ns)[:, initial]]).ravel(order="F")
    return aug, seed


def _substep_chain(f: ca.Function, sym: type, nx: int, nu: int, n_p: int, h: float, n: int) -> Callable:
    """``(x, u, p) -> x`` after ``n`` RK4 substeps of ``h``: one substep function chained by ``mapaccum``, which the
    code generator writes as a loop, so the generated C does not grow with the substeps (the same operations in
    the same order as written out). ``sym``: ca.SX inlines ``f`` in the substep (a small plant: as fast as the
    written-out step), ca.MX calls it in each stage (a large one)."""
    x, u, p = sym.sym("x", nx), sym.sym("u", nu), sym.sym("p", n_p)
    chain = ca.Function("rk4", [x, u, p], [_rk4(f, x, u, p, h)]).mapaccum("rk4_n", n)
    return lambda xk, uk, pk: chain(xk, uk, pk)[:, -1]


def _rk4(f: Callable, x, u, p, h: float):
    """One classical RK4 substep of ``h`` of der(x) = f(x, u, p), u held (SX or MX, as the arguments)."""
    k1 = f(x, u, p)
    k2 = f(x + h / 2 * k1, u, p)
    k3 = f(x + h / 2 * k2, u, p)
    k4 = f(x + h * k3, u, p)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def _sensitivity_substep_chain(slope: Callable, sym: type, nx: int, na: int, nu: int, n_p: int, h: float, n: int
                               ) -> Callable:
    """:func:`_substep_chain` of the state and its sensitivities ``(x, Sx, u, Su, p) -> (x, Sx)``, the
    variational RK4 of :func:`_called_sensitivity_step`."""
    x, sx = sym.sym("x", nx), sym.sym("sx", nx, na)
    u, su, p = sym.sym("u", nu), sym.sym("su", nu, na), sym.sym("p", n_p)
    k1, d1 = slope(x, u, p, sx, su)
    k2, d2 = slope(x + h / 2 * k1, u, p, sx + h / 2 * d1, su)
    k3, d3 = slope(x + h / 2 * k2, u, p, sx + h / 2 * d2, su)
    k4, d4 = slope(x + h * k3, u, p, sx + h * d3, su)
    sub = ca.Function("rk4_sens", [x, sx, u, su, p],
                      [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), sx + h / 6 * (d1 + 2 * d2 + 2 * d3 + d4)])
    chain = sub.mapaccum("rk4_sens_n", n, [0, 1], [0, 1])

    def run(xk: ca.MX, sk: ca.MX, uk: ca.MX, duk: ca.MX, pk: ca.MX) -> tuple[ca.MX, ca.MX]:
        xs, ss = chain(xk, sk, uk, duk, pk)
        return xs[:, -1], ss[:, -na:] if na else ss
    return run


#: a plant whose full Jacobian [df/dx, df/du, df/dp] exceeds this many CasADi instructions gets forward directional
#: derivatives instead (:func:`_plant_derivatives`); the CheungManipulator (13 901) keeps the full Jacobians, the
#: Hexapod (69 463) gets directions
DIRECTIONAL_INSTRUCTIONS = 30_000


def _full_jacobian(model: symbolic.SymbolicModel) -> ca.Function:
    """(x, u, p) -> (f, df/dx, df/du, df/dp) of the plant's right-hand side."""
    return ca.Function("f_jac", [model.x, model.u, model.p],
                       [model.dx] + [ca.jacobian(model.dx, v) for v in (model.x, model.u, model.p)])


def directional_derivatives(model: symbolic.SymbolicModel, f_jac: ca.Function | None = None) -> bool:
    """Whether the loop's sensitivities take forward directional derivatives of the plant (its full Jacobian,
    ``f_jac`` when already built, is above :data:`DIRECTIONAL_INSTRUCTIONS`) rather than its full Jacobians."""
    return (f_jac if f_jac is not None else _full_jacobian(model)).n_instructions() > DIRECTIONAL_INSTRUCTIONS


def _plant_derivatives(model: symbolic.SymbolicModel, observed: list[str], dp: np.ndarray
                       ) -> tuple[Callable, Callable]:
    """``slope(x, u, p, Sx, Su) -> (f, df/dx Sx + df/du Su + df/dp dp)`` and ``measure(x, u, p, Sx) -> (h, dh/dx Sx +
    dh/dp dp)`` on MX, ``dp`` (parameters x directions) the constant d p / d [theta, s0]. A small plant: its full
    Jacobians in x and u and its Jacobian in the parameters ``dp`` moves, as one called function each,
    multiplied out. A large one (the full Jacobian above
    :data:`DIRECTIONAL_INSTRUCTIONS`): one forward directional derivative per call, mapped over the directions,
    about 3 right-hand sides per direction; the Hexapod (12 + 6 + 25 Jacobian columns against 7-11 directions):
    its Jacobian pass over 1500 samples 2.5 s -> 0.8 s of CPU with the same values to 2e-15, its generated C
    5.5 -> 1.2 MB (gcc -O1 28 -> 22 s of CPU); the CheungManipulator would run 1.6x slower so."""
    dx_expr = model.dx
    q_expr = ca.vertcat(*[_output_expression(model, name) for name in observed])
    f_jac = _full_jacobian(model)
    dp_dm = ca.DM(dp)
    if not directional_derivatives(model, f_jac):
        # d/dp of the parameters that move only (the free ones): a plant of 15 parameters with 2 free ones
        # computes 2 of its 15 columns, the CheungManipulator's derivative step 13 901 -> ~7 000 instructions
        moved = [i for i in range(dp.shape[0]) if np.any(dp[i])]
        p_moved = ca.vertcat(*[model.p[i] for i in moved]) if moved else ca.SX(0, 1)
        f_jac = ca.Function("f_jac", [model.x, model.u, model.p],
                            [dx_expr] + [ca.jacobian(dx_expr, v) for v in (model.x, model.u, p_moved)])
        h_jac = ca.Function("h_jac", [model.x, model.u, model.p],
                            [q_expr] + [ca.jacobian(q_expr, v) for v in (model.x, model.u, p_moved)])
        dp_moved = ca.DM(dp[moved, :]) if moved else ca.DM.zeros(0, dp.shape[1])

        def slope(x: ca.MX, u: ca.MX, p: ca.MX, sx: ca.MX, su: ca.MX) -> tuple[ca.MX, ca.MX]:
            k, fx, fu, fp = f_jac(x, u, p)
            return k, fx @ sx + fu @ su + fp @ dp_moved

        def measure(x: ca.MX, u: ca.MX, p: ca.MX, sx: ca.MX) -> tuple[ca.MX, ca.MX]:
            q, hx, _, hp = h_jac(x, u, p)
            return q, hx @ sx + hp @ dp_moved

        return slope, measure
    na, nu = dp.shape[1], model.u.numel()
    args = ca.vertcat(model.x, model.u, model.p)
    seed = ca.SX.sym("seed", args.numel())
    f_fn = ca.Function("f", [model.x, model.u, model.p], [dx_expr])
    h_fn = ca.Function("h", [model.x, model.u, model.p], [q_expr])
    f_dir = ca.Function("f_dir", [model.x, model.u, model.p, seed], [ca.jtimes(dx_expr, args, seed)]).map(na)
    h_dir = ca.Function("h_dir", [model.x, model.u, model.p, seed], [ca.jtimes(q_expr, args, seed)]).map(na)

    def slope_dir(x: ca.MX, u: ca.MX, p: ca.MX, sx: ca.MX, su: ca.MX) -> tuple[ca.MX, ca.MX]:
        return f_fn(x, u, p), f_dir(x, u, p, ca.vertcat(sx, su, dp_dm))

    def measure_dir(x: ca.MX, u: ca.MX, p: ca.MX, sx: ca.MX) -> tuple[ca.MX, ca.MX]:
        return h_fn(x, u, p), h_dir(x, u, p, ca.vertcat(sx, ca.MX.zeros(nu, na), dp_dm))

    return slope_dir, measure_dir


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
    """``sim`` and ``jac`` as CasADi ``mapaccum`` chains (the fallback without a C compiler), each built on its
    first call: a caller that only steps the loop (:func:`observer.k_step_ahead`) does not pay for them (0.37 s
    each on a 10 s recording of a 64-substep loop)."""
    n_in = [step.numel_in(i) for i in range(4)]
    s0, th, pf = ca.MX.sym("s0", n_in[0]), ca.MX.sym("th", n_in[2]), ca.MX.sym("pf", n_in[3])
    W = ca.MX.sym("W", n_in[1], n_samples)

    @functools.cache
    def sim_function() -> ca.Function:
        stepper = ca.Function("step", step.sx_in(), step.call(step.sx_in()), opts) if opts else step
        _, q_all, u_all = _chain(stepper, n_samples, s0, W, th, pf)
        # the output at sample k is read from the state at t_k, which the chain's output k holds
        return ca.Function("sim", [s0, W, th, pf], [q_all, u_all])

    @functools.cache
    def jac_function() -> ca.Function:
        stepper = ca.Function("sstep", aug.sx_in(), aug.call(aug.sx_in()), opts) if opts else aug
        blocks = _chain(stepper, n_samples, ca.vertcat(s0, ca.DM(seed)), W, th, pf)[1:]
        return ca.Function("simjac", [s0, W, th, pf], [b.T for b in blocks])

    return (lambda *args: sim_function()(*args),
            None if aug is None else lambda *args: _with_initial_blocks([np.array(b) for b in jac_function()(*args)]))


def _chain(step: ca.Function, n_samples: int, s0: ca.MX, W: ca.MX, th: ca.MX, pf: ca.MX) -> list[ca.MX]:
    """``step`` applied ``n_samples`` times, the state accumulated, one column of W per sample."""
    return step.mapaccum("chain", n_samples, [0], [0])(s0, W, th, pf)
