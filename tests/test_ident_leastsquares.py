"""Gauss-Markov least squares: covariance vs empirical spread, identifiability messages, base parameters."""
import numpy as np
import pytest

from motiontwin.ident.joint import joint_regressor
from motiontwin.ident.leastsquares import UnidentifiableError, base_parameters, check_identifiability, gauss_markov

TRUTH = np.array([2.0, -1.0, 0.5, 3.0])
NAMES = ["a", "b", "c", "d"]
CHANNEL_COV = np.array([[0.04, 0.03], [0.03, 0.09]])  # strongly correlated channels


def _regressor(n_samples: int) -> np.ndarray:
    t = np.linspace(0, 1, n_samples)
    rows = []
    for ch in range(2):
        rows.append(np.column_stack([np.sin(2 * np.pi * t + ch), np.cos(6 * t), t**2 + ch, np.ones_like(t)]))
    return np.stack(rows, axis=1).reshape(2 * n_samples, 4)  # sample-major rows


def test_wls_covariance_matches_monte_carlo_and_intervals_cover_truth():
    psi = _regressor(100)
    chol = np.linalg.cholesky(CHANNEL_COV)
    estimates, covered = [], []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        noise = (chol @ rng.standard_normal((2, 100))).T.reshape(-1)
        res = gauss_markov(psi, psi @ TRUTH + noise, names=NAMES, channel_covariance=CHANNEL_COV)
        estimates.append(res.estimate)
        ci = res.confidence_interval(0.95)
        covered.append((ci[:, 0] <= TRUTH) & (TRUTH <= ci[:, 1]))
    empirical = np.cov(np.array(estimates).T)
    # relative standard error of a variance estimated from 300 seeds is sqrt(2/299) = 8 %: allow 30 %
    np.testing.assert_allclose(np.diag(empirical), np.diag(res.covariance), rtol=0.3)
    coverage = np.mean(covered)  # 1200 intervals: binomial std 0.6 %
    assert 0.92 <= coverage <= 0.98, coverage
    assert np.all(np.abs(np.mean(estimates, axis=0) - TRUTH) < 4 * np.sqrt(np.diag(res.covariance) / 300))


def test_channel_covariance_equals_full_block_diagonal_covariance():
    psi = _regressor(30)
    rng = np.random.default_rng(5)
    y = psi @ TRUTH + 0.1 * rng.standard_normal(60)
    block = gauss_markov(psi, y, channel_covariance=CHANNEL_COV)
    full = gauss_markov(psi, y, noise_covariance=np.kron(np.eye(30), CHANNEL_COV))
    np.testing.assert_allclose(block.estimate, full.estimate, rtol=1e-10)
    np.testing.assert_allclose(block.covariance, full.covariance, rtol=1e-10)
    # explicit GLS formula as independent reference
    w = np.linalg.inv(np.kron(np.eye(30), CHANNEL_COV))
    cov = np.linalg.inv(psi.T @ w @ psi)
    np.testing.assert_allclose(full.estimate, cov @ psi.T @ w @ y, rtol=1e-9)
    np.testing.assert_allclose(full.covariance, cov, rtol=1e-9)


def test_ols_statistics_match_textbook_formulas():
    rng = np.random.default_rng(2)
    psi = rng.standard_normal((50, 3))
    y = psi @ np.array([1.0, 2.0, 3.0]) + 0.5 * rng.standard_normal(50)
    res = gauss_markov(psi, y, names=["x", "y", "z"])
    coef, rss, *_ = np.linalg.lstsq(psi, y, rcond=None)
    cov = rss[0] / 47 * np.linalg.inv(psi.T @ psi)
    np.testing.assert_allclose(res.estimate, coef, rtol=1e-10)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-10)
    np.testing.assert_allclose(np.diag(res.correlation), 1.0)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert res.correlation_condition == pytest.approx(np.linalg.cond(corr))
    assert "cond(correlation)" in res.summary()


def test_only_positive_velocity_names_the_negative_friction_parameters():
    t = np.linspace(0, 2, 500)
    q = 0.5 * t + 0.1 * np.sin(3 * t)
    qd = 0.5 + 0.3 * np.cos(3 * t)  # always > 0: negative-velocity friction never excited
    qdd = -0.9 * np.sin(3 * t)
    psi, names = joint_regressor(q, qd, qdd)
    with pytest.raises(UnidentifiableError) as err:
        gauss_markov(psi, np.ones(500), names=names)
    assert set(err.value.parameters) == {"fv_neg", "fc_neg"}
    assert "fv_neg" in str(err.value) and "fc_neg" in str(err.value)


def test_collinear_columns_name_the_combination():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((40, 2))
    psi = np.column_stack([x[:, 0], x[:, 1], 2 * x[:, 0]])
    report = check_identifiability(psi, ["J_motor", "fv", "J_load"])
    assert report.rank == 2 and set(report.unidentifiable) == {"J_motor", "J_load"}
    with pytest.raises(UnidentifiableError, match="J_motor.*J_load|J_load.*J_motor"):
        gauss_markov(psi, x[:, 0], names=["J_motor", "fv", "J_load"])


def test_base_parameters_regroup_dependent_columns():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((60, 3))
    psi = np.column_stack([x[:, 0], x[:, 1], x[:, 0] + 2 * x[:, 1], x[:, 2]])
    base = base_parameters(psi, ["m1", "m2", "m12", "fv"])
    assert len(base.independent) == 3 and len(base.dependent) == 1
    theta = np.array([1.0, 2.0, 0.5, -1.0])
    # the base regressor reproduces the full model with the regrouped parameters
    np.testing.assert_allclose(base.reduce_regressor(psi) @ base.from_full(theta), psi @ theta, atol=1e-12)
    fit = gauss_markov(base.reduce_regressor(psi), psi @ theta)
    np.testing.assert_allclose(fit.estimate, base.from_full(theta), rtol=1e-10)
