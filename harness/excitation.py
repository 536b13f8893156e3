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

Experiment files (TOML, read by :func:`load_experiment`)::

    name = "swept_sine_80_500"           # optional, default: file stem
    description = "free text"            # optional
    sample_time = 0.0005                 # [s], required
    duration = 2.0                       # [s], required except for kind "fourier" (n_periods / f_fundamental)
    target = "u_ext"                     # optional: the port this excitation drives

    [excitation]
    kind = "swept_sine"                  # one of EXCITATION_KINDS
    f_start = 80.0                       # the kind's fields, listed in EXCITATION_KINDS
    ...

Kinds and their ``[excitation]`` fields (defaults in brackets; "numbers" = a number, or a list per axis)::

    point_to_point               start, end (numbers), move_time, t0 [0]
    end_effector_point_to_point  pose_start, pose_end ([x, y, z, theta] in m, rad), move_time, t0 [0]
    fourier                      f_fundamental, n_periods (integer), a, b (lists, or lists of per-axis lists),
                                 q0 [0]
    bang_bang                    positions (list), max_velocity, max_acceleration, dwell [0], t0 [0]
    swept_sine                   f_start, f_end, sweep_time, amplitude, method ["linear"], t0 [0], ramp_time [0]
    multisine                    f_resolution, harmonics (integers), amplitude, phases ["schroeder"], seed [none]
    prbs                         n_bits, clock_period, amplitude, seed, offset [0], t0 [0]
    step                         t_step, amplitude, initial [0]

The time grid is ``t = k * sample_time`` for ``k = 0 .. round(duration / sample_time) - 1``, so N periods of a
periodic excitation hold exactly N * period / sample_time samples. Unknown kinds, missing or unknown fields and
wrongly typed values raise :class:`ExperimentError` naming the file and the field.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np
import scipy.signal

from motiontwin.fmus.limits import check_memory, load_toml
from motiontwin.harness.numbers import is_finite_number as is_number
from motiontwin.harness.numbers import is_integer
from motiontwin.harness.system import check_run_length

if TYPE_CHECKING:
    from motiontwin.harness.recording import Recording

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


def _time(t: ArrayLike) -> np.ndarray:
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
    t = _time(t)
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
    t = _time(t)
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
    phase = np.multiply.outer(_time(t), w)
    sin, cos = np.sin(phase), np.cos(phase)
    return FourierBasis(position=np.hstack([sin / w, -cos / w]), velocity=np.hstack([cos, sin]),
                        acceleration=np.hstack([-sin * w, cos * w]), jerk=np.hstack([-cos * w**2, -sin * w**2]))


def fourier_trajectory(
    t: ArrayLike, f_fundamental: float, a: ArrayLike, b: ArrayLike, q0: ArrayLike = 0.0
) -> Profile:
    """Periodic finite Fourier series trajectory (:func:`fourier_basis`) and its analytic derivatives.

    a, b: shape (L,) for one axis or (L, n_axes); harmonic l = 1..L. The trajectory repeats every 1/f_fundamental.
    """
    t = _time(t)
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
    t = _time(t)
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
    t = _time(t)
    sequence = max_length_sequence(n_bits, seed)
    index = np.floor((t - t0) / clock_period + 1e-9).astype(np.int64)
    value = offset + amplitude * sequence[np.mod(index, sequence.size)]
    return np.where(index >= 0, value, offset)


def step(t: ArrayLike, t_step: float, amplitude: float, initial: float = 0.0) -> np.ndarray:
    """``initial`` before ``t_step`` [s], ``initial + amplitude`` from then on."""
    t = _time(t)
    return np.where(t >= t_step, initial + amplitude, initial)


def bang_bang_move(
    t: ArrayLike, distance: float, max_velocity: float, max_acceleration: float, t0: float = 0.0, start: float = 0.0
) -> Profile:
    """Rest-to-rest move with bang-bang acceleration (+a, coast, -a): a trapezoidal (or triangular) velocity.

    The jerk is a sum of Dirac impulses at the switching instants; the returned jerk is zero between them.
    """
    if max_velocity <= 0 or max_acceleration <= 0:
        raise ValueError("max_velocity and max_acceleration must be positive")
    t = _time(t)
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
    t = _time(t)
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


# ---------------------------------------------------------------- experiment files


class ExperimentError(ValueError):
    """An experiment file is invalid; the message names the file and the field."""


@dataclass(frozen=True)
class _Field:
    kind: str  # "number", "integer", "string", "numbers" (a number or nested lists), "integers"
    default: Any = None
    required: bool = True


def _req(kind: str) -> _Field:
    return _Field(kind)


def _opt(kind: str, default: Any) -> _Field:
    return _Field(kind, default, required=False)


