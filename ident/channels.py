"""Channel check of a closed-loop recording: is the recorded force u what the known controller commands,
u = controller(r, q) + u_ext? Run before any fit, so that a channel in the wrong unit, with the wrong sign or
shifted in time is named instead of being absorbed into a wrong model.

The sampled controller (:class:`ident.controller.Controller`) is run on the recorded r and q: its forced
response p_k (zero initial state) and its free response rows G_k = C A^k, so that the prediction is
p_k + G_k z_0 + u_ext_k with the unknown initial controller state z_0 (an integrator holding a load at t = 0)
fitted by least squares. The nominal mismatch is the RMS of u - p - G z_0 - u_ext. The hypotheses fitted
beside it, each by linear least squares at each delay d = -``MAX_DELAY``..``MAX_DELAY`` samples, are
u_{k} = a p_{k-d} + c u_ext_{k-d} + G_{k-d} z_0: a gain or unit factor (a = c != 1), a sign flip (a = -1),
a controller gain (a != 1, c = 1), a scaled, reversed or missing u_ext (c != 1, c = -1, c = 0) and a delay of
d samples. The recording is consistent when the nominal mismatch is within ``RELATIVE_TOLERANCE`` of the RMS of
u (round-off, quantisation), or within ``NOISE_FACTOR`` times the best hypothesis's residual (no hypothesis
explains it: taken as noise) and below ``UNEXPLAINED_SHARE`` of the RMS of u (a larger force that nothing
explains is no recording noise: a missing u_ext or another controller). Units: those of the recording (u and
u_ext in one force unit).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from motiontwin.harness.recording import Recording
from motiontwin.ident.controller import Controller, at_recording_step
from motiontwin.ident.oeloop import Signals

__all__ = ["ChannelCheck", "check_channels", "channel_problem", "content_key", "controller_relation",
           "controller_responses", "lifted",
           "MAX_DELAY", "NOISE_FACTOR", "RELATIVE_TOLERANCE", "UNEXPLAINED_SHARE"]

MAX_DELAY = 10            # samples searched either way
NOISE_FACTOR = 3.0        # nominal RMS mismatch over the best hypothesis's residual RMS
RELATIVE_TOLERANCE = 1e-3  # of the RMS of u: below it the channels agree whatever the hypotheses say
UNEXPLAINED_SHARE = 0.1   # of the RMS of u: an unexplained mismatch above it is refused
COEFFICIENT_TOLERANCE = 0.01   # |a - 1|, |c - 1| below it: that factor is 1


@dataclass(frozen=True)
class ChannelCheck:
    """One axis: RMS of u, the nominal mismatch u - controller(r, q) - u_ext, the best hypothesis (delay
    [samples], factor ``gain`` on controller(r, q), factor ``ext_gain`` on u_ext (None: u_ext is zero)) and its
    residual RMS, the verdict and, when inconsistent, the likely cause in words."""

    force: str
    rms_u: float
    mismatch: float
    residual: float
    delay: int
    gain: float
    ext_gain: float | None
    consistent: bool
    cause: str


def lifted(ctrl: Controller) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The controller over one recorded sample (``ctrl.ticks`` updates) as the loop simulates it, the references
    held over the sample and the positions interpolated linearly between the samples (the loop takes them
    from the model at each update): z_{k+1} = A_l z_k + B_0 y_k + B_1 y_{k+1}. One update: (A, B, 0)."""
    n, n_ref = ctrl.ticks, ctrl.B.shape[1] // 2      # y = [r_1..r_n, q_1..q_n]
    a_l, b0, b1 = np.eye(ctrl.A.shape[0]), np.zeros_like(ctrl.B), np.zeros_like(ctrl.B)
    for j in range(n):               # update j sees r_k and q_k + j/n (q_{k+1} - q_k)
        w1 = np.r_[np.zeros(n_ref), np.full(ctrl.B.shape[1] - n_ref, j / n)]
        a_l = ctrl.A @ a_l
        b0, b1 = ctrl.A @ b0 + ctrl.B * (1 - w1), ctrl.A @ b1 + ctrl.B * w1
    return a_l, b0, b1


def content_key(*parts: np.ndarray | float) -> bytes:
    """A digest of the shapes and contents of ``parts`` (arrays or numbers): the key of the caches that keep
    what is computed from a controller and recorded signals alone."""
    digest = hashlib.blake2b(digest_size=20)
    for part in parts:
        part = np.ascontiguousarray(part, float)
        digest.update(str(part.shape).encode())
        digest.update(part.tobytes())
    return digest.digest()


_RESPONSES: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
_RESPONSES_KEPT = 8     # a diagnosis asks for the same few (its recordings under one controller) dozens of times


