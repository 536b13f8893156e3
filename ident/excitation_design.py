"""Optimal periodic excitation for a serial joint in CasADi/IPOPT (Abdellatif eqs. 19-22; Bona eq. 20).

Design variables: the Fourier coefficients a_k, b_k and the offset q0 of harness.excitation.fourier_basis (fundamental
frequency fixed). Constraints (eq. 20) on sampled instants of one period: |q - q_center| <= q_range,
|qd| <= v_max, |qdd| <= a_max. Criteria:

  - 'condition' (deterministic design, eq. 21): condition number of the regressor. cond(Psi)^2 =
    lambda_max/lambda_min of M = Psi^T Psi is replaced by the smooth p-norm surrogate
    (tr M^p)^(1/p) (tr M^-p)^(1/p), p = 16, which brackets it within a factor n^(2/p); the reported
    value is the exact condition number.
  - 'd_optimal' (statistical design, eq. 22): maximise log det(Psi^T Sigma^-1 Psi), through a symbolic
    Cholesky factor (log det = 2 sum log L_ii). With white torque noise Sigma = sigma^2 I the
    optimiser does not depend on sigma.

The Coulomb columns use tanh(qd / smoothing_speed) during optimisation (sign() has no gradient);
evaluate_design() reports the criteria with the exact sign model of ident.joint.

Hexapod design (Abdellatif sec. 4): :func:`optimize_hexapod_excitation` designs the six pose Fourier
series under leg-speed/-acceleration and pose-range limits on the symbolic regressor of the Modelica
truth (ident.hexapod). Both criteria use the whitened regressor Sigma^-1/2 Psi; the condition criterion
additionally scales each base-parameter column by its a-priori value, so cond() measures how unequal
the *relative* parameter uncertainties are (the unscaled cond mixes kg, kg m^2 and N s/m and is
dominated by units). Several random starts, the best kept; the winner is then stretched or shrunk
to use the limits fully.

Units: rad, rad/s, rad/s^2, Hz, N m (hexapod: m, rad, s, N).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from motiontwin.ident.joint import joint_regressor
from motiontwin.harness.excitation import fourier_basis, fourier_trajectory

if TYPE_CHECKING:  # ident.hexapod imports this module lazily; import it only for annotations
    from motiontwin.ident.hexapod import HexapodLimits, PoseExcitation
    from motiontwin.ident.leastsquares import BaseParameters

__all__ = [
    "ExcitationLimits",
    "ExcitationDesign",
    "DesignMetrics",
    "evaluate_design",
    "random_design",
    "optimize_excitation",
    "HexapodDesign",
    "fit_to_limits",
    "predicted_relative_std",
    "optimize_hexapod_excitation",
]

_P_NORM = 16


@dataclass(frozen=True)
class ExcitationLimits:
    """Actuator limits: q within q_center +- q_range [rad], |qd| <= v_max [rad/s], |qdd| <= a_max [rad/s^2]."""

    q_center: float
    q_range: float
    v_max: float
    a_max: float


@dataclass(frozen=True)
class ExcitationDesign:
    """Fourier excitation: coefficients a, b [rad/s], offset q0 [rad], fundamental frequency [Hz]."""

    a: np.ndarray
    b: np.ndarray
    q0: float
    fundamental_frequency: float
    criterion: str

    def trajectory(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at times ``t``."""
        profile = fourier_trajectory(t, self.fundamental_frequency, self.a, self.b, self.q0)
        return profile.position, profile.velocity, profile.acceleration


@dataclass(frozen=True)
class DesignMetrics:
    """Exact criteria of a design on a fine grid: regressor condition number, log det of the
    information matrix for torque noise variance ``noise_variance`` per sample, and the largest
    constraint use (<= 1 means feasible)."""

    condition_number: float
    log_det_information: float
    max_constraint_ratio: float


def _sample_times(f0: float, n_samples: int) -> np.ndarray:
    return np.arange(n_samples) / (n_samples * f0)


def evaluate_design(
    design: ExcitationDesign,
    limits: ExcitationLimits,
    *,
    n_samples: int = 2000,
    noise_variance: float = 1.0,
    friction: str = "asymmetric",
) -> DesignMetrics:
    """Exact condition number, log det information and constraint use on ``n_samples`` per period."""
    t = _sample_times(design.fundamental_frequency, n_samples)
    q, qd, qdd = design.trajectory(t)
    phi, _ = joint_regressor(q, qd, qdd, friction=friction)
    sign, logdet = np.linalg.slogdet(phi.T @ phi / noise_variance)
    ratio = max(
        np.max(np.abs(q - limits.q_center)) / limits.q_range,
        np.max(np.abs(qd)) / limits.v_max,
        np.max(np.abs(qdd)) / limits.a_max,
    )
    return DesignMetrics(
        float(np.linalg.cond(phi)), float(logdet) if sign > 0 else -np.inf, float(ratio)
    )


