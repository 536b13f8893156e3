"""Closed-loop free-run simulation of a plant (SymbolicModel) with a sampled linear controller, in CasADi,
and the output-error refit of plant parameters.

At each sample t_k the controller reads r_k and the measured position q_k (+ a measurement-noise input
n_k, zero in free run), applies u_k = C z_k + D [r_k; q_k + n_k] + u_ext_k, held over [t_k, t_k + Ts),
and updates z_{k+1} = A z_k + B [r_k; q_k + n_k]. The plant is integrated over one sample by RK4 with
``substeps`` steps. One step function is built once and chained with ``mapaccum`` over the recording, so
parameter Jacobians come from algorithmic differentiation. Units: SI (s, m, N).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from fmus import symbolic
from harness.recording import Recording
from ident.diagnosis.bundle import Controller


@dataclass
class Loop:
    """A plant + controller loop whose parameters ``free`` are symbolic; the others are fixed values."""

    model: symbolic.SymbolicModel
    controller: Controller
    position_state: str
    free: list[str]
    values: dict[str, float]            # every plant parameter's current value (free ones: starting point)
    substeps: int
    n_samples: int
    sim: ca.Function = field(repr=False)   # (s0, W[3xN], theta, pfix) -> (Q[1xN], U[1xN])
    jac: ca.Function | None = field(repr=False)   # (s0, W, theta, pfix) -> (dQ/dtheta, dU/dtheta)
    tracking: dict[str, str] = field(default_factory=dict)  # state -> "q" or "u": starts at q_0 or u_0

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
                    self.n_samples, self.sim, self.jac, self.tracking)


def stable_substeps(model: symbolic.SymbolicModel, values: dict[str, float], ts: float,
                    minimum: int = 1, maximum: int = 64) -> int:
    """RK4 substeps per sample so that the fastest linearised plant mode stays well inside RK4's stability
    region (|lambda| h <= 1) at rest and at a moderate speed."""
    p = np.array([values[v.name] for v in model.parameters])
    jac_fn = ca.Function("a", [model.x, model.u, model.p], [ca.jacobian(model.dx, model.x)])
    worst = 0.0
    for speed in (0.0, 1e-3, 0.05):
        x = np.zeros(model.x.numel())
        a = np.array(jac_fn(x + speed, 0.0, p))
        if np.all(np.isfinite(a)) and a.size:
            worst = max(worst, float(np.max(np.abs(np.linalg.eigvals(a)))))
    return int(min(maximum, max(minimum, math.ceil(worst * ts / 1.0))))


def build_loop(model: symbolic.SymbolicModel, controller: Controller, position_state: str, free: list[str],
               values: dict[str, float], n_samples: int, substeps: int | None = None,
               tracking: dict[str, str] | None = None, with_jacobian: bool = True, min_substeps: int = 1) -> Loop:
    """Compile the closed-loop simulation of ``n_samples`` samples with the parameters ``free`` symbolic."""
    if ca.depends_on(model.dx, model.t):
        raise ValueError(f"{model.name}: time-varying plants are not supported by the diagnosis")
    names = [v.name for v in model.parameters]
    unknown = [n for n in free if n not in names]
    if unknown:
        raise KeyError(f"{model.name} has no parameter {unknown}")
    values = {n: float(values.get(n, model.parameters[i].start)) for i, n in enumerate(names)}
    substeps = substeps or max(min_substeps, stable_substeps(model, values, controller.Ts))
    fixed = [n for n in names if n not in free]
    theta = ca.SX.sym("theta", len(free))
    pfix = ca.SX.sym("pfix", len(fixed))
    p_full = ca.vertcat(*[theta[free.index(n)] if n in free else pfix[fixed.index(n)] for n in names])
    f = ca.Function("f", [model.x, model.u, model.p], [model.dx])
    nx, nz = model.x.numel(), controller.n_states
    s = ca.SX.sym("s", nx + nz)
    w = ca.SX.sym("w", 3)  # r, u_ext, measurement noise
    x, z = s[:nx], s[nx:]
    pos = [v.name for v in model.states].index(position_state)
    q = x[pos]
    y = ca.vertcat(w[0], q + w[2])
    A, B, C, D = (ca.DM(m) for m in (controller.A, controller.B, controller.C, controller.D))
    u = (C @ z if nz else 0) + D @ y + w[1]
    z_next = A @ z + B @ y if nz else z
    h = controller.Ts / substeps
    xk = x
    for _ in range(substeps):
        k1 = f(xk, u, p_full)
        k2 = f(xk + h / 2 * k1, u, p_full)
        k3 = f(xk + h / 2 * k2, u, p_full)
        k4 = f(xk + h * k3, u, p_full)
        xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("step", [s, w, theta, pfix], [ca.vertcat(xk, z_next), ca.vertcat(q, u)])
    chain = step.mapaccum("chain", n_samples, [0], [0])
    s0 = ca.MX.sym("s0", nx + nz)
    W = ca.MX.sym("W", 3, n_samples)
    th = ca.MX.sym("th", len(free))
    pf = ca.MX.sym("pf", len(fixed))
    states, out = chain(s0, W, th, pf)
    # the output at sample k is read from the state at t_k, which the chain's first output row holds
    Q, U = out[0, :], out[1, :]
    sim = ca.Function("sim", [s0, W, th, pf], [Q, U])
    jac = ca.Function("simjac", [s0, W, th, pf], [ca.jacobian(Q.T, th), ca.jacobian(U.T, th)]) \
        if with_jacobian else None
    return Loop(model, controller, position_state, list(free), values, substeps, n_samples, sim, jac,
                dict(tracking or {}))


def initial_state(loop: Loop, rec: Recording, values: dict[str, float] | None = None) -> np.ndarray:
    """Start from the first recorded sample at rest: position = q_0, other plant states at their start
    values, controller state giving the recorded force u_0 (least-norm solution of C z = u_0 - D y_0)."""
    values = values or loop.values
    model, ctrl = loop.model, loop.controller
    p = np.array([values[v.name] for v in model.parameters])
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    pos = [v.name for v in model.states].index(loop.position_state)
    x0[pos] = rec["q"][0]
    names = [v.name for v in model.states]
    for state, signal in loop.tracking.items():
        x0[names.index(state)] = rec["q"][0] if signal == "q" else rec["u"][0]
    y0 = np.array([rec["r"][0], rec["q"][0]])
    if ctrl.n_states:
        target = rec["u"][0] - rec["u_ext"][0] - float((ctrl.D @ y0)[0])
        z0 = np.linalg.pinv(ctrl.C) @ np.atleast_1d(target)
    else:
        z0 = np.zeros(0)
    return np.concatenate([x0, z0])


def drive(rec: Recording, noise: np.ndarray | None = None) -> np.ndarray:
    """The 3 x N input matrix [r; u_ext; measurement noise] of a recording."""
    n = rec.time.size
    return np.vstack([rec["r"], rec["u_ext"], np.zeros(n) if noise is None else noise])


def simulate(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
             noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Free-run closed-loop simulation along ``rec``; returns simulated (q, u) at the sample instants."""
    values = {**loop.values, **(values or {})}
    if rec.time.size != loop.n_samples:
        raise ValueError(f"loop compiled for {loop.n_samples} samples, recording has {rec.time.size}")
    pf = np.array([values[n] for n in loop.fixed])
    q, u = loop.sim(initial_state(loop, rec, values), drive(rec, noise), loop.theta(values), pf)
    return np.array(q).ravel(), np.array(u).ravel()


