"""Maximum likelihood with the data-filter cut-off as an extra parameter (Abdellatif eq. 24), in CasADi.

For a period-averaged position record q_bar (N samples) and torque tau_bar, the filtered position is
q_f(f_c) = IDFT(W(f_c) X), velocity and acceleration by j*omega (ident.signals), and

    min over (theta, f_c):  1/2 sum_k delta_k^2 / s_delta + 1/2 sum_k eta_k^2 / s_eta,
    delta = q_bar - q_f(f_c),   eta = tau_bar - Phi(q_f, qd_f, qdd_f) theta.

The rectangular window W is made differentiable in f_c by a logistic edge of width ``edge_width``
(a fraction of a bin), so each DFT bin's contribution is a smooth function of f_c: q_f = mean +
sum_k w_k(f_c) x_k(t) with precomputed per-bin signals x_k. The objective is piecewise flat between
harmonics, so f_c is first located by a profile-likelihood scan (theta has a closed-form weighted LS
solution for fixed f_c), then (theta, f_c) are refined jointly with IPOPT.

Units: rad, rad/s, rad/s^2, N m, Hz. Joint model: ident.joint (asymmetric friction).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident.joint import joint_regressor

__all__ = ["MaximumLikelihoodResult", "ml_joint_with_cutoff"]


@dataclass(frozen=True)
class MaximumLikelihoodResult:
    """estimate (theta by names), cutoff_frequency [Hz], covariance of [theta, f_c] from the inverse
    Hessian of the negative log-likelihood, cost at the optimum, and the profile scan
    (profile_cutoffs [Hz], profile_costs)."""

    estimate: np.ndarray
    names: list[str]
    cutoff_frequency: float
    covariance: np.ndarray
    cost: float
    profile_cutoffs: np.ndarray
    profile_costs: np.ndarray

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def _bin_signals(x: np.ndarray, sample_rate: float, max_frequency: float):
    n = x.size
    spectrum = np.fft.rfft(x)
    freqs = np.fft.rfftfreq(n, 1.0 / sample_rate)
    bins = np.nonzero((freqs > 0) & (freqs <= max_frequency) & (np.arange(freqs.size) < n / 2))[0]
    t = np.arange(n) / sample_rate
    phase = np.exp(2j * np.pi * np.outer(t, freqs[bins]))
    contrib = 2.0 / n * spectrum[bins] * phase
    jw = 2j * np.pi * freqs[bins]
    return freqs[bins], spectrum[0].real / n, contrib.real, (jw * contrib).real, (jw**2 * contrib).real


def ml_joint_with_cutoff(
    position: np.ndarray,
    torque: np.ndarray,
    sample_rate: float,
    position_variance: float,
    torque_variance: float,
    *,
    cutoff_range: tuple[float, float],
    mask: np.ndarray | None = None,
    edge_width: float = 0.05,
) -> MaximumLikelihoodResult:
    """ML estimate of the joint parameters and the filter cut-off f_c from one averaged period.

    ``position_variance``/``torque_variance``: variances of one averaged sample (e.g.
    PeriodAverage.mean_covariance). ``cutoff_range``: (low, high) search interval for f_c [Hz].
    ``mask``: samples used in the torque term (e.g. |qd| > v_min); default all.
    ``edge_width``: width of the smooth window edge as a fraction of the bin spacing.
    """
    q = np.asarray(position, dtype=float).reshape(-1)
    tau = np.asarray(torque, dtype=float).reshape(-1)
    if q.shape != tau.shape:
        raise ValueError(f"position and torque must have the same length, got {q.size} and {tau.size}")
    if position_variance <= 0 or torque_variance <= 0:
        raise ValueError("position_variance and torque_variance must be > 0")
    low, high = cutoff_range
    if not 0 < low < high:
        raise ValueError(f"cutoff_range must satisfy 0 < low < high, got {cutoff_range}")
    mask = np.ones(q.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    df = sample_rate / q.size
    freqs, mean, bq, bv, ba = _bin_signals(q, sample_rate, high + 2 * df)
    width = edge_width * df

    def signals(fc: float):
        w = (freqs <= fc).astype(float)  # ideal window for the scan
        return mean + bq @ w, bv @ w, ba @ w

    def profile(fc: float):
        qf, qdf, qddf = signals(fc)
        phi, names = joint_regressor(qf[mask], qdf[mask], qddf[mask])
        theta, *_ = np.linalg.lstsq(phi, tau[mask], rcond=None)
        eta = tau[mask] - phi @ theta
        delta = q - qf
        return 0.5 * (delta @ delta / position_variance + eta @ eta / torque_variance), theta, names

    grid = np.arange(np.ceil(low / df - 0.5) + 0.5, np.floor(high / df - 0.5) + 1.0) * df
    grid = grid[(grid >= low) & (grid <= high)]
    if grid.size == 0:
        raise ValueError(f"cutoff_range {cutoff_range} contains no DFT bin edge (bin spacing {df} Hz)")
    costs = np.array([profile(fc)[0] for fc in grid])
    best_fc = float(grid[np.argmin(costs)])
    _, theta0, names = profile(best_fc)

    theta = ca.MX.sym("theta", len(names))
    fc = ca.MX.sym("fc")
    w = 1.0 / (1.0 + ca.exp(-(fc - ca.DM(freqs)) / width))
    qf = mean + ca.mtimes(ca.DM(bq), w)
    qdf = ca.mtimes(ca.DM(bv[mask]), w)
    qddf = ca.mtimes(ca.DM(ba[mask]), w)
    qfm = mean + ca.mtimes(ca.DM(bq[mask]), w)
    pos = ca.if_else(qdf > 0, 1.0, 0.0)
    neg = ca.if_else(qdf < 0, 1.0, 0.0)
    phi = ca.horzcat(qddf, ca.sin(qfm), ca.cos(qfm), qdf * pos, pos, qdf * neg, -neg)
    eta = ca.DM(tau[mask]) - ca.mtimes(phi, theta)
    delta = ca.DM(q) - qf
    cost = 0.5 * (ca.sumsqr(delta) / position_variance + ca.sumsqr(eta) / torque_variance)
    x = ca.vertcat(theta, fc)
    solver = ca.nlpsol("ml", "ipopt", {"x": x, "f": cost},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.max_iter": 200})
    lbx = [-np.inf] * len(names) + [low]
    ubx = [np.inf] * len(names) + [high]
    sol = solver(x0=np.concatenate([theta0, [best_fc]]), lbx=lbx, ubx=ubx)
    x_opt = np.asarray(sol["x"]).reshape(-1)
    hess = np.asarray(ca.Function("h", [x], [ca.hessian(cost, x)[0]])(x_opt))
    covariance = np.linalg.pinv(hess)
    return MaximumLikelihoodResult(
        x_opt[:-1], names, float(x_opt[-1]), covariance, float(sol["f"]), grid, costs
    )
