"""Candidate effects (the issue-7 vocabulary): each a Modelica fragment with its parameters, bounds,
data-driven starts and the contract's parameters; :mod:`ident.diagnosis.augmented` writes them into the
augmented model.

Force laws come from ``MotionTwin.Effects`` functions (a positive effect force opposes positive motion);
structural effects (an extra mass, a Pade input delay, a position-dependent mass) add states or terms; a sensor
effect (:mod:`ident.diagnosis.sensor_effects`) adds its error to the measured output. Effects write the plant's
position and velocity as ``$x`` and ``$v``. Positions, velocities and the :class:`Context` are in the plant's
state coordinates (``position_gain`` converts them to the measured output). Units: SI (m, s, N, kg, Hz).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy.signal import find_peaks

from motiontwin.ident.diagnosis.effect_base import (Context, Effect, Param, _eps_bounds, _eps_grid, _ls, _p,
                                                    _scale, _sign, _v_eps)
from motiontwin.ident.diagnosis.sensor_effects import encoder_error

FRICTION = "friction"


def gravity_offset(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        f0 = float(np.median(c.force)) if c.force is not None else 0.0
        return [{"gravity_F0": f0 or 0.1}]
    return Effect("gravity_offset", "gravity_offset",
                  [_p("gravity_F0", "N", "Constant opposing force (gravity or cable offset)", -1e4, 1e4, zero=0.0)],
                  "", "gravity_F0", [], [], init,
                  lambda v, c: {"F0": v["gravity_F0"]},
                  "A constant force acts on the axis (gravity on an inclined axis, cable or spring preload): "
                  "at rest the controller must hold it, so the force residual has a non-zero mean that does "
                  "not depend on the direction of motion.", regressor=lambda c, x, v: np.ones_like(x))


def coulomb_friction(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None:
            return [{"coulomb_Fc": 0.1, "coulomb_v_eps": _v_eps(c)}]
        return [{"coulomb_Fc": max(abs(float(_ls([np.tanh(c.v / e), np.ones_like(c.v)], c.force)[0])), 1e-3),
                 "coulomb_v_eps": e} for e in _eps_grid(c)]
    params = [_p("coulomb_Fc", "N", "Coulomb friction level", 0.0, 1e4, zero=0.0),
              _p("coulomb_v_eps", "m/s", "Velocity scale of the tanh (presliding)",
                 *_eps_bounds(ctx))]
    return Effect("coulomb_friction", FRICTION, params, "",
                  "MotionTwin.Effects.CoulombFriction($v, coulomb_Fc, coulomb_v_eps)", [],
                  ["CoulombFriction.mo"], init, lambda v, c: {"Fc": v["coulomb_Fc"]},
                  "A friction force of constant magnitude opposes the motion: the force residual jumps with "
                  "the sign of the velocity and is flat in |v|.",
                  regressor=lambda c, x, v: np.tanh(v / _v_eps(c)))


def asymmetric_friction(ctx: Context) -> Effect:
    eps = _v_eps(ctx)

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None:
            return [{"asym_Fc_pos": 0.1, "asym_Fc_neg": 0.1}]
        sp = (1 + _sign(c)) / 2
        moving = np.abs(c.v) > 3 * eps
        a, b = _ls([(_sign(c) * sp)[moving], (_sign(c) * (1 - sp))[moving]], c.force[moving])
        return [{"asym_Fc_pos": max(a, 1e-3), "asym_Fc_neg": max(b, 1e-3), "asym_v_eps": _v_eps(c)}]
    params = [_p("asym_Fc_pos", "N", "Coulomb level for v > 0", 0.0, 1e4, zero=0.0),
              _p("asym_Fc_neg", "N", "Coulomb level (magnitude) for v < 0", 0.0, 1e4, zero=0.0),
              _p("asym_zero", "N.s/m", "No direction-dependent viscous part", 0.0, 0.0, False),
              _p("asym_v_eps", "m/s", "Velocity scale of the tanh (presliding)",
                 *_eps_bounds(ctx))]
    return Effect("asymmetric_friction", FRICTION, params, "",
                  "MotionTwin.Effects.AsymmetricFriction($v, asym_zero, asym_zero, asym_Fc_pos, "
                  "asym_Fc_neg, asym_v_eps)", [], ["AsymmetricFriction.mo"], init,
                  lambda v, c: {"Fc_pos": v["asym_Fc_pos"], "Fc_neg": v["asym_Fc_neg"]},
                  "Friction whose level depends on the direction of motion: the force residual jumps at "
                  "velocity reversals by different amounts for positive and negative velocities, and "
                  "vanishes at rest.")


def stribeck_friction(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        starts = []
        base = abs(float(_ls([_sign(c)], c.force)[0])) if c.force is not None else 0.1
        for vs in (0.02 * c.v_max, 0.1 * c.v_max):
            starts.append({"stribeck_Fc": max(base, 1e-3), "stribeck_Fs": max(2 * base, 2e-3),
                           "stribeck_vs": vs, "stribeck_v_eps": _v_eps(c)})
        return starts
    params = [_p("stribeck_Fc", "N", "Coulomb (sliding) friction level", 0.0, 1e4, zero=0.0),
              _p("stribeck_Fs", "N", "Static (breakaway) friction level", 0.0, 1e4, zero=0.0),
              _p("stribeck_vs", "m/s", "Stribeck velocity", 1e-4 / _scale(ctx), max(ctx.v_max, 1e-3 / _scale(ctx))),
              _p("stribeck_v_eps", "m/s", "Velocity scale of the tanh (presliding)",
                 *_eps_bounds(ctx))]
    return Effect("stribeck_friction", FRICTION, params, "",
                  "MotionTwin.Effects.StribeckFriction($v, stribeck_Fc, stribeck_Fs, stribeck_vs, "
                  "stribeck_v_eps)", [], ["StribeckFriction.mo"], init,
                  lambda v, c: {"Fc": v["stribeck_Fc"], "Fs": v["stribeck_Fs"],
                                "vs": v["stribeck_vs"] * abs(c.position_gain)},
                  "Friction that is higher near standstill than at speed (Stribeck curve): the force residual "
                  "opposes the motion and its magnitude falls with |v| over the first few mm/s.",
                  unphysical=lambda v: "" if v["stribeck_Fs"] >= v["stribeck_Fc"] else "its breakaway level lies "
                  "below the Coulomb level (friction rising with speed is not a Stribeck curve)")


def position_ripple(ctx: Context) -> Effect:
    span = max(ctx.x_max - ctx.x_min, 1e-6 / _scale(ctx))
    travelled = float(np.ptp(ctx.x)) if ctx.x is not None else span   # by the training run the fit sees

    def init(c: Context) -> list[dict[str, float]]:
        periods = span / np.linspace(0.75, 40, 400)
        if c.force is None:
            return [{"ripple_period": span / 4, "ripple_a": 0.0, "ripple_b": 0.0}]
        best = []
        mat = np.column_stack([np.empty_like(c.x), np.empty_like(c.x), np.ones_like(c.x), _sign(c)])
        for period in periods:      # the level and sign columns are the same for every period
            k = 2 * np.pi / period
            mat[:, 0], mat[:, 1] = np.sin(k * c.x), np.cos(k * c.x)
            coef, *_ = np.linalg.lstsq(mat, c.force, rcond=None)
            best.append((float(np.hypot(coef[0], coef[1])), period, coef[0], coef[1]))
        best.sort(reverse=True)
        return [{"ripple_period": p, "ripple_a": a, "ripple_b": b} for _, p, a, b in best[:2]]
    params = [_p("ripple_a", "N", "Sine amplitude of the ripple force", -1e4, 1e4, zero=0.0),
              _p("ripple_b", "N", "Cosine amplitude of the ripple force", -1e4, 1e4, zero=0.0),
              _p("ripple_period", "m", "Spatial period (e.g. magnet pitch)", span / 60, 2 * span),
              _p("ripple_zero", "rad", "Phase of the sine part", 0.0, 0.0, False),
              _p("ripple_quarter", "rad", "Phase of the cosine part", math.pi / 2, math.pi / 2, False)]
    return Effect("position_ripple", "position_ripple", params, "",
                  "MotionTwin.Effects.RippleForce($x, ripple_a, ripple_period, ripple_zero) + "
                  "MotionTwin.Effects.RippleForce($x, ripple_b, ripple_period, ripple_quarter)", [],
                  ["RippleForce.mo"], init,
                  lambda v, c: {"amplitude": float(math.hypot(v["ripple_a"], v["ripple_b"])),
                                "period": v["ripple_period"] * abs(c.position_gain)},
                  "A force periodic in position (cogging or motor force ripple): the residual oscillates as a "
                  "function of position with a fixed spatial period, at any speed.",
                  unphysical=lambda v: "" if v["ripple_period"] <= 2 * travelled else "its period exceeds twice "
                  "the range the training run travels (less than half a cycle is seen: a single bump or slope over "
                  "the stroke, which an offset or a position-dependent force gives too, is not shown to be periodic)")


def position_dependent_inertia(ctx: Context) -> Effect:
    centre = 0.5 * (ctx.x_min + ctx.x_max)
    half = max(0.5 * (ctx.x_max - ctx.x_min), 1e-6 / _scale(ctx))

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None:
            return [{"inertia_slope": 0.0}]
        col = (c.x - centre) * c.a + 0.5 * c.v ** 2
        k = float(_ls([col, np.ones_like(col)], c.force)[0])
        return [{"inertia_slope": k}, {"inertia_slope": -k}]
    bound = 0.9 * ctx.mass / half
    params = [_p("inertia_slope", "kg/m", "Change of the moving mass per metre", -bound, bound,
                 zero=0.0, physical=(True, True)),   # the mass stays positive over the stroke
              _p("inertia_centre", "m", "Position where the mass equals plant.m", centre, centre, False)]
    return Effect("position_dependent_inertia", "position_dependent_inertia", params, "",
                  "inertia_slope*($x - inertia_centre)*der($v) + 0.5*inertia_slope*$v^2", [],
                  [], init,
                  lambda v, c: _mass_range(v, c),
                  "The moving mass changes along the stroke (a cable chain, an arm or a payload that moves "
                  "with position): the residual is proportional to the acceleration with a gain that varies "
                  "with position; the v^2 term keeps the energy balance (Lagrange).")


def _mass_range(v: dict[str, float], c: Context) -> dict[str, float]:
    centre = v["inertia_centre"]
    m = v.get("plant.m", c.mass)
    ends = [(m + v["inertia_slope"] * (x - centre)) / abs(c.position_gain) for x in (c.x_min, c.x_max)]
    return {"mass_min": float(min(ends)), "mass_max": float(max(ends))}


def time_delay(ctx: Context) -> Effect:
    """Pade(2,2) delay of the commanded force, exactly the library's DelayedInputJoint for T >= T0 = Ts/4.
    Below T0 the applied force interpolates linearly between the undelayed force and its T0 delay (a
    fractional delay), so the effect vanishes exactly at T = 0 and the Pade states never get stiffer than at
    T0: |lambda| = sqrt(12)/T0, 14 RK4 substeps per sample (35 with T0 = Ts/10, which made the delay's
    screening the slowest of all). A fitted delay below T0, which the sampled loop does not resolve, is not
    reported as a delay."""
    t0 = ctx.ts / 4

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None or c.udot is None:
            return [{"delay_T": ctx.ts}]
        tau = float(_ls([c.udot, np.ones_like(c.udot), _sign(c)], c.force)[0])
        return [{"delay_T": float(np.clip(tau, 0.1 * ctx.ts, 20 * ctx.ts))}, {"delay_T": ctx.ts},
                {"delay_T": 4 * ctx.ts}]
    params = [_p("delay_T", "s", "Delay between the commanded and the applied force", 0.0, 20 * ctx.ts, zero=0.0)]
    decl = ('  Real delay_p1(unit = "N", start = 0, fixed = true) "First Pade state";\n'
            '  Real delay_s(unit = "N", start = 0, fixed = true) "Second Pade state, u - u_delayed";\n'
            '  Real delay_a(unit = "N") "Commanded minus applied force";\n')
    eqs = [f"max(delay_T, {t0!r})*der(delay_p1) = delay_s",
           f"max(delay_T, {t0!r})*der(delay_s) = 12*(u - delay_p1) - 6*delay_s",
           f"delay_a = min(delay_T/{t0!r}, 1)*delay_s"]
    return Effect("time_delay", "time_delay", params, decl, "", eqs, [], init,
                  lambda v, c: {"delay": v["delay_T"]},
                  "The applied force lags the commanded force (amplifier, communication or computation "
                  "delay), realised as the Pade(2,2) approximant of MotionTwin.Effects.DelayedInputJoint: "
                  "the residual grows with the rate of change of the force and reduces the phase margin.",
                  delays_input=True, tracks_force=["delay_p1"],
                  unphysical=lambda v: "" if v["delay_T"] >= t0 else "a delay below Ts/4, which the sampled "
                  "loop does not resolve (the search starts at 0 only so that it cannot end worse)")


def resonance(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        guesses = c.resonance_guess or [0.1 / c.ts]
        starts = []
        for f_res in guesses[:3]:
            starts.append({"resonance_m2": 0.1 * c.mass, "resonance_fa": f_res / math.sqrt(1.1),
                           "resonance_zeta": 0.03})
        return starts
    params = _two_mass_params(ctx, "resonance")
    decl = _two_mass_declarations("resonance")
    k, c = _two_mass_terms("resonance")
    eqs = ["der(resonance_x2) = resonance_v2",
           "resonance_m2*der(resonance_v2) = resonance_F",
           f"resonance_F = {k}*($x - resonance_x2) + {c}*($v - resonance_v2)"]
    return Effect("resonance", "resonance", params, decl, "resonance_F", eqs, [], init,
                  lambda v, c: _two_mass_contract(v, c, "resonance"),
                  "An unmodelled structural mode: a second mass coupled by a spring and a damper to the driven "
                  "mass (as MotionTwin.Effects.TwoMassJoint); the residual concentrates in a narrow frequency "
                  "band of the swept-sine excitation.", tracks_position=["resonance_x2"])


def _two_mass_contract(v: dict[str, float], c: Context, prefix: str) -> dict[str, float]:
    """Frequency [Hz] and damping ratio of the coupled mode (driven mass plant.m, coupled mass PREFIX_m2)."""
    m1, m2 = v.get("plant.m", c.mass), v[f"{prefix}_m2"]
    ratio = math.sqrt((m1 + m2) / m1)
    return {"frequency": v[f"{prefix}_fa"] * ratio, "damping": v[f"{prefix}_zeta"] * ratio}


def _two_mass_params(ctx: Context, prefix: str) -> list[Param]:
    """Coupled mass, antiresonance frequency and damping ratio of a second mass on the driven one."""
    return [_p(f"{prefix}_m2", "kg", "Mass coupled elastically to the driven mass", 1e-6 * ctx.mass, ctx.mass,
               zero=1e-6 * ctx.mass),
            _p(f"{prefix}_fa", "Hz", "Antiresonance frequency sqrt(k/m2)/(2 pi)", 5.0, 0.45 / ctx.ts,
               zero=0.45 / ctx.ts),
            _p(f"{prefix}_zeta", "1", "Damping ratio of the coupling (relative to m2)", 1e-3, 0.5)]


def _two_mass_declarations(prefix: str) -> str:
    return (f'  Real {prefix}_x2(unit = "m", start = 0, fixed = true) "Position of the coupled mass";\n'
            f'  Real {prefix}_v2(unit = "m/s", start = 0, fixed = true) "Velocity of the coupled mass";\n'
            f'  Real {prefix}_F(unit = "N") "Coupling force on the driven mass";\n')


def _two_mass_terms(prefix: str) -> tuple[str, str]:
    """Stiffness and damping coefficient of the coupling from PREFIX_m2, PREFIX_fa, PREFIX_zeta."""
    return (f"{prefix}_m2*(6.283185307179586*{prefix}_fa)^2",
            f"2*{prefix}_zeta*{prefix}_m2*6.283185307179586*{prefix}_fa")


BACKLASH_EPS = 1e-7    # rounding of the gap's corners [m of the measured output]


def backlash(ctx: Context) -> Effect:
    """Backlash (MotionTwin.Effects.BacklashJoint): a load mass m2 behind a gap of 2*b in a compliant
    transmission. The load is taken out of the plant's mass (the motor is plant.m - m2), so plant.m stays the
    total mass the nominal refit found and the fit starts at the nominal's low-frequency behaviour."""
    def init(c: Context) -> list[dict[str, float]]:
        guesses = c.resonance_guess or [0.1 / c.ts]
        return [{"backlash_m2": 0.3 * c.mass, "backlash_fa": f_res / math.sqrt(1.5), "backlash_zeta": 0.05,
                 "backlash_b": gap / _scale(c)} for f_res in guesses[:3] for gap in (2e-6, 1e-5, 4e-5)]
    params = [_p("backlash_m2", "kg", "Load mass behind the gap (the motor mass is plant.m - m2)", 1e-6 * ctx.mass,
                 0.9 * ctx.mass, zero=1e-6 * ctx.mass, physical=(True, True))] + _two_mass_params(ctx, "backlash")[1:] + [
        _p("backlash_b", "m", "Half-width of the gap (total backlash 2*b)", 0.0, 1e-4 / _scale(ctx), zero=0.0),
        _p("backlash_eps", "m", "Rounding of the gap corners", BACKLASH_EPS / _scale(ctx),
           BACKLASH_EPS / _scale(ctx), False)]
    k, c = _two_mass_terms("backlash")
    gap = "$x - backlash_x2, backlash_b, backlash_eps"
    eqs = ["der(backlash_x2) = backlash_v2",
           "backlash_m2*der(backlash_v2) = backlash_F",
           f"backlash_F = {k}*MotionTwin.Effects.DeadZone({gap}) + "
           f"{c}*MotionTwin.Effects.DeadZoneSlope({gap})*($v - backlash_v2)"]
    return Effect("backlash", "resonance", params, _two_mass_declarations("backlash"),
                  "backlash_F - backlash_m2*der($v)", eqs,
                  ["DeadZone.mo", "DeadZoneSlope.mo"], init,
                  lambda v, c: {"b": v["backlash_b"] * abs(c.position_gain),
                                "gap": 2 * v["backlash_b"] * abs(c.position_gain),
                                **_two_mass_contract({**v, "plant.m": v.get("plant.m", c.mass) - v["backlash_m2"]},
                                                     c, "backlash")},
                  "A gap in a compliant transmission between the motor and a load mass: inside the gap the "
                  "motor moves alone, in contact the pair is a two-mass resonator; the residual shows a force "
                  "step at every velocity reversal (the load is picked up after crossing the gap) and the "
                  "contact resonance in the swept sine.", tracks_position=["backlash_x2"])


