"""Periodic Fourier excitation trajectories (Swevers; Abdellatif eqs. 12-15; Bona eqs. 17-19).

    q(t)   = q0 + sum_k  a_k/(k w) sin(k w t) - b_k/(k w) cos(k w t)
    qd(t)  =      sum_k  a_k cos(k w t) + b_k sin(k w t)
    qdd(t) =      sum_k -a_k k w sin(k w t) + b_k k w cos(k w t),      w = 2 pi f0.

Linear in the coefficients c = [a_1..a_n, b_1..b_n], so a trajectory is q = q0 + Bq @ c, qd = Bv @ c,
qdd = Ba @ c with basis matrices that work equally for numpy arrays and CasADi symbols.

Units: t [s], f0 [Hz], q [rad or m], a_k, b_k [rad/s or m/s].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FourierBasis", "fourier_basis", "fourier_trajectory"]


@dataclass(frozen=True)
class FourierBasis:
    """Basis matrices (n_samples x 2*n_harmonics) for position, velocity and acceleration."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


def fourier_basis(t: np.ndarray, fundamental_frequency: float, n_harmonics: int) -> FourierBasis:
    """Basis of the finite Fourier series at times ``t``."""
    if n_harmonics < 1:
        raise ValueError(f"n_harmonics must be >= 1, got {n_harmonics}")
    t = np.asarray(t, dtype=float).reshape(-1, 1)
    w = 2 * np.pi * fundamental_frequency
    kw = w * np.arange(1, n_harmonics + 1)
    s, c = np.sin(kw * t), np.cos(kw * t)
    return FourierBasis(
        position=np.hstack([s / kw, -c / kw]),
        velocity=np.hstack([c, s]),
        acceleration=np.hstack([-s * kw, c * kw]),
    )


def fourier_trajectory(
    t: np.ndarray, fundamental_frequency: float, a: np.ndarray, b: np.ndarray, q0: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of the Fourier trajectory with coefficients a, b."""
    a, b = np.asarray(a, dtype=float).reshape(-1), np.asarray(b, dtype=float).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"a and b must have the same length, got {a.shape} and {b.shape}")
    basis = fourier_basis(t, fundamental_frequency, a.size)
    c = np.concatenate([a, b])
    return q0 + basis.position @ c, basis.velocity @ c, basis.acceleration @ c
