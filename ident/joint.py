"""Inverse-dynamics model of one serial joint, linear in its parameters (Bona & Curatella eqs. 2, 21-23).

    tau = J*qdd + k*sin(q + q_off) + f(qd)

Gravity k*sin(q + q_off) = g_sin*sin(q) + g_cos*cos(q) with g_sin = k*cos(q_off), g_cos = k*sin(q_off),
so it is linear in (g_sin, g_cos). Friction (eq. 2) is asymmetric viscous + Coulomb::

    f = fv_pos*qd + fc_pos   for qd > 0,
    f = fv_neg*qd - fc_neg   for qd < 0,   0 at qd = 0.

Eq. 2 prints "+ beta_c-" for qd < 0; Table 2 lists positive Coulomb values for both signs, so the
Coulomb torque is read as opposing the motion (- fc_neg), which makes fc_neg > 0 physically.
For one joint moved alone J, g_sin, g_cos and the friction coefficients are already base parameters.

A prismatic axis (positions in m, forces in N) has no sine gravity: ``gravity="constant"`` models a constant
force F0 instead (the weight on a vertical or inclined axis, a cable or hose preload, a force-sensor or
amplifier offset): tau = m*qdd + F0 + f(qd). With a constant force, asymmetric Coulomb friction is not
identifiable (fc_pos - fc_neg and F0 enter the data the same way while moving), so the prismatic default is
symmetric friction plus the constant force; its equivalent asymmetric levels are fc_pos = fc + F0 and
fc_neg = fc - F0. Sine gravity on metres is the reason the revolute default gives meaningless values on a
linear axis: over a stroke of a few cm, cos(q) is a constant to within q^2/2 and so nearly collinear with the
two Coulomb columns, and sin(q) ~ q acts as a spring.

Units: q [rad], qd [rad/s], qdd [rad/s^2], tau [N m], J [kg m^2], g_* [N m], fv_* [N m s/rad], fc_* [N m];
prismatic: m, m/s, m/s^2, N, kg, F0 [N], fv [N s/m], fc [N].
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from motiontwin.harness.labdata import clock_step, jitter_report
from motiontwin.harness.recording import SAMPLE_TIME_TOLERANCE
from motiontwin.ident.leastsquares import LeastSquaresResult, gauss_markov
from motiontwin.ident.signals import lowpass_differentiate, period_average, samples_per_period
from motiontwin.ident.units import check_inertia, check_motion, checked_columns

__all__ = [
    "FRICTION_MODELS",
    "GRAVITY_MODELS",
    "PERIOD_RTOL",
    "PeriodicRecord",
    "periodic_record",
    "find_period",
    "default_model",
    "joint_parameter_names",
    "joint_regressor",
    "joint_torque",
    "GravityParameters",
    "gravity_amplitude_offset",
    "JointIdentification",
    "identify_joint_periodic",
    "FrictionModelComparison",
    "compare_friction_models",
    "identify_joint_recording",
    "serial_joint_parameters",
    "prismatic_axis_parameters",
]

FRICTION_MODELS = ("asymmetric", "symmetric", "viscous", "none")
GRAVITY_MODELS = ("sine", "constant", "none")   # revolute k*sin(q + q_off); constant force F0; nothing
PERIOD_RTOL = 1e-6   # accepted relative deviation of (sample rate / f0) from a whole number of samples

_FRICTION_NAMES = {
    "asymmetric": ["fv_pos", "fc_pos", "fv_neg", "fc_neg"],
    "symmetric": ["fv", "fc"],
    "viscous": ["fv"],
    "none": [],
}


def _gravity_kind(gravity: bool | str) -> str:
    """``True``/``False`` (revolute or none, the original flag) or one of GRAVITY_MODELS."""
    if gravity is True:
        return "sine"
    if gravity is False:
        return "none"
    if gravity not in GRAVITY_MODELS:
        raise ValueError(f"gravity must be one of {GRAVITY_MODELS}, got {gravity!r}")
    return gravity


def joint_parameter_names(friction: str = "asymmetric", gravity: bool | str = True) -> list[str]:
    """Parameter names in regressor column order."""
    if friction not in FRICTION_MODELS:
        raise ValueError(f"friction must be one of {FRICTION_MODELS}, got {friction!r}")
    kind = _gravity_kind(gravity)
    return ["J"] + {"sine": ["g_sin", "g_cos"], "constant": ["F0"], "none": []}[kind] + _FRICTION_NAMES[friction]


def joint_regressor(
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    *,
    friction: str = "asymmetric",
    gravity: bool | str = True,
) -> tuple[np.ndarray, list[str]]:
    """Regressor Phi (n_samples x n_parameters) with tau = Phi @ theta, and the parameter names.

    gravity: True / "sine" (revolute), "constant" (a constant force F0), False / "none"."""
    q, qd, qdd = (np.asarray(a, dtype=float).reshape(-1) for a in (q, qd, qdd))
    if not (q.shape == qd.shape == qdd.shape):
        raise ValueError(f"q, qd, qdd must have the same length, got {q.shape}, {qd.shape}, {qdd.shape}")
    names = joint_parameter_names(friction, gravity)
    columns = [qdd]
    kind = _gravity_kind(gravity)
    if kind == "sine":
        columns += [np.sin(q), np.cos(q)]
    elif kind == "constant":
        columns += [np.ones_like(q)]
    positive = (qd > 0).astype(float)
    negative = (qd < 0).astype(float)
    if friction == "asymmetric":
        columns += [qd * positive, positive, qd * negative, -negative]
    elif friction == "symmetric":
        columns += [qd, np.sign(qd)]
    elif friction == "viscous":
        columns += [qd]
    return np.column_stack(columns), names


def joint_torque(
    parameters: dict[str, float],
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    *,
    friction: str = "asymmetric",
    gravity: bool | str = True,
) -> np.ndarray:
    """Inverse dynamics tau(q, qd, qdd) for named parameters (missing names raise KeyError)."""
    phi, names = joint_regressor(q, qd, qdd, friction=friction, gravity=gravity)
    missing = [n for n in names if n not in parameters]
    if missing:
        raise KeyError(f"joint parameters missing: {missing}")
    return phi @ np.array([parameters[n] for n in names])


@dataclass(frozen=True)
class GravityParameters:
    """Gravity amplitude k [N m] and offset q_off [rad] with standard deviations (delta method)."""

    amplitude: float
    offset: float
    amplitude_std: float
    offset_std: float


def gravity_amplitude_offset(
    g_sin: float, g_cos: float, covariance: np.ndarray | None = None
) -> GravityParameters:
    """Convert (g_sin, g_cos) to Bona eq. 23's k and q_off; propagate the 2x2 covariance if given."""
    k = float(np.hypot(g_sin, g_cos))
    if k == 0.0:
        raise ValueError("gravity amplitude is zero: q_off is undefined")
    offset = float(np.arctan2(g_cos, g_sin))
    if covariance is None:
        return GravityParameters(k, offset, float("nan"), float("nan"))
    jac = np.array([[g_sin / k, g_cos / k], [-g_cos / k**2, g_sin / k**2]])
    cov = jac @ np.asarray(covariance, dtype=float) @ jac.T
    return GravityParameters(k, offset, float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])))


