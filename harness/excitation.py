"""Excitation signals and reference trajectories for motion experiments, on a given time grid.

Units: SI throughout: time in s, frequencies in Hz, positions in m (or rad for rotary axes), velocities in
m/s, accelerations in m/s^2, jerks in m/s^3, forces in N. Every generator takes a time vector ``t`` and
returns numpy arrays sampled on it: a :class:`Profile` (position and its analytic derivatives, for references
and feedforward) or a plain array (a force or other input signal).

Generators
    - :func:`quintic_point_to_point`: fifth-order polynomial rest-to-rest move (per actuator with array ends).
    - :func:`swept_sine`: linear or logarithmic sweep, e.g. 80-500 Hz on the controller output (Cheung).
    - :func:`fourier_trajectory`: periodic finite Fourier series (Swevers; Bona eqs. 17-19; Abdellatif
      eqs. 12-15) with analytic derivatives, repeated for N periods on :func:`periodic_time_grid`.
    - :func:`multisine` (Schroeder phases), :func:`prbs` (maximum-length sequence, seeded),
      :func:`step`, :func:`bang_bang_move` / :func:`bang_bang_sequence` (EMPS-style acceleration profiles).

Experiment files that name these generators are read by :mod:`harness.experiment`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.signal

ArrayLike = float | Sequence[float] | np.ndarray


@dataclass
class Profile:
    """A reference trajectory sampled on ``time`` [s] with analytic derivatives.

    position, velocity, acceleration, jerk: shape (N,) for one axis or (N, n_axes) for several.
    """

    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def as_dict(self) -> dict[str, np.ndarray]:
        """The five arrays by name (``time``, ``position``, ``velocity``, ``acceleration``, ``jerk``)."""
        return {
            "time": self.time,
            "position": self.position,
            "velocity": self.velocity,
            "acceleration": self.acceleration,
            "jerk": self.jerk,
        }


def time_grid(t: ArrayLike) -> np.ndarray:
    """``t`` as a 1-D float array [s] (ValueError naming its shape otherwise)."""
    array = np.asarray(t, dtype=float)
    if array.ndim != 1:
        raise ValueError(f"time grid must be 1-D, got shape {array.shape}")
    return array


def quintic_point_to_point(
    t: ArrayLike, start: ArrayLike, end: ArrayLike, move_time: float, t0: float = 0.0
) -> Profile:
    """Rest-to-rest move from ``start`` to ``end`` in ``move_time`` seconds beginning at ``t0``.

    Uses s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (tau = (t - t0) / move_time), the fifth-order polynomial with zero
    velocity and acceleration at both ends; holds ``start`` before and ``end`` after the move. The jerk jumps to
    60 D / T^3 at both ends (inherent to the quintic). Array ends give one column per actuator (the per-actuator
    profiles of Cheung's point-to-point experiment).
    """
    if move_time <= 0:
        raise ValueError(f"move_time must be positive, got {move_time}")
    t = time_grid(t)
    start = np.asarray(start, dtype=float)
    distance = np.asarray(end, dtype=float) - start
    tau = np.clip((t - t0) / move_time, 0.0, 1.0)
    inside = ((t >= t0) & (t <= t0 + move_time)).astype(float)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    ds = 30 * tau**2 * (1 - tau) ** 2 / move_time
    dds = 60 * tau * (1 - 3 * tau + 2 * tau**2) / move_time**2
    ddds = 60 * (1 - 6 * tau + 6 * tau**2) / move_time**3 * inside
    outer = np.multiply.outer
    return Profile(
        time=t,
        position=start + outer(s, distance),
        velocity=outer(ds, distance),
        acceleration=outer(dds, distance),
        jerk=outer(ddds, distance),
    )


def actuator_point_to_point(
    t: ArrayLike, actuator_start: ArrayLike, actuator_end: ArrayLike, move_time: float, t0: float = 0.0
) -> Profile:
    """Per-actuator quintic profiles between two actuator position vectors; arrays of shape (N, n_actuators)."""
    start = np.atleast_1d(np.asarray(actuator_start, dtype=float))
    end = np.atleast_1d(np.asarray(actuator_end, dtype=float))
    if start.shape != end.shape or start.ndim != 1:
        raise ValueError(f"actuator start {start.shape} and end {end.shape} must be vectors of equal length")
    return quintic_point_to_point(t, start, end, move_time, t0)


def swept_sine(
    t: ArrayLike,
    f_start: float,
    f_end: float,
    sweep_time: float,
    amplitude: float = 1.0,
    method: str = "linear",
    t0: float = 0.0,
    ramp_time: float = 0.0,
) -> np.ndarray:
    """Sine sweep amplitude * sin(phi(t)) from ``f_start`` to ``f_end`` [Hz] during [t0, t0 + sweep_time], zero outside.

    method: ``"linear"`` (frequency linear in time) or ``"logarithmic"`` (exponential in time, equal time per
    octave). ramp_time: raised-cosine fade in and out [s] to avoid exciting the plant with a step in slope.
    The phase is that of scipy.signal.chirp; it starts at zero so the force starts at zero.
    """
    if method not in ("linear", "logarithmic"):
        raise ValueError(f"method must be 'linear' or 'logarithmic', got {method!r}")
    if sweep_time <= 0 or f_start <= 0 or f_end <= 0:
        raise ValueError("sweep_time, f_start and f_end must be positive")
    if not 0 <= 2 * ramp_time <= sweep_time:
        raise ValueError(f"ramp_time {ramp_time} must be between 0 and sweep_time / 2")
    t = time_grid(t)
    rel = t - t0
    inside = (rel >= 0) & (rel <= sweep_time)
    signal = scipy.signal.chirp(rel, f0=f_start, t1=sweep_time, f1=f_end, method=method, phi=-90.0)
    envelope = np.ones_like(t)
    if ramp_time > 0:
        fade = np.minimum(rel, sweep_time - rel) / ramp_time
        envelope = np.where(fade < 1, 0.5 - 0.5 * np.cos(np.pi * np.clip(fade, 0, 1)), 1.0)
    return np.where(inside, amplitude * envelope * signal, 0.0)


def swept_sine_frequency(
    t: ArrayLike, f_start: float, f_end: float, sweep_time: float, method: str = "linear", t0: float = 0.0
) -> np.ndarray:
    """Instantaneous frequency [Hz] of :func:`swept_sine` (clipped to the sweep interval), for binning responses."""
    rel = np.clip(np.asarray(t, dtype=float) - t0, 0.0, sweep_time)
    if method == "linear":
        return f_start + (f_end - f_start) * rel / sweep_time
    if method == "logarithmic":
        return f_start * (f_end / f_start) ** (rel / sweep_time)
    raise ValueError(f"method must be 'linear' or 'logarithmic', got {method!r}")


def periodic_time_grid(period: float, n_periods: int, sample_time: float) -> np.ndarray:
    """Time grid [s] of ``n_periods`` whole periods; the period must hold an integer number of samples."""
    samples = period / sample_time
    per_period = round(samples)
    if per_period < 1 or abs(samples - per_period) > 1e-9 * max(1.0, samples):
        raise ValueError(f"period {period} s is not an integer multiple of sample_time {sample_time} s")
    if n_periods < 1:
        raise ValueError(f"n_periods must be at least 1, got {n_periods}")
    return np.arange(per_period * n_periods) * sample_time


@dataclass(frozen=True)
class FourierBasis:
    """Basis matrices (n_samples x 2 L) of the finite Fourier series: with the coefficients c = [a_1..a_L,
    b_1..b_L] (or one column per axis), position = q0 + position @ c, velocity = velocity @ c, and so on.
    Linear in c, so they multiply numpy arrays and CasADi symbols alike (excitation design)."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray


def fourier_basis(t: ArrayLike, f_fundamental: float, n_harmonics: int) -> FourierBasis:
    """Basis of the periodic finite Fourier series (Swevers; Bona eqs. 17-19; Abdellatif eqs. 12-15) at ``t``.

    q(t) = q0 + sum_l a_l / (w_f l) sin(w_f l t) - b_l / (w_f l) cos(w_f l t), w_f = 2 pi f_fundamental,
    so the velocity is sum_l a_l cos(w_f l t) + b_l sin(w_f l t) (eq. 18) and a_l, b_l are velocity amplitudes.
    """
    if n_harmonics < 1:
        raise ValueError(f"n_harmonics must be >= 1, got {n_harmonics}")
    w = 2 * np.pi * f_fundamental * np.arange(1, n_harmonics + 1)
    phase = np.multiply.outer(time_grid(t), w)
    sin, cos = np.sin(phase), np.cos(phase)
    return FourierBasis(position=np.hstack([sin / w, -cos / w]), velocity=np.hstack([cos, sin]),
                        acceleration=np.hstack([-sin * w, cos * w]), jerk=np.hstack([-cos * w**2, -sin * w**2]))


def fourier_trajectory(
    t: ArrayLike, f_fundamental: float, a: ArrayLike, b: ArrayLike, q0: ArrayLike = 0.0
) -> Profile:
    """Periodic finite Fourier series trajectory (:func:`fourier_basis`) and its analytic derivatives.

    a, b: shape (L,) for one axis or (L, n_axes); harmonic l = 1..L. The trajectory repeats every 1/f_fundamental.
    """
    t = time_grid(t)
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim not in (1, 2) or a.shape[0] == 0:
        raise ValueError(f"a {a.shape} and b {b.shape} must have equal shape (L,) or (L, n_axes)")
    basis = fourier_basis(t, f_fundamental, a.shape[0])
    c = np.concatenate([a, b])
    return Profile(time=t, position=np.asarray(q0, dtype=float) + basis.position @ c, velocity=basis.velocity @ c,
                   acceleration=basis.acceleration @ c, jerk=basis.jerk @ c)


def schroeder_phases(amplitudes: ArrayLike) -> np.ndarray:
    """Schroeder (1970) phases phi_k = -2 pi sum_{l<k} (k - l) p_l, p_l the power share of line l; low crest factor."""
    amplitudes = np.atleast_1d(np.asarray(amplitudes, dtype=float))
    power = amplitudes**2 / np.sum(amplitudes**2)
    k = np.arange(1, amplitudes.size + 1)
    return np.array([-2 * np.pi * np.sum((kk - k[: kk - 1]) * power[: kk - 1]) for kk in k])


def multisine(
    t: ArrayLike,
    f_resolution: float,
    harmonics: Sequence[int],
    amplitude: ArrayLike = 1.0,
    phases: str | ArrayLike = "schroeder",
    seed: int | np.random.Generator | None = None,
) -> np.ndarray:
    """Sum of cosines amplitude_k cos(2 pi h_k f_resolution t + phi_k) at the integer lines ``harmonics``.

    Periodic with period 1/f_resolution; over whole periods its spectrum holds only the chosen lines.
    phases: ``"schroeder"``, ``"random"`` (uniform, from ``seed``) or an array of phases [rad].
    """
    t = time_grid(t)
    harmonics = np.asarray(harmonics)
    if harmonics.ndim != 1 or harmonics.size == 0 or np.any(harmonics < 1) or np.any(harmonics % 1):
        raise ValueError(f"harmonics must be positive integers, got {harmonics}")
    amplitudes = np.broadcast_to(np.asarray(amplitude, dtype=float), harmonics.shape)
    if isinstance(phases, str):
        if phases == "schroeder":
            phi = schroeder_phases(amplitudes)
        elif phases == "random":
            phi = np.random.default_rng(seed).uniform(0, 2 * np.pi, harmonics.size)
        else:
            raise ValueError(f"phases must be 'schroeder', 'random' or an array, got {phases!r}")
    else:
        phi = np.broadcast_to(np.asarray(phases, dtype=float), harmonics.shape)
    omega = 2 * np.pi * f_resolution * harmonics.astype(float)
    return np.cos(np.multiply.outer(t, omega) + phi) @ amplitudes


def max_length_sequence(n_bits: int, seed: int | np.random.Generator | None = None) -> np.ndarray:
    """One period (2**n_bits - 1 values of +-1) of a maximum-length sequence from scipy's LFSR.

    The seed picks the (non-zero) initial register state, i.e. a cyclic shift of the same sequence.
    """
    if not 2 <= n_bits <= 32:
        raise ValueError(f"n_bits must be between 2 and 32, got {n_bits}")
    rng = np.random.default_rng(seed)
    state = np.zeros(n_bits, dtype=np.int8)
    while not state.any():
        state = rng.integers(0, 2, n_bits).astype(np.int8)
    bits, _ = scipy.signal.max_len_seq(n_bits, state=state)
    return 2.0 * bits - 1.0


def prbs(
    t: ArrayLike,
    n_bits: int,
    clock_period: float,
    amplitude: float = 1.0,
    seed: int | np.random.Generator | None = None,
    offset: float = 0.0,
    t0: float = 0.0,
) -> np.ndarray:
    """Pseudo-random binary signal offset +- amplitude, each bit held for ``clock_period`` [s] from ``t0``.

    Periodic with period (2**n_bits - 1) * clock_period; zero-mean up to one bit per period; ``offset`` before t0.
    """
    if clock_period <= 0:
        raise ValueError(f"clock_period must be positive, got {clock_period}")
    t = time_grid(t)
    sequence = max_length_sequence(n_bits, seed)
    index = np.floor((t - t0) / clock_period + 1e-9).astype(np.int64)
    value = offset + amplitude * sequence[np.mod(index, sequence.size)]
    return np.where(index >= 0, value, offset)


def step(t: ArrayLike, t_step: float, amplitude: float, initial: float = 0.0) -> np.ndarray:
    """``initial`` before ``t_step`` [s], ``initial + amplitude`` from then on."""
    t = time_grid(t)
    return np.where(t >= t_step, initial + amplitude, initial)


def bang_bang_move(
    t: ArrayLike, distance: float, max_velocity: float, max_acceleration: float, t0: float = 0.0, start: float = 0.0
) -> Profile:
    """Rest-to-rest move with bang-bang acceleration (+a, coast, -a): a trapezoidal (or triangular) velocity.

    The jerk is a sum of Dirac impulses at the switching instants; the returned jerk is zero between them.
    """
    if max_velocity <= 0 or max_acceleration <= 0:
        raise ValueError("max_velocity and max_acceleration must be positive")
    t = time_grid(t)
    sign, length = math.copysign(1.0, distance), abs(distance)
    accel_time = max_velocity / max_acceleration
    if length < max_velocity * accel_time:
        accel_time = math.sqrt(length / max_acceleration)
    peak = max_acceleration * accel_time
    coast_time = (length - peak * accel_time) / peak if peak > 0 else 0.0
    total = 2 * accel_time + coast_time
    r = np.clip(t - t0, 0.0, total)
    t1, t2 = accel_time, accel_time + coast_time
    a = max_acceleration
    d1 = np.clip(r, 0, t1)
    d2 = np.clip(r - t1, 0, coast_time)
    d3 = np.clip(r - t2, 0, accel_time)
    finished = r >= total
    position = np.where(finished, length, 0.5 * a * d1**2 + peak * d2 + peak * d3 - 0.5 * a * d3**2)
    velocity = np.where(finished, 0.0, a * d1 - a * d3)
    acceleration = np.where((r > 0) & (r < t1), a, 0.0) - np.where((r >= t2) & (r < total), a, 0.0)
    acceleration = np.where(t - t0 > 0, acceleration, 0.0)
    return Profile(
        time=t,
        position=start + sign * position,
        velocity=sign * velocity,
        acceleration=sign * acceleration,
        jerk=np.zeros_like(t),
    )


def bang_bang_move_time(distance: float, max_velocity: float, max_acceleration: float) -> float:
    """Duration [s] of :func:`bang_bang_move` for the given distance and limits."""
    length = abs(distance)
    if length < max_velocity**2 / max_acceleration:
        return 2 * math.sqrt(length / max_acceleration)
    return length / max_velocity + max_velocity / max_acceleration


def bang_bang_sequence(
    t: ArrayLike,
    positions: Sequence[float],
    max_velocity: float,
    max_acceleration: float,
    dwell: float = 0.0,
    t0: float = 0.0,
) -> Profile:
    """Chain of bang-bang moves through ``positions`` (first = start), resting ``dwell`` [s] after each move.

    Mimics the EMPS benchmark references: back-and-forth rest-to-rest moves with saturated acceleration.
    """
    t = time_grid(t)
    positions = [float(p) for p in positions]
    if len(positions) < 2:
        raise ValueError("positions needs a start and at least one target")
    total = bang_bang_move(t, 0.0, max_velocity, max_acceleration, t0, positions[0])
    begin = t0
    for previous, target in zip(positions[:-1], positions[1:]):
        move = bang_bang_move(t, target - previous, max_velocity, max_acceleration, begin, 0.0)
        total.position = total.position + move.position
        total.velocity = total.velocity + move.velocity
        total.acceleration = total.acceleration + move.acceleration
        begin += bang_bang_move_time(target - previous, max_velocity, max_acceleration) + dwell
    return total


# ---------------------------------------------------------------- end-effector moves


def end_effector_point_to_point(
    t: ArrayLike,
    pose_start: ArrayLike,
    pose_end: ArrayLike,
    move_time: float,
    t0: float = 0.0,
    inverse_kinematics: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Profile:
    """Per-actuator quintic profiles for an end-effector move (Cheung's substrate alignment).

    The start and end poses are mapped to actuator positions by the inverse kinematics, and each actuator
    follows :func:`quintic_point_to_point` between them, as the paper pre-computes for its four linear motors.
    inverse_kinematics: pose -> actuator positions; default: the 4-DOF manipulator's
    :func:`harness.kinematics.cheung_inverse` (pose [x, y, z, theta] -> actuators [d1, d3, d5, d7]).
    """
    ik = inverse_kinematics or _default_inverse_kinematics()
    start = np.asarray(ik(np.asarray(pose_start, dtype=float)), dtype=float)
    end = np.asarray(ik(np.asarray(pose_end, dtype=float)), dtype=float)
    return actuator_point_to_point(t, start, end, move_time, t0)


def _default_inverse_kinematics() -> Callable[[np.ndarray], np.ndarray]:
    from motiontwin.harness import kinematics

    return kinematics.cheung_inverse
