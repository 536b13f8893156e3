"""Margins of the discrete loop the 2 kHz DSP closes around the Cheung & Hung robust joint controller.

The loop is what the 2 kHz DSP closes: the plant P(s) (eqs. 6-8, ``ident.frf.JointModel`` or any stable
continuous LTI) behind a zero-order hold, optionally one sample of computation delay, and the controller
exactly as the FMU runs it: the Tustin matrices Ad, Bd, Cd, Dd of ``MotionTwin.Controllers.RobustJointController``
(``fmus.build.load_model``), evaluated numerically with a ``casadi.Function`` of the parameters. The loop
transfer is L = C(z) z^-d P_zoh(z) with the feedback column of the law (input r; feedforward plays no part in
the margins).

Figures computed per plant set: gain margin GM (eq. 14, dB; the phase crossover whose |L| is nearest 1, as
python-control reports it), phase margin PM (eq. 15; the paper's "PM <= 60 deg" is read as a target band
[pm_min, pm_max], the usual requirement being the lower bound), closed-loop bandwidth CLBW (eq. 16 read as
the lowest frequency where |T| = |L/(1+L)| drops below -3 dB; feedback path only), max |S| below CLBW
(eq. 17), the modulus margin peak Ms = max |S| over all frequencies, the balanced disk margin
1/max|S - 1/2| (python-control ``disk_margins`` with skew 0, on the dense grid) and the slowest closed-loop
time constant tau_cl.

tau_cl (decay-rate / pole-region bound): tau_cl = -Ts / ln max|z_i| over the poles z_i of the sampled closed
loop (ZOH, delay and controller included), i.e. of the "gang of four" r, d -> y, u (d a load force at the
plant input). Why this and not a frequency-domain figure: a PID whose integral zero sits far below the
crossover leaves a closed-loop pole next to z = 1 with a small residue, invisible in GM, PM, Ms and CLBW, that
removes a load change (gravity along the move) only over seconds. Bounding tau_cl <= tau_max places every
pole inside the disk |z| <= exp(-Ts/tau_max) (the discrete form of the classical minimum-decay-rate region,
the D-stability/pole-placement region of robust control); the load-disturbance step response then decays at
least like exp(-t/tau_max), which ties the spec directly to the settling times the application needs: the
paper settles within tens of ms after the move, and a load error of about 10 um (the gravity change along
the move on the Cheung manipulator) falls below the 5 um band within tau ln 2, so default tau_max = 0.03 s
(at most 21 ms). 0.02 s is not reachable together with PM >= 45 deg on the Cheung joint and manipulator
channels (best 28 ms, the PM bound active). The low-frequency
disturbance-rejection bound |P S| would need a frequency and a level per plant; the pole bound needs neither.
Exactly cancelled pole-zero pairs are ignored: modes of the realisation that are uncontrollable from both
r and d or unobservable in both y and u (left/right eigenvector test on the balanced realisation, relative
1e-6; a genuine slow mode scores 1e-2 and more). They arise inside the controller realisation (a notch with
depth sigma = 1, a lag with fc = fp, the derivative filter with Kd = 0) and in the manipulator channels,
whose other-joint friction poles are cancelled by zeros to rounding (scores 1e-8 and below after
``minreal``); they never act on the loop. A controller zero cancelling a plant pole is kept: that pole stays
visible from d to y (internal stability).

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import Callable, Sequence

import casadi as ca
import control
import numpy as np
import scipy.linalg
import scipy.optimize

from motiontwin.ident.frf import JointModel, state_space_response
from motiontwin.ident.tuning.spec import CONTROLLER_CLASS, LoopMargins, TuningError

__all__ = [
    "controller_defaults", "controller_matrices", "controller_system", "check_plant", "discrete_plant",
    "loop_system", "frequency_grid", "closed_loop_modes", "slowest_time_constant", "margins_from_response",
    "loop_margins", "exact_crossovers", "disk_margin_from_response", "position_sets", "feedforward_path_response",
]


@functools.lru_cache(maxsize=1)
def _law() -> tuple[ca.Function, tuple[str, ...], dict[str, float]]:
    """casadi Function p -> feedback-path Tustin matrices (input r, output u) of the controller class."""
    from motiontwin.fmus import build

    model = build.load_model(CONTROLLER_CLASS)
    names = tuple(v.name for v in model.parameters)
    r = [v.name for v in model.inputs].index("r")
    u = [c.var.name for c in model.computed].index("u")
    fn = ca.Function("robust_joint_law", [model.p],
                     [model.Ad, model.Bd[:, r], model.Cd[u, :], model.Dd[u, r]])
    return fn, names, dict(zip(names, model.parameter_values()))


@functools.lru_cache(maxsize=1)
def _feedforward_law() -> ca.Function:
    """casadi Function p -> Tustin matrices of the feedforward path r_dot -> u (F_L F_N times Kv)."""
    from motiontwin.fmus import build

    model = build.load_model(CONTROLLER_CLASS)
    r_dot = [v.name for v in model.inputs].index("r_dot")
    u = [c.var.name for c in model.computed].index("u")
    return ca.Function("robust_joint_feedforward", [model.p],
                       [model.Ad, model.Bd[:, r_dot], model.Cd[u, :], model.Dd[u, r_dot]])


def controller_defaults() -> dict[str, float]:
    """The controller FMU's parameter start values (Table 2 column d1 and tau = 2 Ts)."""
    return dict(_law()[2])