@dataclass(frozen=True)
class JointIdentification:
    """Result of identify_joint_periodic: the fit plus the processed signals it used.

    fit: LeastSquaresResult; gravity: amplitude/offset form; mask: samples used (|qd| > v_min);
    position, velocity, acceleration: filtered averaged period [rad, rad/s, rad/s^2];
    torque: averaged period [N m]; torque_variance: variance of one averaged torque sample [N^2 m^2];
    record_notes: what identify_joint_recording did to the record (sample time, jitter, trimming, model).
    """

    fit: LeastSquaresResult
    gravity: GravityParameters | None
    mask: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray
    torque_variance: float
    record_notes: tuple[str, ...] = ()


def identify_joint_periodic(
    position: np.ndarray,
    torque: np.ndarray,
    sample_rate: float,
    fundamental_frequency: float,
    cutoff_frequency: float,
    *,
    min_speed: float = 0.0,
    friction: str = "asymmetric",
    gravity: bool | str = True,
) -> JointIdentification:
    """Identify a joint from a periodic recording (whole number of periods, >= 2).

    Pipeline (Abdellatif sec. 3): average the periods; estimate the torque noise variance from the
    spread between periods; filter and differentiate the averaged position in the frequency domain at
    ``cutoff_frequency``; drop samples slower than ``min_speed`` (where the sign of the filtered velocity,
    and so the Coulomb term, is unreliable); weighted Gauss-Markov least squares. The torque is not
    filtered (its noise is output-additive).
    """
    n_per = samples_per_period(sample_rate, fundamental_frequency)
    q_avg = period_average(position, n_per)
    tau_avg = period_average(torque, n_per)
    filtered = lowpass_differentiate(q_avg.mean[:, 0], sample_rate, cutoff_frequency)
    mask = np.abs(filtered.velocity) > min_speed
    phi, names = joint_regressor(
        filtered.position[mask], filtered.velocity[mask], filtered.acceleration[mask],
        friction=friction, gravity=gravity,
    )
    variance = float(tau_avg.mean_covariance[0, 0])
    tau = tau_avg.mean[:, 0]
    fit = gauss_markov(phi, tau[mask], names=names, noise_covariance=variance if variance > 0 else None)
    grav = None
    if _gravity_kind(gravity) == "sine":
        i, j = names.index("g_sin"), names.index("g_cos")
        grav = gravity_amplitude_offset(
            fit.estimate[i], fit.estimate[j], fit.covariance[np.ix_([i, j], [i, j])]
        )
    return JointIdentification(
        fit, grav, mask, filtered.position, filtered.velocity, filtered.acceleration, tau, variance
    )