LUGRE_STEP = 4       # the bristle state's rate |v|/z0 times Ts stays below this at the top recorded speed
LUGRE_VS_START = 0.05   # the Stribeck velocity's start, a share of the top recorded speed (no slope at Fs = Fc)


def lugre_friction(ctx: Context) -> Effect:
    """LuGre friction (Canudas de Wit et al. 1995) with its Stribeck curve g(v) = Fc + (Fs - Fc) exp(-(v/vs)^2)
    and its bristle damping sigma1, the viscous part sigma2 at 0 (the plant's d is the viscous part); Fs = Fc,
    sigma1 = 0 is Dahl's form. The bristle state is written as the bristle force F_z = sigma0*z, so that it starts
    at the held force (its vanishing point Fc, Fs -> 0 is then the current model only after the first few z0 of
    travel).
    Why the Stribeck curve: in Dahl's form the fit bends z0 to stand in for a breakaway above the sliding level
    (the independent tuning-set truth, Fs = 1.5 Fc: z0 58 % low and the recorded force left 1.59x its floor).
    Why sigma1: without it the fresh-seed LuGre truth (sigma1 0.2 of the pre-sliding spring's critical damping)
    ended at a breakaway 12x too high with vs and z0 on their lower limits, its cost above Coulomb friction's."""
    z0_min = max(1e-6 / _scale(ctx), ctx.v_max * ctx.ts / LUGRE_STEP)

    def init(c: Context) -> list[dict[str, float]]:
        fc = abs(float(_ls([_sign(c), np.ones_like(c.v)], c.force)[0])) if c.force is not None else 0.1
        return [{"lugre_Fc": max(fc, 1e-3), "lugre_dFs": 0.0, "lugre_vs": LUGRE_VS_START * c.v_max,
                 "lugre_z0": k * z0_min, "lugre_sigma1": 0.0} for k in (4, 1.5, 16)]
    z0_max = max(1e-3 / _scale(ctx), 10 * z0_min)
    params = [_p("lugre_Fc", "N", "Coulomb (sliding) friction level", 1e-6, 1e4, zero=1e-6),
              _p("lugre_dFs", "N", "Static (breakaway) friction level above the Coulomb level, Fs - Fc", 0.0, 1e4,
                 zero=0.0),
              _p("lugre_vs", "m/s", "Stribeck velocity", 1e-4 / _scale(ctx), max(ctx.v_max, 1e-3 / _scale(ctx))),
              _p("lugre_z0", "m", "Pre-sliding displacement Fc/sigma0 (bristle deflection in sliding)", z0_min,
                 z0_max, physical=(True, True)),   # z0_min: the RK4 substeps; z0_max: a spring, not friction
              _p("lugre_sigma1", "N.s/m", "Bristle damping (of the pre-sliding spring)", 0.0,
                 LUGRE_STEP * ctx.mass / ctx.ts, zero=0.0, physical=(False, True))]   # its rate sigma1/m: as z0_min
    decl = ('  Real lugre_Fz(unit = "N", start = 0, fixed = true) "Bristle force sigma0*z";\n'
            '  Real lugre_F(unit = "N") "LuGre friction force";\n'
            '  Real lugre_dz(unit = "m/s") "Rate of the bristle deflection";\n')
    eqs = ["(lugre_F, lugre_dz) = MotionTwin.Effects.LuGreFriction($v, lugre_z0/lugre_Fc*lugre_Fz, lugre_Fc, "
           "lugre_Fc + lugre_dFs, lugre_vs, lugre_Fc/lugre_z0, lugre_sigma1, 0.0)",
           "der(lugre_Fz) = lugre_Fc/lugre_z0*lugre_dz"]
    return Effect("lugre_friction", FRICTION, params, decl, "lugre_F", eqs, ["LuGreFriction.mo"], init,
                  lambda v, c: {"Fc": v["lugre_Fc"], "Fs": v["lugre_Fc"] + v["lugre_dFs"],
                                "vs": v["lugre_vs"] * abs(c.position_gain), "z0": v["lugre_z0"] * abs(c.position_gain),
                                "sigma0": v["lugre_Fc"] / (v["lugre_z0"] * abs(c.position_gain)),
                                "sigma1": v["lugre_sigma1"] / abs(c.position_gain)},
                  "Friction with pre-sliding (LuGre bristle model): after each velocity reversal the friction force "
                  "builds up over a displacement of about z0 instead of switching with the velocity, so the residual "
                  "is a hysteresis loop in position around every reversal and the axis behaves like a spring of "
                  "stiffness sigma0 = Fc/z0, damped by sigma1, at rest; in sliding it follows the Stribeck curve "
                  "from the breakaway level Fs down to the Coulomb level Fc over the Stribeck velocity vs.",
                  tracks_force=["lugre_Fz"], min_substeps=math.ceil(ctx.v_max * ctx.ts / z0_min),
                  unphysical=lambda v: "" if v["lugre_z0"] < 0.99 * z0_max else "its pre-sliding displacement "
                  "reaches the largest one allowed (a spring holding a force over the stroke, not friction)")


