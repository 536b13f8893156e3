"""Frequency-response identification of a direct-drive joint (Cheung & Hung eqs. 6-8).

    P(s) = L(s) H(s),   L(s) = K / (s (s + alpha)),
    H(s) = prod_m (w_m^2 / wb_m^2) (s^2 + 2 zb_m wb_m s + wb_m^2) / (s^2 + 2 z_m w_m s + w_m^2)

with resonances (w_m, z_m) and antiresonances (wb_m, zb_m); H(0) = 1. The FRF is estimated from
swept-sine data with the H1 estimator (Welch-averaged cross/auto spectra, scipy.signal.csd/welch) and
the coherence. Acceleration is obtained from the encoder position by a centred second difference, whose
exact (real, zero-phase) frequency response is part of the fitted model, so it causes no bias.
The model is fitted by nonlinear least squares on log-magnitude and phase (scipy least_squares), with
parameters in log space so they stay positive.

Units: time s, frequency Hz for data, rad/s for model poles/zeros (omega, alpha); K in
(output unit)/(input unit)/s^2, e.g. m/s^2 per V.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import control
import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.signal

from motiontwin.ident.units import check_inertia, check_motion, checked_columns

__all__ = [
    "FrequencyResponse",
    "estimate_frf",
    "excited_band",
    "default_segment_length",
    "acceleration_from_position",
    "second_difference_response",
    "state_space_response",
    "JointModel",
    "JointModelFit",
    "fit_joint_frf",
    "LowFrequencyFit",
    "fit_low_frequency_model",
    "joint_model_parameters",
    "DEFAULT_ALPHA",
    "identify_frf_recording",
    "WorstCase",
    "select_worst_case",
    "identify_frf_worst_case",
    "frf_document",
]


@dataclass(frozen=True)
class FrequencyResponse:
    """Estimated FRF: frequency [Hz], complex response y/u, coherence in [0, 1]."""

    frequency: np.ndarray
    response: np.ndarray
    coherence: np.ndarray

    def band(self, f_min: float, f_max: float, min_coherence: float = 0.0) -> "FrequencyResponse":
        """Points with f_min <= f <= f_max and coherence >= min_coherence."""
        keep = (self.frequency >= f_min) & (self.frequency <= f_max) & (self.coherence >= min_coherence)
        return FrequencyResponse(self.frequency[keep], self.response[keep], self.coherence[keep])


def estimate_frf(
    u: np.ndarray,
    y: np.ndarray,
    sample_rate: float,
    segment_length: int,
    *,
    overlap: int | None = None,
    window: str = "hann",
) -> FrequencyResponse:
    """H1 estimate H = S_uy / S_uu with Welch averaging, and the coherence |S_uy|^2/(S_uu S_yy).

    H1 is unbiased for noise on the output y (encoder/acceleration noise), which is the case here.
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    if u.shape != y.shape:
        raise ValueError(f"u and y must have the same length, got {u.size} and {y.size}")
    if segment_length > u.size:
        raise ValueError(f"segment_length {segment_length} exceeds the record length {u.size}")
    kw = dict(fs=sample_rate, window=window, nperseg=segment_length, noverlap=overlap, detrend="constant")
    f, s_uy = scipy.signal.csd(u, y, **kw)
    _, s_uu = scipy.signal.welch(u, **kw)
    _, s_yy = scipy.signal.welch(y, **kw)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = s_uy / s_uu
        coh = np.abs(s_uy) ** 2 / (s_uu * s_yy)
    keep = s_uu > 0
    return FrequencyResponse(f[keep], h[keep], np.clip(np.nan_to_num(coh[keep]), 0.0, 1.0))


