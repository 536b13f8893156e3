"""Start values and initial state for output-error refits and the diagnosis (issue 13, item 1).

* user values: ``NAME=VALUE`` assignments and a values file (the JSON ``identify`` writes,
  ``{"parameters": {...}}``, or a flat ``{"m": 95.0}``), checked against the plant's parameters;
* an automatic starting point from inverse-dynamics least squares: the force the plant needs for the
  measured (low-pass filtered, differentiated) motion, ``u = g(x, v, a, p)``, is regressed on the recorded
  force for the parameters that enter it linearly (mass, viscous friction, Coulomb level, offset, ...), so a
  free run from the Modelica defaults (m = 2 kg against a 95 kg axis) is never the first thing tried;
* the initial velocity from the first samples (a quadratic fit), so a recording that is already moving
  at t = 0 does not start the free run at rest;
* :class:`DivergenceError`: a free run that diverges, named with what diverged and what to set.

Units: SI (s, m, N), those of the Modelica model.
"""
from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.fmus.limits import load_json
from motiontwin.ident.plant_states import velocity_state
from motiontwin.ident.signals import lowpass_differentiate

#: the longest window of the local cubic that gives the initial position and velocity [s] (at least 8 samples)
FIRST_SAMPLES_SECONDS = 0.02
#: two windows' estimates agree when they differ by at most this many of their standard deviations added
FIRST_SAMPLES_AGREEMENT = 2.0


class StartValueError(ValueError):
    """A start value is unusable; the message names the option, file or field at fault."""


class DivergenceError(ValueError):
    """A free run of the plant (or closed loop) diverges from the start values."""


def read_values_file(path: Path) -> dict[str, float]:
    """Parameter values from JSON: ``{"parameters": {NAME: VALUE}}`` (as ``identify --out`` writes) or a flat
    ``{NAME: VALUE}``. Errors name the file, line/column or the field."""
    doc = load_json(path, StartValueError)
    values = doc.get("parameters", doc) if isinstance(doc, dict) else None
    if not isinstance(values, dict):
        raise StartValueError(f"{path}: expected a JSON object {{\"parameters\": {{NAME: VALUE}}}}")
    return check_numbers(values, str(path))


def check_numbers(values: dict, where: str) -> dict[str, float]:
    """``values`` as floats; a non-numeric or non-finite entry raises naming ``where`` and the field."""
    out: dict[str, float] = {}
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise StartValueError(f"{where}: field 'parameters.{name}' must be a finite number, got {value!r}")
        out[str(name)] = float(value)
    return out


def check_parameters(model: symbolic.SymbolicModel, values: dict[str, float], where: str) -> None:
    """Every name in ``values`` must be a parameter of ``model`` within its Modelica min/max."""
    by_name = {v.name: v for v in model.parameters}
    for name, value in values.items():
        if name not in by_name:
            raise StartValueError(f"{where}: {model.name} has no parameter {name!r}; its parameters are "
                                  f"{', '.join(by_name)}")
        var = by_name[name]
        if not var.min <= value <= var.max:
            raise StartValueError(f"{where}: {name} = {value!r} is outside its Modelica range "
                                  f"[{var.min}, {var.max}]")


_FIRST_SAMPLES: dict[bytes, tuple[float, float]] = {}  # by the samples it reads: every fit evaluation asks again


def first_samples(q: np.ndarray, ts: float) -> tuple[float, float]:
    """Position [m] and velocity [m/s] at t = 0 from a local cubic fitted to the first samples of ``q``, its
    window chosen by Lepski's rule: windows grow from 8 samples to ``FIRST_SAMPLES_SECONDS`` while the
    estimate stays within ``FIRST_SAMPLES_AGREEMENT`` standard deviations of every shorter window's (noise
    level from the fourth differences). A fixed window biases the velocity of a move that starts at t = 0
    (a jerk-limited onset is cubic): a quadratic over 10 ms gave 1.8 mm/s for a start at rest."""
    q = np.asarray(q, float)
    longest = int(min(q.size, max(8, round(FIRST_SAMPLES_SECONDS / ts))))
    key = q[:max(longest, 16)].tobytes() + repr((longest, float(ts))).encode()
    if key not in _FIRST_SAMPLES:
        if len(_FIRST_SAMPLES) >= 64:
            _FIRST_SAMPLES.clear()
        _FIRST_SAMPLES[key] = _first_samples(q, ts, longest)
    return _FIRST_SAMPLES[key]