def _u_max(ctx: Context) -> float:
    return float(np.max(np.abs(ctx.u))) if ctx.u is not None and ctx.u.size else 1e4


def _saturation_excess(u: np.ndarray, limit: float) -> np.ndarray:
    return u - np.clip(u, -limit, limit)


#: limits tried between the largest peaks of the recorded force (a concealed limit clips a few peaks only)
PEAK_LIMITS = 24


def _peak_limits(u: np.ndarray) -> list[float]:
    """Limits halfway between consecutive heights of the ``PEAK_LIMITS`` + 1 largest peaks of |u|: each clips
    one more of them. Why: the cost in a limit is a needle (flat above the largest force, a wound-up loop that
    diverges a little below the true limit), which quantiles of |u| (the 99.5 % one is far below a peak hit a
    few times) and a local search do not find; the limit that clips exactly the peaks the data show clipped
    does, and the screening ranks these starts by one free run each."""
    magnitude = np.abs(u)
    peaks, _ = find_peaks(magnitude)
    heights = np.sort(magnitude[peaks])[::-1][:PEAK_LIMITS + 1]
    return [float(0.5 * (a + b)) for a, b in zip(heights[:-1], heights[1:]) if a > b]


def actuator_saturation(ctx: Context) -> Effect:
    u_max = _u_max(ctx)

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None or c.u is None:
            return [{"saturation_Fmax": 0.9 * u_max}]
        best = []
        for limit in np.quantile(np.abs(c.u), [0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995]):
            cols = [_saturation_excess(c.u, limit), _sign(c), np.ones_like(c.u)]
            coef, *_ = np.linalg.lstsq(np.column_stack(cols), c.force, rcond=None)
            rest = c.force - np.column_stack(cols) @ coef
            best.append((float(np.sum(rest ** 2)), float(limit)))
        return [{"saturation_Fmax": limit} for _, limit in sorted(best)[:3]] + [
            {"saturation_Fmax": limit} for limit in _peak_limits(c.u)]
    params = [_p("saturation_Fmax", "N", "Force limit of the actuator (current limit of the amplifier)",
                 0.2 * u_max, 1.5 * u_max, zero=1.5 * u_max),
              _p("saturation_eps", "N", "Rounding of the saturation corners", 1e-3 * u_max, 1e-3 * u_max, False)]
    return Effect("actuator_saturation", "actuator_saturation", params, "",
                  "u - MotionTwin.Effects.SaturatedForce(u, saturation_Fmax, saturation_eps)", [],
                  ["SaturatedForce.mo"], init, lambda v, c: {"Fmax": v["saturation_Fmax"]},
                  "The actuator delivers at most +-Fmax (amplifier current limit): the residual is zero for "
                  "small commands and grows as u - Fmax*sign(u) on the largest |u| (fast moves, the sweep), "
                  "in the direction of the command.")