#: Fields of each excitation kind: name -> (type, default); fields without default are required.
EXCITATION_KINDS: dict[str, dict[str, _Field]] = {
    "point_to_point": {
        "start": _req("numbers"),
        "end": _req("numbers"),
        "move_time": _req("number"),
        "t0": _opt("number", 0.0),
    },
    "end_effector_point_to_point": {
        "pose_start": _req("numbers"),
        "pose_end": _req("numbers"),
        "move_time": _req("number"),
        "t0": _opt("number", 0.0),
    },
    "swept_sine": {
        "f_start": _req("number"),
        "f_end": _req("number"),
        "sweep_time": _req("number"),
        "amplitude": _req("number"),
        "method": _opt("string", "linear"),
        "t0": _opt("number", 0.0),
        "ramp_time": _opt("number", 0.0),
    },
    "fourier": {
        "f_fundamental": _req("number"),
        "n_periods": _req("integer"),
        "a": _req("numbers"),
        "b": _req("numbers"),
        "q0": _opt("numbers", 0.0),
    },
    "multisine": {
        "f_resolution": _req("number"),
        "harmonics": _req("integers"),
        "amplitude": _req("numbers"),
        "phases": _opt("string", "schroeder"),
        "seed": _opt("integer", None),
    },
    "prbs": {
        "n_bits": _req("integer"),
        "clock_period": _req("number"),
        "amplitude": _req("number"),
        "seed": _req("integer"),
        "offset": _opt("number", 0.0),
        "t0": _opt("number", 0.0),
    },
    "step": {"t_step": _req("number"), "amplitude": _req("number"), "initial": _opt("number", 0.0)},
    "bang_bang": {
        "positions": _req("numbers"),
        "max_velocity": _req("number"),
        "max_acceleration": _req("number"),
        "dwell": _opt("number", 0.0),
        "t0": _opt("number", 0.0),
    },
}

#: Kinds that produce a Profile (position and derivatives); the others produce one signal ``value``.
# Peak memory per generated value (arrays, the recording and its CSV text): 2e6 samples x 2 columns of a swept
# sine raised the peak RSS of `motiontwin excite` by 162 MB, 40 B per value (/usr/bin/time -v); 64 B leaves margin.
BYTES_PER_VALUE = 64
TRAJECTORY_KINDS = ("point_to_point", "end_effector_point_to_point", "fourier", "bang_bang")
_TOP_FIELDS = {"name", "description", "sample_time", "duration", "target", "excitation"}


