"""Multiple-shooting variant of the output-error refit (:mod:`ident.outputerror`), solved by IPOPT.

The recording is split into N segments of equal length L (the last one padded past the end of the
recording; the padding's outputs are not fitted). Decision variables: the free parameters (scaled by their
start values, as in the single-shooting fit), the estimated initial plant states, and the loop state (plant
+ controller in closed loop) at the start of segments 1..N-1, scaled by their magnitude along the start
free run; segment 0 starts from the same initial state as the single-shooting fit. Objective: half the
same weighted sum of squares (output and, in closed loop, force residuals); equalities: s_{j+1} = F(s_j,
theta), F the loop's own one-sample step function (RK4 substeps, sampled controller) chained over L samples
with ``mapaccum`` and mapped over the segments. Parameter bounds: the Modelica min/max as in single
shooting. Segment states start from the single-shooting free run at the start values. IPOPT runs with a
Gauss-Newton Hessian of the Lagrangian (J^T J of the weighted residuals, constraint curvature dropped) and
the adaptive barrier update (in trials on a lightly damped oscillator with the stiffness started 3x off,
the exact Hessian, ``hessian="exact"``, ended in the degenerate valley of huge m, d, k, where the input has
no effect, and Gauss-Newton did not). Multiple shooting is not globally convergent either: on the unstable
test plant some starts at 2x-3x off still end in that valley.

At a converged solution the segments join into the single-shooting free run, so the returned
:class:`ident.outputerror.Fit` (simulation, cost, Jacobian for :func:`ident.outputerror.statistics`) is that
free run's. Units: those of the Modelica model (SI).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from motiontwin.harness.recording import Recording
from motiontwin.ident import oefit as oe
from motiontwin.ident import oeloop

__all__ = ["fit", "initial_state_function", "IPOPT_OPTIONS"]

IPOPT_OPTIONS = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "show_eval_warnings": False,
                 "ipopt.mu_strategy": "adaptive"}
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
STALLED = ("Search_Direction_Becomes_Too_Small",)   # converged within round-off when the segments join


def initial_state_function(loop: oeloop.Loop, rec: Recording, values: dict[str, float],
                           known: dict[str, float], estimate_initial: list[str] | tuple[str, ...]) -> ca.Function:
    """(theta, x_init) -> loop state at t_0, symbolic: :func:`ident.outputerror.initial_state`, with the
    plant states it does not set from the recording (or ``known``, or the estimated ``x_init``) at the
    model's start values as functions of the parameters."""
    model = loop.model
    names = [v.name for v in model.parameters]
    theta = ca.SX.sym("theta", len(loop.free))
    x_init = ca.SX.sym("x_init", len(estimate_initial))
    p = ca.vertcat(*[theta[loop.free.index(n)] if n in loop.free else values[n] for n in names])
    x0 = ca.Function("x0", [model.p], [model.x0()])(p)
    base = oe.initial_state(loop, rec, values, known)
    states = [v.name for v in model.states]
    i_out = oeloop.output_state(model, loop.position_state)
    preset = {loop.position_state, *loop.tracking, *known, *([] if i_out is None else [states[i_out]])}
    entries = [x0[i] if name not in preset else base[i] for i, name in enumerate(states)]
    for k, i in enumerate(oe.state_indices(loop, estimate_initial)):
        entries[i] = x_init[k]
    entries += [base[i] for i in range(len(states), base.size)]
    return ca.Function("s0", [theta, x_init], [ca.vertcat(*entries)])


def _gauss_newton_hessian(v: ca.MX, r: ca.MX, n_g: int) -> ca.Function:
    """IPOPT's Hessian of the Lagrangian replaced by the Gauss-Newton sigma_f J^T J (J = dr/dv; the
    curvature of the residuals and of the continuity constraints is dropped)."""
    p, lam_f, lam_g = ca.MX.sym("p", 0), ca.MX.sym("lam_f"), ca.MX.sym("lam_g", n_g)
    jac = ca.jacobian(r, v)
    return ca.Function("nlp_hess_l", [v, p, lam_f, lam_g], [ca.triu(lam_f * (jac.T @ jac))],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])