COGGING_ORDERS = range(1, 13)   # cogging periods per pole pitch tried (e.g. slots per pole)


def _cogging_fit(c: Context, pitch: float, order: int) -> float:
    """Residual sum of squares of the force residual after the two cogging harmonics of ``order``."""
    theta = 2 * np.pi * order * c.x / pitch
    cols = np.column_stack([np.sin(theta), np.cos(theta), np.sin(2 * theta), np.cos(2 * theta),
                            np.ones_like(c.x), _sign(c)])
    coef, *_ = np.linalg.lstsq(cols, c.force, rcond=None)
    return float(np.sum((c.force - cols @ coef) ** 2))


def cogging_order(c: Context, pitch: float) -> int:
    """Cogging periods per pole pitch whose two harmonics explain most of the force residual (1 without it)."""
    if c.force is None or c.x is None:
        return 1
    return min(COGGING_ORDERS, key=lambda order: _cogging_fit(c, pitch, order))


def cogging(ctx: Context) -> Effect:
    """Cogging tied to the motor's pole pitch: period pole_pitch/n (n an integer, chosen from the residual)
    and its second harmonic. Only with ``plant.pole_pitch`` in the bundle; else ``position_ripple`` (free
    period, one harmonic) stands for any force periodic in position."""
    span = max(ctx.x_max - ctx.x_min, 1e-6 / _scale(ctx))
    pitch = ctx.pole_pitch if ctx.pole_pitch is not None else span / 4
    order = cogging_order(ctx, pitch)

    def init(c: Context) -> list[dict[str, float]]:
        start = {"cogging_a1": 0.0, "cogging_b1": 0.0, "cogging_a2": 0.0, "cogging_b2": 0.0}
        if c.force is None:
            return [start]
        theta = 2 * np.pi * order * c.x / pitch
        coef = _ls([np.sin(theta), np.cos(theta), np.sin(2 * theta), np.cos(2 * theta), np.ones_like(c.x),
                    _sign(c)], c.force)
        return [dict(zip(start, (float(a) for a in coef[:4])))]
    params = [_p("cogging_a1", "N", "Sine amplitude of the fundamental", -1e4, 1e4, zero=0.0),
              _p("cogging_b1", "N", "Cosine amplitude of the fundamental", -1e4, 1e4, zero=0.0),
              _p("cogging_a2", "N", "Sine amplitude of the second harmonic", -1e4, 1e4, zero=0.0),
              _p("cogging_b2", "N", "Cosine amplitude of the second harmonic", -1e4, 1e4, zero=0.0),
              _p("cogging_pitch", "m", "Magnet pole pitch (plant.pole_pitch)", pitch, pitch, False),
              _p("cogging_n", "1", "Cogging periods per pole pitch", order, order, False),
              _p("cogging_zero", "rad", "Phase of the sine parts", 0.0, 0.0, False),
              _p("cogging_quarter", "rad", "Phase of the cosine parts", math.pi / 2, math.pi / 2, False)]
    harmonics = "cogging_pitch, cogging_n, cogging_{0}1, cogging_{0}2, cogging_{1}, cogging_{1}"
    return Effect("cogging", "position_ripple", params, "",
                  f"MotionTwin.Effects.CoggingForce($x, {harmonics.format('a', 'zero')}) + "
                  f"MotionTwin.Effects.CoggingForce($x, {harmonics.format('b', 'quarter')})", [],
                  ["CoggingForce.mo"], init,
                  lambda v, c: {"A1": float(math.hypot(v["cogging_a1"], v["cogging_b1"])),
                                "A2": float(math.hypot(v["cogging_a2"], v["cogging_b2"])),
                                "n": v["cogging_n"],
                                "period": abs(v["cogging_pitch"] * c.position_gain) / v["cogging_n"]},
                  "Cogging of a permanent-magnet motor: a force periodic in position with the period "
                  "pole_pitch/n and its second harmonic, at any speed (position_ripple has a free period and "
                  "one harmonic).", applicable=ctx.pole_pitch is not None)