def excited_band(u: np.ndarray, sample_rate: float, segment_length: int, *,
                 level: float = 1e-3) -> tuple[float, float]:
    """[Hz] lowest and highest frequency at which the input's power per relative bandwidth f S_uu(f)
    (Welch) is at least ``level`` times its maximum: the band a swept sine excites (flat for a logarithmic
    sweep, rising for a linear one); outside it H1 is leakage of the fades over noise."""
    u = np.asarray(u, dtype=float).reshape(-1)
    f, s_uu = scipy.signal.welch(u, fs=sample_rate, nperseg=segment_length, detrend="constant")
    per_octave = f * s_uu
    excited = np.nonzero(per_octave >= level * per_octave.max())[0] if per_octave.max() > 0 else []
    if len(excited) == 0:
        raise ValueError("the input has no power above zero frequency: nothing to identify")
    return float(f[excited[0]]), float(f[excited[-1]])


def default_segment_length(n: int, largest: int = 4096) -> int:
    """Welch segment: the largest power of two <= min(largest, n / 4), i.e. at least 7 half-overlapping
    averages, so that the coherence means something (with one segment it is identically 1)."""
    return int(2 ** np.floor(np.log2(max(min(largest, n / 4), 8))))


def acceleration_from_position(position: np.ndarray, sample_rate: float) -> np.ndarray:
    """Centred second difference (q[n+1] - 2 q[n] + q[n-1]) fs^2; length n - 2, aligned with q[1:-1]."""
    q = np.asarray(position, dtype=float).reshape(-1)
    return (q[2:] - 2 * q[1:-1] + q[:-2]) * sample_rate**2


def second_difference_response(frequency: np.ndarray, sample_rate: float) -> np.ndarray:
    """Frequency response of the centred second difference: -4 fs^2 sin^2(pi f / fs) (vs -(2 pi f)^2)."""
    return -4.0 * sample_rate**2 * np.sin(np.pi * np.asarray(frequency) / sample_rate) ** 2


def state_space_response(matrices: Sequence[np.ndarray], z: np.ndarray) -> np.ndarray:
    """C (z I - A)^-1 B + D of a SISO state-space system (A, B, C, D) at the complex points ``z`` (s or z), in
    one batched solve (python-control evaluates its systems point by point without Slycot: 0.3 s on 8000)."""
    a, b, c, d = (np.atleast_2d(np.asarray(m, dtype=float)) for m in matrices)
    z = np.asarray(z, dtype=complex)
    if a.size == 0:
        return np.full(z.shape, d[0, 0], dtype=complex)
    x = np.linalg.solve(z.reshape(-1)[:, None, None] * np.eye(a.shape[0]) - a,
                        np.broadcast_to(b, (z.size,) + b.shape))
    return ((c @ x)[:, 0, 0] + d[0, 0]).reshape(z.shape)


@dataclass(frozen=True)
class JointModel:
    """Cheung's joint model. gain K; alpha [rad/s]; resonances/antiresonances: ((omega [rad/s], zeta), ...)."""

    gain: float
    alpha: float
    resonances: tuple[tuple[float, float], ...] = ()
    antiresonances: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if len(self.resonances) != len(self.antiresonances):
            raise ValueError("need one antiresonance per resonance (Cheung eq. 8)")

    def position_response(self, frequency: np.ndarray) -> np.ndarray:
        """P(j omega) at frequency [Hz]."""
        s = 2j * np.pi * np.asarray(frequency, dtype=float)
        p = self.gain / (s * (s + self.alpha))
        for (wr, zr), (wa, za) in zip(self.resonances, self.antiresonances):
            p = p * (wr**2 / wa**2) * (s**2 + 2 * za * wa * s + wa**2) / (s**2 + 2 * zr * wr * s + wr**2)
        return p

    def sampled_response(self, frequency: np.ndarray, sample_rate: float) -> np.ndarray:
        """Exact FRF of P behind a zero-order hold, sampled at ``sample_rate`` (what a digital
        controller sees: ZOH delay and aliasing included)."""
        sys_d = control.c2d(control.ss(self.transfer_function()), 1.0 / sample_rate, method="zoh")
        z = np.exp(2j * np.pi * np.asarray(frequency, dtype=float) / sample_rate)
        return state_space_response((sys_d.A, sys_d.B, sys_d.C, sys_d.D), z)

    def transfer_function(self) -> control.TransferFunction:
        """P(s) as a python-control transfer function."""
        p = control.tf([self.gain], [1.0, self.alpha, 0.0])
        for (wr, zr), (wa, za) in zip(self.resonances, self.antiresonances):
            p = p * control.tf(
                [wr**2 / wa**2, 2 * za * wa * wr**2 / wa**2, wr**2], [1.0, 2 * zr * wr, wr**2]
            )
        return p

    def to_vector(self) -> np.ndarray:
        v = [self.gain, self.alpha]
        for (wr, zr), (wa, za) in zip(self.resonances, self.antiresonances):
            v += [wr, zr, wa, za]
        return np.log(np.array(v))

    @classmethod
    def from_vector(cls, log_values: np.ndarray) -> "JointModel":
        v = np.exp(np.asarray(log_values))
        modes = v[2:].reshape(-1, 4)
        return cls(
            float(v[0]), float(v[1]),
            tuple((float(m[0]), float(m[1])) for m in modes),
            tuple((float(m[2]), float(m[3])) for m in modes),
        )


