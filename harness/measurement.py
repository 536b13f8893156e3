"""Measurement realism for simulated experiments: encoder quantisation, sensor noise, force disturbances.

Units: SI (positions in m, forces in N, times in s, frequencies in Hz). Every random function takes ``rng``: a
numpy Generator, an integer seed or None, so that a recording made with a given seed is reproducible.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

Seed = int | np.random.Generator | None


def generator(rng: Seed) -> np.random.Generator:
    """The numpy Generator for ``rng`` (a Generator is passed through, an int or None seeds a new one)."""
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def quantize(x: np.ndarray, resolution: float) -> np.ndarray:
    """Round to the nearest multiple of ``resolution`` (an encoder count, e.g. 1e-7 m); error <= resolution / 2."""
    if resolution <= 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    return np.round(np.asarray(x, dtype=float) / resolution) * resolution


def add_noise(x: np.ndarray, std: float, rng: Seed = None) -> np.ndarray:
    """``x`` plus white Gaussian noise of standard deviation ``std`` (same unit as ``x``)."""
    if std < 0:
        raise ValueError(f"std must be non-negative, got {std}")
    x = np.asarray(x, dtype=float)
    return x + generator(rng).normal(0.0, std, x.shape) if std > 0 else x.copy()


def encoder(position: np.ndarray, resolution: float, noise_std: float = 0.0, rng: Seed = None) -> np.ndarray:
    """A position measurement: true position plus Gaussian noise ``noise_std``, then counted by an encoder."""
    return quantize(add_noise(position, noise_std, rng), resolution)


def lowpass_noise(n_samples: int, std: float, bandwidth: float, sample_time: float, rng: Seed = None) -> np.ndarray:
    """Stationary first-order low-pass Gaussian noise: y[k] = a y[k-1] + (1 - a) w[k], a = exp(-2 pi bandwidth Ts).

    The white input is scaled so that the stationary standard deviation is ``std`` and the first sample is drawn
    from the stationary distribution; the lag-1 autocorrelation is ``a``.
    """
    if n_samples < 1 or std < 0 or bandwidth <= 0 or sample_time <= 0:
        raise ValueError("n_samples, bandwidth and sample_time must be positive and std non-negative")
    a = float(np.exp(-2 * np.pi * bandwidth * sample_time))
    gen = generator(rng)
    white = gen.normal(0.0, std * np.sqrt((1 + a) / (1 - a)), n_samples)
    first = gen.normal(0.0, std)
    rest, _ = scipy.signal.lfilter([1 - a], [1.0, -a], white[1:], zi=[a * first])
    return np.concatenate([[first], rest])


def force_disturbance(
    t: np.ndarray,
    std: float = 0.0,
    bandwidth: float = 10.0,
    offset: float = 0.0,
    steps: list[tuple[float, float]] | None = None,
    sine: tuple[float, float] | None = None,
    rng: Seed = None,
) -> np.ndarray:
    """A disturbance force [N] on the time grid ``t`` (uniformly sampled).

    offset: constant force; steps: (time [s], size [N]) pairs added from that time on; sine: (amplitude [N],
    frequency [Hz]); std, bandwidth: low-pass Gaussian noise as in :func:`lowpass_noise`.
    """
    t = np.asarray(t, dtype=float)
    force = np.full(t.shape, float(offset))
    for when, size in steps or []:
        force += np.where(t >= when, size, 0.0)
    if sine is not None:
        amplitude, frequency = sine
        force += amplitude * np.sin(2 * np.pi * frequency * t)
    if std > 0:
        if t.size < 2:
            raise ValueError("noise needs a time grid of at least two samples")
        force += lowpass_noise(t.size, std, bandwidth, float(t[1] - t[0]), rng)
    return force