def load_dependent_friction(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None or c.u is None:
            return [{"load_Fc0": 0.1, "load_mu": 0.01, "load_v_eps": _v_eps(c)}]
        fc0, mu = _ls([_sign(c), np.abs(c.u) * _sign(c), np.ones_like(c.v)], c.force)[:2]
        return [{"load_Fc0": max(float(fc0), 1e-3), "load_mu": max(float(mu), 1e-4), "load_v_eps": _v_eps(c)}]
    params = [_p("load_Fc0", "N", "Coulomb friction level without load", 0.0, 1e4, zero=0.0),
              _p("load_mu", "1", "Friction rise per newton of drive force", 0.0, 2.0, zero=0.0),
              _p("load_v_eps", "m/s", "Velocity scale of the tanh (presliding)", *_eps_bounds(ctx))]
    return Effect("load_dependent_friction", FRICTION, params, "",
                  "MotionTwin.Effects.LoadDependentFriction($v, u, load_Fc0, load_mu, load_v_eps)", [],
                  ["LoadDependentFriction.mo"], init, lambda v, c: {"Fc0": v["load_Fc0"], "mu": v["load_mu"]},
                  "Friction that grows with the drive force (gear, screw or preloaded bearing friction): the "
                  "residual opposes the motion like Coulomb friction, with a level that rises with |u| (larger "
                  "while accelerating than while cruising).")


def friction_drift(ctx: Context) -> Effect:
    """Coulomb friction whose level drifts over the run with a first-order (thermal) state s, s(0) = 0:
    Fc = Fc0 + dFc*s, tau*der(s) = 1 - s (a state, not ``time``: the loop's dynamics are time-invariant).
    Each recording starts at s = 0, i.e. train and validation start in the same thermal state."""
    duration = ctx.duration or 1.0
    shortest = 0.05 * duration   # a drift over the run, not a change confined to its start (never widened)

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None:
            return [{"drift_Fc0": 0.1, "drift_dFc": 0.0, "drift_tau": duration, "drift_v_eps": _v_eps(c)}]
        t = np.arange(c.force.size) * c.ts
        best = []
        for tau in (0.2 * duration, 0.5 * duration, duration):
            cols = np.column_stack([_sign(c), _sign(c) * (1 - np.exp(-t / tau)), np.ones_like(t)])
            coef, *_ = np.linalg.lstsq(cols, c.force, rcond=None)
            best.append((float(np.sum((c.force - cols @ coef) ** 2)), tau, float(coef[0]), float(coef[1])))
        _, tau, fc0, dfc = min(best)
        fc0 = max(fc0, 1e-3)   # the slope of a noisy residual overshoots: start at most half the level
        return [{"drift_Fc0": fc0, "drift_dFc": float(np.clip(dfc, -0.5 * fc0, 0.5 * fc0)), "drift_tau": tau,
                 "drift_v_eps": _v_eps(c)}]
    params = [_p("drift_Fc0", "N", "Coulomb friction level at the start of the recording", 0.0, 1e4,
                 zero=0.0),
              _p("drift_dFc", "N", "Change of the Coulomb level once settled", -1e4, 1e4, zero=0.0),
              _p("drift_tau", "s", "Time constant of the drift", shortest, 10 * duration, physical=(True, False)),
              _p("drift_v_eps", "m/s", "Velocity scale of the tanh (presliding)", *_eps_bounds(ctx))]
    decl = '  Real drift_s(start = 0, fixed = true) "Progress of the drift, 1 - exp(-t/tau)";\n'
    return Effect("friction_drift", FRICTION, params, decl,
                  "MotionTwin.Effects.CoulombFriction($v, drift_Fc0 + drift_dFc*drift_s, drift_v_eps)",
                  ["drift_tau*der(drift_s) = 1 - drift_s"], ["CoulombFriction.mo"], init,
                  lambda v, c: {"Fc_start": v["drift_Fc0"], "dFc": v["drift_dFc"], "tau": v["drift_tau"]},
                  "Coulomb friction whose level changes slowly over the run (the lubricant warms up): the "
                  "residual jumps with the sign of the velocity as for Coulomb friction, by an amount that "
                  "trends over time, Fc0 + dFc*(1 - exp(-t/tau)) from the start of the recording.",
                  unphysical=lambda v: "its friction level falls below 0 (a force pushing along the motion)"
                  if min(v["drift_Fc0"], v["drift_Fc0"] + v["drift_dFc"]) < 0 else
                  f"its time constant is the shortest the model allows ({shortest:.3g} s, a twentieth of the run): "
                  f"a change confined to the run's start is a start transient, not a drift over the run"
                  if v["drift_tau"] <= 1.01 * shortest else "")


VOCABULARY: dict[str, Callable[[Context], Effect]] = {
    "gravity_offset": gravity_offset,
    "coulomb_friction": coulomb_friction,
    "asymmetric_friction": asymmetric_friction,
    "stribeck_friction": stribeck_friction,
    "position_ripple": position_ripple,
    "position_dependent_inertia": position_dependent_inertia,
    "time_delay": time_delay,
    "resonance": resonance,
    "backlash": backlash,
    "lugre_friction": lugre_friction,
    "actuator_saturation": actuator_saturation,
    "cogging": cogging,
    "load_dependent_friction": load_dependent_friction,
    "friction_drift": friction_drift,
    "encoder_error": encoder_error,
}

#: richer effect -> the simpler effect it contains (preferred unless the extra parameters earn their place)
NESTED = {"stribeck_friction": "coulomb_friction", "asymmetric_friction": "coulomb_friction",
          "lugre_friction": "coulomb_friction", "load_dependent_friction": "coulomb_friction",
          "friction_drift": "coulomb_friction", "backlash": "resonance"}

#: richer effect -> its values that reproduce the simpler effect it nests, from the simpler one's fitted values:
#: the start of a fit in place of the simpler one, so that fit cannot end above the model it replaces (exact for
#: the tanh frictions; LuGre's stiffest bristle only approximates Coulomb friction)
NESTED_START: dict[str, Callable[[dict[str, float]], dict[str, float]]] = {
    "stribeck_friction": lambda v: {"stribeck_Fc": v["coulomb_Fc"], "stribeck_Fs": v["coulomb_Fc"],
                                    "stribeck_v_eps": v["coulomb_v_eps"]},
    "asymmetric_friction": lambda v: {"asym_Fc_pos": v["coulomb_Fc"], "asym_Fc_neg": v["coulomb_Fc"],
                                      "asym_v_eps": v["coulomb_v_eps"]},
    "load_dependent_friction": lambda v: {"load_Fc0": v["coulomb_Fc"], "load_mu": 0.0,
                                          "load_v_eps": v["coulomb_v_eps"]},
    "friction_drift": lambda v: {"drift_Fc0": v["coulomb_Fc"], "drift_dFc": 0.0, "drift_v_eps": v["coulomb_v_eps"]},
    "lugre_friction": lambda v: {"lugre_Fc": v["coulomb_Fc"], "lugre_dFs": 0.0, "lugre_z0": 0.0,
                                 "lugre_sigma1": 0.0},
}

#: richer effect -> the simpler effect's values nearest to it, from the richer one's fitted values and the context
#: (a mean level, its sign's velocity scale): the start of a fit of the simpler effect in its place, the mirror of
#: ``NESTED_START`` (the tanh frictions)
NESTED_PROJECTION: dict[str, Callable[[dict[str, float], Context], dict[str, float]]] = {
    "stribeck_friction": lambda v, c: {"coulomb_Fc": v["stribeck_Fc"], "coulomb_v_eps": v["stribeck_v_eps"]},
    "asymmetric_friction": lambda v, c: {"coulomb_Fc": 0.5 * (v["asym_Fc_pos"] + v["asym_Fc_neg"]),
                                         "coulomb_v_eps": v["asym_v_eps"]},
    "load_dependent_friction": lambda v, c: {
        "coulomb_Fc": v["load_Fc0"] + v["load_mu"] * (float(np.mean(np.abs(c.u))) if c.u is not None else 0.0),
        "coulomb_v_eps": v["load_v_eps"]},
    "friction_drift": lambda v, c: {"coulomb_Fc": v["drift_Fc0"] + 0.5 * v["drift_dFc"],
                                    "coulomb_v_eps": v["drift_v_eps"]},
}
