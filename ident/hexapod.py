"""Base-parameter identification of the 6-DOF hexapod from periodic pose excitation (Abdellatif & Heimann).

Pipeline (paper sec. 3): a Fourier trajectory per pose coordinate (eqs. 12-15) is run periodically;
leg lengths and leg forces are recorded over N_m periods. Each measured leg-length sample is mapped
to a pose by Newton-Raphson direct kinematics (harness.kinematics.hexapod_direct, warm-started from
the previous sample); poses and forces are averaged over the periods, with the full 6x6
cross-covariance of the force errors (sec. 3.2); the averaged poses are low-pass filtered and
differentiated exactly in the frequency domain (sec. 3.3); velocities and accelerations become twists
by eq. (16); the leg-force regressor (eq. 7, harness.kinematics.hexapod_regressor) is reduced to the
base parameters (QR with column pivoting) and solved by Gauss-Markov least squares with the
block-diagonal force covariance (eqs. 8-11).

The synthetic "measurement" used by tests and benchmarks comes from the Modelica truth model
``MotionTwin.Plants.Hexapod`` (its CasADi symbolic form, the one its FMU is built from): leg forces by
inverse dynamics of that model along the prescribed pose trajectory, i.e. a perfectly tracking closed
loop, which is what the paper's closed-loop measurement amounts to; leg lengths from the model's outputs.

Excitation design (sec. 4, eqs. 19-22): Fourier coefficients optimised by CasADi/IPOPT under pose-range,
leg-speed and leg-acceleration limits, by the condition number of the regressor (deterministic design)
or by D-optimality with the force covariance (statistical design); the regressor is differentiated
symbolically from the same Modelica model (forces are linear in the parameters).

Units: m, rad, s, Hz, N; parameters in kg, kg m^2, kg m, N, N s/m.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from motiontwin.harness.kinematics import (
    HEXAPOD,
    HEXAPOD_HOME,
    HEXAPOD_PARAMETERS,
    HexapodGeometry,
    hexapod_direct,
    hexapod_inverse,
    hexapod_length_jacobian,
    hexapod_regressor,
    pose_rates_to_twist,
)
from motiontwin.ident.leastsquares import (
    BaseParameters,
    LeastSquaresResult,
    UnidentifiableError,
    base_parameters,
    gauss_markov,
)
from motiontwin.ident.signals import lowpass_differentiate, period_average, samples_per_period
from motiontwin.harness.excitation import fourier_basis
from motiontwin.ident.units import UnitError, check_inertia, checked_columns

__all__ = [
    "POSE_NAMES",
    "PoseExcitation",
    "random_pose_excitation",
    "stacked_regressor",
    "hexapod_base_parameters",
    "ModelicaHexapod",
    "simulate_period",
    "MeasurementNoise",
    "measure_periods",
    "direct_kinematics_series",
    "HexapodIdentification",
    "identify_hexapod_periodic",
    "HexapodLimits",
    "PoseDesignMetrics",
    "leg_motion",
    "limit_ratio",
    "scale_to_limits",
    "random_limited_excitation",
    "evaluate_pose_design",
    "identify_hexapod_recording",
]

POSE_NAMES = ("x", "y", "z", "a", "b", "c")


@dataclass(frozen=True)
class PoseExcitation:
    """Periodic pose trajectory, eqs. (12)-(15): per coordinate i, offset[i] and Fourier coefficients
    a[i, k] (mu_k), b[i, k] (nu_k) in m/s or rad/s; fundamental frequency f0 [Hz] common to all."""

    a: np.ndarray
    b: np.ndarray
    offset: np.ndarray
    fundamental_frequency: float

    def __post_init__(self) -> None:
        a, b = np.atleast_2d(self.a), np.atleast_2d(self.b)
        if a.shape != b.shape or a.shape[0] != 6:
            raise ValueError(f"a and b must both be (6, n_harmonics), got {a.shape} and {b.shape}")
        if np.shape(self.offset) != (6,):
            raise ValueError(f"offset must have 6 entries (x, y, z, a, b, c), got {np.shape(self.offset)}")

    @property
    def n_harmonics(self) -> int:
        return int(np.atleast_2d(self.a).shape[1])

    def trajectory(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose, pose rates and pose second derivatives at times ``t``, each (n_samples, 6)."""
        basis = fourier_basis(t, self.fundamental_frequency, self.n_harmonics)
        coef = np.hstack([np.atleast_2d(self.a), np.atleast_2d(self.b)]).T  # (2 nh, 6)
        return (np.asarray(self.offset) + basis.position @ coef, basis.velocity @ coef,
                basis.acceleration @ coef)