@dataclass
class Fit:
    """Result of an output-error refit."""

    values: dict[str, float]     # all plant parameters after the fit
    cost: float                  # weighted sum of squares (q and u channels)
    rms_q: float                 # RMS of measured minus simulated q [m]
    q_sim: np.ndarray
    u_sim: np.ndarray
    jacobian: np.ndarray         # weighted residual Jacobian w.r.t. the free parameters at the optimum
    success: bool


@dataclass
class Weights:
    """Noise levels used to weight the two residual channels: sigma_q [m], sigma_u [N]."""

    sigma_q: float
    sigma_u: float


def residuals(loop: Loop, rec: Recording, values: dict[str, float], weights: Weights,
              noise: np.ndarray | None = None, q_meas: np.ndarray | None = None,
              u_meas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted residual vector [(q_meas - q_sim)/sigma_q; (u_meas - u_sim)/sigma_u] and the simulation."""
    q, u = simulate(loop, rec, values, noise)
    qm = rec["q"] if q_meas is None else q_meas
    um = rec["u"] if u_meas is None else u_meas
    return np.concatenate([(qm - q) / weights.sigma_q, (um - u) / weights.sigma_u]), q, u


def fit(loop: Loop, rec: Recording, weights: Weights, bounds: dict[str, tuple[float, float]],
        start: dict[str, float] | None = None, max_nfev: int = 40,
        q_meas: np.ndarray | None = None, u_meas: np.ndarray | None = None) -> Fit:
    """Output-error least squares of ``loop.free`` within ``bounds`` (scipy TRF with CasADi Jacobians)."""
    values = {**loop.values, **(start or {})}
    names = loop.free
    lo = np.array([bounds[n][0] for n in names])
    hi = np.array([bounds[n][1] for n in names])
    theta0 = np.clip(loop.theta(values), lo + 1e-12 * np.abs(lo), hi - 1e-12 * np.abs(hi))
    scale = np.maximum(np.abs(theta0), 1e-12)
    s0_cache: dict[bytes, np.ndarray] = {}
    qm = rec["q"] if q_meas is None else q_meas
    um = rec["u"] if u_meas is None else u_meas
    W = drive(rec)
    pf = loop.pfix()

    def state(theta: np.ndarray) -> np.ndarray:
        key = theta.tobytes()
        if key not in s0_cache:
            s0_cache.clear()
            s0_cache[key] = initial_state(loop, rec, {**values, **dict(zip(names, theta))})
        return s0_cache[key]

    def res(xs: np.ndarray) -> np.ndarray:
        theta = xs * scale
        q, u = loop.sim(state(theta), W, theta, pf)
        r = np.concatenate([(qm - np.array(q).ravel()) / weights.sigma_q,
                            (um - np.array(u).ravel()) / weights.sigma_u])
        return np.where(np.isfinite(r), r, 1e12)

    def jac(xs: np.ndarray) -> np.ndarray:
        theta = xs * scale
        jq, ju = loop.jac(state(theta), W, theta, pf)
        j = -np.vstack([np.array(jq) / weights.sigma_q, np.array(ju) / weights.sigma_u]) * scale
        return np.where(np.isfinite(j), j, 0.0)

    if names:
        sol = least_squares(res, theta0 / scale, jac=jac, bounds=(lo / scale, hi / scale), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)
        theta = sol.x * scale
        success = bool(sol.success or sol.status == 0)
    else:
        theta = np.zeros(0)
        success = True
    final = {**values, **dict(zip(names, map(float, theta)))}
    r, q, u = residuals(loop, rec, final, weights, q_meas=qm, u_meas=um)
    j = jac(theta / scale) / scale if names else np.zeros((r.size, 0))
    cost = float(r @ r) if np.all(np.isfinite(r)) else math.inf
    rms = float(np.sqrt(np.mean((qm - q) ** 2))) if np.all(np.isfinite(q)) else math.inf
    return Fit(final, cost, rms, q, u, j, success)
