"""The optimisation that tunes the Cheung & Hung robust joint controller on all plant sets at once.

Design (eq. 18 recast): maximise the worst-case CLBW over the plant sets (actuator positions) subject to
GM >= gm_min, PM in the band, Ms <= ms_max, tau_cl <= tau_max (and optionally max |S| below CLBW,
CLBW >= bw_min) on every set at once (the paper designs on the worst-case set only; this covers it and the
others), with scipy's differential evolution (the paper's genetic algorithm; seeded), Nelder-Mead refinement
from the best population members, then gradient refinement from each Nelder-Mead end point: scipy's SLSQP
on the epigraph form (maximise t subject to CLBW >= t and the GM, PM-band, Ms, tau_cl (and optional) bounds
as inequality constraints on every set; forward-difference gradients), kept only when it is better and
feasible. Everything is deterministic for a given seed. Constraint violations enter the global search as
penalties, so an infeasible spec ends with the least violating design and an ``InfeasibleSpecError`` naming
each constraint missed and the value reached.
The search evaluates margins on a 1200-point grid with numpy (about 1 ms per plant set) against a spec
tightened by 0.2 dB / 0.3 deg / 0.01, and every reported figure is re-computed with python-control.

Feedforward (eq. 12): the tracking error is E = S (1 - F_L F_N G_f P) R, so Kv, Ka, Kj are fitted after the
feedback design by linear least squares of |1 - F_L F_N G_f P_zoh z^-d| over 0.1 Hz .. CLBW/2 and all plant
sets (``feedforward_gains``): in the narrow-band limit the inverse of K/(s(s+alpha)) through the lag's DC gain,
plus a jerk term for the lag, notch, hold and delay phase. Figures: ``ident.tuning.plots``; per-actuator design
of the coupled manipulator FMU: ``ident.tuning.manipulator``.

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import replace
from typing import Callable, Sequence

import control
import numpy as np
import scipy.optimize

from motiontwin.ident.frf import JointModel, state_space_response
from motiontwin.ident.tuning.margins import (_LoopEvaluator, controller_defaults, discrete_plant,
                                             feedforward_path_response, loop_margins)
from motiontwin.ident.tuning.spec import (FeedforwardFit, InfeasibleSpecError, LoopMargins, TuningError,
                                          TuningResult, TuningSpec, _format_violations, violations)

__all__ = ["DESIGN_BOUNDS", "feedforward_gains", "tune"]


# Search space (the optimiser's coordinates; each maps to a controller parameter):
#   log10(Kp*K)  in [3, 6.5]  Kp*K in 1/s^2: crossover of the P part sqrt(Kp K) from 5 to 280 Hz (the lower
#                             bound was 2: D-dominated designs with Kp there met GM/PM/Ms but left the
#                             integral action seconds slow; tau_cl <= 0.02 s needs Kp/Kd >= ~100 1/s)
#   log10(rho)   in [-3, 0]   rho = 4 Ki Kd/Kp^2: the PID zeros of eq. (9) stay real (rho <= 1, as in every
#                             Table 2 column), the integral zero Ki/Kp from Kp/(4000 Kd) to Kp/(2 Kd) (lower,
#                             the closed-loop pole it attracts sits within 1e-8 of z = 1: stability is noise); a
#                             free Ki let the search place a lightly damped zero pair at a few Hz, whose
#                             closed-loop poles ring for seconds while GM, PM and Ms stay fine
#   log10(Kd*K)  in [0, 3.5]  Kd*K in 1/s: crossover of the D part from 0.16 to 500 Hz
#   KL           in [1, 10]   lag high-frequency gain (Table 2 uses 10)
#   fp [Hz]      in [50, 900] lag pole
#   fc/fp        in [1, 4]    lag zero above the pole (a lag, as in Table 2)
#   log10(sigma) in [0, 1.7]  notch depth 1..50 (Table 2: 15..30)
#   f0 [Hz]      in [150, 950] notch centre sqrt(wl*wh), below the 1/(2 Ts) Nyquist frequency at 2 kHz
#   width        in [0.05, 1] (wh - wl)/f0
# K is the lowest low-frequency gain over the plant sets, so the gain bounds follow the moving mass.
DESIGN_BOUNDS: tuple[tuple[float, float], ...] = (
    (3.0, 6.5), (-3.0, 0.0), (0.0, 3.5), (1.0, 10.0), (50.0, 900.0), (1.0, 4.0), (0.0, 1.7), (150.0, 950.0),
    (0.05, 1.0))


def feedforward_gains(parameters: dict[str, float], plants: Sequence[JointModel | control.LTI],
                      delay_samples: int = 1, band_hz: tuple[float, float] = (0.1, 20.0), jerk: bool = True,
                      points: int = 200) -> FeedforwardFit:
    """Kv, Ka (and Kj) of eq. (12) that invert the sampled loop path from the reference derivatives to q.

    The tracking error is E = S (1 - F_L F_N G_f P) R (eq. 13 with G_f = Kj s^3 + Ka s^2 + Kv s fed by the
    analytic reference derivatives), so the gains minimise sum |1 - F_L F_N G_f P_zoh z^-d|^2 over a log grid
    of ``band_hz`` and all plant sets (linear least squares). For P = K/(s(s+alpha)) and a narrow band this is
    the inverse of the low-frequency model through the lag's DC gain g_L = KL fc/fp: Kv = alpha/(K g_L),
    Ka = 1/(K g_L); Kj takes up the lag, notch, resonance, hold and delay phase (first Taylor term)."""
    if not plants:
        raise TuningError("feedforward_gains: give at least one plant set")
    lo, hi = band_hz
    if not 0 < lo < hi:
        raise TuningError(f"feedforward_gains: band_hz {band_hz} must satisfy 0 < low < high")
    ts = float(parameters.get("Ts", controller_defaults()["Ts"]))
    f = np.logspace(np.log10(lo), np.log10(min(hi, 0.45 / ts)), points)
    s = 2j * np.pi * f
    path = feedforward_path_response(parameters, f)
    z = np.exp(s * ts)
    orders = (1, 2, 3) if jerk else (1, 2)
    blocks = []
    for k, plant in enumerate(plants):
        sampled = discrete_plant(plant, ts, delay_samples, where=f"plant set {k}")
        pz = state_space_response((sampled.A, sampled.B, sampled.C, sampled.D), z)
        blocks.append(np.column_stack([path * pz * s ** n for n in orders]))
    columns = np.vstack(blocks)
    scale = np.max(np.abs(columns), axis=0)
    a = columns / scale
    target = np.ones(columns.shape[0], dtype=complex)
    solution, *_ = np.linalg.lstsq(np.vstack([a.real, a.imag]), np.concatenate([target.real, target.imag]),
                                   rcond=None)
    gains = solution / scale
    residual = float(np.max(np.abs(1 - columns @ gains)))
    kv, ka = float(gains[0]), float(gains[1])
    return FeedforwardFit(kv, ka, float(gains[2]) if jerk else 0.0, (float(lo), float(f[-1])), residual)


def _decode(x: np.ndarray, k_min: float, fixed: dict[str, float]) -> dict[str, float]:
    """Optimiser coordinates -> controller parameters (see DESIGN_BOUNDS; fc kept below Nyquist)."""
    f0, width = x[7], x[8]
    half = width / 2
    kp, kd = 10 ** x[0] / k_min, 10 ** x[2] / k_min
    return {**fixed, "Kp": kp, "Ki": 10 ** x[1] * kp ** 2 / (4 * kd), "Kd": kd, "KL": x[3],
            "fp": x[4], "fc": min(x[4] * x[5], 0.95 / (2 * fixed["Ts"])), "sigma": 10 ** x[6],
            "wl": f0 * (math.sqrt(1 + half ** 2) - half), "wh": f0 * (math.sqrt(1 + half ** 2) + half)}


def _cost(margins: list[LoopMargins], spec: TuningSpec, bw_scale: float) -> float:
    """-(worst-case CLBW)/bw_scale plus 10 per unit of normalised violation (1 dB, 10 deg, 0.1 of |S|, a
    factor e of tau_cl over tau_max)."""
    if not all(m.stable for m in margins):
        return 1e3 + max(m.spectral_radius for m in margins if not m.stable)
    penalty = 0.0
    for m in margins:
        penalty += max(0.0, spec.gm_min_db - abs(m.gm_db))
        penalty += max(0.0, spec.pm_min_deg - m.pm_deg) / 10 + max(0.0, m.pm_deg - spec.pm_max_deg) / 10
        penalty += max(0.0, min(m.ms, 1e3) - spec.ms_max) / 0.1
        if spec.s_below_bw_max is not None:
            penalty += max(0.0, m.s_below_bw - spec.s_below_bw_max) / 0.1
        if spec.bandwidth_min_hz is not None:
            penalty += max(0.0, spec.bandwidth_min_hz - m.bandwidth_hz) / 10
        if spec.tau_max_s is not None and m.tau_cl > spec.tau_max_s:
            penalty += math.log(min(m.tau_cl, 1e6) / spec.tau_max_s)
    return -min(m.bandwidth_hz for m in margins) / bw_scale + 10.0 * penalty


def _slack(margins: list[LoopMargins], spec: TuningSpec) -> np.ndarray:
    """Normalised slack of every constraint on every plant set, >= 0 where met, on the scales of :func:`_cost`
    (1 dB, 10 deg, 0.1 of |S|, 10 Hz, a factor e of tau_cl); an unstable set gives -(1 + spectral radius)."""
    rows = []
    for m in margins:
        row = [min(abs(m.gm_db), 60.0) - spec.gm_min_db, (min(m.pm_deg, 180.0) - spec.pm_min_deg) / 10,
               (spec.pm_max_deg - min(m.pm_deg, 180.0)) / 10, (spec.ms_max - min(m.ms, 1e3)) / 0.1]
        if spec.s_below_bw_max is not None:
            row.append((spec.s_below_bw_max - min(m.s_below_bw, 1e3)) / 0.1)
        if spec.bandwidth_min_hz is not None:
            row.append((m.bandwidth_hz - spec.bandwidth_min_hz) / 10)
        if spec.tau_max_s is not None:
            row.append(math.log(spec.tau_max_s / min(max(m.tau_cl, 1e-9), 1e6)))
        rows.append(row if m.stable else [-(1.0 + m.spectral_radius)] * len(row))
    return np.array(rows, dtype=float).ravel()

_SLACK_MARGIN = 1e-4  # SLSQP ends on active constraints up to ~1e-9: aim this far inside so the result meets them


def _refine_gradient(evaluate: Callable[[np.ndarray], list[LoopMargins]], start: np.ndarray,
                     bounds: Sequence[tuple[float, float]], spec: TuningSpec, bw_scale: float,
                     iterations: int) -> np.ndarray:
    """Gradient refinement of one design: SLSQP on the epigraph form (maximise t subject to CLBW_k >= t and
    every normalised slack >= 1e-4 on every set, so the non-smooth worst case becomes smooth constraints) in
    coordinates scaled to [0, 1], forward-difference gradients with step 1e-6 (on the grid of ``evaluate``:
    ``tune`` gives it 4x the search's points). Deterministic: no random state. Returns the end point in the
    search coordinates (clipped to ``bounds``)."""
    lo, hi = (np.array(b, dtype=float) for b in zip(*bounds))
    span = hi - lo
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def parts(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = u.tobytes()  # the finite-difference step in t re-uses the design's evaluation
        if key not in cache:
            margins = evaluate(lo + span * np.clip(u, 0.0, 1.0))
            cache.clear()
            cache[key] = (np.array([m.bandwidth_hz if m.stable else 0.0 for m in margins]) / bw_scale,
                          _slack(margins, spec))
        return cache[key]

    def constraints(y: np.ndarray) -> np.ndarray:
        bw, slack = parts(np.ascontiguousarray(y[:-1]))
        return np.concatenate([bw - y[-1], slack - _SLACK_MARGIN])

    u0 = np.clip((start - lo) / span, 0.0, 1.0)
    y0 = np.append(u0, float(np.min(parts(u0)[0])))
    grad = np.zeros(y0.size)
    grad[-1] = -1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = scipy.optimize.minimize(lambda y: -y[-1], y0, jac=lambda y: grad, method="SLSQP",
                                         bounds=[(0.0, 1.0)] * u0.size + [(0.0, 10.0)],
                                         constraints={"type": "ineq", "fun": constraints},
                                         options={"maxiter": iterations, "ftol": 1e-9, "eps": 1e-6})
    return lo + span * np.clip(result.x[:-1], 0.0, 1.0)


def tune(plants: Sequence[JointModel | control.LTI], ts: float = 5e-4, spec: TuningSpec = TuningSpec(),
         delay_samples: int = 1, tau: float | None = None, seed: int = 0, popsize: int = 12, maxiter: int = 80,
         refine: int = 3, refine_evaluations: int = 2000, progress: bool = True,
         points: int = 1200, feedforward: bool = True, jerk: bool = True,
         gradient_iterations: int = 60) -> TuningResult:
    """Design Kp, Ki, Kd, KL, fp, fc, sigma, wl, wh for all ``plants`` at once (see the module docstring).

    Search: seeded differential evolution, then Nelder-Mead (``refine_evaluations``) from the ``refine`` best
    members, then SLSQP (:func:`_refine_gradient`, ``gradient_iterations`` per start, 0: none) from each
    Nelder-Mead end point. A gradient result replaces the best design only if, re-checked with python-control
    (:func:`loop_margins`), it meets the spec and has a higher worst-case CLBW, or nothing met the spec so far
    and it violates less: the result is never worse than without it.
    ``tau`` (derivative filter, not in Table 2) defaults to 2 ts. With ``feedforward`` the gains Kv, Ka (and
    Kj with ``jerk``) of eq. (12) are then fitted on all plant sets by :func:`feedforward_gains` over
    0.1 Hz .. half the worst-case CLBW; without it they stay at the FMU defaults.
    Raises InfeasibleSpecError (with the best design attached) when a constraint cannot be met.
    """
    if not plants:
        raise TuningError("tune: give at least one plant set")
    if ts <= 0:
        raise TuningError(f"tune: sample period ts = {ts} must be positive")
    evaluator = _LoopEvaluator(plants, ts, delay_samples, points)
    # K of eq. (7), or for a general plant the mass line |P(j w)| w^2 at 50 Hz, scales the gain bounds
    gains = [p.gain if isinstance(p, JointModel) else abs(complex(p(2j * np.pi * 50))) * (2 * np.pi * 50) ** 2
             for p in plants]
    k_min = min(gains)
    fixed = {"tau": 2 * ts if tau is None else tau, "Ts": ts}
    nyquist = 1 / (2 * ts)
    bounds = [(lo, min(hi, 0.95 * nyquist) if i in (4, 7) else hi) for i, (lo, hi) in enumerate(DESIGN_BOUNDS)]

    # the search works on a grid of `points` frequencies: aim slightly inside the spec so that the final check
    # with python-control (denser grid, exact crossovers) still passes
    inner = replace(spec, gm_min_db=spec.gm_min_db + 0.2, pm_min_deg=spec.pm_min_deg + 0.3,
                    pm_max_deg=spec.pm_max_deg - 0.3, ms_max=spec.ms_max - 0.01,
                    s_below_bw_max=None if spec.s_below_bw_max is None else spec.s_below_bw_max - 0.01,
                    bandwidth_min_hz=None if spec.bandwidth_min_hz is None else spec.bandwidth_min_hz * 1.005,
                    tau_max_s=None if spec.tau_max_s is None else spec.tau_max_s * 0.995)

    def evaluate(x: np.ndarray) -> list[LoopMargins]:
        return evaluator.evaluate(_decode(np.clip(x, *zip(*bounds)), k_min, fixed))

    def objective(x: np.ndarray) -> float:
        return _cost(evaluate(x), inner, nyquist / 10)

    bar = _progress(maxiter, progress)
    try:
        de = scipy.optimize.differential_evolution(
            objective, bounds, seed=seed, popsize=popsize, maxiter=maxiter, tol=1e-8, polish=False,
            init="sobol", callback=lambda intermediate_result: bar(), updating="immediate")
    finally:
        bar(close=True)
    order = np.argsort(de.population_energies)[:max(1, refine)]
    best_x, best_cost = de.x, de.fun
    local_ends = []
    for start in de.population[order]:
        local = scipy.optimize.minimize(objective, start, method="Nelder-Mead", bounds=bounds,
                                        options={"maxfev": refine_evaluations, "xatol": 1e-6, "fatol": 1e-9})
        local_ends.append(local.x)
        if local.fun < best_cost:
            best_x, best_cost = local.x, local.fun

    def checked(x: np.ndarray) -> tuple[dict[str, float], list[LoopMargins], tuple[bool, float]]:
        """Parameters, python-control margins on every set, rank (spec missed, cost) on the real spec."""
        params = {k: float(v) for k, v in _decode(np.clip(x, *zip(*bounds)), k_min, fixed).items()}
        found_margins = [loop_margins(params, p, delay_samples) for p in plants]
        missed = bool(violations(found_margins, spec))
        return params, found_margins, (missed, _cost(found_margins, spec, nyquist / 10))

    parameters, margins, rank = checked(best_x)
    if gradient_iterations > 0:
        # SLSQP pushes onto the active constraints and finds the notch/resonance features a coarse grid misses
        # (GM 0.8 dB off on 600 points): it works on a grid 4x denser
        fine = _LoopEvaluator(plants, ts, delay_samples, 4 * points)

        def evaluate_fine(x: np.ndarray) -> list[LoopMargins]:
            return fine.evaluate(_decode(np.clip(x, *zip(*bounds)), k_min, fixed))

        fine_cost = _cost(evaluate_fine(best_x), inner, nyquist / 10)
        for start in local_ends:
            x = _refine_gradient(evaluate_fine, start, bounds, inner, nyquist / 10, gradient_iterations)
            if _cost(evaluate_fine(x), inner, nyquist / 10) < fine_cost:  # re-check densely, keep only if better
                candidate = checked(x)
                if candidate[2] < rank:
                    parameters, margins, rank = candidate
    found = violations(margins, spec)
    fit = None
    if feedforward and all(m.stable for m in margins):
        fit = feedforward_gains(parameters, plants, delay_samples,
                                (0.1, max(0.2, 0.5 * min(m.bandwidth_hz for m in margins))), jerk)
        parameters |= fit.gains()
    result = TuningResult(parameters, margins, spec, ts, delay_samples, found, fit)
    if found:
        raise InfeasibleSpecError(_format_violations(found), found, result)
    return result


def _progress(total: int, enabled: bool) -> Callable[..., None]:
    """A tqdm bar over DE generations (a no-op when disabled)."""
    if not enabled:
        return lambda close=False: None
    from tqdm import tqdm

    bar = tqdm(total=total, desc="differential evolution", unit="gen")

    def step(close: bool = False) -> None:
        bar.close() if close else bar.update(1)
    return step
