"""Hexapod base-parameter identification (ident.hexapod) against the Modelica truth MotionTwin.Plants.Hexapod.

References: the Modelica model's own forward dynamics and a CasADi CVODES simulation of it (for the
synthetic measurement), Table I of Abdellatif & Heimann (structure of the regrouped parameters), and
the truth parameter values (Monte Carlo recovery and interval coverage).
"""
from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np
import pytest

from motiontwin.harness import kinematics as kin
from motiontwin.ident.hexapod import (
    HexapodLimits,
    MeasurementNoise,
    ModelicaHexapod,
    evaluate_pose_design,
    hexapod_base_parameters,
    identify_hexapod_periodic,
    leg_motion,
    limit_ratio,
    measure_periods,
    random_limited_excitation,
    random_pose_excitation,
    simulate_period,
    stacked_regressor,
)
from motiontwin.ident.leastsquares import UnidentifiableError, gauss_markov

POSE_RANGE = np.array([0.06, 0.06, 0.05, 0.12, 0.12, 0.15])
F0, FS, NH, N_PERIODS = 0.5, 100.0, 5, 20
NOISE = MeasurementNoise(sigma_length=2e-6, length_quantum=1e-6,
                         force_covariance=0.5**2 * (0.7 * np.eye(6) + 0.3 * np.ones((6, 6))))


@lru_cache(maxsize=None)
def truth() -> ModelicaHexapod:
    return ModelicaHexapod()


@lru_cache(maxsize=None)
def base():
    return hexapod_base_parameters()


def test_inverse_dynamics_is_consistent_with_a_cvodes_simulation_of_the_modelica_model():
    """Forces from inverse dynamics, fed to the Modelica model integrated by CVODES, reproduce the pose.

    A wider Coulomb regularisation (v_eps = 10 mm/s) keeps the force interpolation between samples
    accurate at leg reversals, so the comparison measures the dynamics, not the interpolation.
    """
    plant = ModelicaHexapod(truth().model, v_eps=0.01)
    model = plant.model
    excitation = random_pose_excitation(POSE_RANGE, F0, NH, np.random.default_rng(1))
    t = np.arange(0, 0.3 + 1e-9, 5e-4)
    pose, pose_dot, pose_ddot = excitation.trajectory(t)
    forces = plant.inverse_dynamics(pose, pose_dot, pose_ddot)
    regressor_forces = (stacked_regressor(pose, pose_dot, pose_ddot, v_eps=0.01) @ plant.theta()).reshape(-1, 6)
    np.testing.assert_allclose(forces, regressor_forces, rtol=0, atol=1e-9)
    time = ca.SX.sym("t")
    tau = ca.vertcat(*[ca.interpolant(f"tau{j}", "bspline", [t], forces[:, j])(time) for j in range(6)])
    p = np.array([plant.parameters[v.name] for v in model.parameters])
    dae = {"x": model.x, "t": time, "ode": ca.substitute(model.dx, ca.vertcat(model.u, model.p),
                                                          ca.vertcat(tau, p))}
    sim = ca.integrator("hexapod", "cvodes", dae, 0.0, t[100::100], {"reltol": 1e-10, "abstol": 1e-12})
    twist0, _ = kin.pose_rates_to_twist(pose[0], pose_dot[0], pose_ddot[0])
    xs = np.array(sim(x0=np.concatenate([pose[0], twist0]))["xf"]).T
    drift = np.abs(xs[:, :6] - pose[100::100]).max()
    assert drift < 1e-6  # the pose moves by ~1e-2 over the window
    assert np.abs(pose[-1] - pose[0]).max() > 1e-2


def test_base_parameters_span_table_one_regrouping():
    """The 18 base parameters are functions of Table I's p6, p7, p8, p10 (and the unregrouped ones)."""
    names = kin.HEXAPOD_PARAMETERS
    assert len(base().names) == 18
    anchors = kin.hexapod_anchors()[1]  # platform anchors, platform frame (the r_B of Table I)
    rng = np.random.default_rng(5)
    for _ in range(3):
        theta = dict(zip(names, rng.uniform(0.5, 2.0, len(names))))
        p6 = theta["IxxE"] + theta["m3"] * np.sum(anchors[:, 1] ** 2 + anchors[:, 2] ** 2)
        p7 = theta["IyyE"] + theta["m3"] * np.sum(anchors[:, 0] ** 2 + anchors[:, 2] ** 2)
        p8 = theta["IzzE"] + theta["m3"] * np.sum(anchors[:, 0] ** 2 + anchors[:, 1] ** 2)
        p10 = theta["mE"] + 6 * theta["m3"]
        # mE and m3 only act through p6..p8 and p10, so the regrouped set is a function of them
        r2 = kin.HEXAPOD.platform_radius**2
        expected = [p6 - r2 / 2 * p10, p7 - r2 / 2 * p10, p8 - r2 * p10, p10 / 6]
        got = base().from_full(np.array([theta[n] for n in names]))
        np.testing.assert_allclose(got[:4], expected, rtol=1e-9)
        np.testing.assert_allclose(got[4:], [theta[n] for n in names[5:]], rtol=1e-12)


