"""Truth simulations shared by the ident tests and benchmarks (not a test module).

Serial joint under a stiff PD + inertia-feedforward position loop tracking a Fourier reference,
integrated with scipy solve_ivp (LSODA, rtol 1e-10). Coulomb friction uses tanh(qd/1e-3): identical to
the sign model of ident.joint for |qd| > 0.02 rad/s, and smooth enough for the integrator.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from motiontwin.harness.excitation import fourier_trajectory

JOINT_TRUTH = {
    "J": 0.5,
    "g_sin": 3.0 * np.cos(0.3),
    "g_cos": 3.0 * np.sin(0.3),
    "fv_pos": 1.5,
    "fc_pos": 2.0,
    "fv_neg": 1.95,
    "fc_neg": 1.5,
}
REFERENCE_A = 4.0 * np.array([1.0, -0.6, 0.4, 0.3, -0.2])
REFERENCE_B = 4.0 * np.array([-0.5, 0.7, -0.3, 0.2, 0.25])
TANH_SPEED = 1e-3


def friction_torque(truth: dict, qd: float) -> float:
    s = np.tanh(qd / TANH_SPEED)
    pos, neg = 0.5 * (1 + s), 0.5 * (1 - s)
    return (truth["fv_pos"] * qd + truth["fc_pos"]) * pos + (truth["fv_neg"] * qd - truth["fc_neg"]) * neg


def simulate_joint_period(
    truth: dict = JOINT_TRUTH,
    a: np.ndarray = REFERENCE_A,
    b: np.ndarray = REFERENCE_B,
    q0: float = 0.0,
    f0: float = 0.5,
    fs: float = 1000.0,
    loop_bandwidth_hz: float = 100.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One steady-state period (after one warm-up period) of time, position q [rad], torque u [N m]."""
    wn = 2 * np.pi * loop_bandwidth_hz
    kp, kd = truth["J"] * wn**2, 2 * 0.7 * wn * truth["J"]

    def reference(t):
        profile = fourier_trajectory(np.atleast_1d(t), f0, a, b, q0)
        return profile.position, profile.velocity, profile.acceleration

    def control(t, q, qd):
        r, rd, rdd = reference(t)
        return truth["J"] * rdd + kp * (r - q) + kd * (rd - qd)

    def rhs(t, x):
        q, qd = x
        u = control(t, q, qd)[0]
        gravity = truth["g_sin"] * np.sin(q) + truth["g_cos"] * np.cos(q)
        return [qd, (u - gravity - friction_torque(truth, qd)) / truth["J"]]

    n = int(round(fs / f0))
    t = np.arange(2 * n) / fs
    r0, rd0, _ = reference(0.0)
    sol = solve_ivp(rhs, (0, t[-1]), [r0[0], rd0[0]], t_eval=t, method="LSODA", rtol=1e-10, atol=1e-12)
    if sol.status != 0:
        raise RuntimeError(sol.message)
    q, qd = sol.y
    u = control(t, q, qd)
    return t[n:] - t[n], q[n:], u[n:]


def noisy_periods(q: np.ndarray, u: np.ndarray, n_periods: int, sigma_q: float, sigma_u: float, rng):
    """Repeat the steady-state period and add independent white noise to position and torque."""
    qs = np.tile(q, n_periods) + sigma_q * rng.standard_normal(q.size * n_periods)
    us = np.tile(u, n_periods) + sigma_u * rng.standard_normal(u.size * n_periods)
    return qs, us
