"""Sensor effects: an error of the measured position, added to the plant's output (``Effect.sensor``) instead of
acting on the plant as a force. The loop feeds the erroneous measurement back and the controller moves the
plant against it, so the error shows in the measured position, and in the force only through the loop; a
force law (``position_ripple``) shows in the force. The closed-loop output-error fit weighs both channels, so
the two are told apart by their costs. Positions and the :class:`Context` are in the plant's state
coordinates, the error in the measured output's unit (m or rad). Units: SI (m, s, N, kg).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from motiontwin.ident.diagnosis.effect_base import Context, Effect, _p, _scale, _sign

ENCODER_CYCLES = 500        # the shortest signal period fitted: the recorded span / this
ENCODER_STEP = 0.25         # spacing of the periods scanned for starts, in periods over the span
ENCODER_STARTS = 3          # data-driven starts: the strongest distinct periods of the scan
BIN_SHARE = 1 / 16          # width of the position bins of the scan, as a share of the shortest period
AMPLITUDE_SHARE = 1e-3      # bound of each error amplitude, as a share of the recorded span


def _error_columns(c: Context, k: float) -> np.ndarray:
    """The force residual (samples x 2) that a position error sin(k x), cos(k x) of the measurement leaves in
    the inverse dynamics: the nominal model explains the measured motion x + e(x) while the plant made x, so
    the residual is -m d2e/dt2 = -m (e'(x) a + e''(x) v^2) (the damping's share, d/(m k v), is neglected)."""
    s, co = np.sin(k * c.x), np.cos(k * c.x)
    kv2 = k * k * c.v * c.v
    return -c.mass * np.column_stack([k * c.a * co - kv2 * s, -k * c.a * s - kv2 * co])


def _position_transform(x: np.ndarray, span: float, shortest: float
                        ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """(wavenumbers [1/m] of every period from ``shortest`` to 2 ``span``, ENCODER_STEP periods over the span
    apart; w -> sum_t w_t exp(i k x_t) at those wavenumbers): one FFT of position bins."""
    h = BIN_SHARE * shortest
    n = int(math.ceil(span / (ENCODER_STEP * h)))
    bins = np.minimum(np.round((x - x.min()) / h).astype(int), n - 1)
    k = 2 * np.pi * np.arange(n) / (n * h)
    keep = (k >= np.pi / span) & (k <= 2 * np.pi / shortest)
    return k[keep], lambda w: (n * np.fft.ifft(np.bincount(bins, w, minlength=n)))[keep]


def _scan(c: Context, force: np.ndarray, span: float, shortest: float) -> tuple[np.ndarray, np.ndarray]:
    """(wavenumbers [1/m], reduction of |force|^2) of an error periodic in position at every period of
    :func:`_position_transform`: the matched filter of :func:`_error_columns` (its two columns taken as
    orthogonal and of equal norm)."""
    k, transform = _position_transform(c.x, span, shortest)
    matched = 1j * k * transform(force * c.a) - k * k * transform(force * c.v ** 2)
    energy = 0.5 * (k * k * np.sum(c.a ** 2) + k ** 4 * np.sum(c.v ** 4))
    return k, np.abs(matched) ** 2 / energy


def residual_periods(c: Context, span: float, shortest: float) -> list[tuple[float, tuple[float, ...]]]:
    """(period, zero amplitudes) of an encoder error in the nominal's training output residual
    (``c.q_residual``): the strongest period there and twice it. Why: where the axis moves slowly the error's
    force (m e'' v^2) is below the process noise while the measured position still shows it, through the loop's
    sensitivity, which weights the second harmonic up (the strongest peak can be it; on the tuning encoder-error
    case 0.5 mm for a 1 mm period). The amplitudes start at zero: the output-error fit finds them in its first
    step (the measured position is linear in them), while a regression on the residual would start them with
    the sensitivity's gain and phase."""
    if c.q_residual is None or c.x is None:
        return []
    k, transform = _position_transform(c.x, span, shortest)
    if not k.size:
        return []
    peak = float(k[int(np.argmax(np.abs(transform(c.q_residual - np.mean(c.q_residual)))))])
    return [(2 * np.pi / kk, (0.0, 0.0, 0.0, 0.0)) for kk in (peak, peak / 2)]