def fit(loop: oeloop.Loop, rec: Recording, weights: oe.Weights, segments: int,
        bounds: dict[str, tuple[float, float]] | None = None, start: dict[str, float] | None = None,
        q_meas: np.ndarray | None = None, u_meas: np.ndarray | None = None,
        estimate_initial: list[str] | tuple[str, ...] = (), initial: dict[str, float] | None = None,
        max_iter: int = 200, tol: float = 1e-8, hessian: str = "gauss-newton") -> oe.Fit:
    """Output-error fit of ``loop.free`` by multiple shooting over ``segments`` segments (same arguments
    and result as :func:`ident.outputerror.fit`; ``nfev``: IPOPT objective evaluations)."""
    if loop.step is None or loop.jac is None:
        raise ValueError("the loop needs its step function and Jacobian (ident.outputerror.build_loop, "
                         "with_jacobian=True)")
    if hessian not in ("gauss-newton", "exact"):
        raise ValueError(f"hessian must be 'gauss-newton' or 'exact', not {hessian!r}")
    n, n_seg = loop.n_samples, int(segments)
    if rec.time.size != n:
        raise ValueError(f"loop compiled for {n} samples, recording has {rec.time.size}")
    length = math.ceil(n / max(n_seg, 1))
    if n_seg < 1 or (n_seg - 1) * length >= n:
        raise ValueError(f"cannot split {n} samples into {segments} non-empty segments of equal length")
    known = dict(initial or {})
    values = {**loop.values, **(start or {})}
    names = loop.free
    lo, hi = oe.bound_arrays(loop, bounds)
    idx = oe.state_indices(loop, estimate_initial)
    n_th, n_x0 = len(names), len(idx)
    theta0 = oe._interior(loop.theta(values), lo, hi)
    base = oe.initial_state(loop, rec, values, known)
    x_init0 = base[idx]
    sig = loop.signals
    qm = oe._column(rec, sig.output) if q_meas is None else q_meas
    um = (oe._column(rec, sig.input) if u_meas is None else u_meas) if loop.closed else None
    W = oe.drive(rec, signals=sig, closed=loop.closed)
    W_pad = np.hstack([W, np.zeros((W.shape[0], n_seg * length - n))])
    pf = np.array([values[k] for k in loop.fixed])
    s0_fn = initial_state_function(loop, rec, values, known, estimate_initial)
    th_scale = oe.parameter_scale(theta0)
    if np.any(np.abs(theta0) <= oe.ZERO_START):   # zero starts: scaled by what the data ask for, as in oefit.fit
        s0 = np.array(s0_fn(theta0, x_init0)).ravel()
        q0, u0 = loop.sim(s0, W, theta0, pf)
        r0 = oe._weighted(qm, np.array(q0).ravel(), weights.sigma_q)
        if loop.closed:
            r0 = np.concatenate([r0, oe._weighted(um, np.array(u0).ravel(), weights.sigma_u)])
        j0 = oe.weighted_jacobian(loop, s0, W, theta0, pf, idx, weights)[:, :n_th]
        th_scale = oe.parameter_scale(theta0, r0, j0)
    segment = loop.step.mapaccum("segment", length, [0], [0])
    ns = segment.numel_in(0)

    s_start = np.array(s0_fn(theta0, x_init0)).ravel()
    free_run = []
    for j in range(n_seg):
        s_all = np.array(segment(s_start, W_pad[:, j * length:(j + 1) * length], theta0, pf)[0])
        free_run.append(np.column_stack([s_start, s_all[:, :-1]]))
        s_start = s_all[:, -1]
    free_run = np.hstack(free_run)
    if not np.all(np.isfinite(free_run)):
        raise ValueError("the free run at the start values is not finite; multiple shooting starts from it")
    x_scale = np.max(np.abs(free_run), axis=1)
    x_scale = np.where(x_scale > 0, x_scale, 1.0)
    nodes0 = free_run[:, length::length][:, :n_seg - 1]

    v = ca.MX.sym("v", n_th + n_x0 + ns * (n_seg - 1))
    theta = v[:n_th] * th_scale
    x_init = v[n_th:n_th + n_x0]
    nodes = ca.reshape(v[n_th + n_x0:], ns, n_seg - 1) * ca.repmat(ca.DM(x_scale), 1, n_seg - 1)
    starts = ca.horzcat(s0_fn(theta, x_init), nodes)
    s_all, q_all, u_all = segment.map(n_seg, "serial")(starts, W_pad, theta, pf)
    r = (qm - q_all[:n].T) / weights.sigma_q
    if loop.closed:
        r = ca.vertcat(r, (um - u_all[:n].T) / weights.sigma_u)
    ends = s_all[:, [(j + 1) * length - 1 for j in range(n_seg - 1)]]
    g = ca.vec((nodes - ends) / ca.repmat(ca.DM(x_scale), 1, n_seg - 1))
    opts = {**IPOPT_OPTIONS, "ipopt.max_iter": int(max_iter), "ipopt.tol": tol}
    if hessian == "gauss-newton":
        opts["hess_lag"] = _gauss_newton_hessian(v, r, g.numel())
    solver = ca.nlpsol("oe_ms", "ipopt", {"x": v, "f": 0.5 * ca.sumsqr(r), "g": g}, opts)
    n_free_nodes = ns * (n_seg - 1)
    v0 = np.concatenate([theta0 / th_scale, x_init0, (nodes0 / x_scale[:, None]).ravel(order="F")])
    lbx = np.concatenate([lo / th_scale, np.full(n_x0 + n_free_nodes, -np.inf)])
    ubx = np.concatenate([hi / th_scale, np.full(n_x0 + n_free_nodes, np.inf)])
    sol = solver(x0=v0, lbx=lbx, ubx=ubx, lbg=0, ubg=0)
    stats = solver.stats()
    gap = float(np.max(np.abs(np.array(sol["g"])), initial=0.0))
    success = stats["return_status"] in CONVERGED or (stats["return_status"] in STALLED and gap <= 1e-8)
    v_opt = np.array(sol["x"]).ravel()
    theta_opt, x_init_opt = v_opt[:n_th] * th_scale, v_opt[n_th:n_th + n_x0]
    final = {**values, **dict(zip(names, map(float, theta_opt)))}
    estimated = dict(zip(estimate_initial, map(float, x_init_opt)))
    res, q, u = oe.residuals(loop, rec, final, weights, q_meas=qm, u_meas=um, initial={**known, **estimated})
    s0 = oe.initial_state(loop, rec, final, {**known, **estimated})
    j = oe.weighted_jacobian(loop, s0, W, theta_opt, pf, idx, weights)
    j = np.where(np.isfinite(j), j, 0.0)
    cost = float(res @ res) if np.all(np.isfinite(res)) else math.inf
    rms = float(np.sqrt(np.mean((qm - q) ** 2))) if np.all(np.isfinite(q)) else math.inf
    return oe.Fit(final, cost, rms, q, u, j, success, int(stats.get("n_call_nlp_f", 0)),
                  estimated)