def _first_samples(q: np.ndarray, ts: float, longest: int) -> tuple[float, float]:
    """:func:`first_samples` over the first ``longest`` samples of ``q``."""
    if longest < 8:                      # a very short record: one polynomial through all of it
        if q.size < 2:
            return float(q[0]), 0.0
        coef = np.polyfit(np.arange(q.size) * ts, q, min(2, q.size - 1))
        return float(np.polyval(coef, 0.0)), float(np.polyval(np.polyder(coef), 0.0))
    fourth = np.diff(q[:max(longest, 16)], 4)
    sigma = max(float(np.median(np.abs(fourth))) / 0.6745 / math.sqrt(70.0), 1e-12 * max(1.0, abs(float(q[0]))))
    chosen = (float(q[0]), 0.0)
    previous: list[tuple[np.ndarray, np.ndarray]] = []
    for n in sorted({int(round(n)) for n in np.geomspace(8, longest, 6)}):
        x = np.vander(np.arange(n) / n, 4, increasing=True)          # time scaled to the window: conditioned
        coef = np.linalg.lstsq(x, q[:n], rcond=None)[0]
        per_second = np.array([1.0, 1.0 / (n * ts)])
        estimate = coef[:2] * per_second
        sd = sigma * np.sqrt(np.diag(np.linalg.inv(x.T @ x))[:2]) * per_second
        if any(np.any(np.abs(estimate - e) > FIRST_SAMPLES_AGREEMENT * (sd + s)) for e, s in previous):
            break
        previous.append((estimate, sd))
        chosen = (float(estimate[0]), float(estimate[1]))
    return chosen


def derivative_cutoff(fs: float) -> float:
    """The low-pass [Hz] of the inverse dynamics at sample rate ``fs`` [Hz]: a tenth of it, at most 150 Hz
    (the encoder noise, differentiated twice, grows with the fourth power of frequency)."""
    return min(0.1 * fs, 150.0)