@dataclass(frozen=True)
class JointModelFit:
    """Fitted model, the data it was fitted to and the RMS of the log-ratio residual (dimensionless).
    alpha_fixed: alpha was held (not fitted); alpha_log_std: Gauss-Newton standard deviation of ln(alpha)
    (about its relative error; nan when fixed)."""

    model: JointModel
    data: FrequencyResponse
    rms_log_error: float
    optimizer_message: str = field(repr=False, default="")
    alpha_fixed: bool = False
    alpha_log_std: float = float("nan")


def _initial_guess(frf: FrequencyResponse, to_position: np.ndarray, alpha: float | None = None) -> JointModel:
    """One resonance pair from peak picking on the acceleration FRF s^2 P: the resonance at the magnitude's
    maximum, the antiresonance at its minimum below it; alpha from the phase (unless given); K from the
    magnitude at the lowest frequency divided by the guessed |s/(s+alpha) H|."""
    w = 2 * np.pi * frf.frequency
    acc = frf.response * (-(w**2)) / to_position  # acceleration-like FRF ~ K s/(s+alpha) H
    mag = scipy.ndimage.median_filter(np.abs(acc), size=7, mode="nearest")
    i_r = int(np.argmax(mag))
    i_a = int(np.argmin(mag[: i_r + 1])) if i_r > 0 else 0
    w_r, w_a = w[i_r], w[i_a]
    if w_a >= w_r:
        w_a = 0.7 * w_r
    if alpha is None:
        phase = np.unwrap(np.angle(acc))
        cross = np.nonzero((w < w_a) & (phase < phase[0] - np.pi / 4))[0]
        alpha = w[cross[0]] if cross.size else w[0]
    pair = JointModel(1.0, alpha, ((w_r, 0.05),), ((w_a, 0.05),))
    i_k = int(np.argmin(np.abs(w - np.sqrt(max(alpha, w[0]) * w_a)))) if w[0] < w_a / 2 else 0
    shape = pair.position_response(frf.frequency[i_k]) * (2j * np.pi * frf.frequency[i_k]) ** 2
    return JointModel(float(mag[i_k] / abs(shape)), alpha, ((w_r, 0.05),), ((w_a, 0.05),))


