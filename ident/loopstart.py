"""The state a compiled closed loop (:class:`ident.oeloop.Loop`) starts from on a recording: the plant at the
first recorded position (and slope, for a loop moving at t = 0), effect states at the recorded position or held
force, the controller state that reproduces the first recorded forces. Every free run and every fit evaluation
asks for it, so what depends on the recording and the model only is derived once.
Units: those of the Modelica model (SI)."""
from __future__ import annotations

import casadi as ca
import numpy as np

from motiontwin.harness.recording import Recording
from motiontwin.ident import plant_states, startvalues
from motiontwin.ident.channels import content_key, controller_responses
from motiontwin.ident.controller import Controller
from motiontwin.ident.oeloop import Loop, _output_gain, _state_for_output, output_state


def _column(rec: Recording, name: str, optional: bool = False) -> np.ndarray:
    if name in rec.columns:
        return rec[name]
    if optional:
        return np.zeros_like(rec.time)
    raise KeyError(f"recording has no column {name!r}; columns: {', '.join(rec.columns)}")


def _states_for_outputs(model, targets: dict[str, tuple[float, float]], x0: np.ndarray, p: np.ndarray,
                        steps: int = 30) -> bool:
    """Set in ``x0`` (in place) the states that the outputs ``targets`` (name -> recorded value and slope at
    t = 0) depend on, by Newton's method from ``x0``, when they are as many as the outputs (six leg lengths, six
    pose coordinates), and then the velocity-level states that the outputs' rates are affine in from the slopes
    (when as many, and the rates depend on no input); False, ``x0`` unchanged, when the positions are not
    determined or Newton does not converge."""
    dep, fn, vel, rate_fn = _output_functions(model, tuple(targets))
    if fn is None:
        return False
    x = x0.copy()
    goal, u0 = np.array([v[0] for v in targets.values()]), np.zeros(model.u.numel())
    for _ in range(steps):
        value, jac = (np.array(m) for m in fn(x, u0, p))
        try:
            step = np.linalg.solve(jac, goal - value.ravel())
        except np.linalg.LinAlgError:
            return False
        x[dep] += step
        if np.max(np.abs(step)) <= 1e-12 * max(1.0, float(np.max(np.abs(x[dep])))):
            break
    else:
        return False
    if rate_fn is not None:
        x[vel] = 0.0
        offset, gain = (np.array(m) for m in rate_fn(x, u0, p))
        try:
            x[vel] = np.linalg.solve(gain, np.array([v[1] for v in targets.values()]) - offset.ravel())
        except np.linalg.LinAlgError:
            x[vel] = x0[vel]
    x0[:] = x
    return True


def _output_functions(model, names: tuple[str, ...]) -> tuple[list[int], ca.Function | None, list[int],
                                                               ca.Function | None]:
    """For the outputs ``names``: the states they depend on, (x, u, p) -> (outputs, their Jacobian in those
    states) (None unless they are as many as the outputs), the velocity-level states the outputs' rates are
    affine in, and (x, u, p) -> (rates, their Jacobian in those) (None unless as many, and the rates depend on
    no input). Built once per model: every free run of a fit asks for its start."""
    def build() -> tuple[list[int], ca.Function | None, list[int], ca.Function | None]:
        h = ca.vertcat(*[plant_states.output_expression(model, name) for name in names])
        nx = model.x.numel()
        dep = [i for i in range(nx) if ca.depends_on(h, model.x[i])]
        if len(dep) != len(names):
            return dep, None, [], None
        fn = ca.Function("h", [model.x, model.u, model.p], [h, ca.jacobian(h, model.x)[:, dep]])
        rate = ca.jtimes(h, model.x, model.dx)
        vel = [i for i in range(nx) if i not in dep and ca.depends_on(rate, model.x[i])]
        if len(vel) != len(names) or ca.depends_on(rate, model.u):
            return dep, fn, vel, None
        return dep, fn, vel, ca.Function("r", [model.x, model.u, model.p], [rate, ca.jacobian(rate, model.x)[:, vel]])
    return plant_states.per_model(model, ("output_functions", names), build)


def initial_state(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
                  initial: dict[str, float] | None = None, shift: np.ndarray | None = None) -> np.ndarray:
    """Start from the first recorded sample at rest: the output state (when the output is a state) = q_0, or
    the state an output expression is affine in (an alias, gear ratio or offset) such that the output = q_0,
    outputs that are expressions of several states (leg lengths of a pose) all at q_0 by Newton on those states,
    and their rates at the first samples' slopes (:func:`_states_for_outputs`; then, as for a loop moving at t = 0, the controller state from the first samples: a pose held against
    gravity need not have settled when the recording starts), other plant states at their start values, tracked states at that position or u_0, states in ``initial`` at those
    values, and in closed loop the controller state giving the recorded force u_0 (least-norm solution of
    C z = u_0 - u_ext_0 - D y_0), plus ``shift`` (the correction a joint fit estimates, :func:`fit`,
    :func:`start_shift`; states tracking u_0 then hold the force the shifted controller holds), added to the
    controller state, or to the loop's ``shift_states`` when it names them (an unknown controller's predictor).
    Multi-axis: the same for every axis; a tracking signal may name its axis by output (``"dq:q3"``,
    ``"q:q3"``, ``"u:q3"``; without it, the first axis)."""
    s0 = unshifted_start_state(loop, rec, values, initial)
    if shift is not None and len(shift) and loop.shift_states is not None:
        s0[list(loop.shift_states)] += shift
    elif shift is not None and len(shift):
        s0[s0.size - len(shift):] += shift
        held = loop.controller.C @ shift     # the force each axis's shifted controller holds in addition
        names = [v.name for v in loop.model.states]
        outputs = [sig.output for sig in loop.channels]
        for state, tracked in loop.tracking.items():
            signal, _, axis = tracked.partition(":")
            if signal == "u" and state not in (initial or {}):
                s0[names.index(state)] += float(held[outputs.index(axis) if axis else 0])
    return s0


