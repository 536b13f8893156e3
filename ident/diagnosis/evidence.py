"""Evidence for the decision: noise levels, inverse-dynamics force residuals, where the residual sits
(time windows, velocity, position, frequency) and the noise-aware significance test.

The significance test is a parametric bootstrap of the current (fitted) model: the loop is re-simulated
with white measurement noise of the estimated level fed back through the controller, and each candidate's
improvement of the weighted cost is read the same way it is on the data, linearised at the candidate's
optimum (projection of the bootstrap residual onto the candidate's and the current model's Jacobians).
A candidate is significant when its improvement exceeds the 99.9 % quantile of that null distribution; it is
kept when it passes the validation rule too (:func:`validation_accepts`: position, or recorded force).
Units: SI (s, m, N, Hz).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from scipy import signal as sps
from scipy import stats

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import channels
from motiontwin.ident.startvalues import derivative_cutoff, mirror_derivatives

if TYPE_CHECKING:
    from motiontwin.ident.diagnosis.axis_units import AxisUnits
    from motiontwin.ident import outputerror

NULL_QUANTILE = 0.999
VALIDATION_GAIN = 0.9        # an effect must reduce the validation RMS by at least 10 %
#: standard deviation of the white part of a residual (median PSD over the upper half band)
noise_level = channels.noise_level


@dataclass
class InverseDynamics:
    """Filtered x, v, a [m, m/s, m/s^2], du/dt [N/s] and the force the nominal model leaves unexplained [N];
    ``u``: the filtered applied force [N] the residual was computed with."""

    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    udot: np.ndarray
    force: np.ndarray
    cutoff: float
    u: np.ndarray | None = None


def held_mean(u: np.ndarray) -> np.ndarray:
    """The force acting around each sample when the recorded one was held over each period (zero-order hold): the
    mean of samples k-1 and k."""
    u = np.asarray(u, float)
    return 0.5 * (np.concatenate([u[:1], u[:-1]]) + u)


def central_acceleration(x: np.ndarray, a: np.ndarray, ts: float) -> np.ndarray:
    """``a`` with its inner samples replaced by the central second difference of ``x`` (along the last axis): for a
    force held over each sample, x[k+1] - 2 x[k] + x[k-1] = ts^2/m (u[k-1] + u[k])/2 exactly (:func:`held_mean`)."""
    out = np.array(a, float)
    out[..., 1:-1] = (x[..., 2:] - 2 * x[..., 1:-1] + x[..., :-2]) / ts ** 2
    return out


def inverse_dynamics(rec: Recording, model: symbolic.SymbolicModel, values: dict[str, float],
                     position_state: str, velocity_state: str, ts: float,
                     input_index: int = 0, held_input: bool = False,
                     states: np.ndarray | None = None) -> InverseDynamics | None:
    """Force residual u - (force the nominal model needs for the measured motion) (``input_index``: the driven
    input; the others are held at 0). ``held_input``: the recorded force was held over each sample (zero-order
    hold), so the force acting around sample k is the mean of samples k-1 and k; without this the half-sample
    lag leaves a residual proportional to du/dt (large under a swept sine) that hides small force laws.

    ``states``: the model's state trajectory (``model.states`` x samples, e.g. its free run,
    :func:`outputerror.simulate_states`) for a model with more than the two motion states (delay, load,
    bristle, drift states): the filtered measured position and velocity replace their rows, the other rows are
    low-passed by the same filter. Without it a model of more than two states gives None.

    The residual is a force at the plant's input, where an effect's force enters (``plant.<input> = u - ... -
    F``): (a_model - a) divided by d(acc)/du at zero command, which is the plant's force gain with any mass an
    effect adds (a load behind backlash, a position-dependent inertia), since the effects that shape the
    command pass a small command through with unit gain (the Pade delay's direct feedthrough u - delay_s, the
    saturation's unit slope); at the recorded command a saturated force would have a vanishing gain. None when
    the acceleration does not respond to the input directly (no finite non-zero gain)."""
    if states is None and model.x.numel() != 2:
        return None
    fs = 1 / ts
    fc = derivative_cutoff(fs)
    x, v, a = mirror_derivatives(rec["q"], fs, fc)
    u = np.asarray(rec["u"], float)
    if held_input:
        u = held_mean(u)
    u_f, udot, _ = mirror_derivatives(u, fs, fc)
    names = [s.name for s in model.states]
    i_x, i_v = names.index(position_state), names.index(velocity_state)
    p = np.array([values[s.name] for s in model.parameters])
    acc = model.dx[i_v]
    fn = ca.Function("acc", [model.x, model.u, model.p], [acc, ca.jacobian(acc, model.u[input_index])]).map(x.size)
    full = np.zeros((model.x.numel(), x.size))
    if states is not None:
        full = np.array([mirror_derivatives(row, fs, fc)[0] for row in np.asarray(states, float)])
    full[i_x], full[i_v] = x, v
    inputs = np.zeros((model.u.numel(), x.size))
    inputs[input_index] = u_f
    a_model = np.array(fn(full, inputs, p)[0]).ravel()
    gain = np.array(fn(full, np.zeros_like(inputs), p)[1]).ravel()
    if not np.all(np.isfinite(gain)) or np.any(gain == 0):
        return None
    force = (a_model - a) / gain
    return InverseDynamics(x, v, a, udot, force, fc, u_f)


def mass_equivalent(model: symbolic.SymbolicModel, values: dict[str, float], velocity_state: str,
                    input_index: int = 0) -> float:
    """1 / (d velocity' / d force) at rest [kg or kg.m2 in the plant's coordinates]."""
    i_v = [s.name for s in model.states].index(velocity_state)
    gain = ca.Function("g", [model.x, model.u, model.p], [ca.jacobian(model.dx[i_v], model.u[input_index])])
    p = np.array([values[s.name] for s in model.parameters])
    return float(1 / np.array(gain(np.zeros(model.x.numel()), np.zeros(model.u.numel()), p)).item())


def flagged_windows(residual: np.ndarray, time: np.ndarray, sigma: float, ts: float,
                    width: float = 0.1) -> list[tuple[float, float]]:
    """Time windows where the moving RMS of the residual exceeds 3 noise levels (merged, in s)."""
    n = max(3, int(round(width / ts)))
    ms = np.convolve(residual ** 2, np.ones(n) / n, mode="same")
    hot = np.sqrt(ms) > 3 * sigma
    windows: list[tuple[float, float]] = []
    start = None
    for i, h in enumerate(hot):
        if h and start is None:
            start = i
        if (not h or i == hot.size - 1) and start is not None:
            windows.append((float(time[start]), float(time[i])))
            start = None
    return windows


def spectrum(residual: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectral density of a residual (Welch), frequencies in Hz."""
    f, pxx = sps.welch(residual - np.mean(residual), fs=1 / ts, nperseg=min(2048, residual.size))
    return f, np.sqrt(pxx)


def resonance_guesses(residual: np.ndarray, ts: float, count: int = 3) -> list[float]:
    """Frequencies [Hz] of the strongest narrow peaks of a residual spectrum above 20 Hz."""
    f, asd = spectrum(residual, ts)
    keep = (f > 20) & (f < 0.45 / ts)
    f, asd = f[keep], asd[keep]
    if f.size < 5:
        return []
    base = sps.medfilt(asd, 31 if asd.size > 31 else (asd.size // 2) * 2 - 1)
    ratio = asd / np.maximum(base, 1e-300)
    peaks, _ = sps.find_peaks(ratio, distance=5)
    order = peaks[np.argsort(ratio[peaks])[::-1]]
    return [float(f[i]) for i in order[:count]]


def locate(residual: np.ndarray, v: np.ndarray, x: np.ndarray, ts: float) -> dict[str, object]:
    """Where a residual concentrates: velocity and position bins with the largest mean |residual|, and
    the frequency band holding the most residual power."""
    out: dict[str, object] = {}
    for name, axis in (("velocity", v), ("position", x)):
        edges = np.quantile(axis, np.linspace(0, 1, 11))
        idx = np.clip(np.searchsorted(edges, axis, side="right") - 1, 0, 9)
        level = np.array([np.sqrt(np.mean(residual[idx == b] ** 2)) if np.any(idx == b) else 0 for b in range(10)])
        b = int(np.argmax(level))
        out[f"{name}_range"] = [float(edges[b]), float(edges[b + 1])]
    f, asd = spectrum(residual, ts)
    power = asd ** 2
    i = int(np.argmax(power[1:])) + 1
    out["frequency_peak_hz"] = float(f[i])
    return out


def bootstrap_residuals(simulate_noisy, q_model: np.ndarray, u_model: np.ndarray, sigma_q: float,
                        sigma_u: float, n: int, count: int, seed: int = 0) -> np.ndarray:
    """``count`` weighted residual vectors of the fitted model re-simulated with white measurement noise
    (a multi-axis loop: one noise level per axis, arrays ``sigma_q``/``sigma_u``; rows channel-major).
    ``simulate_noisy(noise, rng)`` returns (q, u); it may add process noise of its own (:mod:`noise`)."""
    rng = np.random.default_rng(seed)
    out = []
    per_axis = np.ndim(sigma_q) > 0
    s_q = np.reshape(sigma_q, (-1, 1)) if per_axis else sigma_q
    s_u = np.reshape(sigma_u, (-1, 1)) if per_axis else sigma_u
    for _ in range(count):
        noise = rng.normal(0.0, 1.0, (np.size(sigma_q), n)) * s_q if per_axis else rng.normal(0.0, sigma_q, n)
        q, u = simulate_noisy(noise, rng)
        out.append(np.concatenate([((q + noise - q_model) / s_q).ravel(), ((u - u_model) / s_u).ravel()]))
    return np.array(out)


def consistent_null(null: np.ndarray, fitted_cost: float) -> tuple[np.ndarray, float]:
    """The bootstrap residual replicates ``null`` (rows) scaled so that their mean cost is at most the cost the
    model leaves on the data (``fitted_cost``), and the factor applied to that cost (1: none). Noise cannot leave
    more residual than a fitted model has: where the replicates do, the model's closed loop echoes the noise more
    than the data shows (a mass a twentieth of the true one, taken up by a missing friction, echoes the encoder
    noise 9x more), or the noise estimate holds structure; a null drawn from it would hide every effect."""
    cost = float(np.mean(np.sum(null ** 2, axis=1)))
    factor = min(1.0, fitted_cost / cost) if cost > 0 and math.isfinite(fitted_cost) else 1.0
    return null * math.sqrt(factor), factor


def _basis(jac: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the column space of ``jac`` (columns scaled to unit norm; dependent ones dropped)."""
    if jac.shape[1] == 0:
        return np.zeros((jac.shape[0], 0))
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1
    qmat, rmat = np.linalg.qr(jac / scale)
    return qmat[:, np.abs(np.diag(rmat)) > 1e-9 * np.max(np.abs(np.diag(rmat)))]


def projected_gain(jac: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Squared norm of each sample's projection onto the column space of ``jac``."""
    return np.sum((samples @ _basis(jac)) ** 2, axis=1)


def extension_null(trial_jac: np.ndarray, base_jac: np.ndarray, null: np.ndarray,
                   base_gain: np.ndarray | None = None) -> np.ndarray:
    """The null improvement of extending a model (Jacobian ``base_jac``) to ``trial_jac``: each bootstrap
    sample's projected gain on the extension minus that on the base (``base_gain``, when computed already).
    Where the trial's linearisation is no extension of the base's (the mean difference is not positive: its
    sensitivity explodes along the run, column norms of 1e100 on a real servo's Coulomb fit, so the projection
    sees the last samples only and the threshold would fall to its chi-square floor), the base's mean gain per
    direction times the number of added directions stands in for it."""
    base = projected_gain(base_jac, null) if base_gain is None else base_gain
    gain = projected_gain(trial_jac, null) - base
    if np.all(np.isfinite(gain)) and float(np.mean(gain)) > 0:
        return gain
    per_direction = float(np.mean(base)) / max(_basis(base_jac).shape[1], 1)
    return np.full(gain.shape, per_direction * max(trial_jac.shape[1] - base_jac.shape[1], 1))


def null_threshold(null_gains: np.ndarray, dof: int) -> float:
    """99.9 % quantile of the null improvement: a scaled chi-square matched to the bootstrap mean, at least
    the largest bootstrap value, and at least the chi-square quantile of unit variance per parameter (the
    cost is noise-weighted, so no noise gives less; a candidate whose Jacobian the bootstrap barely
    excites would otherwise meet a threshold of ~0)."""
    dof = max(dof, 1)
    mean = max(float(np.mean(null_gains)), 1e-12)
    unit = stats.chi2.ppf(NULL_QUANTILE, dof)
    return float(max(mean / dof * unit, np.max(null_gains), unit))


def validation_accepts(before: float, after: float, force_before: float, force_after: float) -> bool:
    """The validation rule: the effect lowers the validation RMS of the position by the margin
    (``VALIDATION_GAIN``) without raising the recorded force's by more than the margin, or lowers the force's
    by the margin without raising the position's by more than the margin. Why the force: a loop with integral
    action rejects a force law from the position (LuGre friction concealed to 1.02x the position floor while the
    force channel is at 3.4x its own); the recorded force still shows it, and an effect that buys position with
    force is no physics (a position ripple after LuGre on the held-out LuGre case: position -12 %, force x2.6).
    The margin both ways: a constant force through a PID sits in the force alone (a fresh-seed offset truth:
    force -68 %, position +0.5 %, at its noise floor), and had been refused for that half percent. A NaN force
    (no force channel) leaves the position to decide."""
    if after < VALIDATION_GAIN * before:
        return not VALIDATION_GAIN * force_after > force_before
    return bool(VALIDATION_GAIN * after <= before and force_after < VALIDATION_GAIN * force_before)


#: the validation figures of an accepted effect (position [m or rad], force channel [N or N.m])
VALIDATION_FIELDS = ("validation_rms_before", "validation_rms_after", "validation_force_rms_before",
                     "validation_force_rms_after")


def validation_text(info: dict, units: AxisUnits, axis: str | None = None) -> str:
    """The validation RMS of an accepted effect, and the force channel's where the position's did not fall by
    the rule's margin (the loop's integral action rejects the effect from the position)."""
    q0, q1, f0, f1 = (info.get(k, math.nan) for k in VALIDATION_FIELDS)
    text = f"the validation RMS{f' of {axis}' if axis else ''} goes from {q0:.3g} to {q1:.3g} {units.position}"
    if math.isfinite(f0) and not q1 < VALIDATION_GAIN * q0:
        text += (f", that of the recorded force (which the loop's rejection leaves) from {f0:.3g} to {f1:.3g} "
                 f"{units.force}")
    return text


#: an effect whose vanishing changes the validation run by less than this share of its RMS (position and force)
#: is not exercised by the validation recording (:func:`select._unexercised`)
SILENT_SHARE = 0.01


def half_gains(q: np.ndarray, u: np.ndarray, before: tuple[np.ndarray, np.ndarray],
               after: tuple[np.ndarray, np.ndarray], weights: outputerror.Weights,
               with_force: bool = True) -> list[float]:
    """The noise-weighted cost reduction of ``after`` (simulated output, force) over ``before`` on recorded
    ``q``, ``u``, in each half of the recording (1-D signals or one row per axis, weighted by
    ``weights.sigma_q``/``sigma_u`` per axis; the force channel only ``with_force``)."""
    def cost(sim: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        sq = np.reshape(np.asarray(weights.sigma_q, float), (-1, 1))
        per = ((np.atleast_2d(q) - np.atleast_2d(sim[0])) / sq) ** 2
        if with_force:
            su = np.reshape(np.asarray(weights.sigma_u, float), (-1, 1))
            per = per + ((np.atleast_2d(u) - np.atleast_2d(sim[1])) / su) ** 2
        return np.sum(per, axis=0)
    gain = cost(before) - cost(after)
    return [float(np.sum(half)) for half in np.array_split(gain, 2)]


def silent_text(info: dict) -> str:
    """Why a significant effect the validation rejected is not confirmed (:func:`select._unexercised`)."""
    q, u = info["validation_change"]
    first, second = info["training_halves"]
    return (f"not confirmed: the validation recording does not exercise it (at its vanishing point the validation "
            f"run changes by {100 * q:.2g} % of its RMS in position, {100 * u:.2g} % in force), so the validation "
            f"can neither confirm nor refute it; its training cost reduction is {first:.4g} in the first half of "
            f"the recording and {second:.4g} in the second")


#: equal-count bins of the measured validation position in none of which an accepted effect may make the
#: recorded force's residual much worse (:func:`stroke_ratios`)
STROKE_BINS = 4
#: an effect that raises the force residual's mean square by more than this in one bin is not reported as its
#: physics (:func:`stroke_ratios`). Measured on the independent benchmark's tuning and held-out sets: effects
#: that are the truth's physics reach at most 1.6 (a Coulomb friction fitted before the constant force it shares
#: the residual with), a Coulomb friction fitted to a friction bump 6.3
STROKE_RATIO = 3.0


def stroke_ratios(position: np.ndarray, error_before: np.ndarray, error_after: np.ndarray,
                  bins: int = STROKE_BINS) -> list[tuple[float, float, float]]:
    """Per equal-count bin of ``position``: (lowest, highest position, mean square of ``error_after`` over
    that of ``error_before``). An effect that is the right physics brings the force residual nearer the noise
    in every part of the stroke, or leaves it there; a law fitted to a force it does not describe can lower the
    residual overall and make one part much worse (a Coulomb friction fitted to a friction bump on one stretch
    of the rail: x0.23, x0.27 and x0.70 in the quarters where the axis moves, x6.3 in the quarter where it
    rests, where the rail has no friction)."""
    order = np.argsort(position, kind="stable")
    out = []
    for idx in np.array_split(order, bins):
        before, after = float(np.mean(error_before[idx] ** 2)), float(np.mean(error_after[idx] ** 2))
        out.append((float(position[idx[0]]), float(position[idx[-1]]),
                    after / before if before > 0 else (math.inf if after > 0 else 1.0)))
    return out
