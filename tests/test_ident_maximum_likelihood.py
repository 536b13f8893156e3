"""Maximum likelihood with the filter cut-off as a parameter (Abdellatif eq. 24).

Reference: the position signal is a Fourier series with 10 harmonics of 0.5 Hz (bandwidth exactly 5 Hz)
plus white noise, so the likelihood-optimal cut-off must keep the 10 harmonics and no noise-only bin:
5.0 <= f_c < 5.5 Hz. Torque from the exact inverse dynamics plus white noise.
"""
import numpy as np
import pytest

from motiontwin.ident.joint import identify_joint_periodic, joint_regressor
from motiontwin.ident.maximum_likelihood import ml_joint_with_cutoff
from motiontwin.ident.signals import period_average
from motiontwin.harness.excitation import fourier_trajectory
from tests.ident_truth import JOINT_TRUTH

NAMES = list(JOINT_TRUTH)
TRUTH = np.array([JOINT_TRUTH[n] for n in NAMES])
F0, FS, NH, PERIODS = 0.5, 200.0, 10, 10


def band_limited_periods(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """PERIODS periods at FS of position [rad] (bandwidth exactly NH * F0 = 5 Hz, noise 1e-3 rad) and
    torque [N m] (exact inverse dynamics of JOINT_TRUTH, noise 0.3 N m)."""
    rng = np.random.default_rng(seed)
    scale = 4 / np.sqrt(np.arange(1, NH + 1))
    a, b = rng.standard_normal(NH) * scale, rng.standard_normal(NH) * scale
    t = np.arange(int(FS / F0)) / FS
    profile = fourier_trajectory(t, F0, a, b, 0.0)
    q, qd, qdd = profile.position, profile.velocity, profile.acceleration
    phi, _ = joint_regressor(q, qd, qdd)
    n = q.size * PERIODS
    qs = np.tile(q, PERIODS) + 1e-3 * rng.standard_normal(n)
    taus = np.tile(phi @ TRUTH, PERIODS) + 0.3 * rng.standard_normal(n)
    return qs, taus


@pytest.fixture(scope="module")
def data():
    return band_limited_periods(0)


def test_ml_selects_the_signal_bandwidth_and_matches_gm_there(data):
    qs, taus = data
    n = int(FS / F0)
    q_avg, tau_avg = period_average(qs, n), period_average(taus, n)
    gm_ref = identify_joint_periodic(qs, taus, FS, F0, 5.2, min_speed=0.2)
    mask = np.abs(gm_ref.velocity) > 0.2
    ml = ml_joint_with_cutoff(
        q_avg.mean[:, 0], tau_avg.mean[:, 0], FS, q_avg.mean_covariance[0, 0], tau_avg.mean_covariance[0, 0],
        cutoff_range=(1.0, 15.0), mask=mask,
    )
    assert 5.0 <= ml.cutoff_frequency < 5.5
    assert ml.names == NAMES
    # inside the flat region of the window theta_ML is the least-squares solution on (almost) the same
    # signals: the difference is far below the parameter uncertainty
    assert np.all(np.abs(ml.estimate - gm_ref.fit.estimate) < 0.5 * gm_ref.fit.std)
    assert ml.std[:-1] == pytest.approx(gm_ref.fit.std, rel=0.2)
    assert ml.cost < np.min(ml.profile_costs[ml.profile_cutoffs < 4.9])
    assert ml.cost < np.min(ml.profile_costs[ml.profile_cutoffs > 6.0])


def test_cutoff_from_ml_beats_too_low_and_too_high_cutoffs(data):
    qs, taus = data

    def worst_error(fc):
        fit = identify_joint_periodic(qs, taus, FS, F0, fc, min_speed=0.2).fit
        return np.max(np.abs(fit.estimate / TRUTH - 1))

    assert worst_error(5.2) < 0.05
    assert worst_error(5.2) < worst_error(2.5) / 10
    assert worst_error(5.2) < worst_error(30.0)
