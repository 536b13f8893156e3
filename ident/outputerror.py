"""Output-error (simulation-error) refit of a Modelica plant's parameters against a recording, in CasADi.

The plant is the :class:`fmus.symbolic.SymbolicModel` the FMU is generated from, so the refit and the
FMU share one set of equations. Two set-ups:

* open loop: the plant input is the recorded input column, held over each sample (ZOH, as a
  co-simulation master sets it); the residual is measured minus simulated output;
* closed loop: a sampled linear controller (:class:`ident.controller.Controller`) reads r_k and the
  simulated output q_k (+ a measurement-noise input n_k, zero in a free run), applies
  u_k = C z_k + D [r_k; q_k + n_k] + u_ext_k over [t_k, t_k + Ts) and updates z_{k+1} = A z_k + B [r_k; q_k + n_k];
  the residual stacks the output and the force channels, each weighted by its noise level.

The plant is integrated over one sample by RK4 with ``substeps`` steps. One step function (CasADi SX) is
built once, with its forward-sensitivity step from algorithmic differentiation, so the residual Jacobian with
respect to the free parameters is exact instead of finite differences. Both are chained over the recording in
compiled C (:mod:`ident.chain`: CasADi-generated code + a model-agnostic loop, cached by source hash), or,
without a C compiler, with CasADi's ``mapaccum`` (same results, much slower on long recordings).

Shooting: single shooting is the default. For the stable or marginally stable loops of motion systems
(a joint is an integrator with damping; in closed loop the controller stabilises it) the free run stays
bounded for any parameter value inside the bounds, the Gauss-Newton iteration with exact AD Jacobians
converges in a few steps, and there are only n_free unknowns. Multiple shooting (:mod:`ident.multipleshooting`,
``identify(..., shooting="multiple")``) adds n_s unknowns and n_s continuity constraints per segment node,
solved by IPOPT on the same step function; it can pay off for unstable plants, whose free run from a poor
start diverges.

Parameter statistics: covariance = s^2 (J^T J)^-1 with J the weighted residual Jacobian at the optimum and
s^2 = weighted RSS / (rows - free parameters); exact for white output noise in open loop, too small when the
residual is coloured (closed loop, model error, filtered noise). ``robust_covariance`` of the statistics is
the HAC sandwich (J^T J)^-1 S (J^T J)^-1 with S the Newey-West long-run covariance of the per-sample scores
(:func:`ident.leastsquares.hac_covariance`), which holds for coloured residuals; both are printed.

Units: SI (s, m, N), those of the Modelica model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import multipleshooting, plant_states, startvalues
from motiontwin.ident.controller import Controller, at_recording_step
from motiontwin.ident.leastsquares import (LeastSquaresResult, UnidentifiableError, check_identifiability,
                                          hac_covariance)
from motiontwin.ident.loopstart import _column, initial_state
from motiontwin.ident.oefit import (TOLERANCE, Fit, Weights, _interior, bound_arrays, controller_states, drive, fit,
                                    measured, relation_shift, residuals, simulate, simulate_states,
                                    squared_norm, start_shift, state_indices, weighted_jacobian, whitened)
from motiontwin.ident.oeloop import (Loop, Signals, _check_names, axis_signals, build_loop, default_bounds,
                                     initial_motion_states, output_state, stable_substeps)

__all__ = ["TOLERANCE", "Signals", "Loop", "Weights", "Fit", "OutputErrorResult", "build_loop", "default_bounds",
           "simulate", "simulate_states", "residuals", "fit", "statistics", "identify", "bound_arrays",
           "axis_signals", "drive", "initial_state", "measured", "stable_substeps", "_column", "_interior",
           "state_indices", "weighted_jacobian", "output_state", "initial_motion_states", "start_shift",
           "controller_states", "relation_shift", "squared_norm", "whitened"]


def _covariances(loop: Loop, result: Fit, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, int | None]:
    """s^2 (J^T J)^-1 and the HAC sandwich over the Jacobian columns ``keep`` (parameters then initial states)."""
    j = result.jacobian[:, keep]
    dof = result.jacobian.shape[0] - result.jacobian.shape[1]
    factor = result.cost / dof if dof > 0 else float("nan")
    col = np.linalg.norm(j, axis=0)
    jn = j / col
    bread = np.linalg.inv(jn.T @ jn) / np.outer(col, col)
    robust, lags = None, None
    if result.residual is not None and np.all(np.isfinite(result.residual)):
        channels = j.shape[0] // loop.n_samples   # rows are channel-major: output samples, then force samples
        by_sample = j.reshape(channels, loop.n_samples, -1).transpose(1, 0, 2).reshape(j.shape)
        residual = np.asarray(result.residual).reshape(channels, loop.n_samples).T.ravel()
        robust, lags = hac_covariance(by_sample, residual, rows_per_sample=channels, bread=bread)
    return bread * factor, robust, lags


def _held_on_bounds(loop: Loop, theta: np.ndarray, std: np.ndarray,
                    bounds: dict[str, tuple[float, float]] | None) -> dict[str, float]:
    """Free parameters the fit left on a bound: within 1e-8 of it (relative) or within 1e-3 of their std."""
    lo, hi = bound_arrays(loop, bounds)
    held: dict[str, float] = {}
    for name, value, s, a, b in zip(loop.free, theta, std, lo, hi):
        for bound in (a, b):
            if np.isfinite(bound) and abs(value - bound) <= max(1e-8 * max(abs(bound), abs(value)), 1e-3 * s):
                held[name] = float(bound)
    return held


def statistics(loop: Loop, result: Fit, bounds: dict[str, tuple[float, float]] | None = None) -> LeastSquaresResult:
    """Estimate, covariance s^2 (J^T J)^-1, std and correlation of the free parameters at the optimum, and the
    HAC (Newey-West) sandwich covariance that holds for coloured residuals (closed loop, model error).
    Parameters on a bound (``bounds`` over the Modelica min/max) are held there: no std of their own, the
    others' covariances conditional on them (their columns left out).

    Raises :class:`ident.leastsquares.UnidentifiableError` naming the parameters the recording does not
    determine (a rank-deficient Jacobian)."""
    j = result.jacobian
    names = loop.free + [f"{n}(t0)" for n in result.initial]
    names += [f"start shift {k + 1}" for k in range(j.shape[1] - len(names))]   # a fit with ``estimate_start``
    report = check_identifiability(j, names)
    if not report.identifiable:
        raise UnidentifiableError(report.message(), report.unidentifiable, report.null_directions)
    n_th = len(loop.free)
    theta = loop.theta(result.values)
    everything = np.arange(j.shape[1])
    cov_keep, robust_keep, lags = _covariances(loop, result, everything)
    held = _held_on_bounds(loop, theta, np.sqrt(np.abs(np.diag(cov_keep)))[:n_th], bounds)
    keep = np.array([i for i in everything if i >= n_th or loop.free[i] not in held], dtype=int)
    if held:
        cov_keep, robust_keep, lags = _covariances(loop, result, keep)
    params = keep[keep < n_th]
    index = np.searchsorted(keep, params)
    cov = np.zeros((n_th, n_th))
    cov[np.ix_(params, params)] = cov_keep[np.ix_(index, index)]
    robust = None
    if robust_keep is not None:
        robust = np.zeros((n_th, n_th))
        robust[np.ix_(params, params)] = robust_keep[np.ix_(index, index)]
    sv = np.linalg.svd(j[:, :n_th], compute_uv=False)
    dof = j.shape[0] - j.shape[1]
    return LeastSquaresResult(theta, cov, list(loop.free), result.cost, dof, False, float(sv[0] / sv[-1]), robust,
                              lags, held)


@dataclass
class OutputErrorResult:
    """An output-error identification: the compiled loop, the fit and the parameter statistics."""

    loop: Loop
    fit: Fit
    weights: Weights
    statistics: LeastSquaresResult


def _rms_weight(residual: np.ndarray) -> float:
    rms = float(np.sqrt(np.mean(residual ** 2)))
    return rms if rms > 0 and math.isfinite(rms) else 1.0


def identify(model: symbolic.SymbolicModel, rec: Recording, free: list[str], controller: Controller | None = None,
             signals: Signals = Signals(), bounds: dict[str, tuple[float, float]] | None = None,
             start: dict[str, float] | None = None, substeps: int | None = None,
             tracking: dict[str, str] | None = None, max_nfev: int = 50,
             input_name: str | None = None, estimate_initial: list[str] | None = None,
             shooting: str = "single", segments: int = 4, auto_start: bool = False,
             initial: str = "rest") -> OutputErrorResult:
    """Refit ``free`` parameters of ``model`` (values of the others: ``start`` or the Modelica start values)
    so that its free run reproduces ``rec``; closed loop when ``controller`` is given.

    The recording must be sampled uniformly (at the controller period in closed loop). Each channel is
    weighted by the RMS of its residual after a first fit, then the fit is repeated. ``estimate_initial``:
    plant states whose initial value is estimated too (default: :func:`initial_motion_states`: the state the
    output is affine in (the output state itself, or the state behind an alias, gear ratio or offset) and its
    velocity state).
    ``input_name``: the driven plant input (default: the one named like the input column, else the only one).
    ``shooting``: "single" (:func:`fit`, ``max_nfev`` free runs per fit) or "multiple"
    (:func:`ident.multipleshooting.fit` over ``segments`` segments, IPOPT). ``auto_start``: free parameters
    not in ``start`` that enter the inverse dynamics linearly start from its least-squares estimate
    (:func:`ident.startvalues.inverse_dynamics_start`). A free run that diverges from the start values raises
    :class:`ident.startvalues.DivergenceError` naming the values and what to set. ``initial``: "rest" (the
    velocity state starts at its start value) or "samples" (at the slope of the first samples, for a loop
    already moving at t = 0); both are then estimated with ``estimate_initial``."""
    if initial not in ("rest", "samples"):
        raise ValueError(f"initial must be 'rest' or 'samples', not {initial!r}")
    if not free:
        raise ValueError("name at least one free parameter")
    if shooting not in ("single", "multiple"):
        raise ValueError(f"shooting must be 'single' or 'multiple', not {shooting!r}")
    _check_names(model, free)
    needed = [signals.output, signals.input] + ([signals.reference] if controller is not None else [])
    missing = [c for c in needed if c not in rec.columns]
    if missing:
        raise KeyError(f"recording has no column {', '.join(repr(c) for c in missing)} "
                       f"(columns: {', '.join(rec.columns)})")
    steps = np.diff(rec.time)
    if controller is not None:
        controller = at_recording_step(controller, rec.time, "recording")
    ts = float(np.median(steps)) if controller is None else controller.sample_time
    bad = np.flatnonzero(np.abs(steps - ts) > 1e-3 * ts)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"recording row {i + 3}, column 'time': step {steps[i]:.9g} s differs from the sample "
                         f"period {ts:.9g} s (the refit needs uniform sampling at the controller's instants)")
    values = {v.name: float(v.start) for v in model.parameters}
    values.update(start or {})
    if input_name is None and signals.input in [v.name for v in model.inputs]:
        input_name = signals.input
    if auto_start:
        guess = [n for n in free if n not in (start or {})]
        found = plant_states.position_from_output(model, signals.output, values, rec[signals.output])
        if found is not None:
            values.update(startvalues.inverse_dynamics_start(model, found[1], rec[signals.input], ts,
                                                             found[0], guess, values, bounds, input_name))
    i_pos = output_state(model, signals.output)
    i_vel = None if i_pos is None else plant_states.velocity_state(model, i_pos)
    if initial == "samples" and i_vel is not None:
        tracking = {model.states[i_vel].name: "dq", **(tracking or {})}
    loop = build_loop(model, controller, signals.output, list(free), values, rec.time.size, substeps=substeps,
                      tracking=tracking, ts=ts, input_name=input_name, signals=signals)
    q0, u0 = simulate(loop, rec)
    qm = rec[signals.output]
    startvalues.check_free_run(q0, qm, rec.time, f"the {'closed' if loop.closed else 'open'}-loop free run of "
                               f"{model.name} on the recording", {n: values[n] for n in free},
                               "Give start values: --set NAME=VALUE or --values FILE (identify oe), or start=.")
    weights = Weights(_rms_weight(qm - q0), _rms_weight(rec[signals.input] - u0) if loop.closed else 1.0)
    if estimate_initial is None:
        estimate_initial = initial_motion_states(model, signals.output)
    if shooting == "multiple":
        def refit(lp: Loop, w: Weights) -> Fit:
            return multipleshooting.fit(lp, rec, w, segments, bounds, estimate_initial=estimate_initial)
    else:
        def refit(lp: Loop, w: Weights) -> Fit:
            return fit(lp, rec, w, bounds, max_nfev=max_nfev, estimate_initial=estimate_initial)
    result = refit(loop, weights)
    weights = Weights(_rms_weight(qm - result.q_sim),
                      _rms_weight(rec[signals.input] - result.u_sim) if loop.closed else 1.0)
    result = refit(loop.with_values(result.values), weights)
    loop = loop.with_values(result.values)
    return OutputErrorResult(loop, result, weights, statistics(loop, result, bounds))
