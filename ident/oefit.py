"""Free runs, weighted residuals and the Gauss-Newton (trust-region) fit of a compiled :class:`ident.oeloop.Loop`
against a recording (single shooting; :mod:`ident.multipleshooting` solves the same problem by IPOPT).
Units: those of the Modelica model (SI)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from motiontwin.harness.recording import Recording
from motiontwin.ident.channels import content_key, controller_relation, lifted, noise_level
from motiontwin.ident.loopstart import _column, initial_state, unshifted_start_state
from motiontwin.ident.oeloop import Loop, Signals, default_bounds

def drive(rec: Recording, noise: np.ndarray | None = None, signals: Signals | tuple[Signals, ...] = Signals(),
          closed: bool = True) -> np.ndarray:
    """The 3n x N input matrix of a recording (n axes, ``signals`` one per axis): closed loop
    [r; u_ext; measurement noise], open loop [0; input; 0], each block one row per axis."""
    channels = (signals,) if isinstance(signals, Signals) else tuple(signals)
    n = rec.time.size
    zeros = np.zeros((len(channels), n))
    if noise is not None:
        noise = np.asarray(noise, float).reshape(len(channels), n)
    if not closed:
        return np.vstack([zeros, [_column(rec, sig.input) for sig in channels], zeros])
    return np.vstack([[_column(rec, sig.reference) for sig in channels],
                      [_column(rec, sig.disturbance, True) for sig in channels],
                      zeros if noise is None else noise])


def _shaped(loop: Loop, values: np.ndarray) -> np.ndarray:
    """Simulated outputs (axes x N) as the caller sees them: 1-D for a single-axis loop."""
    values = np.asarray(values, float).reshape(len(loop.channels), -1)
    return values if loop.axes else values.ravel()


def measured(loop: Loop, rec: Recording, kind: str) -> np.ndarray:
    """The recorded outputs (``kind="output"``) or forces (``"input"``) of the loop's axes, shaped as
    :func:`simulate` returns them."""
    return _shaped(loop, np.array([_column(rec, getattr(sig, kind)) for sig in loop.channels]))


def simulate(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
             noise: np.ndarray | None = None, initial: dict[str, float] | None = None,
             shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Free-run simulation along ``rec`` (plant states in ``initial`` start there, the controller state
    shifted by ``shift`` from its first-samples estimate); returns simulated
    (output, input) at the sample instants: 1-D arrays, or (axes x samples) for a multi-axis loop (whose
    ``noise`` is axes x samples too)."""
    values = {**loop.values, **(values or {})}
    if rec.time.size != loop.n_samples:
        raise ValueError(f"loop compiled for {loop.n_samples} samples, recording has {rec.time.size}")
    pf = np.array([values[n] for n in loop.fixed])
    q, u = loop.sim(initial_state(loop, rec, values, initial, shift), drive(rec, noise, loop.channels, loop.closed),
                    loop.theta(values), pf)
    return _shaped(loop, np.array(q)), _shaped(loop, np.array(u))


def simulate_states(loop: Loop, rec: Recording, values: dict[str, float] | None = None,
                    initial: dict[str, float] | None = None) -> np.ndarray:
    """The plant state trajectory of the same free run as :func:`simulate` (plant states x samples, rows in
    ``loop.model.states`` order, at the sample instants: column k is the state the output q_k is read from),
    for the states no measurement gives (delay, load, bristle, drift states). One CasADi ``mapaccum`` of
    ``loop.step``, not a Python loop over the samples."""
    if loop.step is None:
        raise ValueError("the loop has no one-sample step function to chain")
    values = {**loop.values, **(values or {})}
    s0 = initial_state(loop, rec, values, initial)
    pf = np.array([values[n] for n in loop.fixed])
    chain = loop.step.mapaccum("states", rec.time.size, [0], [0])
    s_next = np.array(chain(s0, drive(rec, None, loop.channels, loop.closed), loop.theta(values), pf)[0])
    states = np.hstack([s0[:, None], s_next[:, :-1]])
    return states[:loop.model.x.numel()]


