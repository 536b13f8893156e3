"""Standard deviations that hold for coloured residuals: the HAC (Newey-West) sandwich of ident.leastsquares,
on the linear least squares and on the output-error refit.

Reference: the truth of seeded Monte Carlo cases. With AR(1) noise (phi = 0.8 / 0.9) the white-noise formula's
95 % intervals cover the truth far too rarely; the HAC intervals must cover it in 85-99 % of the cases for every
parameter. The output-error data come from the exact zero-order-hold discretisation of m q'' = u - d q'
(scipy.signal.cont2discrete), independent of the refit's RK4 integrator.
"""
import numpy as np
import scipy.signal as sps

from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording
from motiontwin.ident import outputerror as oe
from motiontwin.ident.leastsquares import gauss_markov, hac_covariance


def ar1(rng: np.random.Generator, n: int, phi: float, sigma: float) -> np.ndarray:
    """Stationary-scale AR(1) noise e_k = phi e_{k-1} + w_k with std ``sigma``."""
    return sigma * np.sqrt(1 - phi**2) * sps.lfilter([1.0], [1.0, -phi], rng.standard_normal(n))


def coverage(estimates: np.ndarray, stds: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.mean(np.abs(estimates - truth) < 1.96 * stds, axis=0)


def least_squares_coverage(seeds: int = 200, phi: float = 0.8) -> dict[str, np.ndarray]:
    """Monte Carlo of y = X theta + e (4 smooth regressors, 2000 samples): coverage of the 95 % intervals per
    parameter with white and with AR(1) noise, by the white formula and by HAC, and the mean HAC/white std ratio."""
    n = 2000
    t = np.arange(n) / n
    regressor = np.column_stack([np.ones(n), np.sin(2 * np.pi * 3 * t), np.cos(2 * np.pi * 7 * t), t])
    truth = np.array([1.0, 2.0, -0.5, 0.3])
    white, coloured = [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        for noise, out in ((rng.standard_normal(n), white), (ar1(rng, n, phi, 1.0), coloured)):
            fit = gauss_markov(regressor, regressor @ truth + noise)
            out.append((fit.estimate, fit.std, fit.robust_std))
    est, std, hac = (np.array([row[i] for row in coloured]) for i in range(3))
    west, wstd, whac = (np.array([row[i] for row in white]) for i in range(3))
    return {"ar1_hac": coverage(est, hac, truth), "ar1_white": coverage(est, std, truth),
            "white_hac": coverage(west, whac, truth), "white_white": coverage(west, wstd, truth),
            "white_ratio": np.mean(whac / wstd, axis=0)}


def test_least_squares_hac_intervals_cover_under_ar1_noise():
    result = least_squares_coverage()
    assert np.all(result["ar1_hac"] >= 0.85) and np.all(result["ar1_hac"] <= 0.99)
    assert np.all(result["ar1_white"] < 0.70)          # the white formula under-covers badly
    assert np.all(np.abs(result["white_ratio"] - 1) < 0.1)   # white residuals: both agree
    assert np.all(result["white_hac"] >= 0.9)


def test_hac_with_zero_lags_is_the_white_sandwich():
    """L = 0 reduces the sandwich to White's heteroskedasticity-consistent form, written out here."""
    rng = np.random.default_rng(5)
    psi = rng.standard_normal((300, 3))
    e = rng.standard_normal(300) * np.linspace(0.5, 2.0, 300)
    cov, lags = hac_covariance(psi, e, lags=0)
    bread = np.linalg.inv(psi.T @ psi)
    np.testing.assert_allclose(cov, bread @ (psi.T * e**2) @ psi @ bread, rtol=1e-10)
    assert lags == 0


def output_error_coverage(seeds: int = 100, phi: float = 0.9) -> dict[str, np.ndarray]:
    """Monte Carlo of the open-loop output-error refit of LinearMotorJoint (m, d; 1 s at 2 kHz, multisine force)
    on exact ZOH data with AR(1) encoder noise: coverage of the 95 % intervals by the white formula and by HAC."""
    ts, n = 5e-4, 2000
    truth = {"m": 2.6, "d": 14.0}
    t = np.arange(n) * ts
    phases = np.random.default_rng(99).uniform(0, 2 * np.pi, 20)
    u = 20 * sum(np.sin(2 * np.pi * (k + 1) * t + p) for k, p in enumerate(phases)) / np.sqrt(20)
    a = np.array([[0.0, 1.0], [0.0, -truth["d"] / truth["m"]]])
    b = np.array([[0.0], [1.0 / truth["m"]]])
    ad, bd, *_ = sps.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), ts, "zoh")
    x, q = np.zeros(2), np.zeros(n)
    for k in range(n):
        q[k] = x[0]
        x = ad @ x + bd[:, 0] * u[k]
    model = build.load_model("MotionTwin.Plants.LinearMotorJoint")
    loop = oe.build_loop(model, None, "q", ["m", "d"], dict(truth), n, ts=ts)
    rows = []
    for seed in range(seeds):
        noise = ar1(np.random.default_rng(seed), n, phi, 2e-6)
        rec = make_recording(t, {"q": q + noise, "u": u}, sample_time=ts)
        fit = oe.fit(loop, rec, oe.Weights(2e-6), start={"m": 2.0, "d": 10.0}, estimate_initial=["x"])
        stats = oe.statistics(loop, fit)
        rows.append((stats.estimate, stats.std, stats.robust_std, stats.robust_lags))
    est, std, hac = (np.array([row[i] for row in rows]) for i in range(3))
    reference = np.array([truth["m"], truth["d"]])
    return {"ar1_hac": coverage(est, hac, reference), "ar1_white": coverage(est, std, reference),
            "lags": np.array([row[3] for row in rows])}


def test_output_error_hac_intervals_cover_under_ar1_noise():
    result = output_error_coverage()
    assert np.all(result["ar1_hac"] >= 0.85) and np.all(result["ar1_hac"] <= 0.99)
    assert np.all(result["ar1_white"] < 0.6)
    assert np.all(result["lags"] > 10)


def test_summary_prints_both_standard_deviations():
    rng = np.random.default_rng(0)
    regressor = np.column_stack([np.ones(500), np.arange(500) / 500])
    fit = gauss_markov(regressor, regressor @ [1.0, 2.0] + ar1(rng, 500, 0.5, 0.1), names=["a", "b"])
    text = fit.summary()
    assert "HAC std" in text and f"Bartlett bandwidth {fit.robust_lags} samples" in text
