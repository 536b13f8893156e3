"""Frequency-domain filtering/differentiation and period averaging against analytic references."""
import numpy as np
import pytest

from motiontwin.ident.signals import lowpass_differentiate, period_average, samples_per_period


FS = 1000.0
F0 = 0.5


def _periodic_signal(t):
    """x(t) = sum of harmonics of F0 with analytic first and second derivatives."""
    w = 2 * np.pi * F0
    ks = np.array([1, 2, 5, 7])
    amps = np.array([1.0, -0.4, 0.2, 0.05])
    phases = np.array([0.1, 1.0, -0.5, 2.0])
    arg = np.outer(t, ks * w) + phases
    x = np.sin(arg) @ amps
    xd = np.cos(arg) @ (amps * ks * w)
    xdd = -np.sin(arg) @ (amps * (ks * w) ** 2)
    return x, xd, xdd


def test_differentiation_matches_analytic_derivatives():
    n = samples_per_period(FS, F0) * 3
    t = np.arange(n) / FS
    x, xd, xdd = _periodic_signal(t)
    out = lowpass_differentiate(x, FS, cutoff_frequency=4.0)
    assert np.max(np.abs(out.position - x)) < 1e-12
    assert np.max(np.abs(out.velocity - xd)) < 1e-10 * np.max(np.abs(xd))
    assert np.max(np.abs(out.acceleration - xdd)) < 1e-10 * np.max(np.abs(xdd))
    assert out.harmonics_kept == 24  # 4 Hz / (0.5 Hz / 3 periods) bins


def test_ideal_lowpass_removes_everything_above_cutoff():
    n = samples_per_period(FS, F0) * 2
    t = np.arange(n) / FS
    x, xd, _ = _periodic_signal(t)
    noisy = x + 0.3 * np.sin(2 * np.pi * 50 * t) + 0.2 * np.cos(2 * np.pi * 120 * t)
    out = lowpass_differentiate(np.column_stack([noisy, 2 * noisy]), FS, cutoff_frequency=10.0)
    assert np.max(np.abs(out.position[:, 0] - x)) < 1e-12
    assert np.max(np.abs(out.velocity[:, 1] - 2 * xd)) < 1e-9
    # cutting below the 7th harmonic (3.5 Hz) removes exactly that component
    cut = lowpass_differentiate(x, FS, cutoff_frequency=3.0)
    w7 = 2 * np.pi * 3.5
    np.testing.assert_allclose(x - cut.position, 0.05 * np.sin(w7 * t + 2.0), atol=1e-12)


def test_samples_per_period_rejects_fractional_periods():
    assert samples_per_period(1000.0, 0.5) == 2000
    with pytest.raises(ValueError, match="not an integer number of samples"):
        samples_per_period(1000.0, 0.3)


def test_period_average_recovers_cross_covariance():
    rng = np.random.default_rng(1)
    n_per, n_periods = 400, 200
    t = np.arange(n_per) / n_per
    clean = np.column_stack([np.sin(2 * np.pi * t), np.cos(2 * np.pi * t), t])
    true_cov = np.array([[1.0, 0.6, -0.2], [0.6, 2.0, 0.3], [-0.2, 0.3, 0.5]]) * 1e-2
    noise = rng.multivariate_normal(np.zeros(3), true_cov, size=n_per * n_periods)
    data = np.tile(clean, (n_periods, 1)) + noise
    avg = period_average(data, n_per)
    assert avg.n_periods == n_periods
    # 80000 samples: relative standard error of a covariance entry ~ sqrt(2/80000) = 0.5 %
    np.testing.assert_allclose(avg.noise_covariance, true_cov, atol=0.03 * np.max(true_cov))
    np.testing.assert_allclose(avg.mean_covariance, avg.noise_covariance / n_periods)
    assert np.max(np.abs(avg.mean - clean)) < 6 * np.sqrt(np.max(np.diag(true_cov)) / n_periods)
    with pytest.raises(ValueError, match="not a whole number of periods"):
        period_average(data[:-1], n_per)