@dataclass
class Fit:
    """Result of an output-error refit."""

    values: dict[str, float]     # all plant parameters after the fit
    cost: float                  # weighted sum of squares (output channel, and force channel in closed loop)
    rms_q: float                 # RMS of measured minus simulated output
    q_sim: np.ndarray
    u_sim: np.ndarray
    jacobian: np.ndarray         # weighted residual Jacobian w.r.t. the free parameters (then the estimated
                                 # initial states) at the optimum
    success: bool
    nfev: int = 0                # residual evaluations (free runs) of the optimiser
    initial: dict[str, float] = field(default_factory=dict)   # estimated initial plant states
    residual: np.ndarray | None = None   # weighted residual at the optimum, rows as ``jacobian`` (for the HAC std)
    shift: np.ndarray | None = None      # estimated correction of the loop's start (estimate_start)
    weights: Weights | None = None       # the noise levels that weighted the fit


@dataclass
class Weights:
    """Noise levels used to weight the residual channels: sigma_q [output unit], sigma_u [N]
    (sigma_u is unused in open loop, where the input is given); a multi-axis loop takes one level per axis
    (arrays), so each axis's output and force channel is weighted by its own noise. ``whiten_q``/``whiten_u``
    (one axis): causal FIR taps applied to that channel's residual before the division by its sigma, the
    inverse of a noise model, so that a residual coloured by the closed loop's echo of process noise counts
    as its innovations do (prediction-error weighting, :func:`whitened`); None: the residual as it is."""

    sigma_q: float | np.ndarray
    sigma_u: float | np.ndarray = 1.0
    whiten_q: np.ndarray | None = None
    whiten_u: np.ndarray | None = None

    def same_as(self, other: "Weights") -> bool:
        """Whether ``other`` weights every residual as these do (equal levels and taps; arrays compared by value)."""
        def same(x, y) -> bool:
            return (x is None) == (y is None) and (x is None or np.array_equal(np.asarray(x), np.asarray(y)))
        return all(same(getattr(self, f), getattr(other, f)) for f in ("sigma_q", "sigma_u", "whiten_q", "whiten_u"))


def whitened(x: np.ndarray, taps: np.ndarray | None) -> np.ndarray:
    """``x`` filtered along its first axis (time) by the causal FIR ``taps`` from zero initial conditions:
    y[t] = sum_k taps[k] x[t - k]; ``x`` itself without taps."""
    if taps is None:
        return x
    x = np.asarray(x, float)
    with np.errstate(over="ignore", invalid="ignore"):   # a diverging free run: inf, which the callers handle
        out = taps[0] * x
        for k in range(1, min(len(taps), x.shape[0])):
            out[k:] += taps[k] * x[:-k]
    return out


def _weighted(meas: np.ndarray, sim: np.ndarray, sigma: float | np.ndarray,
              taps: np.ndarray | None = None) -> np.ndarray:
    """(meas - sim) / sigma, channel-major (axis 0's samples, then axis 1's, ...); one axis: whitened by
    ``taps`` first (:func:`whitened`)."""
    diff = np.asarray(meas) - np.asarray(sim)
    if diff.ndim == 2:
        if taps is not None:
            raise ValueError("residual whitening is defined for one axis")
        diff = diff / np.reshape(np.asarray(sigma, float), (-1, 1))
        return diff.ravel()
    return whitened(diff, taps) / sigma


def _channel_major(sens: np.ndarray, n_axes: int) -> np.ndarray:
    """Chained sensitivities (samples x (axes * columns)) as rows channel-major: (axes * samples) x columns."""
    sens = np.asarray(sens)
    if n_axes == 1:
        return sens
    n = sens.shape[0]
    if sens.shape[1] == 0:
        return np.zeros((n_axes * n, 0))
    return sens.reshape(n, n_axes, -1).transpose(1, 0, 2).reshape(n_axes * n, -1)