@dataclass(frozen=True)
class FrictionModelComparison:
    """Statistics of one friction parametrisation fitted to the same data (Abdellatif sec. 2):
    correlation_condition = cond(rho) (large means poorly separable parameters), residual_variance_factor
    (about 1 when the model explains the data to the noise level), max_relative_std."""

    friction: str
    correlation_condition: float
    residual_variance_factor: float
    max_relative_std: float


def compare_friction_models(
    position: np.ndarray,
    torque: np.ndarray,
    sample_rate: float,
    fundamental_frequency: float,
    cutoff_frequency: float,
    *,
    min_speed: float = 0.0,
    models: tuple[str, ...] = ("viscous", "symmetric", "asymmetric"),
) -> list[FrictionModelComparison]:
    """Fit each friction model with identify_joint_periodic and report the selection statistics.

    Choose the simplest model whose residual_variance_factor is near 1 and whose correlation
    condition stays moderate; an unidentifiable model is reported with infinite statistics.
    """
    rows = []
    for friction in models:
        try:
            fit = identify_joint_periodic(
                position, torque, sample_rate, fundamental_frequency, cutoff_frequency,
                min_speed=min_speed, friction=friction,
            ).fit
        except ValueError:
            rows.append(FrictionModelComparison(friction, np.inf, np.inf, np.inf))
            continue
        rows.append(FrictionModelComparison(
            friction, fit.correlation_condition, fit.residual_variance_factor, float(np.max(fit.relative_std))
        ))
    return rows


@dataclass(frozen=True)
class PeriodicRecord:
    """Unit-checked columns of a recording cut to whole periods: position and force [SI], the sample rate
    n_per * f0 [Hz] the frequency-domain processing uses, samples per period, and the notes on sample time,
    jitter and trimming (the unit conversions are in ``columns.notes``)."""

    columns: object            # ident.units.CheckedColumns of the whole recording
    position: np.ndarray
    force: np.ndarray
    sample_rate: float
    samples_per_period: int
    notes: list[str]
    fundamental_frequency: float = 0.0   # [Hz]: the one given, or the one found (find_period)