def random_design(
    limits: ExcitationLimits, fundamental_frequency: float, n_harmonics: int, rng: np.random.Generator,
    *, n_samples: int = 2000,
) -> ExcitationDesign:
    """Random Fourier coefficients scaled down to just satisfy the limits (the baseline)."""
    a, b = rng.standard_normal((2, n_harmonics))
    probe = ExcitationDesign(a, b, 0.0, fundamental_frequency, "random")
    q, qd, qdd = probe.trajectory(_sample_times(fundamental_frequency, n_samples))
    q_mid = 0.5 * (q.max() + q.min())
    scale = min(
        limits.q_range / (0.5 * (q.max() - q.min())),
        limits.v_max / np.max(np.abs(qd)),
        limits.a_max / np.max(np.abs(qdd)),
    )
    return ExcitationDesign(a * scale, b * scale, limits.q_center - scale * q_mid, fundamental_frequency,
                            "random")


def _cholesky_logdet(m: ca.SX) -> ca.SX:
    n = m.shape[0]
    low = [[None] * n for _ in range(n)]
    logdet = 0
    for j in range(n):
        pivot = m[j, j] - sum(low[j][k] ** 2 for k in range(j))
        low[j][j] = ca.sqrt(pivot)
        logdet += ca.log(pivot)
        for i in range(j + 1, n):
            low[i][j] = (m[i, j] - sum(low[i][k] * low[j][k] for k in range(j))) / low[j][j]
    return logdet


def _power(m: ca.SX, p: int) -> ca.SX:
    out = m
    while p > 1:
        out = ca.mtimes(out, out)
        p //= 2
    return out


def _log_condition_surrogate(m: ca.SX, p: int = _P_NORM) -> ca.SX:
    """log of (tr M^p)^(1/p) (tr M^-p)^(1/p), scale invariant; approximates log cond(M).

    (tr M^p)^(1/p) is a smooth maximum of the eigenvalues (a p-norm, the matrix analogue of a
    log-sum-exp) and (tr M^-p)^(-1/p) a smooth minimum; both are differentiable where cond() is not
    (repeated extreme eigenvalues), which is what IPOPT needs. p must be a power of two.
    """
    m = m / ca.trace(m)
    inv = ca.solve(m, ca.SX.eye(m.shape[0]))
    return (ca.log(ca.trace(_power(m, p))) + ca.log(ca.trace(_power(inv, p)))) / p


def optimize_excitation(
    limits: ExcitationLimits,
    fundamental_frequency: float,
    n_harmonics: int,
    *,
    criterion: str = "d_optimal",
    n_samples: int = 100,
    smoothing_speed: float | None = None,
    n_starts: int = 3,
    seed: int = 0,
    friction: str = "asymmetric",
    margin: float = 0.01,
) -> ExcitationDesign:
    """Optimal Fourier coefficients by IPOPT from ``n_starts`` random feasible starts; best is kept.

    ``criterion``: 'd_optimal' or 'condition'. ``smoothing_speed``: tanh width for the Coulomb
    columns (default 5 % of v_max). ``margin``: fraction of each limit kept free, because the limits
    are imposed only at the ``n_samples`` design instants. Raises RuntimeError if no start converges
    to a feasible point.
    """
    if criterion not in ("d_optimal", "condition"):
        raise ValueError(f"criterion must be 'd_optimal' or 'condition', got {criterion!r}")
    if friction != "asymmetric":
        raise ValueError("only the asymmetric friction model (Bona eq. 2) is implemented for design")
    eps = smoothing_speed if smoothing_speed is not None else 0.05 * limits.v_max
    basis = fourier_basis(_sample_times(fundamental_frequency, n_samples), fundamental_frequency,
                          n_harmonics)
    c = ca.SX.sym("c", 2 * n_harmonics)
    q0 = ca.SX.sym("q0")
    q = q0 + ca.mtimes(ca.DM(basis.position), c)
    qd = ca.mtimes(ca.DM(basis.velocity), c)
    qdd = ca.mtimes(ca.DM(basis.acceleration), c)
    pos = 0.5 * (1 + ca.tanh(qd / eps))
    neg = 0.5 * (1 - ca.tanh(qd / eps))
    phi = ca.horzcat(qdd, ca.sin(q), ca.cos(q), qd * pos, pos, qd * neg, -neg)
    info = ca.mtimes(phi.T, phi) / n_samples
    objective = -_cholesky_logdet(info) if criterion == "d_optimal" else _log_condition_surrogate(info)
    g = ca.vertcat((q - limits.q_center) / limits.q_range, qd / limits.v_max, qdd / limits.a_max)
    solver = ca.nlpsol(
        "excitation", "ipopt", {"x": ca.vertcat(c, q0), "f": objective, "g": g},
        {"ipopt.print_level": 0, "print_time": False, "ipopt.max_iter": 300, "ipopt.tol": 1e-7},
    )
    rng = np.random.default_rng(seed)
    best, best_value = None, np.inf
    for _ in range(n_starts):
        start = random_design(limits, fundamental_frequency, n_harmonics, rng, n_samples=n_samples)
        x0 = np.concatenate([0.9 * start.a, 0.9 * start.b, [start.q0]])
        sol = solver(x0=x0, lbg=-(1.0 - margin), ubg=1.0 - margin)
        stats = solver.stats()
        value = float(sol["f"])
        if stats["success"] and value < best_value:
            best, best_value = np.asarray(sol["x"]).reshape(-1), value
    if best is None:
        raise RuntimeError(f"IPOPT found no feasible {criterion} design from {n_starts} starts")
    return ExcitationDesign(best[:n_harmonics], best[n_harmonics:2 * n_harmonics], float(best[-1]),
                            fundamental_frequency, criterion)