def residuals(loop: Loop, rec: Recording, values: dict[str, float], weights: Weights,
              noise: np.ndarray | None = None, q_meas: np.ndarray | None = None,
              u_meas: np.ndarray | None = None, initial: dict[str, float] | None = None,
              shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted residual vector [(q_meas - q_sim)/sigma_q; (u_meas - u_sim)/sigma_u (closed loop only)] and
    the simulation."""
    q, u = simulate(loop, rec, values, noise, initial, shift)
    qm = measured(loop, rec, "output") if q_meas is None else q_meas
    if not loop.closed:
        return _weighted(qm, q, weights.sigma_q, weights.whiten_q), q, u
    um = measured(loop, rec, "input") if u_meas is None else u_meas
    return np.concatenate([_weighted(qm, q, weights.sigma_q, weights.whiten_q),
                           _weighted(um, u, weights.sigma_u, weights.whiten_u)]), q, u


def _interior(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``theta`` clipped strictly inside [lo, hi] (scipy's TRF starts from an interior point)."""
    eps = 1e-9 * np.maximum(np.abs(theta), 1e-12)
    lo_f, hi_f = np.where(np.isfinite(lo), lo, 0.0), np.where(np.isfinite(hi), hi, 0.0)
    lo_in = np.where(np.isfinite(lo), lo_f + np.maximum(eps, 1e-12 * np.abs(lo_f)), -np.inf)
    hi_in = np.where(np.isfinite(hi), hi_f - np.maximum(eps, 1e-12 * np.abs(hi_f)), np.inf)
    return np.minimum(np.maximum(theta, lo_in), hi_in)


def bound_arrays(loop: Loop, bounds: dict[str, tuple[float, float]] | None) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of ``loop.free`` (``bounds`` over the Modelica min/max); empty ones raise."""
    names = loop.free
    bounds = {**default_bounds(loop.model, names), **(bounds or {})}
    lo = np.array([bounds[n][0] for n in names], dtype=float)
    hi = np.array([bounds[n][1] for n in names], dtype=float)
    bad = [n for n, a, b in zip(names, lo, hi) if not a < b]
    if bad:
        raise ValueError(f"empty bounds for {', '.join(f'{n} {bounds[n]}' for n in bad)}")
    return lo, hi


def state_indices(loop: Loop, names: list[str] | tuple[str, ...]) -> list[int]:
    """Indices of the plant states ``names`` in the loop state (unknown names raise)."""
    state_names = [v.name for v in loop.model.states]
    unknown = [n for n in names if n not in state_names]
    if unknown:
        raise KeyError(f"{loop.model.name} has no state {unknown}; states: {', '.join(state_names)}")
    return [state_names.index(n) for n in names]


def controller_states(loop: Loop) -> list[int]:
    """Indices of the controller states in the loop state (empty in open loop, for a controller without
    states and a multi-axis loop, whose training start is :func:`relation_shift`:
    sensitivities w.r.t. every controller state would triple a large plant's Jacobian cost, the Hexapod's)."""
    if not loop.closed or not loop.controller.n_states or loop.axes:
        return []
    nx = loop.model.x.numel()
    return list(range(nx, nx + loop.controller.n_states))


def shifted_states(loop: Loop) -> list[int]:
    """Indices of the states a start ``shift`` moves: the loop's ``shift_states`` (an unknown controller's
    predictor: the plant's position and velocity), else :func:`controller_states`."""
    return list(loop.shift_states) if loop.shift_states is not None else controller_states(loop)


def _relation(loop: Loop, rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The controller's relation (:func:`channels.controller_relation`) from the first-samples start, its rows, the
    start shift its whole-run least squares puts (:func:`relation_shift`) and each axis's noise level of
    what that leaves; cached by recording, start and controller (one for every refit of a diagnosis)."""
    ctrl = loop.controller
    z0 = unshifted_start_state(loop, rec, None, None)[-ctrl.n_states:]
    signals = [_column(rec, c, True) for sig in loop.channels
               for c in (sig.reference, sig.input, sig.output, sig.disturbance)]
    key = content_key(*signals, z0, ctrl.A, ctrl.B, ctrl.C, ctrl.D, ctrl.ticks, ctrl.sample_time)
    found = _RELATIONS.get(key)      # one lookup: a concurrent diagnosis may clear the table in between
    if found is None:
        relation, rows = controller_relation(ctrl, rec, loop.channels, z0)
        shift = np.linalg.lstsq(rows, relation, rcond=1e-10)[0]
        left = (relation - rows @ shift).reshape(len(loop.channels), -1)
        found = relation, rows, shift, np.array([noise_level(axis, ctrl.sample_time) for axis in left])
        if len(_RELATIONS) > 8:
            _RELATIONS.clear()
        _RELATIONS[key] = found
    return found


#: _relation's results by recording, start state and controller
_RELATIONS: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}


def relation_shift(loop: Loop, rec: Recording) -> np.ndarray | None:
    """The controller's start state where its own relation on the recorded signals puts it over the whole run,
    as a ``shift`` from the first-samples estimate of :func:`initial_state`: a state that persists (an
    integrator holding a load at t = 0) is fixed by every sample, not by a few noisy first ones, one that
    decays by the samples it still acts on. None in open loop or without controller states. The training
    start of a multi-axis loop, the plant left out (held by every fit, it must not take up a missing load)."""
    return _relation(loop, rec)[2] if loop.closed and loop.controller.n_states else None


def relation_prior(loop: Loop, rec: Recording, weights: Weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The controller's relation (:func:`channels.controller_relation`) from the first-samples start, and its weight
    per row: each axis's noise level of its residual after the whole-run least-squares start, at least 1e-3
    of that axis's sigma_u (a recorded command reproduces the relation to round-off: the start is then known,
    and a shift away from it is priced far above any model error it could hide)."""
    relation, rows, _, levels = _relation(loop, rec)
    sigma_u = np.broadcast_to(np.asarray(weights.sigma_u, float), levels.shape)
    return relation, rows, np.repeat(np.maximum(levels, 1e-3 * sigma_u), rec.time.size)


def start_shift(loop: Loop, rec: Recording, values: dict[str, float], weights: Weights,
                iterations: int = 3, start: np.ndarray | None = None) -> np.ndarray | None:
    """The correction of the loop's start (the controller's state on every axis, or the loop's ``shift_states``)
    on a recording with the parameters held at ``values`` (the validation run; a loop compiled without its
    Jacobian): weighted least squares of the free run's output and force channels over the whole run and, for a
    controller's state, of the controller's own relation on the recorded signals
    (:func:`channels.controller_relation`, weighted by its residual's noise level, the recording's evidence of
    the start state that no plant model can reinterpret). A start state that only a few noisy first samples
    fixed moves to where the whole run puts it; one that the recorded force fixes exactly (a load the model
    lacks, held at t = 0) stays, so that the model's error shows. An unknown controller's predictor
    (``loop.shift_states``): its plant position and velocity, from both channels alone. Gauss-Newton with the
    free run's sensitivity to each shifted state by a finite difference (nearly exact: the controller is linear,
    and a plant nearly so over such a step), from ``start`` (default: none). None when there is nothing to
    estimate or the free run is not finite."""
    ctrl = loop.controller
    if not loop.closed or not (ctrl.n_states if loop.shift_states is None else loop.shift_states):
        return None
    values = {**loop.values, **values}
    qm, um = measured(loop, rec, "output"), measured(loop, rec, "input")
    if loop.shift_states is None:
        relation, rows, sigma_c = relation_prior(loop, rec, weights)
        # a step that moves the controller's output by about its noise level within its first samples
        a_sample = lifted(ctrl)[0]     # the controller over one recorded sample (ticks updates)
        gain = np.max([np.max(np.abs(ctrl.C @ np.linalg.matrix_power(a_sample, j)), axis=0) for j in range(4)],
                      axis=0)
        step = float(np.max(weights.sigma_u)) / np.maximum(gain, 1e-300)
    else:           # the predictor's plant states: the response is nearly linear in them, any small step does
        rows, relation, sigma_c = np.zeros((0, len(loop.shift_states))), np.zeros(0), np.ones(0)
        step = np.full(len(loop.shift_states), max(float(np.max(weights.sigma_q)), 1e-12))

    def res(shift: np.ndarray) -> np.ndarray:
        q, u = simulate(loop, rec, values, shift=shift)
        return np.concatenate([_weighted(qm, q, weights.sigma_q, weights.whiten_q),
                               _weighted(um, u, weights.sigma_u, weights.whiten_u),
                               (relation - rows @ shift) / sigma_c])

    n = step.size
    shift, unit = (np.zeros(n) if start is None else np.asarray(start, float)), np.eye(n)
    r = res(shift)
    if not np.all(np.isfinite(r)):
        return None
    for _ in range(iterations):
        jac = np.column_stack([(res(shift + step[k] * unit[k]) - r) / step[k] for k in range(n)])
        delta = np.linalg.lstsq(jac, -r, rcond=1e-12)[0]
        trial = shift + delta
        r_trial = res(trial)
        if not np.all(np.isfinite(r_trial)) or r_trial @ r_trial >= r @ r:
            break
        shift, r = trial, r_trial
    return shift


def squared_norm(r: np.ndarray) -> float:
    """r . r, the cost of a weighted residual; inf for a diverged free run (non-finite, or overflowing the sum)."""
    if not np.all(np.isfinite(r)):
        return math.inf
    with np.errstate(over="ignore"):
        return float(r @ r)


def weighted_jacobian(loop: Loop, s0: np.ndarray, W: np.ndarray, theta: np.ndarray, pf: np.ndarray,
                      idx: list[int], weights: Weights) -> np.ndarray:
    """Jacobian of the weighted residual of the free run from ``s0`` w.r.t. [theta, s0[idx]] (``idx``: states
    among the loop's ``initial_states``)."""
    n_ax = len(loop.channels)
    jq, ju, jq0, ju0 = (_channel_major(m, n_ax) for m in loop.jac(s0, W, theta, pf))
    rows = loop.n_samples
    missing = [i for i in idx if i not in loop.initial_states]
    if missing:
        raise ValueError(f"the loop was compiled without the initial-value sensitivities of states {missing} "
                         f"(build_loop's initial_states)")
    idx = [loop.initial_states.index(i) for i in idx]

    def scaled(block: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore"):   # a trial step whose loop diverges: inf entries, which the solver refuses
            return block / np.repeat(np.broadcast_to(np.asarray(sigma, float), (n_ax,)), rows)[:, None]

    j = -whitened(scaled(np.hstack([jq, jq0[:, idx]]), weights.sigma_q), weights.whiten_q)
    if loop.closed:
        j = np.vstack([j, -whitened(scaled(np.hstack([ju, ju0[:, idx]]), weights.sigma_u), weights.whiten_u)])
    return j


#: a start value at or below this magnitude counts as zero: the optimiser's scale of that parameter comes from
#: the data, not from the value itself
ZERO_START = 1e-12


def parameter_scale(theta0: np.ndarray, r0: np.ndarray | None = None, j0: np.ndarray | None = None) -> np.ndarray:
    """The optimiser's unit of each free parameter: its start value's magnitude; for a parameter that starts at
    zero (Fc, F0 of a plant written without them, refitted because ``plant.free`` lists them), the magnitude
    the data ask for: its own one-parameter Gauss-Newton step from the start, |J_i . r0| / |J_i|^2, at least
    the change that moves the weighted residual by one (1 / |J_i|), and 1 where it has no effect at the start
    (``r0``, ``j0``: weighted residual and its Jacobian w.r.t. ``theta0`` at the start). Why: the trust region
    is scaled by the Jacobian anyway (x_scale="jac"), but a unit of 1e-12 puts a moved parameter at 1e11 in
    the solver's variables, whose step test (xtol, relative to their norm) then stops the fit early. Without
    ``r0`` and ``j0`` a zero start gets the unit 1."""
    theta0 = np.asarray(theta0, float)
    scale = np.abs(theta0)
    zero = scale <= ZERO_START
    if not zero.any() or r0 is None or j0 is None:
        return np.where(zero, 1.0, scale)
    j0 = np.where(np.isfinite(j0), j0, 0.0)
    r0 = np.where(np.isfinite(r0), r0, 0.0)
    for i in np.flatnonzero(zero):
        with np.errstate(over="ignore"):
            norm2 = float(j0[:, i] @ j0[:, i])
        if not (norm2 > 0 and math.isfinite(norm2)):
            scale[i] = 1.0
            continue
        step = abs(float(j0[:, i] @ r0)) / norm2
        scale[i] = max(step, 1.0 / math.sqrt(norm2), scale[i])
    return scale


#: largest magnitude of a solver Jacobian entry: its column norms (squares summed over 1e5+ rows) stay finite
JACOBIAN_LIMIT = 1e100
RESIDUAL_LIMIT = 1e12      # a weighted residual's largest magnitude in the solver (a diverged run's samples)
#: the trust-region fit's xtol, ftol and gtol: a relative cost change below it is the solver's own convergence
TOLERANCE = 1e-10


def fit(loop: Loop, rec: Recording, weights: Weights, bounds: dict[str, tuple[float, float]] | None = None,
        start: dict[str, float] | None = None, max_nfev: int = 40,
        q_meas: np.ndarray | None = None, u_meas: np.ndarray | None = None,
        estimate_initial: list[str] | tuple[str, ...] = (), initial: dict[str, float] | None = None,
        estimate_start: bool = False, shift: np.ndarray | None = None) -> Fit:
    """Output-error least squares of ``loop.free`` within ``bounds`` (default: the Modelica min/max), by
    scipy's trust-region reflective method with the CasADi Jacobian. The initial values of the plant states
    ``estimate_initial`` are estimated too (unbounded), e.g. the position, which the first noisy sample
    would otherwise fix with an error that the integrator carries through the whole run. ``initial``: known
    initial values of plant states (e.g. a run that starts at rest at a known position).
    ``estimate_start``: the loop's start shift is estimated with them (from its first-samples estimate,
    unbounded, :func:`shifted_states`): the controller's start state, priced by the controller's own relation
    on the recorded signals (:func:`relation_prior`; the reported cost, residual and Jacobian are the
    recording's rows), so that a start state fixed by a few noisy samples is not carried through the whole
    run by an integrator, while one the recorded force fixes exactly stays; or, for a loop with
    ``shift_states`` (an unknown controller's predictor), those plant states, unpriced, so that the observer
    does not spend the run's start pulling in a start the first noisy samples set. ``shift``: where that
    estimate starts (the fitted shift of the model a refit continues or extends; default none), or without the
    estimate the start shift used throughout (a multi-axis loop's :func:`relation_shift`)."""
    known = dict(initial or {})
    values = {**loop.values, **(start or {})}
    names = loop.free
    lo, hi = bound_arrays(loop, bounds)
    idx = state_indices(loop, estimate_initial)
    ctrl_idx = shifted_states(loop) if estimate_start else []
    n_th, n_x = len(names), len(idx)
    theta0 = _interior(loop.theta(values), lo, hi)
    base = initial_state(loop, rec, values, known)
    x_init0 = np.concatenate([base[idx], np.zeros(len(ctrl_idx)) if shift is None or not ctrl_idx else shift])
    scale = np.concatenate([np.ones(n_th), np.ones(x_init0.size)])   # set below, from the start values
    lo_all = np.concatenate([lo, np.full(x_init0.size, -np.inf)])
    hi_all = np.concatenate([hi, np.full(x_init0.size, np.inf)])
    s0_cache: dict[bytes, np.ndarray] = {}
    qm = measured(loop, rec, "output") if q_meas is None else q_meas
    um = (measured(loop, rec, "input") if u_meas is None else u_meas) if loop.closed else None
    W = drive(rec, signals=loop.channels, closed=loop.closed)
    pf = np.array([values[n] for n in loop.fixed])

    def split(xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        full = xs * scale
        return full[:n_th], full[n_th:]

    def state(theta: np.ndarray, x_init: np.ndarray) -> np.ndarray:
        key = theta.tobytes() + x_init.tobytes()
        if key not in s0_cache:
            s0_cache.clear()
            s0_cache[key] = initial_state(loop, rec, {**values, **dict(zip(names, theta))},
                                          {**known, **dict(zip(estimate_initial, x_init[:n_x]))},
                                          x_init[n_x:] if ctrl_idx else shift)
        return s0_cache[key]

    runs: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def point(theta: np.ndarray, x_init: np.ndarray) -> bytes:
        return theta.tobytes() + x_init.tobytes()

    def run_at(theta: np.ndarray, x_init: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The free run's unclipped weighted residual and simulation, kept from the solver's last accepted
        point on (:func:`outcome` asks for that point again)."""
        key = point(theta, x_init)
        if key not in runs:
            q, u = loop.sim(state(theta, x_init), W, theta, pf)
            q, u = _shaped(loop, np.array(q)), _shaped(loop, np.array(u))
            r = _weighted(qm, q, weights.sigma_q, weights.whiten_q)
            if loop.closed:
                r = np.concatenate([r, _weighted(um, u, weights.sigma_u, weights.whiten_u)])
            runs[key] = (r, q, u)
        return runs[key]

    def res_at(theta: np.ndarray, x_init: np.ndarray) -> np.ndarray:
        r = run_at(theta, x_init)[0]
        # a diverging free run: each sample counts RESIDUAL_LIMIT at most, so that the solver's sums stay finite
        # (a run at 1e303 is finite, its squares are not, and the trust-region step then fails on NaN)
        return np.clip(np.where(np.isfinite(r), r, RESIDUAL_LIMIT), -RESIDUAL_LIMIT, RESIDUAL_LIMIT)

    def jac_at(theta: np.ndarray, x_init: np.ndarray) -> np.ndarray:
        return weighted_jacobian(loop, state(theta, x_init), W, theta, pf, idx + ctrl_idx, weights)

    def solver_jacobian(j: np.ndarray) -> np.ndarray:
        """The solver's Jacobian: scaled, finite and bounded (a diverging free run overflows it, and the solver
        squares it for its column norms; its SVD refuses inf and NaN, while a zero or clipped entry only stalls
        that direction of a step the cost then rejects)."""
        with np.errstate(over="ignore", invalid="ignore"):
            j = j * scale
        return np.clip(np.where(np.isfinite(j), j, 0.0), -JACOBIAN_LIMIT, JACOBIAN_LIMIT)

    jac_cache: dict[bytes, np.ndarray] = {}

    def res(xs: np.ndarray) -> np.ndarray:
        return res_at(*split(xs))

    def jac(xs: np.ndarray) -> np.ndarray:
        """The solver's Jacobian, the last one kept: the solver ends on a point whose Jacobian it computed,
        and :func:`outcome` asks for it again."""
        key = xs.tobytes()
        if key not in jac_cache:
            jac_cache.clear()
            jac_cache[key] = solver_jacobian(jac_at(*split(xs)))
        accepted = point(*split(xs))      # the solver asks at accepted points only: the runs of the points it
        for stale in [k for k in runs if k != accepted]:      # refused go
            del runs[stale]
        return jac_cache[key]

    if ctrl_idx and loop.shift_states is None:   # the controller's relation on the recorded signals prices a
        # shift of its start
        relation, rows, sigma_c = relation_prior(loop, rec, weights)
        prior_jac = np.hstack([np.zeros((rows.shape[0], n_th + n_x)), -rows / sigma_c[:, None]])

        def res_all(xs: np.ndarray) -> np.ndarray:
            return np.concatenate([res(xs), (relation - rows @ split(xs)[1][n_x:]) / sigma_c])

        def jac_all(xs: np.ndarray) -> np.ndarray:
            return np.vstack([jac(xs), prior_jac * scale])
    else:
        res_all, jac_all = res, jac

    nfev = 0
    j_start = None
    if np.any(np.abs(theta0) <= ZERO_START) and loop.jac is not None:
        j_start = jac_at(theta0, x_init0)
        j_start = np.where(np.isfinite(j_start), j_start, 0.0)
        scale[:n_th] = parameter_scale(theta0, res_at(theta0, x_init0), j_start[:, :n_th])
    else:
        scale[:n_th] = parameter_scale(theta0)
    x_start = np.concatenate([theta0, x_init0]) / scale
    if j_start is not None:      # the solver's first Jacobian is this one: not computed twice
        jac_cache[x_start.tobytes()] = solver_jacobian(j_start)
    if x_start.size:
        if loop.jac is None:
            raise ValueError("the loop was compiled without its Jacobian (with_jacobian=False)")
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):    # a trial step whose loop diverges
            # overflows the solver's sums: its cost is inf, the trust region shrinks and the step is refused,
            # which is the answer, not a warning
            sol = least_squares(res_all, x_start, jac=jac_all, bounds=(lo_all / scale, hi_all / scale),
                                method="trf", x_scale="jac", max_nfev=max_nfev, xtol=TOLERANCE, ftol=TOLERANCE,
                                gtol=TOLERANCE)
        xs = sol.x
        success = bool(sol.success or sol.status == 0)
        nfev = int(sol.nfev)
    else:
        xs = x_start
        success = True

    def outcome(theta: np.ndarray, x_init: np.ndarray, j: np.ndarray | None) -> Fit:
        """The fit at ``theta`` and the estimated initial states ``x_init`` (``j``: its Jacobian; None: no
        free parameters)."""
        final = {**values, **dict(zip(names, map(float, theta)))}
        initial = dict(zip(estimate_initial, map(float, x_init[:n_x])))
        held = x_init[n_x:] if ctrl_idx else shift      # the controller start of this fit
        r, q, u = run_at(theta, x_init)
        cost = squared_norm(r)
        with np.errstate(over="ignore"):
            rms = float(np.sqrt(np.mean((qm - q) ** 2))) if np.all(np.isfinite(q)) else math.inf
        j = np.zeros((r.size, 0)) if j is None else j
        return Fit(final, cost, rms, q, u, j, success, nfev, initial, r, held, weights)

    result = outcome(*split(xs), jac(xs) / scale if xs.size else None)
    theta_start = loop.theta(values)
    if x_start.size and np.all((lo <= theta_start) & (theta_start <= hi)):
        r0 = res_at(theta_start, x_init0)
        if squared_norm(r0) < result.cost:   # the solver traded recording cost for the controller prior (or for
            # the interior start): the recording's cost never ends above the start's, so the start is the result
            result = outcome(theta_start, x_init0, solver_jacobian(jac_at(theta_start, x_init0)) / scale)
    return result