@dataclass
class Experiment:
    """An excitation experiment read from a TOML file (see the module docstring for the format).

    parameters: the ``[excitation]`` fields with defaults filled in (without ``kind``).
    """

    name: str
    kind: str
    sample_time: float
    duration: float
    parameters: dict[str, Any]
    target: str | None = None
    description: str = ""
    source: Path | None = None

    def time_grid(self) -> np.ndarray:
        """``k * sample_time`` for k = 0 .. round(duration / sample_time) - 1 [s]."""
        return np.arange(round(self.duration / self.sample_time)) * self.sample_time

    def generate(self, inverse_kinematics: Callable[[np.ndarray], np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Sample the excitation: ``time`` plus ``position/velocity/acceleration/jerk`` (trajectory kinds) or
        ``value`` (signal kinds: swept_sine, multisine, prbs, step)."""
        return generate_excitation(self.kind, self.parameters, self.time_grid(), inverse_kinematics)


def experiment_recording(
    experiment: Experiment, inverse_kinematics: Callable[[np.ndarray], np.ndarray] | None = None
) -> Recording:
    """The sampled excitation as a :class:`harness.recording.Recording` (e.g. to store or inspect it).

    Columns: ``position``, ``velocity``, ``acceleration``, ``jerk`` (trajectory kinds; ``position_1`` ..
    ``position_n`` for several axes) or ``value``; ``excited`` holds the kind, target and parameters.
    """
    from motiontwin.harness.recording import make_recording

    samples = round(experiment.duration / experiment.sample_time)
    columns_estimate = (1 + 4 * (6 if experiment.kind.startswith("end_effector") else 1)
                        if experiment.kind in TRAJECTORY_KINDS else 2)
    check_memory(f"{experiment.source or experiment.name}: {samples} samples x {columns_estimate} columns",
                 samples * columns_estimate * BYTES_PER_VALUE, ExperimentError)
    signals = experiment.generate(inverse_kinematics)
    time = signals.pop("time")
    columns: dict[str, np.ndarray] = {}
    for name, values in signals.items():
        if values.ndim == 1:
            columns[name] = values
        else:
            columns.update({f"{name}_{k + 1}": values[:, k] for k in range(values.shape[1])})
    return make_recording(
        time,
        columns,
        units={name: "" for name in columns},
        sample_time=experiment.sample_time,
        excited={"kind": experiment.kind, "target": experiment.target, "parameters": experiment.parameters},
        seed=experiment.parameters.get("seed"),
        metadata={
            "experiment": experiment.name,
            "source": str(experiment.source),
            "description": experiment.description,
        },
    )


def generate_excitation(
    kind: str,
    parameters: dict[str, Any],
    t: ArrayLike,
    inverse_kinematics: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Sample excitation ``kind`` with ``parameters`` on ``t``; see :meth:`Experiment.generate` for the keys."""
    t = _time(t)
    p = parameters
    if kind == "point_to_point":
        if np.shape(p["start"]) != np.shape(p["end"]):
            raise ValueError(f"start {p['start']} and end {p['end']} must have the same length")
        return quintic_point_to_point(t, p["start"], p["end"], p["move_time"], p["t0"]).as_dict()
    if kind == "end_effector_point_to_point":
        return end_effector_point_to_point(
            t, p["pose_start"], p["pose_end"], p["move_time"], p["t0"], inverse_kinematics
        ).as_dict()
    if kind == "fourier":
        return fourier_trajectory(t, p["f_fundamental"], p["a"], p["b"], p["q0"]).as_dict()
    if kind == "bang_bang":
        profile = bang_bang_sequence(t, p["positions"], p["max_velocity"], p["max_acceleration"], p["dwell"], p["t0"])
        return profile.as_dict()
    if kind == "swept_sine":
        keys = ("f_start", "f_end", "sweep_time", "amplitude", "method", "t0", "ramp_time")
        return {"time": t, "value": swept_sine(t, *(p[k] for k in keys))}
    if kind == "multisine":
        value = multisine(t, p["f_resolution"], p["harmonics"], p["amplitude"], p["phases"], p["seed"])
        return {"time": t, "value": value}
    if kind == "prbs":
        keys = ("n_bits", "clock_period", "amplitude", "seed", "offset", "t0")
        return {"time": t, "value": prbs(t, *(p[k] for k in keys))}
    if kind == "step":
        return {"time": t, "value": step(t, p["t_step"], p["amplitude"], p["initial"])}
    raise ValueError(f"unknown excitation kind {kind!r}; known kinds: {sorted(EXCITATION_KINDS)}")


def _check_type(value: Any, spec: _Field, where: str) -> Any:
    def nested_numbers(v: Any) -> bool:
        return is_number(v) or (isinstance(v, list) and len(v) > 0 and all(nested_numbers(x) for x in v))

    ok = {
        "number": is_number(value),
        "integer": is_integer(value),
        "string": isinstance(value, str),
        "numbers": nested_numbers(value),
        "integers": isinstance(value, list) and len(value) > 0 and all(is_integer(v) for v in value),
    }[spec.kind]
    if not ok:
        wanted = {
            "number": "a finite number",
            "integer": "an integer",
            "string": "a string",
            "numbers": "a finite number or a (nested) list of finite numbers",
            "integers": "a non-empty list of integers",
        }[spec.kind]
        raise ExperimentError(f"{where} must be {wanted}, got {value!r}")
    return float(value) if spec.kind == "number" else value


def parse_experiment(doc: dict[str, Any], source: str | os.PathLike = "<experiment>") -> Experiment:
    """Validate a parsed TOML document and build an :class:`Experiment`; errors name ``source`` and the field."""
    src = str(source)
    unknown = sorted(set(doc) - _TOP_FIELDS)
    if unknown:
        raise ExperimentError(f"{src}: unknown field {unknown[0]!r}; allowed top-level fields: {sorted(_TOP_FIELDS)}")
    section = doc.get("excitation")
    if not isinstance(section, dict):
        raise ExperimentError(f"{src}: missing table [excitation] (with a field 'kind')")
    kind = section.get("kind")
    if kind is None:
        raise ExperimentError(f"{src}: field 'excitation.kind' missing; known kinds: {sorted(EXCITATION_KINDS)}")
    if kind not in EXCITATION_KINDS:
        known = sorted(EXCITATION_KINDS)
        raise ExperimentError(f"{src}: field 'excitation.kind' = {kind!r} is unknown; known kinds: {known}")
    schema = EXCITATION_KINDS[kind]
    for name in section:
        if name != "kind" and name not in schema:
            fields = sorted(schema)
            raise ExperimentError(f"{src}: field 'excitation.{name}' is unknown for kind {kind!r}; fields: {fields}")
    parameters: dict[str, Any] = {}
    for name, spec in schema.items():
        if name in section:
            parameters[name] = _check_type(section[name], spec, f"{src}: field 'excitation.{name}'")
        elif spec.required:
            raise ExperimentError(f"{src}: field 'excitation.{name}' missing (required for kind {kind!r})")
        else:
            parameters[name] = spec.default
    if "sample_time" not in doc:
        raise ExperimentError(f"{src}: field 'sample_time' missing")
    sample_time = _check_type(doc["sample_time"], _req("number"), f"{src}: field 'sample_time'")
    if sample_time <= 0:
        raise ExperimentError(f"{src}: field 'sample_time' must be positive, got {sample_time}")
    if kind == "fourier":
        if "duration" in doc:
            raise ExperimentError(f"{src}: field 'duration' not allowed for kind 'fourier' (n_periods sets it)")
        if parameters["f_fundamental"] <= 0 or parameters["n_periods"] < 1:
            raise ExperimentError(
                f"{src}: fields 'excitation.f_fundamental' and 'excitation.n_periods' must be positive"
            )
        try:
            grid = periodic_time_grid(1 / parameters["f_fundamental"], parameters["n_periods"], sample_time)
        except ValueError as exc:
            raise ExperimentError(f"{src}: field 'excitation.f_fundamental': {exc}") from None
        duration = grid.size * sample_time
    else:
        if "duration" not in doc:
            raise ExperimentError(f"{src}: field 'duration' missing")
        duration = _check_type(doc["duration"], _req("number"), f"{src}: field 'duration'")
        if duration < sample_time:
            raise ExperimentError(f"{src}: field 'duration' ({duration} s) is shorter than sample_time")
        try:
            check_run_length(0.0, duration, sample_time, "field 'duration'")
        except ValueError as exc:
            raise ExperimentError(f"{src}: {exc}") from None
    for name in ("name", "description", "target"):
        if name in doc and not isinstance(doc[name], str):
            raise ExperimentError(f"{src}: field {name!r} must be a string, got {doc[name]!r}")
    experiment = Experiment(
        name=doc.get("name", Path(src).stem),
        kind=kind,
        sample_time=sample_time,
        duration=duration,
        parameters=parameters,
        target=doc.get("target"),
        description=doc.get("description", ""),
        source=Path(src),
    )
    try:
        generate_excitation(kind, parameters, np.array([0.0]), _deferred_kinematics)
    except _KinematicsDeferred:
        pass
    except (ValueError, TypeError) as exc:
        raise ExperimentError(f"{src}: [excitation] of kind {kind!r}: {exc}") from None
    return experiment


class _KinematicsDeferred(Exception):
    """Raised by the placeholder used to validate end-effector experiments without running kinematics."""


def _deferred_kinematics(pose: np.ndarray) -> np.ndarray:
    raise _KinematicsDeferred


def load_experiment(path: str | os.PathLike) -> Experiment:
    """Read and validate an experiment TOML file; raises ExperimentError naming the file and the field."""
    path = Path(path)
    return parse_experiment(load_toml(path, ExperimentError)[0], path)


def fourier_experiment_text(
    name: str,
    sample_time: float,
    f_fundamental: float,
    n_periods: int,
    a: Sequence[float],
    b: Sequence[float],
    q0: float = 0.0,
    *,
    description: str = "",
    target: str | None = None,
    comments: Sequence[str] = (),
    source: str | os.PathLike = "<experiment>",
) -> str:
    """An experiment file (TOML) of kind ``fourier`` that :func:`load_experiment` reads back to the same values.

    ``comments`` become leading ``#`` lines (provenance: criterion, metrics). Raises ExperimentError naming
    ``source`` and the field when the values do not make a valid experiment (e.g. a period that is not a
    whole number of samples).
    """
    def number(x: float) -> str:
        value = float(x)
        if not math.isfinite(value):
            raise ExperimentError(f"{source}: non-finite value {value!r} in the Fourier experiment")
        return repr(value)

    def string(text: str) -> str:
        return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ") + '"'

    lines = [f"# {line}" for line in comments]
    lines += [f"name = {string(name)}"]
    if description:
        lines.append(f"description = {string(description)}")
    lines.append(f"sample_time = {number(sample_time)}")
    if target:
        lines.append(f"target = {string(target)}")
    lines += ["", "[excitation]", 'kind = "fourier"', f"f_fundamental = {number(f_fundamental)}",
              f"n_periods = {int(n_periods)}", "a = [" + ", ".join(number(x) for x in a) + "]",
              "b = [" + ", ".join(number(x) for x in b) + "]", f"q0 = {number(q0)}"]
    text = "\n".join(lines) + "\n"
    parse_experiment(tomllib.loads(text), source)
    return text


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
