"""Optimal periodic excitation for a serial joint in CasADi/IPOPT (Abdellatif eqs. 19-22; Bona eq. 20).

Design variables: the Fourier coefficients a_k, b_k and the offset q0 of ident.trajectory (fundamental
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

Units: rad, rad/s, rad/s^2, Hz, N m.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident.joint import joint_regressor
from ident.trajectory import fourier_basis, fourier_trajectory

__all__ = [
    "ExcitationLimits",
    "ExcitationDesign",
    "DesignMetrics",
    "evaluate_design",
    "random_design",
    "optimize_excitation",
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
        return fourier_trajectory(t, self.fundamental_frequency, self.a, self.b, self.q0)


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


def _log_condition_surrogate(m: ca.SX) -> ca.SX:
    """log of (tr M^p)^(1/p) (tr M^-p)^(1/p), scale invariant; approximates log cond(M)."""
    m = m / ca.trace(m)
    inv = ca.solve(m, ca.SX.eye(m.shape[0]))
    return (ca.log(ca.trace(_power(m, _P_NORM))) + ca.log(ca.trace(_power(inv, _P_NORM)))) / _P_NORM


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