# ---------------------------------------------------------------- hexapod (Abdellatif sec. 4)

@dataclass(frozen=True)
class HexapodDesign:
    """Result of :func:`optimize_hexapod_excitation`: the excitation (feasible on a fine grid), the
    criterion, the objective value of every start (nan if IPOPT failed) and the index of the kept one."""

    excitation: PoseExcitation
    criterion: str
    start_objectives: tuple[float, ...]
    best_start: int


def fit_to_limits(excitation: PoseExcitation, limits: HexapodLimits, *, n_samples: int = 400,
                  margin: float = 0.0) -> PoseExcitation:
    """Scale the Fourier coefficients (up or down) so the largest limit use is 1 - margin.

    A fixed-point iteration on the scale (limit use is nearly linear in it), finished by
    ident.hexapod.scale_to_limits so the result is feasible on the grid.
    """
    from motiontwin.ident.hexapod import PoseExcitation, limit_ratio, scale_to_limits

    scale, trial = 1.0, excitation
    for _ in range(8):
        trial = PoseExcitation(excitation.a * scale, excitation.b * scale, excitation.offset,
                               excitation.fundamental_frequency)
        ratio = limit_ratio(trial, limits, n_samples=n_samples)
        if abs(ratio - (1.0 - margin)) < 1e-4:
            break
        scale *= (1.0 - margin) / ratio
    return scale_to_limits(trial, limits, n_samples=n_samples, margin=margin)


def predicted_relative_std(excitation: PoseExcitation, base: BaseParameters, force_covariance: np.ndarray,
                           parameters: np.ndarray, n_periods: int, sample_rate: float) -> np.ndarray:
    """1-sigma relative uncertainty of each base parameter that Gauss-Markov theory predicts for
    ``n_periods`` periods sampled at ``sample_rate`` [Hz] with force covariance per sample [N^2]
    (noise-free regressor): sqrt(diag((Psi^T Sigma^-1 Psi)^-1)) / |theta|, Sigma of the period mean."""
    from motiontwin.ident.hexapod import stacked_regressor
    from motiontwin.ident.signals import samples_per_period

    n = samples_per_period(sample_rate, excitation.fundamental_frequency)
    psi = base.reduce_regressor(stacked_regressor(*excitation.trajectory(np.arange(n) / sample_rate)))
    inv_chol = np.linalg.inv(np.linalg.cholesky(np.asarray(force_covariance, dtype=float) / n_periods))
    whitened = np.einsum("ij,njp->nip", inv_chol, psi.reshape(n, 6, -1)).reshape(psi.shape)
    covariance = np.linalg.inv(whitened.T @ whitened)
    return np.sqrt(np.diag(covariance)) / np.abs(np.asarray(parameters, dtype=float))


