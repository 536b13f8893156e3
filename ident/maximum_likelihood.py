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

import dataclasses
from dataclasses import dataclass

import casadi as ca
import numpy as np

from motiontwin.ident.joint import JointIdentification, identify_joint_periodic, joint_regressor, periodic_record
from motiontwin.ident.leastsquares import LeastSquaresResult
from motiontwin.ident.signals import lowpass_differentiate, period_average
from motiontwin.ident.units import check_inertia, check_motion

__all__ = ["MaximumLikelihoodResult", "ml_joint_with_cutoff", "JointMaximumLikelihood", "identify_joint_ml_recording"]


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


@dataclass(frozen=True)
class JointMaximumLikelihood:
    """Result of identify_joint_ml_recording.

    ml: the joint (theta, f_c) estimate; fit: theta alone as a LeastSquaresResult (marginal covariance of
    theta, torque residual at the ML cut-off) so it prints and converts like a least-squares fit;
    start: the Gauss-Markov fit at the start cut-off (it sets the speed mask and the noise variances);
    cutoff_range: the searched interval [Hz].
    """

    ml: MaximumLikelihoodResult
    fit: LeastSquaresResult
    start: JointIdentification
    cutoff_range: tuple[float, float]


def identify_joint_ml_recording(
    rec,
    fundamental_frequency: float | None,
    cutoff_frequency: float,
    *,
    cutoff_range: tuple[float, float] | None = None,
    position: str = "q",
    force: str = "u",
    min_speed: float = 0.0,
    nominal_inertia: float | None = None,
    source: str = "recording",
) -> tuple[JointMaximumLikelihood, list[str]]:
    """ml_joint_with_cutoff on a harness.recording.Recording (whole number of periods, >= 2), unit-checked.

    ``cutoff_frequency`` is the start value: a Gauss-Markov fit there (ident.joint) gives the samples used
    (|qd| > ``min_speed``) and the torque noise variance; the position noise variance comes from the spread
    between periods. f_c is then estimated within ``cutoff_range`` (default cutoff/2 .. 2 cutoff, capped
    below Nyquist). Only the revolute model of ident.joint (asymmetric friction, sine gravity) is supported, so a
    linear axis (positions in m) is refused. The record is cut to whole periods (ident.joint.periodic_record).
    Returns the result and the notes on unit conversions; raises ident.units.UnitError naming the column.
    """
    data = periodic_record(rec, fundamental_frequency, position=position, force=force, source=source)
    columns, fs = data.columns, data.sample_rate
    fundamental_frequency = data.fundamental_frequency   # the one found when None was given
    if not columns.rotary(position):
        raise ValueError(f"{source}: column {position!r} is a linear position ({columns.units[position]}); the "
                         "maximum-likelihood fit models a revolute joint (sine gravity, asymmetric friction), "
                         "meaningless on a linear axis: identify without --ml (constant force, symmetric friction)")
    nyquist = 0.5 * fs
    low, high = cutoff_range if cutoff_range is not None else (0.5 * cutoff_frequency, 2.0 * cutoff_frequency)
    high = min(high, nyquist - fundamental_frequency)
    if not 0 < low < high:
        raise ValueError(f"{source}: cut-off search range {low:g}..{high:g} Hz is empty (Nyquist {nyquist:g} Hz)")
    start = identify_joint_periodic(data.position, data.force, fs, fundamental_frequency, cutoff_frequency,
                                    min_speed=min_speed)
    start = dataclasses.replace(start, record_notes=tuple(data.notes))
    q_avg = period_average(data.position, data.samples_per_period)
    position_variance = float(q_avg.mean_covariance[0, 0])
    if not position_variance > 0 or not start.torque_variance > 0:
        raise ValueError(f"{source}: columns {position!r} and {force!r} must vary between periods (noise "
                         "variances from the period spread are zero): ML needs the measurement noise")
    ml = ml_joint_with_cutoff(q_avg.mean[:, 0], start.torque, fs, position_variance, start.torque_variance,
                              cutoff_range=(low, high), mask=start.mask)
    filtered = lowpass_differentiate(q_avg.mean[:, 0], fs, ml.cutoff_frequency)
    m = start.mask
    phi, _ = joint_regressor(filtered.position[m], filtered.velocity[m], filtered.acceleration[m])
    eta = start.torque[m] - phi @ ml.estimate
    fit = LeastSquaresResult(ml.estimate, ml.covariance[:-1, :-1], list(ml.names),
                             float(eta @ eta / start.torque_variance), int(m.sum()) - len(ml.names), True,
                             float(np.linalg.cond(phi)))
    check_motion(columns, position, source=source, velocity=filtered.velocity, acceleration=filtered.acceleration)
    check_inertia(float(ml.estimate[0]), "J", position, columns.rotary(position), source=source,
                  nominal=nominal_inertia)
    return JointMaximumLikelihood(ml, fit, start, (float(low), float(high))), columns.notes