def _period(excited=None):
    excitation = random_pose_excitation(POSE_RANGE, F0, NH, np.random.default_rng(1), excited=excited)
    return excitation, *simulate_period(truth(), excitation, FS)


def test_monte_carlo_recovers_base_parameters_with_calibrated_intervals():
    """6 seeds: every base parameter within 2 % on average, 95 % intervals cover the truth ~95 %."""
    _, _, lengths, forces = _period()
    truth_base = base().from_full(truth().theta())
    errors, covered, variance_factors = [], [], []
    for seed in range(6):
        measured = measure_periods(lengths, forces, N_PERIODS, NOISE, np.random.default_rng(seed))
        result = identify_hexapod_periodic(*measured, FS, F0, NH * F0, base=base())
        ci = result.fit.confidence_interval(0.95)
        errors.append((result.fit.estimate - truth_base) / np.abs(truth_base))
        covered.append((ci[:, 0] <= truth_base) & (truth_base <= ci[:, 1]))
        variance_factors.append(result.fit.residual_variance_factor)
        np.testing.assert_allclose(np.sqrt(np.diag(result.force_covariance)), 0.5, rtol=0.05)
    mean_abs = np.abs(np.array(errors)).mean(axis=0)
    assert mean_abs.max() < 0.02, dict(zip(base().names, mean_abs))
    assert 0.85 <= np.mean(covered) <= 1.0
    # residuals at the force noise level (slightly above: pose noise also enters the regressor)
    assert 0.9 < np.mean(variance_factors) < 1.2


def test_excitation_without_rotation_names_the_platform_inertias():
    excitation, t, lengths, forces = _period(excited=[True, True, True, False, False, False])
    measured = measure_periods(lengths, forces, 4, NOISE, np.random.default_rng(0))
    with pytest.raises(UnidentifiableError) as err:
        identify_hexapod_periodic(*measured, FS, F0, NH * F0, base=base())
    inertias = {n for n in base().names if n.startswith(("IxxE", "IyyE", "IzzE"))}
    assert set(err.value.parameters) == inertias and len(inertias) == 3
    # the noise-free regressor of the same motion is exactly rank deficient in the same parameters
    psi = base().reduce_regressor(stacked_regressor(*excitation.trajectory(t)))
    with pytest.raises(UnidentifiableError) as exact:
        gauss_markov(psi, forces.reshape(-1), names=base().names)
    assert set(exact.value.parameters) == inertias


def test_bad_recordings_give_clear_errors():
    _, _, lengths, forces = _period()
    measured_lengths, measured_forces = measure_periods(lengths, forces, 2, NOISE, np.random.default_rng(0))
    with pytest.raises(ValueError, match="not an integer number of samples per period"):
        identify_hexapod_periodic(measured_lengths, measured_forces, FS, 0.3, 1.5, base=base())
    with pytest.raises(ValueError, match=r"\(n_samples, 6\)"):
        identify_hexapod_periodic(measured_lengths[:, :5], measured_forces, FS, F0, 2.5, base=base())
    with pytest.raises(KeyError, match="no parameter"):
        ModelicaHexapod(truth().model, mass=3.0)


def test_leg_motion_matches_time_differences_and_scaling_meets_the_limits():
    """Leg speeds/accelerations against central differences of the inverse kinematics in time."""
    limits = HexapodLimits(POSE_RANGE, leg_speed=0.3, leg_acceleration=3.0)
    excitation = random_limited_excitation(limits, F0, NH, np.random.default_rng(2))
    assert 0.99 < limit_ratio(excitation, limits, n_samples=2000) <= 1.0 + 1e-9
    t = np.linspace(0.1, 1.9, 7)
    h = 1e-4
    lengths, speeds, accelerations = leg_motion(excitation, t)
    around = [np.array([kin.hexapod_inverse(x) for x in excitation.trajectory(t + d)[0]]) for d in (-h, 0, h)]
    np.testing.assert_allclose(lengths, around[1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(speeds, (around[2] - around[0]) / (2 * h), rtol=0, atol=1e-7)
    np.testing.assert_allclose(accelerations, (around[2] - 2 * around[1] + around[0]) / h**2, rtol=0, atol=1e-4)


def test_design_information_equals_the_gauss_markov_covariance():
    """log det of the design information = -log det of the Gauss-Markov covariance on the same samples."""
    excitation = random_pose_excitation(POSE_RANGE, F0, NH, np.random.default_rng(1))
    limits = HexapodLimits(POSE_RANGE, leg_speed=1.0, leg_acceleration=10.0)
    metrics = evaluate_pose_design(excitation, base(), limits, NOISE.force_covariance, n_samples=100)
    t = np.arange(100) / (100 * F0)
    psi = base().reduce_regressor(stacked_regressor(*excitation.trajectory(t)))
    fit = gauss_markov(psi, np.zeros(psi.shape[0]), channel_covariance=NOISE.force_covariance)
    assert metrics.log_det_information == pytest.approx(-np.linalg.slogdet(fit.covariance)[1], rel=1e-9)
    assert metrics.condition_number == pytest.approx(np.linalg.cond(psi), rel=1e-12)