def controller_matrices(parameters: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Ad, Bd, Cd, Dd) of the law r -> u at ``parameters`` (missing ones at the FMU defaults)."""
    fn, names, defaults = _law()
    unknown = sorted(set(parameters) - set(names))
    if unknown:
        raise TuningError(f"{CONTROLLER_CLASS} has no parameter {', '.join(unknown)}")
    p = [float(parameters.get(n, defaults[n])) for n in names]
    return tuple(np.array(m, dtype=float) for m in fn(p))  # type: ignore[return-value]


def controller_system(parameters: dict[str, float]) -> control.StateSpace:
    """The law r -> u as a discrete python-control system with dt = Ts."""
    ts = float(parameters.get("Ts", controller_defaults()["Ts"]))
    return control.ss(*controller_matrices(parameters), dt=ts)


def _plant_fields(plant: JointModel) -> dict[str, float]:
    out = {"gain K": plant.gain, "alpha": plant.alpha}
    for m, ((wr, zr), (wa, za)) in enumerate(zip(plant.resonances, plant.antiresonances), 1):
        out |= {f"omega[{m}]": wr, f"zeta[{m}]": zr, f"omega_bar[{m}]": wa, f"zeta_bar[{m}]": za}
    return out


def check_plant(plant: JointModel | control.LTI, where: str = "plant") -> control.LTI:
    """Continuous P(s) of ``plant``; raises TuningError for a non-identifiable or open-loop unstable plant."""
    if isinstance(plant, JointModel):
        for name, value in _plant_fields(plant).items():
            if not math.isfinite(value):
                raise TuningError(f"{where}: {name} = {value} is not finite (not identified)")
        if plant.gain <= 0:
            raise TuningError(f"{where}: gain K = {plant.gain} must be positive (a zero gain is not identifiable; "
                              "a negative one means the sign of the loop is wrong)")
        for name, value in _plant_fields(plant).items():
            if name.startswith("omega") and value <= 0:
                raise TuningError(f"{where}: {name} = {value} rad/s must be positive")
            if name.startswith(("zeta", "alpha")) and value < 0:
                raise TuningError(f"{where}: {name} = {value} < 0 makes the plant unstable; the margins of "
                                  "eqs. (14)-(17) assume a stable open loop (apart from the integrator)")
        sys = plant.transfer_function()
    else:
        sys = plant
        if sys.isdtime(strict=True):
            raise TuningError(f"{where}: give the continuous plant; it is sampled with a zero-order hold here")
    poles = control.poles(sys)
    if not np.all(np.isfinite(poles)):
        raise TuningError(f"{where}: the plant has non-finite poles (not identified)")
    unstable = poles[poles.real > 1e-9 * max(1.0, float(np.max(np.abs(poles))))]
    if unstable.size:
        raise TuningError(f"{where}: open-loop unstable poles {np.round(unstable, 3).tolist()} rad/s; "
                          "the margins of eqs. (14)-(17) assume a stable open loop (apart from the integrator)")
    if abs(complex(sys(1j))) == 0:
        raise TuningError(f"{where}: the plant has zero gain (not identifiable)")
    return sys


def discrete_plant(plant: JointModel | control.LTI, ts: float, delay_samples: int = 1,
                   where: str = "plant") -> control.StateSpace:
    """P behind a zero-order hold at ``ts`` (python-control 'zoh'), times z^-delay_samples of computation."""
    sys = control.sample_system(control.ss(check_plant(plant, where)), ts, method="zoh")
    if delay_samples:
        sys = control.ss(control.tf([1.0], [1.0] + [0.0] * delay_samples, dt=ts)) * sys
    return sys


def loop_system(parameters: dict[str, float], plant: JointModel | control.LTI, delay_samples: int = 1
                ) -> control.StateSpace:
    """L(z) = C(z) z^-d P_zoh(z), the loop broken at the plant output."""
    c = controller_system(parameters)
    return c * discrete_plant(plant, c.dt, delay_samples)


def frequency_grid(ts: float, points: int = 1500, f_min: float = 0.1) -> np.ndarray:
    """Log grid [Hz] from ``f_min`` to just below the Nyquist frequency 1/(2 ts)."""
    return np.logspace(np.log10(f_min), np.log10(0.9995 / (2 * ts)), points)

_CANCELLED_TOL = 1e-6


def closed_loop_modes(controller: Sequence[np.ndarray], plant: Sequence[np.ndarray]) -> np.ndarray:
    """Poles of the sampled closed loop (u = C(z)(r - y), y = P(z)(u + d)) that act on the loop: eigenvalues of
    the interconnection's state matrix, without modes uncontrollable from both r and d or unobservable in
    both y and u (exactly cancelled pole-zero pairs of the realisation; relative eigenvector test on the
    balanced state matrix, ``scipy.linalg.matrix_balance``, so that the test does not depend on state units).

    ``controller`` is (Ac, Bc, Cc, Dc) and ``plant`` (Ap, Bp, Cp) with D = 0 (ZOH and delay make it so)."""
    ac, bc, cc, dc = (np.atleast_2d(np.asarray(m, dtype=float)) for m in controller)
    ap, bp, cp = (np.atleast_2d(np.asarray(m, dtype=float)) for m in plant)
    n, m = ap.shape[0], ac.shape[0]
    a = np.block([[ap - bp @ dc @ cp, bp @ cc], [-bc @ cp, ac]])
    b = np.column_stack([np.vstack([bp @ dc, bc]), np.vstack([bp, np.zeros((m, bp.shape[1]))])])
    c = np.vstack([np.hstack([cp, np.zeros((cp.shape[0], m))]), np.hstack([-dc @ cp, cc])])
    if n + m == 0:
        return np.zeros(0, dtype=complex)
    a, (scale, _) = scipy.linalg.matrix_balance(a, permute=False, separate=True)
    b, c = b / scale[:, None], c * scale[None, :]
    values, left, right = scipy.linalg.eig(a, left=True, right=True)
    b_unit = b / np.maximum(np.linalg.norm(b, axis=0), np.finfo(float).tiny)
    c_unit = c / np.maximum(np.linalg.norm(c, axis=1), np.finfo(float).tiny)[:, None]
    reach = np.max(np.abs(left.conj().T @ b_unit), axis=1) / np.linalg.norm(left, axis=0)
    seen = np.max(np.abs(c_unit @ right), axis=0) / np.linalg.norm(right, axis=0)
    return values[(reach > _CANCELLED_TOL) & (seen > _CANCELLED_TOL)]


def slowest_time_constant(poles: np.ndarray, ts: float) -> float:
    """tau_cl = -ts / ln max|z| [s] of discrete poles ``poles`` (0 for none or all at the origin, inf if
    max|z| >= 1)."""
    radius = float(np.max(np.abs(poles))) if np.size(poles) else 0.0
    if radius >= 1.0:
        return math.inf
    return 0.0 if radius == 0.0 else -ts / math.log(radius)


def _crossings(x: np.ndarray) -> np.ndarray:
    """Indices i with a sign change of x between i and i+1."""
    return np.nonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))[0]


def margins_from_response(f: np.ndarray, loop: np.ndarray, stable: bool) -> LoopMargins:
    """GM, PM, CLBW, Ms and max |S| below CLBW from the loop response ``loop`` on the grid ``f`` [Hz].

    Crossovers are located by linear interpolation between grid points: GM over the crossings of the
    negative real axis (the one with |L| nearest 1), PM over the crossings of |L| = 1 (the smallest).
    """
    mag = np.abs(loop)
    gm, f_pc = math.inf, math.nan
    for i in _crossings(loop.imag):
        t = loop.imag[i] / (loop.imag[i] - loop.imag[i + 1])
        point = loop[i] + t * (loop[i + 1] - loop[i])
        if point.real < 0:
            g = -20 * math.log10(abs(point.real))
            if abs(g) < abs(gm):
                gm, f_pc = g, f[i] + t * (f[i + 1] - f[i])
    pm, f_gc = math.inf, math.nan
    log_mag = np.log(mag)
    for i in _crossings(log_mag):
        t = log_mag[i] / (log_mag[i] - log_mag[i + 1])
        point = loop[i] + t * (loop[i + 1] - loop[i])
        p = math.degrees(np.angle(-point))
        if p < pm:
            pm, f_gc = p, f[i] + t * (f[i + 1] - f[i])
    s = 1.0 / np.abs(1.0 + loop)
    t_mag = mag * s
    below = np.nonzero(t_mag < 1 / math.sqrt(2))[0]
    if below.size == 0:
        bw = f[-1]
    elif below[0] == 0:
        bw = f[0]
    else:
        i = below[0] - 1
        a, b = math.log(t_mag[i] * math.sqrt(2)), math.log(t_mag[i + 1] * math.sqrt(2))
        bw = math.exp(math.log(f[i]) + a / (a - b) * (math.log(f[i + 1]) - math.log(f[i])))
    s_below = float(np.max(s[f <= bw])) if np.any(f <= bw) else float(s[0])
    return LoopMargins(stable=stable, gm_db=float(gm), pm_deg=float(pm), bandwidth_hz=float(bw),
                       ms=float(np.max(s)), s_below_bw=s_below, gain_crossover_hz=float(f_gc),
                       phase_crossover_hz=float(f_pc))


def loop_margins(parameters: dict[str, float], plant: JointModel | control.LTI, delay_samples: int = 1,
                 points: int = 8000) -> LoopMargins:
    """Margins of the discrete loop built with python-control: stability from the closed-loop poles; GM and PM
    at the exact crossovers (:func:`exact_crossovers`, bracketed on a dense grid of the loop response up to
    Nyquist); CLBW, Ms, max |S| below CLBW and the balanced disk margin (:func:`disk_margin_from_response`) on
    the same grid.

    Why not ``control.stability_margins``: for these 11th-order, lightly damped sampled loops its polynomial
    method is ill-conditioned (a PM of -16.8 deg at 350 Hz where |L| = 0.48), and given the response instead it
    root-finds on a spline through the grid, point by point (1.2 s per loop on 8000 points); the tests keep it
    as the reference (``tests/test_tuning.py``).
    """
    loop = loop_system(parameters, plant, delay_samples)
    ts = loop.dt
    sampled = discrete_plant(plant, ts, delay_samples)
    tau_cl = slowest_time_constant(closed_loop_modes(controller_matrices(parameters),
                                                     (sampled.A, sampled.B, sampled.C)), ts)
    f = frequency_grid(ts, points)
    matrices = (loop.A, loop.B, loop.C, loop.D)
    response = state_space_response(matrices, np.exp(2j * np.pi * f * ts))
    radius = float(np.max(np.abs(control.poles(control.feedback(loop, 1)))))
    stable = radius < 1.0
    grid = margins_from_response(f, response, stable)

    def loop_at(x: float) -> complex:
        return complex(state_space_response(matrices, np.exp(2j * np.pi * x * ts)))

    gm, pm, f_pc, f_gc = exact_crossovers(loop_at, f, response)
    dm, dgm, dpm = disk_margin_from_response(response)
    return LoopMargins(stable=stable, gm_db=gm, pm_deg=pm, bandwidth_hz=grid.bandwidth_hz,
                       ms=grid.ms, s_below_bw=grid.s_below_bw, gain_crossover_hz=f_gc, phase_crossover_hz=f_pc,
                       disk_margin=dm, disk_gm_db=dgm, disk_pm_deg=dpm, spectral_radius=radius, tau_cl=tau_cl)


def exact_crossovers(loop_at: Callable[[float], complex], f: np.ndarray, response: np.ndarray
                     ) -> tuple[float, float, float, float]:
    """(GM [dB], PM [deg], phase crossover [Hz], gain crossover [Hz]) of the loop ``loop_at(f)`` (f in Hz) at its
    exact crossovers, each bracketed by a sign change of Im L (with Re L <= 0 there: the negative real axis) or
    of |L| - 1 between neighbours of the grid ``f`` (``response`` = L on it) and found by Brent's method to
    round-off. The choice as python-control's ``stability_margins``: GM of the phase crossover whose |L| is
    nearest 1, PM (in [-180, 180)) of the gain crossover with the smallest |PM|; inf and nan when there is
    none."""
    gm, f_pc = math.inf, math.nan
    for i in _crossings(response.imag):
        x = scipy.optimize.brentq(lambda v: loop_at(v).imag, f[i], f[i + 1], xtol=1e-13 * f[i], rtol=1e-15)
        value = loop_at(x)
        if value.real <= 0 and abs(value) > 0:
            g = -20 * math.log10(abs(value))
            if abs(g) < abs(gm):
                gm, f_pc = g, x
    pm, f_gc = math.inf, math.nan
    for i in _crossings(np.abs(response) - 1):
        x = scipy.optimize.brentq(lambda v: abs(loop_at(v)) - 1, f[i], f[i + 1], xtol=1e-13 * f[i], rtol=1e-15)
        p = float(np.remainder(math.degrees(np.angle(loop_at(x))), 360.0) - 180.0)
        if abs(p) < abs(pm):
            pm, f_gc = p, x
    return gm, pm, f_pc, f_gc


def disk_margin_from_response(loop: np.ndarray) -> tuple[float, float, float]:
    """Balanced (skew 0) disk margin alpha = 1 / max |S - 1/2| = 1 / max |(S - T)/2| of the loop response
    ``loop`` on a grid, and the disk-based GM [dB] and PM [deg] it guarantees: 20 log10((2 + alpha)/(2 - alpha))
    (inf for alpha >= 2) and 2 atan(alpha/2). The SISO formulas of python-control's ``disk_margins(skew=0)``,
    here on the full dense response: that function re-evaluates the loop per frequency (0.6 s on 8000 points),
    which is why it used to get a grid thinned tenfold."""
    alpha = float(1.0 / np.max(np.abs(1.0 / (1.0 + loop) - 0.5)))
    gm = 20 * math.log10((2 + alpha) / (2 - alpha)) if alpha < 2 else math.inf
    return alpha, gm, math.degrees(2 * math.atan(alpha / 2))


def position_sets(nominal: JointModel, gain_spread: float = 0.3, resonance_spread: float = 0.1
                  ) -> list[JointModel]:
    """Three actuator positions: K*(1 - gain_spread) with resonances raised, nominal, K*(1 + gain_spread) with
    resonances lowered (a heavier linkage load lowers both the gain 1/mass and the resonance)."""
    out = []
    for g, r in ((1 - gain_spread, 1 + resonance_spread), (1.0, 1.0), (1 + gain_spread, 1 - resonance_spread)):
        out.append(JointModel(nominal.gain * g, nominal.alpha,
                              tuple((w * r, z) for w, z in nominal.resonances),
                              tuple((w * r, z) for w, z in nominal.antiresonances)))
    return out


def feedforward_path_response(parameters: dict[str, float], f: np.ndarray) -> np.ndarray:
    """F_L(z) F_N(z) on the grid ``f`` [Hz]: the FMU's Tustin path r_dot -> u with Kv = 1, Ka = Kj = 0."""
    _, names, defaults = _law()
    values = {**defaults, **parameters, "Kv": 1.0, "Ka": 0.0, "Kj": 0.0}
    ts = float(values["Ts"])
    matrices = [np.array(m, dtype=float) for m in _feedforward_law()([float(values[n]) for n in names])]
    return state_space_response(matrices, np.exp(2j * np.pi * f * ts))


