"""What no model can predict: the encoder noise and the process (force) noise, estimated from the data.

A correct model's free run differs from a recording by the encoder noise *and* by the closed loop's echo of
the forces nobody measured (process noise, coloured disturbances). Estimating the floor from encoder noise
alone makes it too low whenever such forces act, and every candidate then looks significant. The process
noise is estimated from the inverse-dynamics force residual of the refitted nominal model, after removing
everything that is a function of the motion (:func:`unpredictable_part`: least squares of the laws every axis
has, then cross-fitted nearest-neighbour means in the state); the force is never a regressor, since with the
acceleration it would rebuild the force noise itself. The spectrum of what is left, below the inverse-dynamics
filter's cut-off, is fitted as the sum of three shapes measured through the same filter: differentiated encoder
noise, white force noise held over each sample, and first-order coloured force noise (time constant chosen on a
grid). The result drives the bootstrap null (:func:`evidence.bootstrap_residuals`) and the validation floor
(:func:`structure.validation_floor`). Units: SI, in the plant's state coordinates (N or N.m, s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import optimize
from scipy import signal as sps
from scipy import spatial

from motiontwin.harness.recording import Recording
from motiontwin.ident import outputerror
from motiontwin.ident.channels import controller_relation
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.plant_roles import output_map
from motiontwin.ident.channels import noise_level
from motiontwin.ident.oeloop import Loop, Signals
from motiontwin.ident.startvalues import mirror_derivatives

#: time constants [s] tried for the coloured part: on the nominal model's residual, and (six per decade) on the
#: final model's
TAU_GRID = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)
RESOLVED_TAU_GRID = tuple(0.005 * 10 ** (k / 6) for k in range(13))
BANDS_PER_OCTAVE = 4    # the final model's residual spectrum is fitted over quarter-octave bands
NEIGHBOURS = 8
BACKFITTING = 3         # rounds of the least-squares laws and the neighbours' means fitted in turn
INERTIA_HARMONICS = 1   # the linear stage's mass varies along the stroke by this many harmonics
BLOCK = 0.25        # [s] time blocks of the cross-fitting (even blocks fit the odd ones, and back)


@dataclass(frozen=True)
class ProcessNoise:
    """Force noise acting on the plant's driven input: white per sample (held over the sample period) with
    standard deviation ``white`` plus first-order coloured noise of standard deviation ``coloured`` and
    time constant ``tau`` [s]. Zero when the data show none."""

    white: float = 0.0
    coloured: float = 0.0
    tau: float = 0.0

    @property
    def present(self) -> bool:
        return self.white > 0 or self.coloured > 0

    def sample(self, n: int, ts: float, rng: np.random.Generator) -> np.ndarray:
        """One realisation of ``n`` samples [N]."""
        out = self.white * rng.standard_normal(n)
        if self.coloured > 0:
            out = out + coloured(n, self.coloured, self.tau, ts, rng)
        return out

    def scaled(self, factor: float) -> "ProcessNoise":
        """The same spectrum with ``factor`` times the standard deviations."""
        return ProcessNoise(self.white * factor, self.coloured * factor, self.tau)

    def describe(self) -> str:
        if not self.present:
            return "none"
        return f"white {self.white:.3g}, coloured {self.coloured:.3g} (tau {self.tau:.3g} s)"

    def as_dict(self) -> dict[str, float]:
        return {"white_std": self.white, "coloured_std": self.coloured, "coloured_tau_s": self.tau}


def coloured(n: int, std: float, tau: float, ts: float, rng: np.random.Generator) -> np.ndarray:
    """First-order (AR(1)) noise of stationary standard deviation ``std`` and time constant ``tau``."""
    a = float(np.exp(-ts / tau))
    e = rng.standard_normal(n) * std * np.sqrt(1 - a * a)
    e[0] = rng.standard_normal() * std      # the first sample in the stationary distribution
    return sps.lfilter([1.0], [1.0, -a], e)


def unpredictable_part(force: np.ndarray, x: np.ndarray, v: np.ndarray, a: np.ndarray, ts: float) -> np.ndarray:
    """``force`` minus what the motion predicts of it, in two parts fitted in turn (backfitting, so that a
    large law does not bias the other part). The laws every axis has a share of, by least squares: linear
    in acceleration (a mass with ``INERTIA_HARMONICS`` harmonics along the stroke: the mass left by the
    refit, or one that varies along it), in velocity (damping), a constant and a Coulomb level; a handful
    of coefficients takes out a negligible share of the noise. Then any law of the state, cross-fitted (each
    half of the time blocks predicted from the other half, so the noise is not fitted away): by forward
    selection, the mean of the ``NEIGHBOURS`` nearest samples in the velocity (drag-like laws), in the
    position for the same direction of motion (ripple, a bump on the rail), or in (position, velocity,
    acceleration), each while it lowers the held-out power; where the motion never revisits a state the
    neighbours are far and their mean would add error instead. A neighbours' mean carries ``1/k`` of the
    noise variance, which is taken out. The force is not a feature: with the acceleration it would rebuild
    the force noise itself."""
    n = force.size
    block = (np.arange(n) * ts // BLOCK).astype(int) % 2
    halves = [(block != k, block == k) for k in (0, 1)]
    phase = np.pi * (x - x.min()) / max(float(np.ptp(x)), 1e-300)
    mass = [np.ones(n)] + [f(k * phase) for k in range(1, INERTIA_HARMONICS + 1) for f in (np.cos, np.sin)]
    laws = np.column_stack([a[:, None] * np.column_stack(mass), v, np.ones(n),
                            np.tanh(v / max(1e-3 * np.ptp(v), 1e-300))])
    span = [max(float(np.ptp(s)), 1e-300) for s in (x, v, a)]
    direction = np.sign(v) * 1e6      # never a neighbour across a reversal
    features = [np.column_stack([v / span[1] * 400]), np.column_stack([x / span[0] * 400, direction]),
                np.column_stack([x / span[0] * 400, v / span[1] * 40, a / span[2] * 20])]
    neighbours = [_neighbours(points, halves) for points in features]
    local = np.zeros(n)
    for _ in range(BACKFITTING):
        coef, *_ = np.linalg.lstsq(laws, force - local, rcond=None)
        linear = force - laws @ coef
        rest, chosen, remaining = linear, 0, list(neighbours)
        while remaining:
            trials = [_neighbour_residual(rest, near, halves) for near in remaining]
            k = int(np.argmin([np.mean(t ** 2) for t in trials]))
            if not np.mean(trials[k] ** 2) < np.mean(rest ** 2):
                break
            rest, chosen = trials[k], chosen + 1
            del remaining[k]
        local = linear - rest
    return rest * np.sqrt(NEIGHBOURS / (NEIGHBOURS + 1)) ** chosen


def _neighbours(points: np.ndarray, halves: list) -> list[np.ndarray]:
    """Per half (fit, use): the indices into the fit half of each used sample's ``NEIGHBOURS`` nearest in
    ``points`` (they depend on the points only: found once, reused by every backfitting round and selection
    step)."""
    return [spatial.cKDTree(points[fit]).query(points[use], k=NEIGHBOURS)[1] for fit, use in halves]


def _neighbour_residual(rest: np.ndarray, neighbours: list[np.ndarray], halves: list) -> np.ndarray:
    """``rest`` minus the mean of its ``NEIGHBOURS`` nearest samples from the other half (:func:`_neighbours`)."""
    out = np.array(rest)
    for (fit, use), idx in zip(halves, neighbours):
        out[use] = rest[use] - rest[fit][idx].mean(axis=1)
    return out


def estimate(force: np.ndarray, x: np.ndarray, v: np.ndarray, a: np.ndarray, input_gain: float, sigma_x: float,
             ts: float, cutoff: float, resolved: bool = False) -> ProcessNoise:
    """The process force noise in the inverse-dynamics force residual ``force`` [N] (computed with the force
    held over each sample, so no half-sample lag is left in it).

    x, v, a: the filtered motion the residual was computed from; input_gain: d(acceleration)/d(force) of the
    model [1/kg]; sigma_x: the encoder noise in the plant's position coordinates; cutoff: the
    inverse-dynamics low-pass [Hz]. The Welch spectrum of the unpredictable part is fitted (non-negative
    least squares, each point's error relative to its power) by three shapes, each the spectrum of a unit
    realisation passed through the same filter: the encoder noise differentiated twice, white force noise per
    sample, first-order coloured force noise (each time constant of the grid).

    ``resolved=False``, for the nominal model's residual, which still holds the force of the effects not yet
    found: each Welch bin weighs alike (nine in ten lie above a tenth of the cut-off, where that slow force
    hardly reaches) over ``TAU_GRID``. ``resolved=True``, for the final model's residual: the spectrum is
    averaged over bands of ``1/BANDS_PER_OCTAVE`` octave, each weighing alike, over ``RESOLVED_TAU_GRID``, so a
    slow noise is read at its level (per bin, 0.093 N at 20 ms for 0.18 N at 58 ms on an independent bundle;
    banded on a nominal residual, the slow force a missing load-dependent friction leaves on a real servo was
    read as 0.026 N.m of noise at 0.16 s, and the selection changed)."""
    e = unpredictable_part(force, x, v, a, ts)
    n, fs = e.size, 1 / ts
    nper = min(4096, n // 4)
    f, p_e = sps.welch(e, fs=fs, nperseg=nper)
    band = (f > 2 * fs / nper) & (f < 0.8 * cutoff)
    if np.count_nonzero(band) < 8:
        return ProcessNoise()
    groups = np.arange(np.count_nonzero(band))
    if resolved:
        groups = np.unique(np.floor(np.log2(f[band] / f[band][0]) * BANDS_PER_OCTAVE), return_inverse=True)[1]
    count = np.bincount(groups)
    rng = np.random.default_rng(12345)

    def banded(power: np.ndarray) -> np.ndarray:
        return np.bincount(groups, power[band]) / count

    def shape(series: np.ndarray, second: bool = False) -> np.ndarray:
        low, _, acc = mirror_derivatives(series, fs, cutoff)
        return banded(sps.welch(acc / input_gain if second else low, fs=fs, nperseg=nper)[1])

    encoder = shape(sigma_x * rng.standard_normal(n), second=True)
    white = shape(rng.standard_normal(n))
    target = banded(p_e)
    weight = 1 / np.maximum(target, 1e-300)
    best: tuple[float, ProcessNoise] | None = None
    for tau in RESOLVED_TAU_GRID if resolved else TAU_GRID:
        design = np.column_stack([encoder, white, shape(coloured(n, 1.0, tau, ts, rng))]) * weight[:, None]
        coef, res = optimize.nnls(design, np.ones_like(target))
        if best is None or res < best[0]:
            best = (res, ProcessNoise(float(np.sqrt(coef[1])), float(np.sqrt(coef[2])),
                                      tau if coef[2] > 0 else 0.0))
    return best[1]


def with_force_noise(rec: Recording, w: np.ndarray, disturbance: str = Signals().disturbance) -> Recording:
    """``rec`` with the force ``w`` added to its disturbance column (created when absent)."""
    base = rec.columns.get(disturbance, np.zeros(rec.time.size))
    return Recording(rec.time, {**rec.columns, disturbance: np.asarray(base, float) + w}, rec.units, rec.meta)


def within_residual(process: ProcessNoise, encoder_floor: float, with_process: float,
                    residual_rms: float) -> ProcessNoise:
    """``process`` scaled down so that the noise it predicts on the training recording (``with_process``, the
    floor with encoder and process noise; ``encoder_floor``, with encoder noise alone) is no more than the
    final model's training residual ``residual_rms``: noise cannot leave more residual than a fitted model
    has. Structure a regression of the motion could not fit away (a law at the motion's own harmonics) is
    taken for process noise at first; once the final model explains it, this bound removes it again. The
    floor's power is the sum of both parts, so the process part scales with the square of the factor."""
    excess = with_process ** 2 - encoder_floor ** 2
    if not process.present or with_process <= residual_rms or excess <= 0:
        return process
    return process.scaled(float(np.sqrt(max(residual_rms ** 2 - encoder_floor ** 2, 0.0) / excess)))


def held_force(inv: evidence.InverseDynamics, input_gain: float, ts: float) -> np.ndarray:
    """The force residual with the acceleration taken as the central second difference of the filtered
    position (:func:`evidence.central_acceleration`), exact for the held-input mean the inverse dynamics uses. The
    spectral derivative differs from it by up to 2 % at
    the cut-off, and the controller's broadband force (its derivative action on encoder noise) would turn
    that difference into a force noise no one applied."""
    return inv.force + (inv.a - evidence.central_acceleration(inv.x, inv.a, ts)) / input_gain


def of_bundle(bundle: Bundle, values: dict[str, float], sigma_q: float, resolved: bool = False) -> ProcessNoise:
    """The process noise of a single-axis bundle's training recording under the refitted nominal plant
    (``values``); ``sigma_q``: the encoder noise in the measured unit; ``resolved``: as :func:`estimate`."""
    plant = bundle.plant
    gain, offset = output_map(plant.model, plant.roles, values)
    rec = Recording(bundle.train.time, {**bundle.train.columns, "q": (bundle.train["q"] - offset) / gain})
    inputs = [v.name for v in plant.model.inputs]
    inv = evidence.inverse_dynamics(rec, plant.model, values, plant.position_state, plant.velocity_state,
                                    bundle.controller.sample_time, inputs.index(plant.input_name), held_input=True)
    if inv is None:
        return ProcessNoise()
    ts = bundle.controller.sample_time
    input_gain = 1 / evidence.mass_equivalent(plant.model, values, plant.velocity_state,
                                              inputs.index(plant.input_name))
    return estimate(held_force(inv, input_gain, ts), inv.x, inv.v, inv.a, input_gain, sigma_q / abs(gain), ts,
                    inv.cutoff, resolved)


def force_measurement(loop: Loop, rec: Recording) -> float:
    """Standard deviation of the recorded force's own measurement noise [N] (a drive's current reading; zero
    for a recorded command): the white part of what the controller's relation on the recorded signals leaves
    (recorded force minus u_ext minus the controller's output on the recorded r and q, from a zero start; the
    start transient is slow and outside the band the level is read in). One axis with a known controller."""
    relation, _ = controller_relation(loop.controller, rec, loop.channels, np.zeros(loop.controller.n_states))
    return noise_level(relation, loop.controller.sample_time)


#: the process noise of one axis, or of each axis of a multi-axis loop (in its axes' order)
Process = ProcessNoise | tuple[ProcessNoise, ...]


def present(process: Process | None) -> bool:
    """Whether ``process`` holds any force noise (on any axis)."""
    if process is None:
        return False
    return any(p.present for p in process) if isinstance(process, tuple) else process.present


def noisy_simulator(loop: Loop, rec: Recording, values: dict[str, float], process: Process | None,
                    shift: np.ndarray | None = None,
                    ) -> Callable[[np.ndarray, np.random.Generator], tuple[np.ndarray, np.ndarray]]:
    """(encoder noise, rng) -> the loop's (q, u) re-simulated along ``rec`` with that encoder noise fed back
    and a fresh realisation of ``process`` acting on the plant (several axes: a tuple, one per axis, each on its
    axis's input), from the controller start ``shift`` (the fit's, so that a replicate differs from the fitted
    free run by the noise alone). The returned u is the force the controller commanded (the process noise is not
    in a recorded force)."""
    per_channel = process if isinstance(process, tuple) else (process,)
    if present(process) and len(per_channel) != len(loop.channels):
        raise ValueError(f"process noise for {len(per_channel)} axes, the loop has {len(loop.channels)}")

    def simulate(noise: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        if not present(process):
            return outputerror.simulate(loop, rec, values, noise=noise, shift=shift)
        w = np.array([p.sample(rec.time.size, loop.ts, rng) for p in per_channel])
        noisy = rec
        for k, sig in enumerate(loop.channels):
            noisy = with_force_noise(noisy, w[k], sig.disturbance)
        q, u = outputerror.simulate(loop, noisy, values, noise=noise, shift=shift)
        return q, u - w.reshape(np.shape(u))
    return simulate


#: order of the autoregressive model of each channel's residual whose inverse whitens it
WHITENING_ORDER = 20
WHITENING_REPLICATES = 2


def _prediction_error_filter(series: list[np.ndarray], order: int) -> tuple[np.ndarray, float, float] | None:
    """Yule-Walker autoregressive model of order ``order`` of the series together: its prediction-error
    filter [1, -a_1, ..., -a_p], the standard deviation of its innovations and the ratio of the series' RMS to
    that (how coloured they are). None when the series are not finite or hold no variance."""
    acf, total = np.zeros(order + 1), 0
    for x in series:
        if not np.all(np.isfinite(x)):
            return None
        x = x - np.mean(x)
        acf += [x[:x.size - k] @ x[k:] for k in range(order + 1)]
        total += x.size
    acf /= max(total, 1)
    if not acf[0] > 0:
        return None
    toeplitz = acf[np.abs(np.subtract.outer(np.arange(order), np.arange(order)))]
    a = np.linalg.solve(toeplitz, acf[1:])
    innovation = float(acf[0] - a @ acf[1:])
    if not innovation > 0:
        return None
    return np.concatenate([[1.0], -a]), math.sqrt(innovation), math.sqrt(acf[0] / innovation)


def whitening(loop: Loop, rec: Recording, values: dict[str, float], process: ProcessNoise | None, sigma_q: float,
              sigma_u: float, shift: np.ndarray | None = None, order: int = WHITENING_ORDER,
              count: int = WHITENING_REPLICATES, seed: int = 0) -> tuple[np.ndarray | None, np.ndarray | None,
                                                                           float, float]:
    """The taps (``outputerror.Weights.whiten_q``/``whiten_u``) that whiten the output and force residuals of a
    correct model of this one-axis loop: an autoregressive model (:func:`_prediction_error_filter`) of each
    channel's residual over ``count`` replicates of the loop at ``values`` re-simulated with the estimated encoder
    noise ``sigma_q`` and process noise (:func:`evidence.bootstrap_residuals`, the bootstrap null's draws), its
    prediction-error filter scaled so that the whitened residual over sigma is unit white noise; and each
    channel's ratio of the residual's RMS to its innovations'. Why: the closed loop's echo of process noise and of
    the encoder noise it feeds back makes the output residual slow and several times the encoder noise, and a
    least-squares fit that weights it as white spends its weight on that echo (:mod:`polish`). From the noise
    estimate, not from the model's own residual, into whose noise model a missing effect would leak. A channel
    whose residual holds no variance keeps None."""
    q_model, u_model = outputerror.simulate(loop, rec, values, shift=shift)
    n = rec.time.size
    replicates = evidence.bootstrap_residuals(noisy_simulator(loop, rec, values, process, shift), q_model, u_model,
                                              sigma_q, sigma_u, n, count, seed=seed)   # over sigma already
    taps, ratios = [], []
    for series in ([row[:n] for row in replicates], [row[n:] for row in replicates]):
        model = _prediction_error_filter(series, order)
        taps.append(None if model is None else model[0] / model[1])
        ratios.append(math.nan if model is None else model[2])
    return taps[0], taps[1], ratios[0], ratios[1]
