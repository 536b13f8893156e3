"""Frequency-domain processing of periodic identification data (Abdellatif & Heimann, sec. 3.2-3.3).

Periodic excitation lets us (i) average the repeated periods and estimate the full cross-covariance of
the measurement errors between channels, and (ii) filter and differentiate *exactly* in the frequency
domain: DFT over an integer number of periods, ideal (rectangular) low-pass at f_c, multiplication by
j*omega. No leakage, no phase lag, no finite-difference noise amplification above f_c.

Units: time in s, frequency in Hz, signals in their own SI unit (rad or m; derivatives per s, per s^2).
Arrays are sample-major: shape (n_samples,) or (n_samples, n_channels).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "samples_per_period",
    "FilteredDerivatives",
    "lowpass_differentiate",
    "PeriodAverage",
    "period_average",
]


def samples_per_period(sample_rate: float, fundamental_frequency: float, *, rtol: float = 1e-9) -> int:
    """Number of samples in one period; raises if the period is not an integer number of samples.

    An integer number of samples per period is what makes the DFT leakage-free.
    """
    if sample_rate <= 0 or fundamental_frequency <= 0:
        raise ValueError(
            f"sample_rate ({sample_rate}) and fundamental_frequency ({fundamental_frequency}) must be > 0"
        )
    ratio = sample_rate / fundamental_frequency
    n = int(round(ratio))
    if n < 2 or abs(ratio - n) > rtol * ratio:
        raise ValueError(
            f"sample_rate/fundamental_frequency = {ratio!r} is not an integer number of samples per period; "
            "choose f0 = fs/n for integer n so the DFT covers whole periods"
        )
    return n


@dataclass(frozen=True)
class FilteredDerivatives:
    """Low-pass filtered signal and its first two time derivatives, same shape as the input.

    position: filtered signal; velocity: d/dt; acceleration: d^2/dt^2;
    cutoff_frequency: the f_c used [Hz]; harmonics_kept: number of DFT bins (excluding DC) passed.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    cutoff_frequency: float
    harmonics_kept: int


def lowpass_differentiate(
    signal: np.ndarray, sample_rate: float, cutoff_frequency: float
) -> FilteredDerivatives:
    """Ideal low-pass at ``cutoff_frequency`` and exact differentiation of a periodic record.

    The record must span an integer number of periods of the excitation (then every excitation harmonic
    falls on a DFT bin). Bins with frequency > f_c are zeroed; velocity and acceleration are obtained by
    multiplying the spectrum by j*omega and -omega^2 (Abdellatif sec. 3.3). The Nyquist bin is always
    removed because its derivative is not representable as a real signal.
    """
    x = np.asarray(signal, dtype=float)
    if x.ndim not in (1, 2):
        raise ValueError(f"signal must be 1-D or 2-D (samples x channels), got shape {x.shape}")
    n = x.shape[0]
    if n < 4:
        raise ValueError(f"signal needs at least 4 samples, got {n}")
    if not np.all(np.isfinite(x)):
        bad = np.argwhere(~np.isfinite(x))[0]
        raise ValueError(f"signal contains a non-finite value at index {tuple(int(i) for i in bad)}")
    if cutoff_frequency <= 0:
        raise ValueError(f"cutoff_frequency must be > 0 Hz, got {cutoff_frequency}")
    spectrum = np.fft.rfft(x, axis=0)
    freqs = np.fft.rfftfreq(n, d=1.0 / sample_rate)
    keep = freqs <= cutoff_frequency * (1 + 1e-12)
    if n % 2 == 0:
        keep[-1] = False
    shape = (-1,) + (1,) * (x.ndim - 1)
    window = keep.reshape(shape)
    jw = (2j * np.pi * freqs).reshape(shape)
    filtered = spectrum * window
    position = np.fft.irfft(filtered, n=n, axis=0)
    velocity = np.fft.irfft(jw * filtered, n=n, axis=0)
    acceleration = np.fft.irfft(jw**2 * filtered, n=n, axis=0)
    return FilteredDerivatives(position, velocity, acceleration, float(cutoff_frequency), int(keep[1:].sum()))


@dataclass(frozen=True)
class PeriodAverage:
    """Period-averaged data and measurement-error statistics (Abdellatif sec. 3.2).

    mean: averaged period, shape (samples_per_period, n_channels).
    noise_covariance: channel cross-covariance of the error of ONE measured sample, (n_channels, n_channels),
    pooled over the samples of the period (the sigma_ij of the paper).
    mean_covariance: covariance of the error of one sample of ``mean`` (= noise_covariance / n_periods).
    n_periods: number of periods averaged.
    """

    mean: np.ndarray
    noise_covariance: np.ndarray
    mean_covariance: np.ndarray
    n_periods: int

    @property
    def correlation(self) -> np.ndarray:
        """Correlation coefficients between channel errors."""
        d = np.sqrt(np.diag(self.noise_covariance))
        return self.noise_covariance / np.outer(d, d)


def period_average(data: np.ndarray, samples_in_period: int) -> PeriodAverage:
    """Average ``data`` over its periods and estimate the full cross-covariance of the errors.

    ``data`` holds n_periods * samples_in_period samples (1-D or samples x channels). The covariance is
    sigma_ij = 1/(N (N_m - 1)) sum_k (x_jk - xbar_j)^T (x_ik - xbar_i), with N samples per period and
    N_m periods, i.e. the unbiased estimate pooled over the period.
    """
    x = np.asarray(data, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"data must be 1-D or 2-D (samples x channels), got shape {x.shape}")
    n_total, n_channels = x.shape
    if samples_in_period < 1 or n_total % samples_in_period:
        raise ValueError(
            f"data has {n_total} samples, not a whole number of periods of {samples_in_period} samples"
        )
    n_periods = n_total // samples_in_period
    if n_periods < 2:
        raise ValueError(f"need at least 2 periods to estimate the noise covariance, got {n_periods}")
    periods = x.reshape(n_periods, samples_in_period, n_channels)
    mean = periods.mean(axis=0)
    deviation = (periods - mean).reshape(-1, n_channels)
    covariance = deviation.T @ deviation / (samples_in_period * (n_periods - 1))
    return PeriodAverage(mean, covariance, covariance / n_periods, n_periods)
