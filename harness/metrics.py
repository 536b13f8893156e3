"""Tracking metrics of a point-to-point move, as Cheung & Hung report them (Tables 3 and 4).

SI units: time in s, positions and errors in m, angles in rad. Every function takes plain numpy arrays
sampled on one time vector ``t`` and the move window ``[t_start, t_end]`` (start and end of the reference
profile, e.g. 70 ms for the paper's substrate move).

- :func:`max_dynamic_error`: max |e| while the reference moves (Table 3, "max. dynamic error").
- :func:`settling_time`: time from the end of the move until |e| stays inside a band for good
  (Table 3: +-5 um per actuator; Table 4: per end-effector axis).
- :func:`steady_state_error`: mean error over the last part of the record (Table 3 and Table 4's
  "end-point accuracy"), signed as the error is.
- :func:`end_effector_error`: pose error of the end-effector from measured actuator positions through the
  forward kinematics (Table 4 measures the pose independently; a model gives it through eqs. 2-3).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

DEFAULT_BAND = 5e-6
"""Settling band of Cheung & Hung: +-5 um (m)."""

DEFAULT_THETA_BAND = 2e-4
"""Settling band of the end-effector rotation: +-0.2 mrad (rad)."""


def _check(t: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)
    e = np.asarray(e, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"time must be a 1-D array with at least 2 samples, got shape {t.shape}")
    if e.shape[0] != t.size:
        raise ValueError(f"error has {e.shape[0]} samples but time has {t.size}")
    if np.any(np.diff(t) <= 0):
        raise ValueError("time must be strictly increasing")
    return t, e


def max_dynamic_error(t: np.ndarray, e: np.ndarray, t_start: float, t_end: float) -> np.ndarray | float:
    """Largest |e| on samples with ``t_start <= t <= t_end`` (the move). ``e`` of shape (N,) or (N, n_axes)."""
    t, e = _check(t, e)
    inside = (t >= t_start) & (t <= t_end)
    if not inside.any():
        raise ValueError(f"no sample inside the move window [{t_start}, {t_end}] s")
    peak = np.max(np.abs(e[inside]), axis=0)
    return float(peak) if np.ndim(peak) == 0 else peak


def settling_time(t: np.ndarray, e: np.ndarray, t_end: float, band: float = DEFAULT_BAND) -> float:
    """Time [s] after ``t_end`` from which |e| <= ``band`` on every later sample.

    0 when the error is inside the band at ``t_end`` and stays there; ``nan`` when the last sample is still
    outside (the record is too short to tell). The settling instant is the first sample after the last one
    outside the band, so the result is resolved to the sample time.
    """
    t, e = _check(t, e)
    if e.ndim != 1:
        raise ValueError("settling_time takes one error signal of shape (N,)")
    if band <= 0:
        raise ValueError(f"band must be positive, got {band}")
    after = t >= t_end - 1e-12
    if not after.any():
        raise ValueError(f"no sample at or after the end of the move t_end = {t_end} s")
    t_after, e_after = t[after], e[after]
    outside = np.nonzero(np.abs(e_after) > band)[0]
    if outside.size == 0:
        return 0.0
    last = outside[-1]
    if last == t_after.size - 1:
        return float("nan")
    return float(t_after[last + 1] - t_end)


def steady_state_error(t: np.ndarray, e: np.ndarray, window: float) -> np.ndarray | float:
    """Mean of ``e`` over the last ``window`` seconds of the record (signed, per column)."""
    t, e = _check(t, e)
    if window <= 0:
        raise ValueError(f"window must be positive, got {window}")
    last = t >= t[-1] - window - 1e-12
    mean = np.mean(e[last], axis=0)
    return float(mean) if np.ndim(mean) == 0 else mean


def end_effector_error(d_measured: np.ndarray, pose_reference: np.ndarray,
                       forward: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Pose error ``pose_reference - forward(d_measured)`` per sample, shape (N, 4) for [x, y, z, theta].

    d_measured: actuator positions, shape (N, 4) or (4,); pose_reference: shape (N, 4) or (4,) (a target pose).
    forward: actuators -> pose; default :func:`harness.kinematics.cheung_forward`.
    """
    if forward is None:
        from motiontwin.harness.kinematics import cheung_forward as forward
    d = np.atleast_2d(np.asarray(d_measured, dtype=float))
    pose = np.array([forward(row) for row in d])
    return np.asarray(pose_reference, dtype=float) - pose
