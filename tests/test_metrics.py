"""harness.metrics against analytic signals with known maxima, settling times and means."""
from __future__ import annotations

import math

import numpy as np
import pytest

from motiontwin.harness import kinematics, metrics

TS = 5e-4


def decay(t: np.ndarray, t_end: float, amplitude: float, tau: float) -> np.ndarray:
    """Zero before t_end, amplitude * exp(-(t - t_end)/tau) after."""
    return np.where(t >= t_end, amplitude * np.exp(-(t - t_end) / tau), 0.0)


def test_settling_time_of_an_exponential_decay_is_tau_log_ratio():
    t = np.arange(0, 0.3, TS)
    t_end, amplitude, tau = 0.08, 40e-6, 0.01
    e = decay(t, t_end, amplitude, tau)
    exact = tau * math.log(amplitude / metrics.DEFAULT_BAND)  # |e| = band at this time after t_end
    assert metrics.settling_time(t, e, t_end) == pytest.approx(exact, abs=TS)
    assert metrics.settling_time(t, -e, t_end) == pytest.approx(exact, abs=TS)  # sign does not matter


def test_settling_time_counts_the_last_excursion_and_flags_unsettled_records():
    t = np.arange(0, 0.2, TS)
    e = np.zeros_like(t)
    e[(t > 0.1) & (t < 0.12)] = 10e-6  # leaves the band again 20 ms after the move ends at 0.1 s
    assert metrics.settling_time(t, e, 0.1) == pytest.approx(0.02, abs=TS)
    assert metrics.settling_time(t, np.zeros_like(t), 0.1) == 0.0
    assert math.isnan(metrics.settling_time(t, np.full_like(t, 1e-3), 0.1))
    assert metrics.settling_time(t, e, 0.1, band=20e-6) == 0.0


def test_max_dynamic_error_is_the_peak_inside_the_move_window():
    t = np.arange(0, 0.2, TS)
    e = np.column_stack([30e-6 * np.sin(2 * np.pi * 10 * t), -50e-6 * np.sin(2 * np.pi * 10 * t)])
    e[t > 0.1] = 1.0  # outside the window: ignored
    peak = metrics.max_dynamic_error(t, e, 0.0, 0.1)
    np.testing.assert_allclose(peak, [30e-6, 50e-6], rtol=1e-9)  # sin reaches 1 at t = 25 ms on the grid
    assert metrics.max_dynamic_error(t, e[:, 0], 0.0, 0.1) == pytest.approx(30e-6)


def test_steady_state_error_is_the_mean_over_the_last_window():
    t = np.arange(0, 0.25 + TS / 2, TS)
    offset = -1.6e-6
    e = offset + 1e-6 * np.sin(2 * np.pi * 100 * t)  # whole periods in the last 50 ms: mean = offset
    assert metrics.steady_state_error(t, e[:, None], 0.05)[0] == pytest.approx(offset, abs=2e-8)
    ramp = t * 1e-5  # mean of a ramp over [T - w, T] = slope * (T - w/2)
    assert metrics.steady_state_error(t, ramp, 0.05) == pytest.approx(1e-5 * (t[-1] - 0.025), rel=1e-3)


def test_end_effector_error_inverts_a_known_pose_offset():
    delta = np.array([3e-6, -2e-6, 1e-6, 5e-5])
    target = kinematics.CHEUNG_END_POSE
    d = kinematics.cheung_inverse(target + delta)  # actuators placed at a pose off by delta
    np.testing.assert_allclose(metrics.end_effector_error(d, target)[0], -delta, atol=1e-12)
    np.testing.assert_allclose(metrics.end_effector_error(kinematics.cheung_inverse(target), target), 0, atol=1e-12)


def test_bad_input_raises_clear_errors():
    t = np.arange(0, 0.1, TS)
    with pytest.raises(ValueError, match="samples"):
        metrics.max_dynamic_error(t, np.zeros(3), 0, 0.05)
    with pytest.raises(ValueError, match="no sample inside"):
        metrics.max_dynamic_error(t, np.zeros_like(t), 1.0, 2.0)
    with pytest.raises(ValueError, match="increasing"):
        metrics.settling_time(t[::-1], np.zeros_like(t), 0.05)
    with pytest.raises(ValueError, match="band"):
        metrics.settling_time(t, np.zeros_like(t), 0.05, band=0)