def fit_joint_frf(
    frf: FrequencyResponse,
    *,
    output: str = "position",
    sample_rate: float | None = None,
    zero_order_hold: bool = True,
    initial: JointModel | None = None,
    min_coherence: float = 0.8,
    max_evaluations: int = 300,
    alpha: float | None = None,
) -> JointModelFit:
    """Least-squares fit of K/(s(s+alpha)) H(s) to an FRF on log-magnitude and phase.

    ``output``: 'position' (FRF of q/u) or 'acceleration' (FRF of the second difference of q over u,
    whose exact response is included in the model). With ``zero_order_hold`` (default) the model is the
    exact ZOH-sampled P (the input is a held controller output sampled at ``sample_rate``); otherwise the
    continuous P(j omega). ``sample_rate`` is required for either.
    ``initial``: starting model; default one resonance pair from peak picking. Points with coherence
    below ``min_coherence`` are ignored; the others are weighted by sqrt(coherence / (1 - coherence)),
    which is proportional to the inverse standard deviation of the log FRF.
    ``alpha`` [rad/s]: hold alpha at this value instead of fitting it (a band far above alpha, such as
    Cheung's 80-500 Hz sweep, does not determine it).
    """
    if output not in ("position", "acceleration"):
        raise ValueError(f"output must be 'position' or 'acceleration', got {output!r}")
    data = frf.band(0.0, np.inf, min_coherence)
    data = FrequencyResponse(data.frequency[data.frequency > 0], data.response[data.frequency > 0],
                             data.coherence[data.frequency > 0])
    if data.frequency.size < 8:
        raise ValueError(
            f"only {data.frequency.size} FRF points have coherence >= {min_coherence}: too little excitation"
        )
    if sample_rate is None and (output == "acceleration" or zero_order_hold):
        raise ValueError("sample_rate is required for output='acceleration' or zero_order_hold=True")
    if output == "acceleration":
        to_output = second_difference_response(data.frequency, sample_rate)
    else:
        to_output = np.ones_like(data.frequency)
    start = initial if initial is not None else _initial_guess(data, to_output, alpha)
    if alpha is not None:
        start = JointModel(start.gain, alpha, start.resonances, start.antiresonances)
    free = np.ones(start.to_vector().size, dtype=bool)
    free[1] = alpha is None
    full = start.to_vector()

    def expand(x: np.ndarray) -> np.ndarray:
        v = full.copy()
        v[free] = x
        return v
    coh = np.clip(data.coherence, 0.0, 1 - 1e-6)
    weight = np.sqrt(coh / (1 - coh))

    def residual(x: np.ndarray) -> np.ndarray:
        model = JointModel.from_vector(expand(x))
        if zero_order_hold:
            response = model.sampled_response(data.frequency, sample_rate)
        else:
            response = model.position_response(data.frequency)
        ratio = response * to_output / data.response
        log_ratio = np.log(np.abs(ratio)) + 1j * np.angle(ratio)
        return np.concatenate([weight * log_ratio.real, weight * log_ratio.imag])

    sol = scipy.optimize.least_squares(residual, full[free], method="trf", max_nfev=max_evaluations)
    model = JointModel.from_vector(expand(sol.x))
    if alpha is not None:
        model = JointModel(model.gain, float(alpha), model.resonances, model.antiresonances)
    raw = residual(sol.x) / np.concatenate([weight, weight])
    alpha_log_std = float("nan")
    if alpha is None:
        sigma2 = float(sol.fun @ sol.fun) / max(sol.fun.size - sol.x.size, 1)
        alpha_log_std = float(np.sqrt(sigma2 * np.linalg.pinv(sol.jac.T @ sol.jac)[1, 1]))
    return JointModelFit(model, data, float(np.sqrt(np.mean(raw**2))), sol.message, alpha is not None,
                         alpha_log_std)


@dataclass(frozen=True)
class LowFrequencyFit:
    """Output-error fit of L(s) = K/(s(s+alpha)): gain K, alpha [rad/s], their covariance
    (Gauss-Newton, noise variance from the residuals), and the RMS output error [position unit]."""

    gain: float
    alpha: float
    covariance: np.ndarray
    rms_error: float


