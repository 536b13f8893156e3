"""Optimal excitation (CasADi/IPOPT): feasibility on a fine grid and criteria vs random coefficients."""
import casadi as ca
import numpy as np
import pytest

from ident.excitation_design import (
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