def _refined(c: Context, k0: float, dk: float) -> tuple[float, float, tuple[float, ...]]:
    """(residual sum of squares, wavenumber, sine and cosine amplitudes of the fundamental and the second
    harmonic in state coordinates) of the best of five wavenumbers within +-dk/2 of ``k0``, by least squares
    with a constant and a Coulomb-like term."""
    fits = []
    for k in k0 + dk * np.linspace(-0.5, 0.5, 5):
        cols = np.column_stack([_error_columns(c, k), _error_columns(c, 2 * k), np.ones_like(c.x), _sign(c)])
        coef, *_ = np.linalg.lstsq(cols, c.force, rcond=None)
        fits.append((float(np.sum((c.force - cols @ coef) ** 2)), float(k), tuple(map(float, coef[:4]))))
    return min(fits)


def encoder_periods(c: Context, span: float, shortest: float) -> list[tuple[float, tuple[float, ...]]]:
    """(period, sine and cosine amplitudes of the fundamental and the second harmonic in state coordinates)
    of the ENCODER_STARTS strongest distinct periods of an encoder error in the inverse-dynamics force
    residual, strongest first."""
    cols = np.column_stack([np.ones_like(c.x), _sign(c)])
    force = c.force - cols @ np.linalg.lstsq(cols, c.force, rcond=None)[0]
    k, score = _scan(c, force, span, shortest)
    peaks = [i for i in range(1, k.size - 1) if score[i - 1] <= score[i] >= score[i + 1]]
    peaks.sort(key=lambda i: -score[i])
    fits = [_refined(c, k[i], k[1] - k[0]) for i in peaks[:ENCODER_STARTS]]
    return [(2 * np.pi / kk, amplitudes) for _, kk, amplitudes in sorted(fits)]


def encoder_error(ctx: Context) -> Effect:
    """Encoder interpolation (cyclic) error: the measured position is q + e with e periodic in the position,
    a free signal period and its second harmonic; starts at the periods that explain most of the force
    residual such an error leaves in the inverse dynamics, and at those of the output residual."""
    span = max(ctx.x_max - ctx.x_min, 1e-6 / _scale(ctx))
    shortest = span / ENCODER_CYCLES
    amplitude = AMPLITUDE_SHARE * span * _scale(ctx)

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None or c.x is None:
            found = [(span / cycles, (1e-6 / _scale(c), 0.0, 0.0, 0.0)) for cycles in (4, 20, 100)]
        else:
            found = encoder_periods(c, span, shortest) + residual_periods(c, span, shortest)
        names = ("encoder_a1", "encoder_b1", "encoder_a2", "encoder_b2")
        return [{"encoder_period": period, **{n: c.position_gain * a for n, a in zip(names, amplitudes)}}
                for period, amplitudes in found]
    params = [_p("encoder_a1", "m", "Sine amplitude of the measured-position error", -amplitude, amplitude, zero=0.0),
              _p("encoder_b1", "m", "Cosine amplitude of the measured-position error", -amplitude, amplitude, zero=0.0),
              _p("encoder_a2", "m", "Sine amplitude of the second harmonic", -amplitude, amplitude, zero=0.0),
              _p("encoder_b2", "m", "Cosine amplitude of the second harmonic", -amplitude, amplitude, zero=0.0),
              _p("encoder_period", "m", "Signal period of the encoder", shortest, 2 * span)]
    theta = f"{math.tau!r}*$x/encoder_period"
    sensor = (f"encoder_a1*sin({theta}) + encoder_b1*cos({theta}) + encoder_a2*sin(2*{theta}) + "
              f"encoder_b2*cos(2*{theta})")
    return Effect("encoder_error", "encoder_error", params, "", "", [], [], init,
                  lambda v, c: {"error_amplitude": float(math.hypot(v["encoder_a1"], v["encoder_b1"])),
                                "error_amplitude_2": float(math.hypot(v["encoder_a2"], v["encoder_b2"])),
                                "period": v["encoder_period"] * abs(c.position_gain)},
                  "The position sensor reads with an error periodic in position (encoder interpolation or "
                  "cyclic error, a fixed signal period and its second harmonic): the controller acts on the "
                  "erroneous measurement and moves the axis against it, so the error shows in the measured "
                  "position, and in the force only through the loop, unlike a force periodic in position.",
                  sensor=sensor)