def unshifted_start_state(loop: Loop, rec: Recording, values: dict[str, float] | None,
                          initial: dict[str, float] | None) -> np.ndarray:
    """:func:`initial_state` without the controller shift."""
    values = values or loop.values
    model, ctrl = loop.model, loop.controller
    p = np.array([values[v.name] for v in model.parameters])
    x0 = plant_states.start_state(model, p)
    names = [v.name for v in model.states]
    positions: dict[str, float] = {}
    joint: dict[str, tuple[float, float]] = {}      # outputs that are expressions of several states (a hexapod's leg lengths)
    for sig in loop.channels:
        output = sig.output if loop.axes else loop.position_state
        q_rec = _column(rec, sig.output)
        if output in names:
            x0[names.index(output)] = q_rec[0]
            positions[sig.output] = q_rec[0]
        else:
            x0 = _state_for_output(model, output, x0, p, q_rec[0])
            i_pos = output_state(model, output, affine=False)
            positions[sig.output] = q_rec[0] if i_pos is None else x0[i_pos]
            if i_pos is None:
                joint[output] = startvalues.first_samples(q_rec, _median_step(rec))
    solved = bool(joint) and _states_for_outputs(model, joint, x0, p)
    by_output = {sig.output: sig for sig in loop.channels}
    for state, tracked in loop.tracking.items():
        signal, _, axis = tracked.partition(":")
        sig = by_output[axis] if axis else loop.channels[0]
        output = sig.output if loop.axes else loop.position_state
        if signal == "dq":      # a velocity state: the slope of the first samples (a loop moving at t = 0)
            slope = startvalues.first_samples(_column(rec, sig.output), _median_step(rec))[1]
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
    if solved or any(t.partition(":")[0] == "dq" for t in loop.tracking.values()):   # moving at t = 0 (or a
        # pose found from the outputs, whose loop need not have settled at rest): the controller
        count = min(rec.time.size, max(20, 4 * ctrl.n_states))            # state from its first outputs
        return np.concatenate([x0, _controller_start(ctrl, np.vstack([refs[:, :count], meas[:, :count]]),
                                                     forces[:, :count])])
    y0 = np.concatenate([refs[:, 0], meas[:, 0]])
    target = forces[:, 0] - ctrl.D @ y0
    z0 = np.linalg.pinv(ctrl.C) @ np.atleast_1d(target)
    return np.concatenate([x0, z0])


_MEDIAN_STEPS: dict[bytes, float] = {}


def _median_step(rec: Recording) -> float:
    """The median time step of ``rec`` [s], kept by the time column's contents (asked with every evaluation)."""
    key = np.ascontiguousarray(rec.time, float).tobytes()
    if key not in _MEDIAN_STEPS:
        if len(_MEDIAN_STEPS) >= 8:
            _MEDIAN_STEPS.clear()
        _MEDIAN_STEPS[key] = float(np.median(np.diff(rec.time)))
    return _MEDIAN_STEPS[key]


_CONTROLLER_STARTS: dict[bytes, np.ndarray] = {}   # the fits ask for the same start with every evaluation


def _controller_start(ctrl: Controller, y: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """The controller state that reproduces the recorded ``forces`` (outputs x samples) on its inputs ``y``
    best (least squares over those samples). It depends on the recording's first samples and the controller
    only, not on the plant's parameters, so it is kept by their contents (a few hundred bytes)."""
    key = content_key(ctrl.A, ctrl.B, ctrl.C, ctrl.D, y, forces, ctrl.ticks)
    start = _CONTROLLER_STARTS.get(key)      # one lookup: a concurrent diagnosis may clear the table in between
    if start is None:
        forced, free = controller_responses(ctrl, y)
        rows = free.transpose(1, 0, 2).reshape(-1, ctrl.n_states)          # sample-major, as the outputs
        start = np.linalg.lstsq(rows, (forces - forced).T.ravel(), rcond=1e-10)[0]
        if len(_CONTROLLER_STARTS) >= 64:
            _CONTROLLER_STARTS.clear()
        _CONTROLLER_STARTS[key] = start
    return start.copy()