def controller_responses(ctrl: Controller, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forced response p (outputs x N) from z_0 = 0 and free-response rows G (outputs x N x states); a
    controller faster than the recording by :func:`lifted`. Kept by the contents of the controller and of
    ``y`` (a per-sample loop that the fits' start-state priors and floors repeat on the same recording);
    the arrays returned are read-only."""
    key = content_key(ctrl.A, ctrl.B, ctrl.C, ctrl.D, y, ctrl.ticks)
    found = _RESPONSES.get(key)      # one lookup: a concurrent diagnosis may clear the table in between
    if found is None:
        found = _responses(ctrl, np.asarray(y, float))
        for a in found:
            a.flags.writeable = False
        if len(_RESPONSES) >= _RESPONSES_KEPT:
            _RESPONSES.clear()
        _RESPONSES[key] = found
    return found


def _responses(ctrl: Controller, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`controller_responses` computed, sample by sample."""
    n = y.shape[1]
    n_out, n_z = ctrl.C.shape[0], ctrl.A.shape[0]
    a_l, b0, b1 = lifted(ctrl)
    p = np.zeros((n_out, n))
    g = np.zeros((n_out, n, n_z))
    z, power = np.zeros(n_z), np.eye(n_z)
    for k in range(n):
        p[:, k] = ctrl.C @ z + ctrl.D @ y[:, k]
        g[:, k, :] = ctrl.C @ power
        z = a_l @ z + b0 @ y[:, k] + b1 @ y[:, min(k + 1, n - 1)]
        power = a_l @ power
    return p, g


def controller_relation(ctrl: Controller, rec: Recording, channels: tuple[Signals, ...],
                        z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The controller's own relation over the whole recording, without the plant: the recorded force minus
    u_ext minus the controller's output on the recorded r and q from ``z0`` (its residual), and the free
    response rows C A^k (samples x states) that a start-state change adds to that output; several axes
    (``channels``, one per axis): the axes' rows one after the other, N per axis."""
    def column(name: str) -> np.ndarray:
        return rec[name] if name in rec.columns else np.zeros_like(rec.time)

    y = np.vstack([[rec[sig.reference] for sig in channels], [rec[sig.output] for sig in channels]])
    force = np.array([rec[sig.input] - column(sig.disturbance) for sig in channels])
    forced, free = controller_responses(ctrl, y)
    rows = free.reshape(-1, free.shape[2])
    return (force - forced).ravel() - rows @ np.asarray(z0, float), rows


def _lstsq(columns: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares with column scaling; returns coefficients and the residual RMS."""
    if columns.shape[1] == 0:
        return np.zeros(0), float(np.sqrt(np.mean(target ** 2)))
    norms = np.linalg.norm(columns, axis=0)
    norms[norms == 0] = 1.0
    coef = np.linalg.lstsq(columns / norms, target, rcond=1e-12)[0] / norms
    return coef, float(np.sqrt(np.mean((target - columns @ coef) ** 2)))


def _shifted(delay: int, n: int) -> tuple[slice, slice]:
    """Index ranges of u and of the prediction when u lags the prediction by ``delay`` samples."""
    return (slice(delay, n), slice(0, n - delay)) if delay >= 0 else (slice(0, n + delay), slice(-delay, n))


def _near(value: float, target: float) -> bool:
    return abs(value - target) <= COEFFICIENT_TOLERANCE * max(1.0, abs(target))


def _unexplained(has_ext: bool, disturbance: str) -> str:
    if not has_ext:
        return (f"a missing {disturbance}: u holds a force controller(r, q) does not command and no gain, sign or "
                f"delay explains (record the added disturbance force as column {disturbance})")
    return (f"none of gain, sign, delay, {disturbance} scale explains it: part of {disturbance} missing, or not "
            "the controller that ran?")


def _cause(delay: int, a: float, c: float | None, ts: float, disturbance: str) -> str:
    """The hypothesis that explains the mismatch, in words."""
    parts = []
    if delay:
        parts.append(f"a delay of {abs(delay)} sample{'s' if abs(delay) > 1 else ''} ({abs(delay) * ts * 1e3:.3g} ms): "
                     f"u {'lags' if delay > 0 else 'leads'} controller(r, q) + {disturbance}")
    if c is not None and not _near(a, 1) and abs(a - c) <= COEFFICIENT_TOLERANCE * max(abs(a), abs(c)):
        parts.append("a sign flip of u: u = -(controller(r, q) + u_ext)" if _near(a, -1) else
                     f"a gain or unit factor on u: u = {a:.4g} * (controller(r, q) + {disturbance})")
    else:
        if not _near(a, 1):
            parts.append("a sign flip: u = -controller(r, q) + u_ext" if _near(a, -1) else
                         f"a gain or unit factor: u = {a:.4g} * controller(r, q) + {disturbance}")
        if c is not None and not _near(c, 1):
            if abs(c) <= COEFFICIENT_TOLERANCE:
                parts.append(f"{disturbance} is not in u (u holds controller(r, q) alone)")
            elif _near(c, -1):
                parts.append(f"{disturbance} has the wrong sign: u = controller(r, q) - {disturbance}")
            else:
                parts.append(f"{disturbance} is scaled by {c:.4g}: u = controller(r, q) + {c:.4g} * {disturbance} "
                             f"({disturbance} in another unit, e.g. volts instead of the force unit?)")
    return "; ".join(parts) or _unexplained(c is not None, disturbance)


def _check_axis(u: np.ndarray, e: np.ndarray, p: np.ndarray, g: np.ndarray, ts: float,
                sig: Signals) -> ChannelCheck:
    n = u.size
    rms_u = float(np.sqrt(np.mean(u ** 2)))
    has_ext = bool(np.any(e))
    _, mismatch = _lstsq(g, u - p - e)
    best = (np.inf, 0, 1.0, None)
    for delay in range(-MAX_DELAY, MAX_DELAY + 1):
        iu, ip = _shifted(delay, n)
        columns = np.column_stack([p[ip]] + ([e[ip]] if has_ext else []) + [g[ip]])
        coef, rms = _lstsq(columns, u[iu])
        if rms < best[0]:
            best = (rms, delay, float(coef[0]), float(coef[1]) if has_ext else None)
    residual, delay, a, c = best
    explained = mismatch > NOISE_FACTOR * residual
    consistent = mismatch <= RELATIVE_TOLERANCE * rms_u or (not explained and mismatch <= UNEXPLAINED_SHARE * rms_u)
    cause = "" if consistent else (_cause(delay, a, c, ts, sig.disturbance) if explained
                                   else _unexplained(has_ext, sig.disturbance))
    return ChannelCheck(sig.input, rms_u, mismatch, residual, delay, a, c, consistent, cause)


def check_channels(rec: Recording, controller: Controller,
                   signals: Signals | list[Signals] | tuple[Signals, ...] = Signals()) -> list[ChannelCheck]:
    """Check u = controller(r, q) + u_ext on ``rec``, one :class:`ChannelCheck` per axis (``signals`` one per
    axis; the controller maps [r_1..r_n, q_1..q_n] to [u_1..u_n]). An absent u_ext column counts as zero."""
    channels = [signals] if isinstance(signals, Signals) else list(signals)
    missing = [c for s in channels for c in (s.reference, s.output, s.input) if c not in rec.columns]
    if missing:
        raise KeyError(f"recording has no column {', '.join(map(repr, missing))} (columns: {', '.join(rec.columns)})")
    controller = at_recording_step(controller, rec.time, "recording")
    y = np.vstack([rec[s.reference] for s in channels] + [rec[s.output] for s in channels])
    p, g = controller_responses(controller, y)
    zero = np.zeros_like(rec.time)
    return [_check_axis(rec[s.input], rec[s.disturbance] if s.disturbance in rec.columns else zero, p[i], g[i],
                        controller.sample_time, s) for i, s in enumerate(channels)]


def channel_problem(rec: Recording, controller: Controller,
                    signals: Signals | list[Signals] | tuple[Signals, ...] = Signals()) -> str | None:
    """None when every axis is consistent, else one sentence per inconsistent axis with its likely cause."""
    problems = [f"column {c.force!r} does not match controller(r, q) + u_ext: RMS mismatch {c.mismatch:.3g} "
                f"({100 * c.mismatch / max(c.rms_u, 1e-300):.3g} % of the RMS of {c.force}), {c.residual:.3g} left "
                f"by the best explanation; likely cause: {c.cause}"
                for c in check_channels(rec, controller, signals) if not c.consistent]
    return "; ".join(problems) or None


def noise_level(residual: np.ndarray, ts: float) -> float:
    """Standard deviation of the white part of ``residual``: median PSD over the upper half band (the
    diagnosis' :data:`ident.diagnosis.evidence.noise_level`), divided by the median of its own distribution.
    Why: each Welch bin of white noise is the mean of K segments' periodograms, chi-square with 2K degrees of
    freedom over 2K, whose median lies below its mean: by ln 2 for one segment (a recording shorter than 1024
    samples), which read the level 17 % low and put a short recording's floor below its own noise."""
    from scipy.signal import welch   # here: scipy.signal takes 0.3-0.7 s to import, and open-loop fits never call this
    from scipy.special import gammaincinv

    x = np.asarray(residual, float) - np.mean(residual)
    nperseg = min(1024, x.size)
    f, pxx = welch(x, fs=1 / ts, nperseg=nperseg)
    band = pxx[f >= 0.25 / ts]
    segments = 1 + (x.size - nperseg) // (nperseg - nperseg // 2)   # welch's default overlap: half a segment
    median_over_mean = float(gammaincinv(segments, 0.5)) / segments
    level = float(np.median(band)) / median_over_mean if band.size else float(np.var(x)) * 2 * ts
    return float(np.sqrt(max(level, 1e-300) / (2 * ts)))