def fit_low_frequency_model(
    u: np.ndarray,
    position: np.ndarray,
    sample_rate: float,
    *,
    initial: tuple[float, float] = (1.0, 1.0),
) -> LowFrequencyFit:
    """Prediction-error (output-error) fit of L(s) = K/(s(s+alpha)) to a point-to-point move.

    Cheung identifies L from low-bandwidth point-to-point moves by PEM; with white position noise the
    PEM predictor is the simulated output, so this is an output-error fit. The plant starts at rest at
    position[0]; the input is held (ZOH) between samples. ``initial`` = (K, alpha) starting values.
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    q = np.asarray(position, dtype=float).reshape(-1)
    if u.shape != q.shape:
        raise ValueError(f"u and position must have the same length, got {u.size} and {q.size}")
    if not np.any(u):
        raise ValueError("input u is identically zero: K and alpha are not identifiable")
    dt = 1.0 / sample_rate

    def simulate(x: np.ndarray) -> np.ndarray:
        gain, alpha = np.exp(x)
        sys_d = control.c2d(control.tf([gain], [1.0, alpha, 0.0]), dt, method="zoh")
        num, den = np.asarray(sys_d.num[0][0]), np.asarray(sys_d.den[0][0])
        num = np.concatenate([np.zeros(den.size - num.size), num])  # strictly proper: q[n] from u[n-1]
        return scipy.signal.lfilter(num, den, u) + q[0]

    def residual(x: np.ndarray) -> np.ndarray:
        return simulate(x) - q

    sol = scipy.optimize.least_squares(residual, np.log(np.asarray(initial, dtype=float)), method="lm")
    gain, alpha = np.exp(sol.x)
    dof = max(q.size - 2, 1)
    sigma2 = float(sol.fun @ sol.fun) / dof
    jac = sol.jac * np.exp(sol.x)  # d residual / d (K, alpha)
    covariance = sigma2 * np.linalg.inv(jac.T @ jac)
    return LowFrequencyFit(float(gain), float(alpha), covariance, float(np.sqrt(np.mean(sol.fun**2))))


FRF_METHOD = ("H1 FRF from swept sine + fit of K/(s(s+alpha)) and resonance/antiresonance pairs "
              "(Cheung eqs. 6-8), rad/s")


def joint_model_parameters(model: JointModel) -> dict[str, float]:
    """The model in the CheungJoint FMU's parameter names: K, alpha, omega, zeta, omega_bar, zeta_bar
    (second and further modes suffixed 2, 3, ...)."""
    values = {"K": model.gain, "alpha": model.alpha}
    for k, ((wr, zr), (wa, za)) in enumerate(zip(model.resonances, model.antiresonances)):
        suffix = "" if k == 0 else str(k + 1)
        values.update({f"omega{suffix}": wr, f"zeta{suffix}": zr, f"omega_bar{suffix}": wa,
                       f"zeta_bar{suffix}": za})
    return values


#: alpha [1/s] held when neither the sweep band, --alpha nor a point-to-point move determines it
#: (the CheungJoint FMU's default); within a band far above alpha it hardly changes the fit.
DEFAULT_ALPHA = 10.0
#: alpha is taken from the sweep only if the fitted band reaches down to ALPHA_BAND_RATIO alpha (so that
#: s/(s+alpha) lags >= 11 deg at the band edge) and its Gauss-Newton relative std is below ALPHA_DETERMINED.
ALPHA_BAND_RATIO = 5.0
ALPHA_DETERMINED = 0.05


def identify_frf_recording(rec, *, input: str = "u", position: str = "q", segment_length: int | None = None,
                           min_coherence: float = 0.9, source: str = "recording",
                           nominal_mass: float | None = None, alpha: float | None = None,
                           low_frequency=None, low_frequency_source: str = "point-to-point recording",
                           ) -> tuple[JointModelFit, list[str]]:
    """Fit Cheung's joint model to a swept-sine harness.recording.Recording, with unit checks.

    Only the band the input excites (excited_band) is fitted. alpha [1/s] comes from, in this order:
    ``low_frequency`` (a point-to-point Recording with the same columns; fit_low_frequency_model, as
    Cheung), ``alpha`` (given), the sweep if its band determines alpha (see ALPHA_BAND_RATIO), else
    DEFAULT_ALPHA; each choice but the sweep is reported in the notes. ``segment_length``: Welch segment
    (default default_segment_length; fewer than 4 averages are refused, as the coherence would be ~1).

    The force column must be in N or N.m and the position in m or rad (mm, um, deg, kN, ms ...
    converted and reported in the returned notes). The position's span and speed, and the moving mass
    1/K (kg or kg.m2; within 10x of ``nominal_mass`` if given) must be plausible, else
    ident.units.UnitError names the column.
    """
    columns = checked_columns(rec, {input: "force", position: "position"}, source=source)
    check_motion(columns, position, source=source)
    notes = list(columns.notes)
    fs = columns.sample_rate
    u = columns[input][1:-1]
    n_seg = default_segment_length(u.size) if segment_length is None else segment_length
    averages = 1 + (u.size - n_seg) // (n_seg - n_seg // 2) if n_seg <= u.size else 0
    if averages < 4:
        raise ValueError(f"{source}: segment length {n_seg} gives {averages} Welch average(s) of {u.size} samples, "
                         f"so the coherence is meaningless: use a segment <= {u.size // 4}")
    frf = estimate_frf(u, acceleration_from_position(columns[position], fs), fs, n_seg)
    frf = frf.band(*excited_band(u, fs, n_seg))
    fixed, how = None, ""
    if low_frequency is not None:
        low = checked_columns(low_frequency, {input: "force", position: "position"}, source=low_frequency_source)
        check_motion(low, position, source=low_frequency_source)
        notes += low.notes
        start = fit_joint_frf(frf, output="acceleration", sample_rate=fs, min_coherence=min_coherence,
                              alpha=alpha or DEFAULT_ALPHA).model  # K of the mass line starts the PEM
        pem = fit_low_frequency_model(low[input], low[position], low.sample_rate, initial=(start.gain, start.alpha))
        fixed = pem.alpha
        how = (f"alpha = {pem.alpha:.6g} 1/s (+- {np.sqrt(pem.covariance[1, 1]):.2g}) from the point-to-point PEM "
               f"of L(s) on {low_frequency_source} (its K = {pem.gain:.6g}; K below is from the sweep)")
    elif alpha is not None:
        fixed, how = alpha, f"alpha = {alpha:.6g} 1/s held as given (--alpha), not fitted"
    fit = fit_joint_frf(frf, output="acceleration", sample_rate=fs, min_coherence=min_coherence, alpha=fixed)
    w_low = 2 * np.pi * fit.data.frequency[0]
    if fixed is None and not (w_low <= ALPHA_BAND_RATIO * fit.model.alpha and fit.alpha_log_std < ALPHA_DETERMINED):
        band = f"{fit.data.frequency[0]:.4g}-{fit.data.frequency[-1]:.4g} Hz"
        how = (f"alpha is not determined by the sweep band {band} (starts at {w_low:.4g} rad/s, free fit "
               f"{fit.model.alpha:.3g} +- {100 * fit.alpha_log_std:.2g} %): held at the default {DEFAULT_ALPHA:g} "
               f"1/s; give a point-to-point move (--low-frequency MOVE.csv) or --alpha")
        fit = fit_joint_frf(frf, output="acceleration", sample_rate=fs, min_coherence=min_coherence,
                            alpha=DEFAULT_ALPHA)
    if how:
        notes.append(f"{source}: {how}")
    check_inertia(1.0 / fit.model.gain, "moving mass 1/K", position, columns.rotary(position), source=source,
                  nominal=nominal_mass)
    return fit, notes


@dataclass(frozen=True)
class WorstCase:
    """Fits over actuator positions and the one with the lowest gain (Cheung: the design model).

    labels: one per position (e.g. recording paths); fits: JointModelFit per position; selected: index of
    the worst case; criterion: 'K' (acceleration gain) or 'K/alpha' (low-frequency velocity gain).
    """

    labels: list[str]
    fits: list[JointModelFit]
    selected: int
    criterion: str

    @property
    def model(self) -> JointModel:
        return self.fits[self.selected].model

    def table(self) -> str:
        """One line per position with K, alpha, K/alpha and the first mode, the worst marked '*'."""
        lines = [f"{'':1} {'position':<28} {'K':>12} {'alpha':>10} {'K/alpha':>10} {'omega':>10} "
                 f"{'omega_bar':>10} {'rms log':>8}"]
        for i, (label, fit) in enumerate(zip(self.labels, self.fits)):
            m = fit.model
            wr = m.resonances[0][0] if m.resonances else float("nan")
            wa = m.antiresonances[0][0] if m.antiresonances else float("nan")
            lines.append(f"{'*' if i == self.selected else ' '} {label[-28:]:<28} {m.gain:12.6g} {m.alpha:10.5g} "
                         f"{m.gain / m.alpha:10.5g} {wr:10.5g} {wa:10.5g} {fit.rms_log_error:8.3g}")
        lines.append(f"* worst case (lowest {self.criterion}), used for design")
        return "\n".join(lines)


def select_worst_case(fits: Sequence[JointModelFit], labels: Sequence[str], *, criterion: str = "K") -> WorstCase:
    """The fit with the lowest gain: ``criterion`` 'K' (acceleration gain of L(s)) or 'K/alpha'
    (velocity gain of L(s) below alpha). Cheung designs the controller on this model, as the other
    positions only have more gain (more phase margin is lost at the lowest gain crossover)."""
    if criterion not in ("K", "K/alpha"):
        raise ValueError(f"criterion must be 'K' or 'K/alpha', got {criterion!r}")
    if not fits or len(fits) != len(labels):
        raise ValueError(f"need one label per fit and at least one fit, got {len(fits)} fits, {len(labels)} labels")
    gains = [f.model.gain if criterion == "K" else f.model.gain / f.model.alpha for f in fits]
    return WorstCase(list(labels), list(fits), int(np.argmin(gains)), criterion)


def identify_frf_worst_case(recordings: Sequence, labels: Sequence[str], *, criterion: str = "K",
                            **options) -> tuple[WorstCase, list[str]]:
    """identify_frf_recording on each recording (one per actuator position), then select_worst_case.
    ``options`` go to identify_frf_recording; returns the selection and all conversion notes."""
    fits, notes = [], []
    for rec, label in zip(recordings, labels, strict=True):
        fit, rec_notes = identify_frf_recording(rec, source=label, **options)
        fits.append(fit)
        notes += rec_notes
    return select_worst_case(fits, labels, criterion=criterion), notes


def frf_document(fit: JointModelFit | WorstCase, recording: str | Sequence[str]) -> dict:
    """The JSON document ``motiontwin identify frf --out`` writes: method, recording, parameters (the
    CheungJoint names, so writeback --values takes it), and for a WorstCase also 'worst_case' with the
    criterion, the selected index and one row of parameters per position."""
    if isinstance(fit, WorstCase):
        doc = {"method": FRF_METHOD + f"; worst case (lowest {fit.criterion}) over actuator positions",
               "recording": fit.labels[fit.selected], "parameters": joint_model_parameters(fit.model)}
        doc["worst_case"] = {
            "criterion": fit.criterion, "selected": fit.selected,
            "positions": [{"recording": label, "parameters": joint_model_parameters(f.model),
                           "rms_log_error": f.rms_log_error} for label, f in zip(fit.labels, fit.fits)],
        }
        return doc
    return {"method": FRF_METHOD, "recording": str(recording), "parameters": joint_model_parameters(fit.model)}