def random_pose_excitation(pose_range: np.ndarray, fundamental_frequency: float, n_harmonics: int,
                           rng: np.random.Generator, *, center: np.ndarray = HEXAPOD_HOME,
                           excited: np.ndarray | None = None, n_samples: int = 1000) -> PoseExcitation:
    """Random Fourier coefficients, each coordinate scaled so it spans exactly center +- pose_range.

    ``excited`` (6 booleans) keeps the other coordinates constant at ``center`` (to build an
    experiment that misses a degree of freedom).
    """
    pose_range = np.asarray(pose_range, dtype=float)
    excited = np.ones(6, bool) if excited is None else np.asarray(excited, bool)
    a, b = rng.standard_normal((2, 6, n_harmonics))
    probe = PoseExcitation(a, b, np.zeros(6), fundamental_frequency)
    pose, _, _ = probe.trajectory(np.arange(n_samples) / (n_samples * fundamental_frequency))
    half_span = 0.5 * (pose.max(axis=0) - pose.min(axis=0))
    scale = np.where(excited, pose_range / half_span, 0.0)
    mid = 0.5 * (pose.max(axis=0) + pose.min(axis=0))
    return PoseExcitation(a * scale[:, None], b * scale[:, None], np.asarray(center) - scale * mid,
                          fundamental_frequency)


def stacked_regressor(pose: np.ndarray, pose_dot: np.ndarray, pose_ddot: np.ndarray,
                      geom: HexapodGeometry = HEXAPOD, g: float = 9.81, v_eps: float = 1e-3) -> np.ndarray:
    """Sample-major stack (6 n_samples x 19) of the leg-force regressor, rows = sample*6 + leg."""
    rows = []
    for x, xd, xdd in zip(np.atleast_2d(pose), np.atleast_2d(pose_dot), np.atleast_2d(pose_ddot)):
        twist, twist_dot = pose_rates_to_twist(x, xd, xdd)
        rows.append(hexapod_regressor(x, twist, twist_dot, geom, g, v_eps))
    return np.vstack(rows)


def hexapod_base_parameters(geom: HexapodGeometry = HEXAPOD, g: float = 9.81, v_eps: float = 1e-3,
                            *, n_samples: int = 60, seed: int = 0) -> BaseParameters:
    """Base parameter set of :data:`HEXAPOD_PARAMETERS` (pivoted QR on a regressor of random states).

    Random independent poses, rates and accelerations excite everything the model can show, so only
    structural dependencies (e.g. the slider masses m3 lumped with the platform) are regrouped.
    """
    rng = np.random.default_rng(seed)
    pose = HEXAPOD_HOME + rng.uniform(-1, 1, (n_samples, 6)) * [0.1, 0.1, 0.1, 0.2, 0.2, 0.2]
    psi = stacked_regressor(pose, rng.uniform(-0.5, 0.5, (n_samples, 6)),
                            rng.uniform(-5, 5, (n_samples, 6)), geom, g, v_eps)
    return base_parameters(psi, HEXAPOD_PARAMETERS)


