"""Cheung's joint model: FRF (H1, swept sine, acceleration from encoder) fit and PEM of L(s).

Truth simulated with scipy.signal.lsim on the continuous model with a zero-order-hold input (independent
of the python-control c2d used inside the fit). Noise: encoder resolution 0.1 um plus white 0.2 um.
"""
import numpy as np
import pytest
import scipy.signal

from ident.frf import (
    JointModel,
    acceleration_from_position,
    estimate_frf,
    fit_joint_frf,
    fit_low_frequency_model,
    second_difference_response,
)

FS = 2000.0  # Cheung's controller rate
TRUTH = JointModel(50.0, 20.0, ((2 * np.pi * 220, 0.04),), ((2 * np.pi * 150, 0.03),))
RESOLUTION = 1e-7


def _simulate(u: np.ndarray, rng) -> np.ndarray:
    tf = TRUTH.transfer_function()
    t = np.arange(u.size) / FS
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, t, interp=False)
    q = q + 2e-7 * rng.standard_normal(q.size)
    return np.round(q / RESOLUTION) * RESOLUTION


def test_second_difference_response_matches_its_fft():
    impulse = np.zeros(64)
    impulse[[0, 1, 2]] = [1.0, -2.0, 1.0]
    f = np.fft.rfftfreq(64, 1 / FS)
    h = np.fft.rfft(impulse) * FS**2 * np.exp(2j * np.pi * f / FS)  # centre the stencil
    np.testing.assert_allclose(h, second_difference_response(f, FS), atol=1e-6 * FS**2)


def test_swept_sine_fit_recovers_gain_alpha_and_mode_frequencies():
    rng = np.random.default_rng(0)
    t = np.arange(int(60 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=0.5, f1=500, t1=t[-1], method="logarithmic")
    q = _simulate(u, rng)
    frf = estimate_frf(u[1:-1], acceleration_from_position(q, FS), FS, 4096)
    assert np.median(frf.band(100, 400).coherence) > 0.95
    fit = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9)
    m = fit.model
    assert m.gain == pytest.approx(TRUTH.gain, rel=0.02)
    assert m.alpha == pytest.approx(TRUTH.alpha, rel=0.02)
    assert m.resonances[0][0] == pytest.approx(TRUTH.resonances[0][0], rel=0.02)
    assert m.antiresonances[0][0] == pytest.approx(TRUTH.antiresonances[0][0], rel=0.02)
    assert m.resonances[0][1] == pytest.approx(TRUTH.resonances[0][1], rel=0.1)
    assert fit.rms_log_error < 0.05


def test_fit_without_hold_model_is_biased():
    """The ZOH matters at 2 kHz: ignoring it (continuous P) misplaces the modes by more than 2 %."""
    rng = np.random.default_rng(1)
    t = np.arange(int(30 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=20, f1=500, t1=t[-1], method="logarithmic")
    frf = estimate_frf(u[1:-1], acceleration_from_position(_simulate(u, rng), FS), FS, 4096)
    exact = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9,
                          initial=TRUTH).model
    naive = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9,
                          initial=TRUTH, zero_order_hold=False).model
    err = lambda m: abs(m.resonances[0][0] / TRUTH.resonances[0][0] - 1)
    assert err(exact) < 0.005 and err(naive) > 4 * err(exact)


def test_low_coherence_is_reported():
    rng = np.random.default_rng(2)
    frf = estimate_frf(rng.standard_normal(8192), rng.standard_normal(8192), FS, 1024)
    with pytest.raises(ValueError, match="too little excitation"):
        fit_joint_frf(frf, sample_rate=FS, min_coherence=0.9)


def test_point_to_point_pem_recovers_low_frequency_model():
    rng = np.random.default_rng(3)
    n = int(0.2 * FS)
    u = np.zeros(n)
    u[: int(0.035 * FS)] = 0.05  # bang-bang move of about 70 ms, then coast
    u[int(0.035 * FS): int(0.07 * FS)] = -0.05
    rigid = JointModel(TRUTH.gain, TRUTH.alpha)
    tf = rigid.transfer_function()
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, np.arange(n) / FS, interp=False)
    q = np.round((q + 2e-7 * rng.standard_normal(n)) / RESOLUTION) * RESOLUTION
    fit = fit_low_frequency_model(u, q, FS, initial=(10.0, 5.0))
    assert fit.gain == pytest.approx(TRUTH.gain, rel=0.02)
    assert fit.alpha == pytest.approx(TRUTH.alpha, rel=0.02)
    assert np.sqrt(fit.covariance[1, 1]) < 0.02 * TRUTH.alpha