def mirror_derivatives(signal: np.ndarray, fs: float, fc: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-phase low-pass and derivatives of a non-periodic record: the even extension is periodic and
    continuous, so the DFT filter/differentiator of Abdellatif sec. 3.3 applies to it."""
    n = signal.size
    ext = np.concatenate([signal, signal[::-1]])
    d = lowpass_differentiate(ext, fs, fc)
    return d.position[:n], d.velocity[:n], d.acceleration[:n]


def inverse_dynamics_start(model: symbolic.SymbolicModel, q: np.ndarray, u: np.ndarray, ts: float,
                           position_state: str, free: list[str], values: dict[str, float],
                           bounds: dict[str, tuple[float, float]] | None = None,
                           input_name: str | None = None) -> dict[str, float]:
    """Least-squares starting values of the free parameters that enter the inverse dynamics linearly.

    Parameters
    ----------
    model : the plant (two states: position and velocity, one driven input).
    q, u : trajectory of the position state (the recorded output mapped by
        :func:`plant_states.position_from_output`: a gear ratio divided out) and plant input force [N],
        uniformly sampled at ``ts`` [s].
    position_state : the state ``q`` is the trajectory of.
    free : parameters to estimate; those entering the needed force nonlinearly keep ``values``.
    values : every parameter's current value (the fixed ones and the nonlinear free ones).
    bounds : the estimates are clipped into these (default: the Modelica min/max).
    input_name : the driven input (default: the only one).

    Returns
    -------
    dict
        Estimated values of the linear free parameters (empty when none can be estimated: another plant
        structure, an input that does not enter linearly, or a rank-deficient regressor).
    """
    names = [s.name for s in model.states]
    inputs = [v.name for v in model.inputs]
    i_x = names.index(position_state) if position_state in names else None
    i_v = None if i_x is None else velocity_state(model, i_x)
    if i_v is None or model.x.numel() != 2 or not free or (input_name is None and len(inputs) != 1):
        return {}
    k_in = inputs.index(input_name or inputs[0])
    acc = model.dx[i_v]
    gain = ca.jacobian(acc, model.u)[k_in]
    if ca.depends_on(gain, model.u):
        return {}
    a_sym = ca.SX.sym("a")
    u_zero = ca.substitute(acc, model.u, ca.DM.zeros(model.u.numel()))
    force = (a_sym - u_zero) / gain
    pnames = [v.name for v in model.parameters]
    fn = ca.Function("force", [model.x, a_sym, model.p], [force, ca.jacobian(force, model.p)])
    fs = 1 / ts
    fc = derivative_cutoff(fs)
    x, v, a = mirror_derivatives(np.asarray(q, float), fs, fc)
    u = np.asarray(u, float)
    held = np.concatenate([u[:1], 0.5 * (u[1:] + u[:-1])])   # the force held over the half samples around t_k
    u_f, _, _ = mirror_derivatives(held, fs, fc)
    n = x.size
    keep = slice(n // 20, n - n // 20)          # the filter's end effects
    states = np.zeros((2, n))
    states[i_x], states[i_v] = x, v
    p0 = np.array([values[name] for name in pnames], float)
    mapped = fn.map(n)

    def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f, j = mapped(states, a[None, :], p)
        return np.array(f).ravel(), np.array(j).reshape(n, len(pnames))   # per sample: one row of dF/dp

    f0, j0 = evaluate(p0)
    idx = [pnames.index(name) for name in free]
    p1 = p0.copy()      # linear in the free parameters jointly, the others held (a zero Fc next to a fixed v_eps)
    p1[idx] = p0[idx] * 1.37 + 0.11
    _, j1 = evaluate(p1)
    linear = [i for i in idx if np.any(j0[:, i] != 0)
              and np.allclose(j0[:, i], j1[:, i], rtol=1e-9, atol=1e-12 * np.max(np.abs(j0[:, i])))]
    if not linear or not np.all(np.isfinite(f0)) or not np.all(np.isfinite(j0[:, linear])):
        return {}
    mat = j0[keep][:, linear]
    target = (u_f - f0)[keep] + mat @ p0[linear]
    scale = np.linalg.norm(mat, axis=0)
    sol, _, rank, _ = np.linalg.lstsq(mat / scale, target, rcond=None)
    if rank < len(linear):
        return {}
    estimate = sol / scale
    by_name = {v.name: v for v in model.parameters}
    out = {}
    for i, value in zip(linear, estimate):
        name = pnames[i]
        lo, hi = (bounds or {}).get(name, (by_name[name].min, by_name[name].max))
        out[name] = float(np.clip(value, lo, hi))
    return out


def check_free_run(q_sim: np.ndarray, q_meas: np.ndarray, time: np.ndarray, what: str, values: dict[str, float],
                   hint: str) -> None:
    """Raise :class:`DivergenceError` when the free run ``q_sim`` leaves the measured range by far (1000 x its
    span) or is not finite: names ``what``, the time, the parameter values used and ``hint`` (what to set)."""
    span = float(np.ptp(q_meas)) or float(np.max(np.abs(q_meas))) or 1.0
    centre = float(np.mean(q_meas))
    bad = ~np.isfinite(q_sim) | (np.abs(q_sim - centre) > 1e3 * span)
    if not np.any(bad):
        return
    k = int(np.argmax(bad))
    shown = ", ".join(f"{k_}={v:.4g}" for k_, v in values.items())
    reached = "not finite" if not np.isfinite(q_sim[k]) else f"{q_sim[k]:.3g}"
    raise DivergenceError(f"{what} diverges: the simulated position is {reached} at t = {time[k]:.4g} s (the "
                          f"recording spans {span:.3g}) with {shown}. {hint}")