class ModelicaHexapod:
    """The truth model MotionTwin.Plants.Hexapod as CasADi functions of its symbolic form.

    ``inverse_dynamics`` solves the model's own equations M(x) a = J^T tau - h(x, v) for the leg forces
    that produce a prescribed motion (its accelerations are affine in tau); ``leg_lengths`` evaluates
    its outputs L1..L6. Parameters: the model's defaults, overridden by keyword.
    """

    def __init__(self, model=None, **parameters: float):
        if model is None:
            from motiontwin.fmus.build import load_model

            model = load_model("MotionTwin.Plants.Hexapod")
        self.model = model
        names = [v.name for v in model.parameters]
        unknown = sorted(set(parameters) - set(names))
        if unknown:
            raise KeyError(f"MotionTwin.Plants.Hexapod has no parameter(s) {unknown}")
        values = np.array(model.parameter_values(), dtype=float)
        for key, val in parameters.items():
            values[names.index(key)] = val
        self.parameters = dict(zip(names, values.tolist()))
        self._p = values
        acc = model.dx[6:]
        free = ca.substitute(acc, model.u, ca.SX.zeros(model.u.shape))
        #: symbolic inverse dynamics: leg forces as a function of (x, twist_dot, p, t)
        self.twist_dot = ca.SX.sym("twist_dot", 6)
        self.forces = ca.solve(ca.jacobian(acc, model.u), self.twist_dot - free)
        self._inverse = ca.Function("hexapod_inverse_dynamics", [model.x, self.twist_dot, model.p, model.t],
                                    [self.forces])
        outputs = {c.var.name: c.expr for c in model.computed}
        #: symbolic leg lengths L1..L6 as a function of (x, p)
        self.lengths = ca.vertcat(*[outputs[f"L{j}"] for j in range(1, 7)])
        self._lengths = ca.Function("hexapod_leg_lengths", [model.x, model.p], [self.lengths])

    def theta(self) -> np.ndarray:
        """True values of :data:`HEXAPOD_PARAMETERS` (regressor order)."""
        return np.array([self.parameters[n] for n in HEXAPOD_PARAMETERS])

    @staticmethod
    def _states(pose, pose_dot, pose_ddot):
        x, acc = [], []
        for p, pd, pdd in zip(pose, pose_dot, pose_ddot):
            twist, twist_dot = pose_rates_to_twist(p, pd, pdd)
            x.append(np.concatenate([p, twist]))
            acc.append(twist_dot)
        return np.array(x), np.array(acc)

    def inverse_dynamics(self, pose: np.ndarray, pose_dot: np.ndarray, pose_ddot: np.ndarray) -> np.ndarray:
        """Leg forces (n_samples, 6) [N] that make the model follow the pose trajectory."""
        x, acc = self._states(np.atleast_2d(pose), np.atleast_2d(pose_dot), np.atleast_2d(pose_ddot))
        n = x.shape[0]
        forces = self._inverse.map(n)(x.T, acc.T, np.tile(self._p[:, None], n), np.zeros((1, n)))
        return np.array(forces).T

    def leg_lengths(self, pose: np.ndarray) -> np.ndarray:
        """Model outputs L1..L6 (n_samples, 6) [m] at the given poses."""
        pose = np.atleast_2d(pose)
        n = pose.shape[0]
        x = np.hstack([pose, np.zeros((n, 6))])
        return np.array(self._lengths.map(n)(x.T, np.tile(self._p[:, None], n))).T