def find_period(signal: np.ndarray, threshold: float = 0.1) -> int:
    """Samples in one period of a periodic ``signal`` (a multisine or Fourier trajectory, with noise).

    The difference function d(N) = sum_k (x[k+N] - x[k])^2 over lags up to half the record, from the power
    spectrum (Wiener-Khinchin: the autocorrelation is its inverse DFT), normalised by its running mean (the
    YIN pitch estimator, de Cheveigne & Kawahara 2002): d'(N) = d(N) N / sum_{j<=N} d(j), ~1 or more for an
    unrelated lag, near 0 at the period and its multiples. The bottom of the first dip below ``threshold``
    locates the period; the vertex of a parabola fitted to d over +-1 % of it (the bottom of the dip is flat
    under noise, its flanks are not) refines it, rounded to a whole number of samples.
    Raises ValueError when no lag up to half the record repeats the signal.
    """
    x = np.asarray(signal, dtype=float) - float(np.mean(signal))
    n = x.size
    top = n // 2
    if top < 2 or not np.any(x):
        raise ValueError(f"{n} samples of a constant signal hold no period")
    power = np.abs(np.fft.rfft(x, 2 * n)) ** 2
    auto = np.fft.irfft(power, 2 * n)[: top + 1]
    energy = np.concatenate([[0.0], np.cumsum(x ** 2)])
    lags = np.arange(top + 1)
    d = energy[n - lags] + (energy[n] - energy[lags]) - 2.0 * auto       # sum over the overlap of length n - N
    d = np.maximum(d, 0.0) / (n - lags)
    running = np.cumsum(d[1:]) / lags[1:]
    normalised = np.concatenate([[1.0], d[1:] / np.where(running > 0, running, np.inf)])
    below = np.flatnonzero(normalised[2:] < threshold)
    if below.size == 0:
        best = int(np.argmin(normalised[2:])) + 2
        raise ValueError(f"no period found: no lag up to {top} samples repeats the signal (best {best} samples, "
                         f"normalised difference {normalised[best]:.3g} >= {threshold:g})")
    start = int(below[0]) + 2
    above = np.flatnonzero(normalised[start:] >= threshold)
    stop = start + int(above[0]) if above.size else top + 1
    lag = start + int(np.argmin(normalised[start:stop]))       # the bottom of the first dip
    window = np.arange(max(2, lag - max(2, lag // 100)), min(top, lag + max(2, lag // 100)) + 1)
    curve = np.polyfit(window - lag, d[window], 2)
    if not curve[0] > 0:
        return lag
    return int(round(lag - curve[1] / (2 * curve[0])))


def periodic_record(rec, fundamental_frequency: float | None, *, position: str = "q", force: str = "u",
                    source: str = "recording") -> PeriodicRecord:
    """The columns of ``rec`` as whole periods of the excitation at ``fundamental_frequency`` [Hz].

    ``fundamental_frequency`` None: found from the spectrum of the reference column ``r`` when the recording
    has one, else of the position (:func:`find_period`), as 1 / (whole samples per period x Ts), and noted.
    Sample time Ts: the sidecar's ``sample_time`` when present, else the median step, snapped to its clock
    when within the jitter (:func:`harness.labdata.clock_step`: 0.000999984 -> 0.001); the jitter of the time
    stamps (deviation of each step from Ts) is reported and accepted up to the recording format's tolerance
    (``SAMPLE_TIME_TOLERANCE`` of Ts; larger jitter: resample with ``motiontwin import --resample``).
    1/(Ts f0) must be a whole number of samples within PERIOD_RTOL (1e-6). Samples after the last whole
    period are dropped (at least 2 periods must remain), and the notes say how many.
    """
    columns = checked_columns(rec, {position: "position", force: "force"}, source=source)
    notes: list[str] = []
    jitter = jitter_report(columns.time)
    declared = rec.meta.get("sample_time") if isinstance(rec.meta, dict) else None
    ts = float(declared) if declared else clock_step(jitter)
    origin = ("the sidecar's sample_time" if declared else "the median time step" if ts == jitter.sample_time
              else f"the median time step {jitter.sample_time:.9g} s snapped to the clock")
    largest = float(np.max(np.abs(np.diff(columns.time) - ts)))
    if largest > SAMPLE_TIME_TOLERANCE * ts:
        raise ValueError(f"{source}: column 'time': steps deviate from the sample time {ts:.9g} s by up to "
                         f"{largest:.3g} s ({largest / ts:.3g} of Ts, accepted {SAMPLE_TIME_TOLERANCE:g}); "
                         "resample it onto a uniform grid (motiontwin import --resample)")
    notes.append(f"{source}: sample time {ts:.9g} s from {origin}; time-stamp jitter up to {largest:.3g} s "
                 f"({largest / ts:.3g} of Ts, RMS {jitter.rms_deviation:.3g} s)")
    if fundamental_frequency is None:
        column = "r" if "r" in rec.columns else position
        try:
            found = find_period(rec.columns[column])
        except ValueError as exc:
            raise ValueError(f"{source}: column {column!r}: {exc}; give the excitation's --f0") from None
        fundamental_frequency = 1.0 / (found * ts)
        notes.append(f"{source}: excitation period {found} samples = {found * ts:.9g} s, f0 = "
                     f"{fundamental_frequency:.9g} Hz, found in the spectrum of column {column!r} (no --f0 given)")
    if not fundamental_frequency > 0:
        raise ValueError(f"fundamental frequency must be > 0 Hz, got {fundamental_frequency}")
    ratio = 1.0 / (ts * fundamental_frequency)
    n_per = int(round(ratio))
    if n_per < 2 or abs(ratio - n_per) > PERIOD_RTOL * ratio:
        raise ValueError(f"{source}: one period of f0 = {fundamental_frequency:g} Hz is {ratio:.9g} samples of "
                         f"{ts:.9g} s, not a whole number (within {PERIOD_RTOL:g}); check --f0 against the "
                         "sample time")
    n = columns.time.size
    periods = n // n_per
    if periods < 2:
        raise ValueError(f"{source}: {n} samples hold {n / n_per:.3g} periods of {n_per} samples; "
                         "at least 2 whole periods are needed")
    keep = periods * n_per
    if keep < n:
        notes.append(f"{source}: trimmed to {periods} whole periods of {n_per} samples: dropped the last "
                     f"{n - keep} samples ({(n - keep) * ts:.6g} s, t > {columns.time[keep - 1]:.9g} s)")
    return PeriodicRecord(columns, columns[position][:keep], columns[force][:keep],
                          n_per * fundamental_frequency, n_per, notes, fundamental_frequency)


def default_model(rotary: bool) -> tuple[str, str]:
    """(friction, gravity) of ``"auto"``: Bona's revolute joint (asymmetric friction, sine gravity) for a
    rotary axis, symmetric friction with a constant force for a prismatic one (see the module docstring)."""
    return ("asymmetric", "sine") if rotary else ("symmetric", "constant")


def identify_joint_recording(
    rec,
    fundamental_frequency: float | None,
    cutoff_frequency: float,
    *,
    position: str = "q",
    force: str = "u",
    min_speed: float = 0.0,
    friction: str = "auto",
    gravity: bool | str = "auto",
    nominal_inertia: float | None = None,
    source: str = "recording",
) -> tuple[JointIdentification, list[str]]:
    """identify_joint_periodic on a harness.recording.Recording, with unit checks (ident.units).

    The position and force columns are checked against their declared units (m with N, or rad with N.m;
    mm, deg, kN, ms ... are converted and reported), the record is cut to whole periods (:func:`periodic_record`:
    sample time, jitter and trimming are reported), the filtered motion and the fitted J are checked for
    plausibility (and against ``nominal_inertia`` within 10x if given). ``friction``/``gravity`` "auto": by the
    axis kind (:func:`default_model`). Returns the identification and the notes; raises
    ident.units.UnitError naming the column otherwise. ``min_speed`` is in SI (m/s or rad/s).
    The notes are the unit conversions; the record's handling is in ``result.record_notes``.
    """
    data = periodic_record(rec, fundamental_frequency, position=position, force=force, source=source)
    columns, notes = data.columns, list(data.notes)
    rotary = columns.rotary(position)
    auto_friction, auto_gravity = default_model(rotary)
    if friction == "auto" or gravity == "auto":
        friction = auto_friction if friction == "auto" else friction
        gravity = auto_gravity if gravity == "auto" else gravity
        notes.append(f"{source}: {'rotary' if rotary else 'linear'} axis ({columns.units[position]}): friction "
                     f"{friction!r}, gravity {_gravity_kind(gravity)!r}")
    result = identify_joint_periodic(
        data.position, data.force, data.sample_rate, data.fundamental_frequency, cutoff_frequency,
        min_speed=min_speed, friction=friction, gravity=gravity,
    )
    fit = result.fit
    if "F0" in fit.names and "fc" in fit.names:
        level = fit.as_dict()
        notes.append(f"{source}: the same fit as asymmetric Coulomb friction: fc_pos = fc + F0 = "
                     f"{level['fc'] + level['F0']:.6g}, fc_neg = fc - F0 = {level['fc'] - level['F0']:.6g}")
    check_motion(columns, position, source=source, velocity=result.velocity, acceleration=result.acceleration)
    check_inertia(float(fit.estimate[0]), "J", position, rotary, source=source, nominal=nominal_inertia)
    return dataclasses.replace(result, record_notes=tuple(notes)), list(columns.notes)


def serial_joint_parameters(fit: LeastSquaresResult) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The fit in the parameter names of ``MotionTwin.Plants.SerialRobotJoint`` (M, k, q_off, beta_vp,
    beta_cp, beta_vn, beta_cn), so that ``motiontwin writeback --values`` takes it as it is, with the
    covariance carried through the (linear, and for k and q_off first-order) change of variables.

    Needs gravity in the fit; symmetric friction is written as equal positive and negative coefficients,
    viscous-only friction with zero Coulomb levels. Returns (names, estimate, covariance).
    """
    names = list(fit.names)
    if "g_sin" not in names:
        raise ValueError("SerialRobotJoint has a gravity term: identify with gravity to write its parameters")
    index = {n: i for i, n in enumerate(names)}
    source = {"asymmetric": {"beta_vp": "fv_pos", "beta_cp": "fc_pos", "beta_vn": "fv_neg", "beta_cn": "fc_neg"},
              "symmetric": {"beta_vp": "fv", "beta_cp": "fc", "beta_vn": "fv", "beta_cn": "fc"},
              "viscous": {"beta_vp": "fv", "beta_vn": "fv"}}
    friction = next((kind for kind, cols in _FRICTION_NAMES.items() if cols and all(c in index for c in cols)),
                    "none")
    out = ["M", "k", "q_off", "beta_vp", "beta_cp", "beta_vn", "beta_cn"]
    gs, gc = fit.estimate[index["g_sin"]], fit.estimate[index["g_cos"]]
    grav = gravity_amplitude_offset(gs, gc)
    jacobian = np.zeros((len(out), len(names)))   # d(out)/d(regressor parameters)
    jacobian[0, index["J"]] = 1.0
    k = grav.amplitude
    jacobian[1, [index["g_sin"], index["g_cos"]]] = [gs / k, gc / k]
    jacobian[2, [index["g_sin"], index["g_cos"]]] = [-gc / k**2, gs / k**2]
    for row, name in enumerate(out[3:], start=3):
        column = source.get(friction, {}).get(name)
        if column is not None:
            jacobian[row, index[column]] = 1.0
    estimate = jacobian @ fit.estimate
    estimate[1], estimate[2] = grav.amplitude, grav.offset
    return out, estimate, jacobian @ fit.covariance @ jacobian.T


def prismatic_axis_parameters(fit: LeastSquaresResult) -> tuple[list[str], np.ndarray, np.ndarray]:
    """A prismatic fit (constant force or no gravity; symmetric, viscous or no friction) in the parameter names of
    ``MotionTwin.Plants.PrismaticAxis`` (m, d, Fc, F0: m*der(v) = u - d*v - Fc*tanh(v/v_eps) - F0), a linear
    change of variables with its covariance. Returns (names, estimate, covariance)."""
    index = {n: i for i, n in enumerate(fit.names)}
    if "g_sin" in index or "fc_pos" in index:
        raise ValueError("PrismaticAxis has symmetric friction and a constant force: identify with "
                         "--friction symmetric (or viscous, none) and --gravity constant (or none)")
    out = {"m": "J", "d": "fv", "Fc": "fc", "F0": "F0"}
    jacobian = np.zeros((len(out), len(fit.names)))
    for row, column in enumerate(out.values()):
        if column in index:
            jacobian[row, index[column]] = 1.0
    return list(out), jacobian @ fit.estimate, jacobian @ fit.covariance @ jacobian.T