def optimize_hexapod_excitation(limits: HexapodLimits, fundamental_frequency: float, n_harmonics: int, *,
                                criterion: str = "d_optimal", truth=None, base=None,
                                force_covariance: np.ndarray | None = None,
                                parameter_scale: np.ndarray | None = None, n_samples: int = 40,
                                smoothing_speed: float = 0.02, n_starts: int = 4, seed: int = 0,
                                margin: float = 0.02, max_iter: int = 150,
                                p_norm: int = 32) -> HexapodDesign:
    """Optimal pose Fourier coefficients (offsets at limits.center) by CasADi/IPOPT, multi-start.

    ``criterion``: 'condition' (deterministic design, eq. 21) minimises the p-norm surrogate of
    cond(M), M = D Psi^T Sigma^-1 Psi D / n with D = diag(parameter_scale) (default: |a-priori base
    parameters| of ``truth``), i.e. the condition number of the information matrix of the *relative*
    parameters; 'd_optimal' (statistical design, eq. 22) maximises log det M (D only shifts it by a
    constant). ``truth``/``base``: ident.hexapod.ModelicaHexapod / BaseParameters (defaults built).
    Limits are imposed at ``n_samples`` instants with ``margin``; each start is a random excitation
    scaled into the limits; the best converged start is stretched to the limits (fit_to_limits).
    """
    from motiontwin.ident.hexapod import (
        ModelicaHexapod,
        PoseExcitation,
        _SymbolicRegressor,
        hexapod_base_parameters,
        random_pose_excitation,
        scale_to_limits,
    )

    if criterion not in ("d_optimal", "condition"):
        raise ValueError(f"criterion must be 'd_optimal' or 'condition', got {criterion!r}")
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts}")
    truth = ModelicaHexapod() if truth is None else truth
    base = hexapod_base_parameters() if base is None else base
    sigma = np.eye(6) if force_covariance is None else np.asarray(force_covariance, dtype=float)
    scale = (np.abs(base.from_full(truth.theta())) if parameter_scale is None
             else np.abs(np.asarray(parameter_scale, dtype=float)))
    if scale.shape != (len(base.names),) or not np.all(scale > 0):
        raise ValueError(f"parameter_scale must hold {len(base.names)} nonzero values, got {scale}")
    sample = _SymbolicRegressor(truth, base, smoothing_speed).function
    basis = fourier_basis(_sample_times(fundamental_frequency, n_samples), fundamental_frequency, n_harmonics)
    coef = ca.MX.sym("coef", 2 * n_harmonics, 6)
    center = ca.repmat(ca.DM(np.asarray(limits.center, dtype=float)).T, n_samples, 1)
    pose = center + ca.mtimes(ca.DM(basis.position), coef)
    rates = ca.mtimes(ca.DM(basis.velocity), coef)
    second = ca.mtimes(ca.DM(basis.acceleration), coef)
    psi, speed, acceleration = sample.map(n_samples)(pose.T, rates.T, second.T)  # psi: 6 x (n * n_base)
    n_base = len(base.names)
    whitened = ca.mtimes(ca.DM(np.linalg.inv(np.linalg.cholesky(sigma))), psi)
    column_scale = ca.DM(np.diag(scale))
    info = sum(ca.mtimes(blk.T, blk) for blk in ca.horzsplit(whitened, n_base)) / n_samples
    info = ca.mtimes(ca.mtimes(column_scale, info), column_scale)
    info_sx = ca.SX.sym("info", n_base, n_base)
    value = -_cholesky_logdet(info_sx) if criterion == "d_optimal" else _log_condition_surrogate(info_sx, p_norm)
    objective = ca.Function("criterion", [info_sx], [value])(info)
    pose_range = ca.repmat(ca.DM(np.asarray(limits.pose_range, dtype=float)).T, n_samples, 1)
    g = ca.vertcat(ca.vec((pose - center) / pose_range), ca.vec(speed) / limits.leg_speed,
                   ca.vec(acceleration) / limits.leg_acceleration)
    solver = ca.nlpsol("hexapod_excitation", "ipopt", {"x": ca.vec(coef), "f": objective, "g": g},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.max_iter": max_iter,
                        "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 5,
                        "ipopt.hessian_approximation": "limited-memory"})
    rng = np.random.default_rng(seed)
    values, solutions = [], []
    for _ in range(n_starts):
        start = scale_to_limits(random_pose_excitation(limits.pose_range, fundamental_frequency, n_harmonics,
                                                       rng, center=limits.center), limits, margin=margin + 0.05)
        x0 = np.hstack([start.a, start.b]).T.reshape(-1, order="F")
        sol = solver(x0=x0, lbg=-(1.0 - margin), ubg=1.0 - margin)
        status = solver.stats()["return_status"]
        converged = status in ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded")
        feasible = float(np.max(np.abs(np.asarray(sol["g"])))) <= 1.0 - margin + 1e-6
        values.append(float(sol["f"]) if converged and feasible else float("nan"))
        solutions.append(np.asarray(sol["x"]).reshape(2 * n_harmonics, 6, order="F"))
    if all(np.isnan(values)):
        raise RuntimeError(f"IPOPT found no feasible {criterion} design from {n_starts} starts")
    best = int(np.nanargmin(values))
    coefficients = solutions[best]
    design = PoseExcitation(coefficients[:n_harmonics].T, coefficients[n_harmonics:].T,
                            np.asarray(limits.center, dtype=float), fundamental_frequency)
    return HexapodDesign(fit_to_limits(design, limits), criterion, tuple(values), best)