def simulate_period(truth: ModelicaHexapod, excitation: PoseExcitation,
                    sample_rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One steady-state period of the truth along the excitation: time [s], leg lengths [m] and leg
    forces [N], each (n_samples, 6) except time; perfect tracking (inverse dynamics)."""
    n = samples_per_period(sample_rate, excitation.fundamental_frequency)
    t = np.arange(n) / sample_rate
    pose, pose_dot, pose_ddot = excitation.trajectory(t)
    return t, truth.leg_lengths(pose), truth.inverse_dynamics(pose, pose_dot, pose_ddot)


@dataclass(frozen=True)
class MeasurementNoise:
    """Sensor model: leg-length white noise sigma_length [m] then quantisation to length_quantum [m]
    (0: none); leg-force noise with (6, 6) covariance force_covariance [N^2]."""

    sigma_length: float
    length_quantum: float
    force_covariance: np.ndarray


def measure_periods(lengths: np.ndarray, forces: np.ndarray, n_periods: int, noise: MeasurementNoise,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Repeat one steady-state period ``n_periods`` times and corrupt it like the sensors would."""
    lengths = np.tile(lengths, (n_periods, 1))
    forces = np.tile(forces, (n_periods, 1))
    measured = lengths + noise.sigma_length * rng.standard_normal(lengths.shape)
    if noise.length_quantum > 0:
        measured = noise.length_quantum * np.round(measured / noise.length_quantum)
    chol = np.linalg.cholesky(np.asarray(noise.force_covariance, dtype=float))
    return measured, forces + rng.standard_normal(forces.shape) @ chol.T


def direct_kinematics_series(lengths: np.ndarray, geom: HexapodGeometry = HEXAPOD,
                             guess: np.ndarray | None = None) -> np.ndarray:
    """Poses (n_samples, 6) from leg lengths by Newton-Raphson, each warm-started from the previous.

    The first sample starts from ``guess`` (default the home pose); non-convergence raises with the
    sample index.
    """
    poses = np.empty((len(lengths), 6))
    current = HEXAPOD_HOME if guess is None else np.asarray(guess, dtype=float)
    for i, sample in enumerate(np.asarray(lengths, dtype=float)):
        try:
            current = hexapod_direct(sample, geom, guess=current, tol=1e-12)
        except RuntimeError as err:
            raise RuntimeError(f"direct kinematics failed at sample {i}: {err}") from err
        poses[i] = current
    return poses


@dataclass(frozen=True)
class HexapodIdentification:
    """Result of :func:`identify_hexapod_periodic`.

    fit: Gauss-Markov estimate of the base parameters (names = regrouped combinations); base: the
    regrouping used; pose, pose_dot, pose_ddot: filtered averaged period (n, 6); forces: averaged
    period (n, 6) [N]; force_covariance: 6x6 error covariance of one measured force sample [N^2];
    mask: samples used (all legs faster than min_leg_speed).
    """

    fit: LeastSquaresResult
    base: BaseParameters
    pose: np.ndarray
    pose_dot: np.ndarray
    pose_ddot: np.ndarray
    forces: np.ndarray
    force_covariance: np.ndarray
    mask: np.ndarray


def identify_hexapod_periodic(lengths: np.ndarray, forces: np.ndarray, sample_rate: float,
                              fundamental_frequency: float, cutoff_frequency: float, *,
                              base: BaseParameters | None = None, min_leg_speed: float = 0.0,
                              max_relative_std: float | None = 0.2, geom: HexapodGeometry = HEXAPOD,
                              g: float = 9.81, v_eps: float = 1e-3,
                              guess: np.ndarray | None = None) -> HexapodIdentification:
    """Identify the hexapod base parameters from measured leg lengths and forces (n_samples, 6).

    The record must hold a whole number (>= 2) of periods of the excitation. ``base`` defaults to
    :func:`hexapod_base_parameters`. Samples where some leg is slower than ``min_leg_speed`` [m/s] are
    dropped (the sign of a filtered velocity near zero, hence the Coulomb term, is unreliable).
    Raises UnidentifiableError naming the base parameters the excitation does not determine: an exactly
    rank-deficient regressor, or (``max_relative_std``) a 1-sigma relative uncertainty above that
    fraction. The second test is needed because a DOF that is not excited still shows measurement
    noise through the direct kinematics, so its regressor columns are tiny but not exactly zero (and the
    column-scaled rank test sees them as independent); pass None for parameters expected near zero.
    """
    lengths, forces = np.asarray(lengths, dtype=float), np.asarray(forces, dtype=float)
    if lengths.ndim != 2 or lengths.shape[1] != 6 or forces.shape != lengths.shape:
        raise ValueError(f"lengths and forces must both be (n_samples, 6), got {lengths.shape} and {forces.shape}")
    n_per = samples_per_period(sample_rate, fundamental_frequency)
    base = hexapod_base_parameters(geom, g, v_eps) if base is None else base
    poses = direct_kinematics_series(lengths, geom, guess)
    pose_avg = period_average(poses, n_per)
    force_avg = period_average(forces, n_per)
    filtered = lowpass_differentiate(pose_avg.mean, sample_rate, cutoff_frequency)
    leg_speed = np.array([hexapod_length_jacobian(x, geom) @ xd
                          for x, xd in zip(filtered.position, filtered.velocity)])
    mask = np.all(np.abs(leg_speed) > min_leg_speed, axis=1)
    psi = stacked_regressor(filtered.position[mask], filtered.velocity[mask], filtered.acceleration[mask],
                            geom, g, v_eps)
    fit = gauss_markov(base.reduce_regressor(psi), force_avg.mean[mask].reshape(-1), names=base.names,
                       channel_covariance=force_avg.mean_covariance)
    if max_relative_std is not None:
        poor = [i for i, r in enumerate(fit.relative_std) if not r <= max_relative_std]
        if poor:
            listing = ", ".join(f"{fit.names[i]!r} (relative std {100 * fit.relative_std[i]:.3g} %)" for i in poor)
            raise UnidentifiableError(
                f"the excitation does not determine {listing}: relative uncertainty above "
                f"{100 * max_relative_std:.3g} %. Excite the pose coordinates these parameters act on "
                "(e.g. rotations for the platform inertias), or raise max_relative_std if they are near zero.",
                [fit.names[i] for i in poor], [],
            )
    return HexapodIdentification(fit, base, filtered.position, filtered.velocity, filtered.acceleration,
                                 force_avg.mean, force_avg.noise_covariance, mask)


def identify_hexapod_recording(rec, fundamental_frequency: float, cutoff_frequency: float, *,
                               lengths: tuple[str, ...] = tuple(f"L{i}" for i in range(1, 7)),
                               forces: tuple[str, ...] = tuple(f"tau{i}" for i in range(1, 7)),
                               min_leg_speed: float = 0.0, geom: HexapodGeometry = HEXAPOD,
                               source: str = "recording", **options) -> tuple[HexapodIdentification, list[str]]:
    """identify_hexapod_periodic on a harness.recording.Recording, with unit checks (ident.units).

    Leg lengths must be lengths (m, or mm/um converted and reported), leg forces forces (N, kN, mN);
    the lengths must lie within 0.5-2x the geometry's leg lengths at home (a length recorded in mm but
    declared m is 1000x off), and the fitted mass parameters must be positive. Returns the result and
    the conversion notes; raises ident.units.UnitError naming the column otherwise. ``options`` go to
    identify_hexapod_periodic.
    """
    columns = checked_columns(rec, {**{c: "length" for c in lengths}, **{c: "force" for c in forces}},
                              source=source)
    home = hexapod_inverse(HEXAPOD_HOME, geom)
    for j, name in enumerate(lengths):
        ratio = float(np.median(columns[name])) / home[j]
        if not 0.5 <= ratio <= 2.0:
            raise UnitError(
                f"{source}: column {name!r} (declared {rec.units.get(name) or 'no unit'}) has median "
                f"{np.median(columns[name]):.4g} m, {ratio:.3g}x the leg length {home[j]:.4g} m at home; "
                "declare the unit the lengths were recorded in (e.g. mm) in the sidecar"
            )
    result = identify_hexapod_periodic(np.column_stack([columns[c] for c in lengths]),
                                       np.column_stack([columns[c] for c in forces]), columns.sample_rate,
                                       fundamental_frequency, cutoff_frequency, min_leg_speed=min_leg_speed,
                                       geom=geom, **options)
    for name, value in zip(result.fit.names, result.fit.estimate):
        if name.startswith("m"):
            check_inertia(float(value), repr(name), ", ".join(lengths), False, source=source)
    return result, columns.notes


# ---------------------------------------------------------------- excitation design (eqs. 19-22)

@dataclass(frozen=True)
class HexapodLimits:
    """Experiment limits: pose within center +- pose_range (m, rad), leg speeds |dL/dt| <= leg_speed
    [m/s] and leg accelerations |d2L/dt2| <= leg_acceleration [m/s^2]."""

    pose_range: np.ndarray
    leg_speed: float
    leg_acceleration: float
    center: np.ndarray = field(default_factory=HEXAPOD_HOME.copy)


@dataclass(frozen=True)
class PoseDesignMetrics:
    """Criteria of an excitation on a fine grid: condition number of the base regressor, log det of
    the information matrix Psi^T Sigma^-1 Psi (force covariance Sigma per sample), largest limit use
    (<= 1 feasible)."""

    condition_number: float
    log_det_information: float
    max_limit_ratio: float


def leg_motion(excitation: PoseExcitation, t: np.ndarray,
               geom: HexapodGeometry = HEXAPOD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leg lengths, speeds and accelerations (n, 6) along the excitation: speed = J x_dot and
    acceleration = J x_ddot + (dJ/dt) x_dot, with dJ/dt by a central difference along x_dot (step 1e-6 s)."""
    pose, pose_dot, pose_ddot = excitation.trajectory(t)
    h = 1e-6
    rows = []
    for x, xd, xdd in zip(pose, pose_dot, pose_ddot):
        jac = hexapod_length_jacobian(x, geom)
        jac_dot = (hexapod_length_jacobian(x + h * xd, geom) - hexapod_length_jacobian(x - h * xd, geom)) / (2 * h)
        rows.append((hexapod_inverse(x, geom), jac @ xd, jac @ xdd + jac_dot @ xd))
    lengths, speeds, accelerations = (np.array(r) for r in zip(*rows))
    return lengths, speeds, accelerations


def limit_ratio(excitation: PoseExcitation, limits: HexapodLimits, *, n_samples: int = 400) -> float:
    """Largest use of the limits over one period (<= 1 means feasible)."""
    t = np.arange(n_samples) / (n_samples * excitation.fundamental_frequency)
    pose, _, _ = excitation.trajectory(t)
    _, speeds, accelerations = leg_motion(excitation, t)
    return float(max(np.max(np.abs(pose - limits.center) / limits.pose_range),
                     np.max(np.abs(speeds)) / limits.leg_speed,
                     np.max(np.abs(accelerations)) / limits.leg_acceleration))


def scale_to_limits(excitation: PoseExcitation, limits: HexapodLimits, *, n_samples: int = 400,
                    margin: float = 0.0) -> PoseExcitation:
    """Shrink the Fourier coefficients about the offset until every limit is used at most 1 - margin."""
    scale = 1.0
    for _ in range(60):
        trial = PoseExcitation(excitation.a * scale, excitation.b * scale, excitation.offset,
                               excitation.fundamental_frequency)
        ratio = limit_ratio(trial, limits, n_samples=n_samples)
        if ratio <= 1.0 - margin:
            return trial
        scale *= (1.0 - margin) / ratio * 0.999
    raise RuntimeError("could not scale the excitation into the limits")


def random_limited_excitation(limits: HexapodLimits, fundamental_frequency: float, n_harmonics: int,
                              rng: np.random.Generator) -> PoseExcitation:
    """Random Fourier coefficients spanning the pose ranges, shrunk to meet the leg limits (the baseline)."""
    excitation = random_pose_excitation(limits.pose_range, fundamental_frequency, n_harmonics, rng,
                                        center=limits.center)
    return scale_to_limits(excitation, limits)


def evaluate_pose_design(excitation: PoseExcitation, base: BaseParameters, limits: HexapodLimits,
                         force_covariance: np.ndarray, *, n_samples: int = 200) -> PoseDesignMetrics:
    """Exact criteria with the numpy regressor on ``n_samples`` instants of one period."""
    t = np.arange(n_samples) / (n_samples * excitation.fundamental_frequency)
    psi = base.reduce_regressor(stacked_regressor(*excitation.trajectory(t)))
    inv_chol = np.linalg.inv(np.linalg.cholesky(np.asarray(force_covariance, dtype=float)))
    whitened = np.einsum("ij,njp->nip", inv_chol, psi.reshape(n_samples, 6, -1)).reshape(psi.shape)
    sign, logdet = np.linalg.slogdet(whitened.T @ whitened)
    return PoseDesignMetrics(float(np.linalg.cond(psi)), float(logdet) if sign > 0 else -np.inf,
                             limit_ratio(excitation, limits))


class _SymbolicRegressor:
    """Base regressor of the Modelica truth as a CasADi function of (pose, pose rates, pose accelerations):
    d(leg forces)/d(theta) of the model's inverse dynamics (exact, since forces are linear in theta)."""

    def __init__(self, truth: ModelicaHexapod, base: BaseParameters, smoothing_speed: float):
        model = truth.model
        names = [v.name for v in model.parameters]
        theta = ca.vertcat(*[model.p[names.index(n)] for n in HEXAPOD_PARAMETERS])
        regressor = ca.jacobian(truth.forces, theta)[:, base.independent.tolist()]
        values = dict(truth.parameters, v_eps=smoothing_speed)
        regressor = ca.substitute(regressor, model.p, ca.DM([values[n] for n in names]))
        pose, rates, second = ca.SX.sym("pose", 6), ca.SX.sym("rates", 6), ca.SX.sym("second", 6)
        a, b = pose[3], pose[4]
        da, db = rates[3], rates[4]
        h = ca.vertcat(ca.horzcat(1, 0, ca.sin(b)), ca.horzcat(0, ca.cos(a), -ca.sin(a) * ca.cos(b)),
                       ca.horzcat(0, ca.sin(a), ca.cos(a) * ca.cos(b)))
        h_dot = ca.jtimes(h, ca.vertcat(a, b), ca.vertcat(da, db))
        w = ca.mtimes(h, rates[3:])
        w_dot = ca.mtimes(h, second[3:]) + ca.mtimes(h_dot, rates[3:])
        state = ca.vertcat(pose, rates[:3], w)
        psi = ca.substitute(regressor, ca.vertcat(model.x, truth.twist_dot, model.t),
                            ca.vertcat(state, second[:3], w_dot, 0))
        lengths = ca.substitute(truth.lengths, ca.vertcat(model.x, model.p),
                                ca.vertcat(state, ca.DM([values[n] for n in names])))
        speed = ca.jtimes(lengths, pose, rates)
        acceleration = ca.jtimes(speed, pose, rates) + ca.jtimes(speed, rates, second)
        self.function = ca.Function("hexapod_design_sample", [pose, rates, second], [psi, speed, acceleration])