class _LoopEvaluator:
    """Margins of candidate designs on every plant set from precomputed plant responses (numpy only)."""

    def __init__(self, plants: Sequence[JointModel | control.LTI], ts: float, delay_samples: int,
                 points: int = 1200):
        self.ts, self.delay = ts, delay_samples
        self.f = frequency_grid(ts, points)
        self.z = np.exp(2j * np.pi * self.f * ts)
        self.plants = []
        for k, plant in enumerate(plants):
            sys = discrete_plant(plant, ts, delay_samples, where=f"plant set {k}")
            a, b, c, d = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
            if abs(d[0, 0]) > 0:
                raise TuningError(f"plant set {k}: the sampled plant must be strictly proper")
            self.plants.append((a, b, c, state_space_response((a, b, c, d), self.z)))

    def response(self, parameters: dict[str, float]) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        matrices = controller_matrices(parameters)
        return state_space_response(matrices, self.z), matrices

    def evaluate(self, parameters: dict[str, float]) -> list[LoopMargins]:
        cz, (ac, bc, cc, dc) = self.response(parameters)
        out = []
        for ap, bp, cp, pz in self.plants:
            n, m = ap.shape[0], ac.shape[0]
            a_cl = np.block([[ap - bp @ dc @ cp, bp @ cc], [-bc @ cp, ac]])
            radius = float(np.max(np.abs(np.linalg.eigvals(a_cl)))) if n + m else 0.0
            margins = margins_from_response(self.f, cz * pz, radius < 1.0)
            if radius < 1.0:
                tau = slowest_time_constant(closed_loop_modes((ac, bc, cc, dc), (ap, bp, cp)), self.ts)
                out.append(replace(margins, spectral_radius=radius, tau_cl=tau))
            else:
                out.append(_unstable(margins, radius))
        return out


def _unstable(m: LoopMargins, radius: float) -> LoopMargins:
    """Marks an unstable loop: no bandwidth, infinite Ms, the closed-loop spectral radius for the penalty."""
    return LoopMargins(stable=False, gm_db=m.gm_db, pm_deg=m.pm_deg, bandwidth_hz=0.0, ms=math.inf,
                       s_below_bw=math.inf, spectral_radius=radius, tau_cl=math.inf)
