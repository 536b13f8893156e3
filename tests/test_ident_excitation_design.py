"""Optimal excitation (CasADi/IPOPT): feasibility on a fine grid and criteria vs random coefficients."""
import casadi as ca
import numpy as np
import pytest

from motiontwin.ident.excitation_design import (
    ExcitationLimits,
    _cholesky_logdet,
    _log_condition_surrogate,
    evaluate_design,
    optimize_excitation,
    random_design,
)

LIMITS = ExcitationLimits(q_center=0.0, q_range=1.5, v_max=6.0, a_max=40.0)
F0, NH = 0.5, 5


@pytest.fixture(scope="module")
def designs():
    return {c: optimize_excitation(LIMITS, F0, NH, criterion=c, n_starts=2) for c in ("condition", "d_optimal")}


def test_symbolic_criteria_match_numpy():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((30, 7)) * np.array([1, 10, 0.1, 1, 3, 1, 0.5])
    m = x.T @ x
    sym = ca.SX.sym("m", 7, 7)
    logdet = float(ca.Function("f", [sym], [_cholesky_logdet(sym)])(m))
    assert logdet == pytest.approx(np.linalg.slogdet(m)[1], rel=1e-10)
    surrogate = np.exp(float(ca.Function("g", [sym], [_log_condition_surrogate(sym)])(m)))
    cond_m = np.linalg.cond(m)
    assert cond_m <= surrogate * (1 + 1e-9) <= cond_m * 7 ** (2 / 16) * (1 + 1e-9)


def test_designs_respect_limits_on_fine_grid(designs):
    for design in designs.values():
        metrics = evaluate_design(design, LIMITS, n_samples=20000)
        assert metrics.max_constraint_ratio <= 1.0 + 1e-3


def test_each_criterion_wins_its_own_measure_and_both_beat_random(designs):
    rng = np.random.default_rng(42)
    randoms = [evaluate_design(random_design(LIMITS, F0, NH, rng), LIMITS) for _ in range(20)]
    cond_d = evaluate_design(designs["condition"], LIMITS)
    d_opt = evaluate_design(designs["d_optimal"], LIMITS)
    assert cond_d.condition_number < d_opt.condition_number
    assert cond_d.condition_number < min(r.condition_number for r in randoms)
    assert d_opt.log_det_information > cond_d.log_det_information
    assert d_opt.log_det_information > max(r.log_det_information for r in randoms)
    assert cond_d.log_det_information > np.median([r.log_det_information for r in randoms])


# ---------------------------------------------------------------- hexapod design helpers
# (the IPOPT hexapod design itself takes minutes: it is measured in tests/benchmarks/bench_ident_hexapod.py)

HEX_RANGE = np.array([0.06, 0.06, 0.05, 0.12, 0.12, 0.15])


def test_fit_to_limits_stretches_and_shrinks_to_the_limits():
    from motiontwin.ident.excitation_design import fit_to_limits
    from motiontwin.ident.hexapod import HexapodLimits, PoseExcitation, limit_ratio, random_pose_excitation

    limits = HexapodLimits(HEX_RANGE, leg_speed=0.3, leg_acceleration=3.0)
    start = random_pose_excitation(HEX_RANGE, 0.5, 5, np.random.default_rng(4))
    for factor in (0.2, 3.0):
        trial = PoseExcitation(start.a * factor, start.b * factor, start.offset, 0.5)
        fitted = fit_to_limits(trial, limits, margin=0.01)
        assert limit_ratio(fitted, limits) == pytest.approx(0.99, abs=2e-3)
        ratio = fitted.a / trial.a  # a pure scaling of the coefficients: the design's shape is kept
        np.testing.assert_allclose(ratio, ratio.flat[0], rtol=1e-12)


def test_predicted_spread_matches_monte_carlo_of_gauss_markov():
    """The design's predicted relative std vs the empirical spread of Gauss-Markov estimates over 400
    noise draws on the same regressor (correlated leg-force noise of the period mean)."""
    from motiontwin.ident.excitation_design import predicted_relative_std
    from motiontwin.ident.hexapod import hexapod_base_parameters, random_pose_excitation, stacked_regressor
    from motiontwin.ident.leastsquares import gauss_markov

    base = hexapod_base_parameters()
    fs, f0, n_periods = 100.0, 0.5, 10
    excitation = random_pose_excitation(HEX_RANGE, f0, 5, np.random.default_rng(1))
    theta = np.linspace(0.5, 20.0, len(base.names))
    sigma = 0.5**2 * (0.7 * np.eye(6) + 0.3 * np.ones((6, 6)))
    predicted = predicted_relative_std(excitation, base, sigma, theta, n_periods, fs)
    t = np.arange(int(fs / f0)) / fs
    psi = base.reduce_regressor(stacked_regressor(*excitation.trajectory(t)))
    rng = np.random.default_rng(0)
    chol = np.linalg.cholesky(sigma / n_periods)
    noise = np.einsum("ij,dnj->dni", chol, rng.standard_normal((400, t.size, 6))).reshape(400, -1)
    fit = gauss_markov(psi, psi @ theta + noise[0], channel_covariance=sigma / n_periods)
    np.testing.assert_allclose(fit.std / theta, predicted, rtol=1e-6)
    inv_chol = np.linalg.inv(chol)  # whiten each sample's 6 legs, then ordinary least squares for all draws
    white = lambda x: np.einsum("ij,...nj->...ni", inv_chol, x.reshape(x.shape[:-1] + (t.size, 6)))
    a = white(psi.T).transpose(1, 2, 0).reshape(-1, psi.shape[1])
    b = white(psi @ theta + noise).reshape(400, -1).T
    estimates = np.linalg.lstsq(a, b, rcond=None)[0].T
    empirical = np.std(estimates, axis=0) / theta
    np.testing.assert_allclose(empirical, predicted, rtol=0.15)
