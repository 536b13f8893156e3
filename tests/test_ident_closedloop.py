"""Projection method vs naive direct output-error identification on closed-loop data.

Truth: ZOH-discretised 5 Hz resonant plant (zeta 0.3) at 200 Hz under a PI controller, reference white
noise (std 1), output disturbance = low-pass (pole 0.95) filtered white noise (std 0.15) that the
controller feeds back into the input. The direct output-error fit assumes white output noise, so in
closed loop it is biased; the projection method needs no noise model (Forssell & Ljung 2000).
"""
import control
import numpy as np
import pytest
import scipy.signal

from motiontwin.ident.closedloop import fit_output_error, project_on_reference

FS = 200.0
N = 20000
M_CAUSAL = 150
PLANT = control.c2d(control.tf([(2 * np.pi * 5) ** 2], [1, 2 * 0.3 * 2 * np.pi * 5, (2 * np.pi * 5) ** 2]),
                    1 / FS, "zoh")
B = np.concatenate([[0.0], np.asarray(PLANT.num[0][0])])
A = np.asarray(PLANT.den[0][0])
KP, KI = 2.0, 10.0
C_NUM, C_DEN = np.array([KP + KI / FS, -KP]), np.array([1.0, -1.0])


def _padd(a, b):
    n = max(a.size, b.size)
    return np.pad(a, (0, n - a.size)) + np.pad(b, (0, n - b.size))


CL_DEN = _padd(np.convolve(A, C_DEN), np.convolve(B, C_NUM))


def _closed_loop_data(seed: int):
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(N)
    v = scipy.signal.lfilter([1.0], [1.0, -0.95], 0.15 * rng.standard_normal(N))
    u = scipy.signal.lfilter(np.convolve(C_NUM, A), CL_DEN, r - v)  # u = C/(1+GC) (r - v)
    y = scipy.signal.lfilter(B, A, u) + v
    return r, u, y


def _features(b, f):
    """Static gain and resonance frequency [Hz] of B/F."""
    pole = np.roots(f)[0]
    return np.array([np.sum(b) / np.sum(f), abs(np.log(pole)) * FS / (2 * np.pi)])


def test_closed_loop_simulation_is_consistent():
    r, u, y = _closed_loop_data(0)
    # the controller law holds sample by sample: u = C (r - y)
    np.testing.assert_allclose(u, scipy.signal.lfilter(C_NUM, C_DEN, r - y), atol=1e-8)
    assert np.max(np.abs(np.roots(CL_DEN))) < 1.0


def test_projection_removes_closed_loop_bias():
    truth = _features(B, A)
    naive_err, pm_err = [], []
    for seed in range(8):
        r, u, y = _closed_loop_data(seed)
        naive = fit_output_error(u, y, 2, 2, skip=M_CAUSAL)
        projection = project_on_reference(r, u, 0, M_CAUSAL)
        assert abs(projection.correlation) < 1e-3
        pm = fit_output_error(projection.projected, y, 2, 2, skip=M_CAUSAL)
        naive_err.append(_features(naive.b, naive.f) / truth - 1)
        pm_err.append(_features(pm.b, pm.f) / truth - 1)
    naive_bias = np.abs(np.mean(naive_err, axis=0))
    pm_bias = np.abs(np.mean(pm_err, axis=0))
    pm_sem = np.std(pm_err, axis=0) / np.sqrt(len(pm_err))
    assert np.all(naive_bias > 0.3), naive_bias  # direct method: > 30 % off
    assert np.all(pm_bias < naive_bias / 5), (pm_bias, naive_bias)
    assert np.all(pm_bias < 3 * pm_sem + 0.01)  # PM bias not distinguishable from its spread


def test_projection_on_open_loop_fir_recovers_taps():
    rng = np.random.default_rng(7)
    r = rng.standard_normal(3000)
    taps = np.array([0.2, -0.5, 1.0, 0.3])  # lags -1..2
    u = 0.2 * np.roll(r, -1) - 0.5 * r + 1.0 * np.roll(r, 1) + 0.3 * np.roll(r, 2)
    res = project_on_reference(r, u, 1, 2, periodic=True)
    np.testing.assert_allclose(res.coefficients, taps, atol=1e-12)
    with pytest.raises(ValueError, match="same length"):
        project_on_reference(r, u[:-1], 1, 2)
