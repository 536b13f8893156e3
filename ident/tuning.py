"""Tuning of the Cheung & Hung robust joint controller (eqs. 9-13) against eqs. (14)-(18), on the discrete loop.

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
plus a jerk term for the lag, notch, hold and delay phase. Figures: ``ident.tuning_plots``; per-actuator design
of the coupled manipulator FMU: ``ident.tuning_manipulator``.

Table 2 comparison: the paper's gains are in its own (unknown) units, so on an SI plant only the controller
shape is comparable; Kp, Ki, Kd are scaled by one factor g chosen so that the CLBW on our plant equals the
paper's CLBW for that column, and the GM, PM, max |S| reached are printed beside the paper's.

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

import functools
import math
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Sequence

import casadi as ca
import control
import numpy as np
import scipy.linalg
import scipy.optimize

from motiontwin.ident.frf import JointModel

__all__ = [
    "CONTROLLER_CLASS", "TuningError", "InfeasibleSpecError", "TuningSpec", "LoopMargins", "TuningResult",
    "DESIGN_BOUNDS", "TABLE2", "controller_defaults", "controller_matrices", "controller_system", "check_plant",
    "discrete_plant", "loop_system", "margins_from_response", "loop_margins", "position_sets", "tune",
    "rescale_to_bandwidth", "table2_comparison", "format_comparison", "format_margins", "violations",
    "frequency_grid", "DESIGN_NAMES", "parse_plant", "cli_tune", "FeedforwardFit", "feedforward_gains",
    "feedforward_path_response", "comparison_markdown", "closed_loop_modes", "slowest_time_constant",
    "disk_margin_from_response",
]

CONTROLLER_CLASS = "MotionTwin.Controllers.RobustJointController"
DESIGN_NAMES = ("Kp", "Ki", "Kd", "KL", "fp", "fc", "sigma", "wl", "wh")

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

# Cheung & Hung Table 2 (gains in the paper's own units; fp, fc, wl = omega_r, wh = omega_b in Hz) and the
# paper's figures GM [dB], PM [deg], CLBW [Hz], S (max |S| below CLBW).
TABLE2: dict[str, dict[str, float]] = {
    "d1": dict(Kp=0.7987, Ki=0.003, Kd=15.1038, Kv=4.8751, Ka=60.411, KL=10, fp=305, fc=533, wl=380, wh=400,
               sigma=15, GM=8.01, PM=50, CLBW=69.6, S=0.98),
    "d3": dict(Kp=0.7229, Ki=0.001, Kd=12.8725, Kv=5.5518, Ka=32.757, KL=10, fp=316, fc=716, wl=446, wh=300,
               sigma=25, GM=8.02, PM=50, CLBW=73.4, S=0.85),
    "d5": dict(Kp=0.9122, Ki=0.0005, Kd=13.1532, Kv=2.8185, Ka=31.04, KL=10, fp=320, fc=690, wl=355, wh=400,
               sigma=15, GM=8.69, PM=49.3, CLBW=59.3, S=0.94),
    "d7": dict(Kp=0.8438, Ki=0.01, Kd=15.4567, Kv=9.6264, Ka=49.411, KL=10, fp=305, fc=617, wl=370, wh=300,
               sigma=30, GM=8.55, PM=60, CLBW=56.1, S=0.7),
}
_PAPER_FIGURES = ("GM", "PM", "CLBW", "S")


class TuningError(ValueError):
    """The plant or the request cannot be tuned for; the message names the plant set and field."""


class InfeasibleSpecError(TuningError):
    """No design meets the spec; ``violations`` lists (constraint, value reached, limit, unit) of the best design."""

    def __init__(self, message: str, violations: list[tuple[str, float, float, str]], result: "TuningResult"):
        super().__init__(message)
        self.violations = violations
        self.result = result


@dataclass(frozen=True)
class TuningSpec:
    """Requirements of eqs. (14)-(17): GM [dB] lower bound, PM band [deg], Ms upper bound, optional eq. (17)
    bound on max |S| below CLBW, optional worst-case CLBW lower bound [Hz] (eq. 16's target) and the bound
    tau_max_s [s] on the slowest closed-loop time constant (None: not constrained)."""

    gm_min_db: float = 7.0
    pm_min_deg: float = 45.0
    pm_max_deg: float = 60.0
    ms_max: float = 2.0
    s_below_bw_max: float | None = None
    bandwidth_min_hz: float | None = None
    tau_max_s: float | None = 0.03

    def __post_init__(self) -> None:
        for name, flag in (("gm_min_db", "--gm"), ("pm_min_deg", "--pm-min"), ("pm_max_deg", "--pm-max"),
                           ("ms_max", "--ms"), ("s_below_bw_max", "--s-below-bw"), ("bandwidth_min_hz", "--bw-min"),
                           ("tau_max_s", "--tau-max")):
            value = getattr(self, name)
            optional = name in ("s_below_bw_max", "bandwidth_min_hz", "tau_max_s")
            if value is None and optional:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) or (
                    math.isinf(value) and name != "tau_max_s"):
                raise TuningError(f"TuningSpec: {name} ({flag}) must be a finite number, got {value!r}")
        if not self.pm_min_deg < self.pm_max_deg:
            raise TuningError(f"TuningSpec: pm_min_deg {self.pm_min_deg} must be below pm_max_deg {self.pm_max_deg}")
        if self.ms_max <= 1.0:
            raise TuningError(f"TuningSpec: ms_max {self.ms_max} must exceed 1 (max |S| >= 1 for any loop)")
        if self.tau_max_s is not None and not self.tau_max_s > 0:
            raise TuningError(f"TuningSpec: tau_max_s {self.tau_max_s} s must be positive (or None)")


@dataclass(frozen=True)
class LoopMargins:
    """Margins of one discrete loop. Frequencies in Hz; nan where a crossover does not exist; tau_cl [s] the
    slowest closed-loop time constant (cancelled pairs excluded, see the module docstring)."""

    stable: bool
    gm_db: float
    pm_deg: float
    bandwidth_hz: float
    ms: float
    s_below_bw: float
    gain_crossover_hz: float = math.nan
    phase_crossover_hz: float = math.nan
    disk_margin: float = math.nan
    disk_gm_db: float = math.nan
    disk_pm_deg: float = math.nan
    spectral_radius: float = math.nan
    tau_cl: float = math.nan


@dataclass
class TuningResult:
    """Tuned controller parameters (FMU names and units) and the margins on every plant set."""

    parameters: dict[str, float]
    margins: list[LoopMargins]
    spec: TuningSpec
    sample_period: float
    delay_samples: int
    violations: list[tuple[str, float, float, str]] = field(default_factory=list)
    feedforward: FeedforwardFit | None = None

    def as_dict(self) -> dict:
        """JSON-ready: ``{"parameters": ...}`` is what ``motiontwin writeback --values`` reads (with Kv, Ka, Kj
        when the feedforward was fitted; ``feedforward`` then holds the band and residual of the fit)."""
        return {"method": "differential evolution + Nelder-Mead + SLSQP on the discrete loop (Cheung eqs. 14-18)",
                "parameters": self.parameters, "spec": asdict(self.spec), "sample_period": self.sample_period,
                "delay_samples": self.delay_samples, "margins": [asdict(m) for m in self.margins],
                "violations": [list(v) for v in self.violations],
                "feedforward": None if self.feedforward is None else asdict(self.feedforward)}


# ---------------------------------------------------------------- controller law (the FMU's own matrices)

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


# ---------------------------------------------------------------- plant and loop

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
    """Margins of the discrete loop built with python-control: stability from the closed-loop poles, GM/PM
    from ``control.stability_margins`` on a dense grid of the loop response up to Nyquist; CLBW, Ms, max |S|
    below CLBW and the balanced disk margin (:func:`disk_margin_from_response`) on the same grid.

    stability_margins gets the (mag, phase, omega) response, not the system: for these 11th-order, lightly
    damped sampled loops its polynomial method is ill-conditioned and its 'frd' fallback interpolates a
    coarse grid, which reported e.g. a PM of -16.8 deg at 350 Hz where |L| = 0.48.
    """
    loop = loop_system(parameters, plant, delay_samples)
    ts = loop.dt
    sampled = discrete_plant(plant, ts, delay_samples)
    tau_cl = slowest_time_constant(closed_loop_modes(controller_matrices(parameters),
                                                     (sampled.A, sampled.B, sampled.C)), ts)
    f = frequency_grid(ts, points)
    w = 2 * np.pi * f
    response = np.asarray(loop(np.exp(1j * w * ts))).reshape(-1)
    radius = float(np.max(np.abs(control.poles(control.feedback(loop, 1)))))
    stable = radius < 1.0
    grid = margins_from_response(f, response, stable)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, _, wpc, wgc, _ = control.stability_margins((np.abs(response), np.degrees(np.angle(response)), w))
    dm, dgm, dpm = disk_margin_from_response(response)
    return LoopMargins(stable=stable, gm_db=float(20 * np.log10(gm)) if np.isfinite(gm) else math.inf,
                       pm_deg=float(pm) if np.isfinite(pm) else math.inf, bandwidth_hz=grid.bandwidth_hz,
                       ms=grid.ms, s_below_bw=grid.s_below_bw,
                       gain_crossover_hz=float(wgc / (2 * np.pi)), phase_crossover_hz=float(wpc / (2 * np.pi)),
                       disk_margin=dm, disk_gm_db=dgm, disk_pm_deg=dpm, spectral_radius=radius, tau_cl=tau_cl)


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


# ---------------------------------------------------------------- feedforward (eq. 12)

@dataclass(frozen=True)
class FeedforwardFit:
    """Feedforward gains of eq. (12) [N s/m, N s^2/m, N s^3/m], the band they were fitted on [Hz] and the
    largest relative tracking residual |1 - F_L F_N G_f P| over the band and the plant sets."""

    Kv: float
    Ka: float
    Kj: float
    band_hz: tuple[float, float]
    residual: float

    def gains(self) -> dict[str, float]:
        return {"Kv": self.Kv, "Ka": self.Ka, "Kj": self.Kj}


def feedforward_path_response(parameters: dict[str, float], f: np.ndarray) -> np.ndarray:
    """F_L(z) F_N(z) on the grid ``f`` [Hz]: the FMU's Tustin path r_dot -> u with Kv = 1, Ka = Kj = 0."""
    _, names, defaults = _law()
    values = {**defaults, **parameters, "Kv": 1.0, "Ka": 0.0, "Kj": 0.0}
    ts = float(values["Ts"])
    a, b, c, d = (np.array(m, dtype=float) for m in _feedforward_law()([float(values[n]) for n in names]))
    z = np.exp(2j * np.pi * f * ts)
    x = np.linalg.solve(z[:, None, None] * np.eye(a.shape[0]) - a, np.broadcast_to(b, (z.size,) + b.shape))
    return (c @ x)[:, 0, 0] + d[0, 0]


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
        pz = np.asarray(discrete_plant(plant, ts, delay_samples, where=f"plant set {k}")(z)).reshape(-1)
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


# ---------------------------------------------------------------- fast evaluation for the search

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
            self.plants.append((a, b, c, np.asarray(sys(self.z)).reshape(-1)))

    def response(self, parameters: dict[str, float]) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        a, b, c, d = controller_matrices(parameters)
        eye = np.eye(a.shape[0])
        x = np.linalg.solve(self.z[:, None, None] * eye - a, np.broadcast_to(b, (self.z.size,) + b.shape))
        return (c @ x)[:, 0, 0] + d[0, 0], (a, b, c, d)

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


def _decode(x: np.ndarray, k_min: float, fixed: dict[str, float]) -> dict[str, float]:
    """Optimiser coordinates -> controller parameters (see DESIGN_BOUNDS; fc kept below Nyquist)."""
    f0, width = x[7], x[8]
    half = width / 2
    kp, kd = 10 ** x[0] / k_min, 10 ** x[2] / k_min
    return {**fixed, "Kp": kp, "Ki": 10 ** x[1] * kp ** 2 / (4 * kd), "Kd": kd, "KL": x[3],
            "fp": x[4], "fc": min(x[4] * x[5], 0.95 / (2 * fixed["Ts"])), "sigma": 10 ** x[6],
            "wl": f0 * (math.sqrt(1 + half ** 2) - half), "wh": f0 * (math.sqrt(1 + half ** 2) + half)}


def violations(margins: Iterable[LoopMargins], spec: TuningSpec) -> list[tuple[str, float, float, str]]:
    """(constraint, worst value reached over the plant sets, limit, unit) for each constraint missed."""
    margins = list(margins)
    out = []
    if not all(m.stable for m in margins):
        out.append(("closed-loop stability (spectral radius < 1)",
                    max(m.spectral_radius for m in margins if not m.stable), 1.0, ""))
        return out
    gm = min(abs(m.gm_db) for m in margins)
    if gm < spec.gm_min_db:
        out.append((f"GM >= {spec.gm_min_db:g} dB", gm, spec.gm_min_db, "dB"))
    pm_lo, pm_hi = min(m.pm_deg for m in margins), max(m.pm_deg for m in margins)
    if pm_lo < spec.pm_min_deg:
        out.append((f"PM >= {spec.pm_min_deg:g} deg", pm_lo, spec.pm_min_deg, "deg"))
    if pm_hi > spec.pm_max_deg:
        out.append((f"PM <= {spec.pm_max_deg:g} deg", pm_hi, spec.pm_max_deg, "deg"))
    ms = max(m.ms for m in margins)
    if ms > spec.ms_max:
        out.append((f"Ms = max|S| <= {spec.ms_max:g}", ms, spec.ms_max, ""))
    if spec.s_below_bw_max is not None:
        s = max(m.s_below_bw for m in margins)
        if s > spec.s_below_bw_max:
            out.append((f"max|S| below CLBW <= {spec.s_below_bw_max:g}", s, spec.s_below_bw_max, ""))
    if spec.bandwidth_min_hz is not None:
        bw = min(m.bandwidth_hz for m in margins)
        if bw < spec.bandwidth_min_hz:
            out.append((f"CLBW >= {spec.bandwidth_min_hz:g} Hz", bw, spec.bandwidth_min_hz, "Hz"))
    if spec.tau_max_s is not None:
        tau = max(m.tau_cl for m in margins)
        if tau > spec.tau_max_s:
            out.append((f"slowest closed-loop time constant tau_cl <= {spec.tau_max_s:g} s", tau, spec.tau_max_s,
                        "s"))
    return out


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


def _format_violations(found: list[tuple[str, float, float, str]]) -> str:
    """'NAME infeasible: best design reaches V (short by / over by D)' for each missed constraint."""
    def one(name: str, value: float, limit: float, unit: str) -> str:
        u = f" {unit}" if unit else ""
        side = "over" if value > limit else "short"
        return f"{name} infeasible: best design reaches {value:.3g}{u} ({side} by {abs(limit - value):.3g}{u})"
    return "; ".join(one(*v) for v in found)


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


# ---------------------------------------------------------------- Table 2 comparison

def rescale_to_bandwidth(parameters: dict[str, float], plant: JointModel | control.LTI, target_hz: float,
                         delay_samples: int = 1) -> tuple[dict[str, float], float]:
    """Scale Kp, Ki, Kd by one factor g (the controller's shape unchanged) so that the closed-loop bandwidth
    on ``plant`` equals ``target_hz``; returns (scaled parameters, g). Why: Table 2 gains are in the paper's
    own (unknown) units, so only their shape is comparable on an SI plant; the paper's own CLBW fixes g."""
    ts = float(parameters.get("Ts", controller_defaults()["Ts"]))
    evaluator = _LoopEvaluator([plant], ts, delay_samples)

    def scaled(log_g: float) -> dict[str, float]:
        g = 10 ** log_g
        return {**parameters, "Kp": parameters["Kp"] * g, "Ki": parameters["Ki"] * g, "Kd": parameters["Kd"] * g}

    def bw_error(log_g: float) -> float:
        m = evaluator.evaluate(scaled(log_g))[0]
        return math.log(max(m.bandwidth_hz, 1e-3) / target_hz) if m.stable else math.inf

    grid = np.linspace(-3, 9, 241)
    errors = np.array([bw_error(g) for g in grid])
    sign = np.nonzero(np.isfinite(errors[:-1]) & np.isfinite(errors[1:]) & (errors[:-1] < 0) & (errors[1:] >= 0))[0]
    if not sign.size:
        raise TuningError(f"no stable scaling of Kp, Ki, Kd reaches a closed-loop bandwidth of {target_hz} Hz")
    log_g = scipy.optimize.brentq(bw_error, grid[sign[0]], grid[sign[0] + 1], xtol=1e-10)
    return scaled(log_g), 10 ** log_g


TABLE2_READINGS = ("per-sample", "continuous")


def table2_parameters(name: str, ts: float = 5e-4, reading: str = "per-sample") -> dict[str, float]:
    """Controller parameters of Table 2 column ``name`` (before rescaling; tau = 2 ts, which Table 2 omits).

    reading: how the printed Kp, Ki, Kd are read. "per-sample" (default): gains of the DSP's discrete PID
    u_k = Kp e_k + Ki sum(e) + Kd (e_k - e_k-1), i.e. Ki/Ts and Kd*Ts in continuous time (PD zero near 17 Hz,
    integral zero near 1 Hz, below the 56-73 Hz CLBW). "continuous": as printed; the PD zero Kp/Kd is then at
    0.008 Hz, a pure damper with almost no position stiffness on an SI plant.
    """
    if reading not in TABLE2_READINGS:
        raise ValueError(f"reading must be one of {TABLE2_READINGS}, got {reading!r}")
    column = TABLE2[name]
    params = {k: float(column[k]) for k in DESIGN_NAMES} | {"tau": 2 * ts, "Ts": ts}
    if reading == "per-sample":
        params |= {"Ki": params["Ki"] / ts, "Kd": params["Kd"] * ts}
    return params


def table2_comparison(plant: JointModel | control.LTI, ts: float = 5e-4, delay_samples: int = 1,
                      tuned: TuningResult | None = None, reading: str = "per-sample") -> list[dict[str, float | str]]:
    """One row per Table 2 column (paper figures beside ours, after rescaling to the paper's CLBW), plus the
    tuned design when given; ``reading`` as :func:`table2_parameters`."""
    rows: list[dict[str, float | str]] = []
    for name, column in TABLE2.items():
        params = table2_parameters(name, ts, reading)
        scaled, g = rescale_to_bandwidth(params, plant, column["CLBW"], delay_samples)
        m = loop_margins(scaled, plant, delay_samples)
        rows.append({"design": f"Table 2 {name}", "scale": g, **{f"paper {k}": column[k] for k in _PAPER_FIGURES},
                     "GM": m.gm_db, "PM": m.pm_deg, "CLBW": m.bandwidth_hz, "S": m.s_below_bw, "Ms": m.ms,
                     "DM": m.disk_margin, "tau_cl": m.tau_cl, "stable": m.stable})
    if tuned is not None:
        m = loop_margins(tuned.parameters, plant, tuned.delay_samples)
        rows.append({"design": "tuned", "scale": 1.0, **{f"paper {k}": math.nan for k in _PAPER_FIGURES},
                     "GM": m.gm_db, "PM": m.pm_deg, "CLBW": m.bandwidth_hz, "S": m.s_below_bw, "Ms": m.ms,
                     "DM": m.disk_margin, "tau_cl": m.tau_cl, "stable": m.stable})
    return rows


def format_comparison(rows: list[dict[str, float | str]]) -> str:
    """Plain-text table of ``table2_comparison`` rows (paper figure / ours)."""
    head = (f"{'design':<12} {'scale g':>9} {'GM paper/ours [dB]':>19} {'PM paper/ours [deg]':>20} "
            f"{'CLBW paper/ours [Hz]':>21} {'S<CLBW paper/ours':>18} {'Ms':>5} {'disk':>5} {'tau_cl [ms]':>11}")
    lines = [head, "-" * len(head)]

    def paper(key: str, width: int) -> str:
        return f"{'-' if math.isnan(r[key]) else format(r[key], '.3g'):>{width}}"
    for r in rows:
        lines.append(f"{r['design']:<12} {r['scale']:>9.3g} {paper('paper GM', 9)} /{r['GM']:>7.3g} "
                     f"{paper('paper PM', 10)} /{r['PM']:>7.3g} {paper('paper CLBW', 11)} /{r['CLBW']:>7.3g} "
                     f"{paper('paper S', 8)} /{r['S']:>7.3g} {r['Ms']:>5.2f} {r['DM']:>5.2f} "
                     f"{r['tau_cl'] * 1e3:>11.4g}")
    return "\n".join(lines)


def comparison_markdown(rows: list[dict[str, float | str]]) -> str:
    """README table of ``table2_comparison`` rows: paper figure / ours for GM, PM, CLBW and max |S| < CLBW."""
    def pair(r: dict, key: str, fmt: str) -> str:
        paper = r[f"paper {key}"]
        ours = format(r[key], fmt)
        return ours if isinstance(paper, float) and math.isnan(paper) else f"{format(paper, fmt)} / {ours}"
    lines = ["| design | Kp,Ki,Kd scale | GM [dB] paper / ours | PM [deg] paper / ours | CLBW [Hz] paper / ours "
             "| max\\|S\\| below CLBW paper / ours | Ms | disk margin | tau_cl [ms] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['design']} | {r['scale']:.3g} | {pair(r, 'GM', '.2f')} | {pair(r, 'PM', '.1f')} | "
                     f"{pair(r, 'CLBW', '.1f')} | {pair(r, 'S', '.2f')} | {r['Ms']:.2f} | {r['DM']:.2f} | "
                     f"{r['tau_cl'] * 1e3:.4g} |")
    return "\n".join(lines)


def format_margins(result: TuningResult, plants: Sequence[JointModel | control.LTI]) -> str:
    """Plain-text table of the achieved figures on every plant set."""
    head = (f"{'plant set':<28} {'GM [dB]':>8} {'PM [deg]':>9} {'CLBW [Hz]':>10} {'Ms':>5} {'S<CLBW':>7} "
            f"{'disk':>5} {'tau_cl [ms]':>11}")
    lines = [head, "-" * len(head)]
    for k, (p, m) in enumerate(zip(plants, result.margins)):
        label = f"{k}: K={p.gain:.3g}" if isinstance(p, JointModel) else f"{k}"
        if isinstance(p, JointModel) and p.resonances:
            label += f", f_res={p.resonances[0][0] / (2 * np.pi):.0f} Hz"
        lines.append(f"{label:<28} {m.gm_db:>8.2f} {m.pm_deg:>9.2f} {m.bandwidth_hz:>10.2f} {m.ms:>5.2f} "
                     f"{m.s_below_bw:>7.2f} {m.disk_margin:>5.2f} {m.tau_cl * 1e3:>11.4g}")
    return "\n".join(lines)


# ---------------------------------------------------------------- command line (motiontwin tune)

PLANT_CLASS = "MotionTwin.Plants.CheungJoint"
_PLANT_KEYS = ("K", "alpha", "omega", "zeta", "omega_bar", "zeta_bar")


def parse_plant(text: str, defaults: dict[str, float], where: str = "--plant") -> JointModel:
    """``K=1.2,omega=2300`` -> JointModel; keys not given take ``defaults`` (the CheungJoint start values)."""
    values = dict(defaults)
    for item in filter(None, (t.strip() for t in text.split(","))):
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in _PLANT_KEYS:
            raise TuningError(f"{where} {text!r}: field {item!r} must be NAME=VALUE with NAME in "
                              f"{', '.join(_PLANT_KEYS)}")
        try:
            values[key.strip()] = float(value)
        except ValueError:
            raise TuningError(f"{where} {text!r}: field {key.strip()!r} = {value!r} is not a number") from None
    for key in _PLANT_KEYS:
        lower_ok = values[key] > 0 if key in ("K", "omega", "omega_bar") else values[key] >= 0
        if not (math.isfinite(values[key]) and lower_ok):
            bound = "positive" if key in ("K", "omega", "omega_bar") else "non-negative"
            raise TuningError(f"{where} {text!r}: field {key!r} = {values[key]!r} must be finite and {bound}")
    if not values["omega"] > values["omega_bar"]:
        raise TuningError(f"{where} {text!r}: field 'omega' = {values['omega']!r} rad/s must be above 'omega_bar' = "
                          f"{values['omega_bar']!r} rad/s (CheungJoint: the antiresonance lies below the resonance)")
    return JointModel(values["K"], values["alpha"], ((values["omega"], values["zeta"]),),
                      ((values["omega_bar"], values["zeta_bar"]),))


def _start_values(text: str, index: int) -> dict[str, float]:
    """``NAME=VALUE,...`` -> dict (start values of a plant FMU)."""
    out = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        key, sep, value = item.partition("=")
        try:
            out[key.strip()] = float(value) if sep else float("nan")
        except ValueError:
            raise TuningError(f"--plant #{index + 1}: field {item!r} must be NAME=VALUE with a number") from None
        if not sep:
            raise TuningError(f"--plant #{index + 1}: field {item!r} must be NAME=VALUE")
        if not math.isfinite(out[key.strip()]):
            raise TuningError(f"--plant #{index + 1}: field {key.strip()!r} = {value.strip()!r} must be finite")
    return out


def _write_controller_fmu(args, parameters: dict[str, float], provenance: dict, out: Path) -> Path:
    """A new controller FMU (``args.fmu`` or one built now) with ``parameters`` as start values."""
    import tempfile

    from motiontwin.fmus import build, writeback
    from motiontwin.fmus.archive import read_description

    values = {k: v for k, v in parameters.items() if k != "Ts"}  # Ts is fixed by the FMU's build
    with tempfile.TemporaryDirectory(prefix="motiontwin-tune-") as tmp:
        source = args.fmu or build.build_fmu(build.load_model(CONTROLLER_CLASS), tmp, args.fmi).path
        fmu_ts = next(float(v.start) for v in read_description(source).modelVariables
                      if v.name == "Ts")
        if not math.isclose(fmu_ts, args.ts, rel_tol=1e-12):
            raise TuningError(f"{source}: the controller FMU samples at Ts = {fmu_ts} s but the design used "
                              f"--ts {args.ts} s; rebuild the controller with that period")
        return writeback.write_back(source, values, out, provenance)


def _suffixed(path: Path, suffix: str) -> Path:
    """build/x.json, "d1" -> build/x_d1.json."""
    return path.with_name(f"{path.stem}_{suffix}{path.suffix}")


def _tune_options(args) -> dict:
    """Keyword arguments of :func:`tune` from the parsed command line (new options read with defaults)."""
    return dict(tau=args.tau, seed=args.seed, popsize=args.popsize, maxiter=args.maxiter, refine=args.refine,
                progress=True, feedforward=not args.no_feedforward,
                jerk=not args.no_jerk)


def _cli_manipulator(args, spec: TuningSpec) -> int:
    """``motiontwin tune --manipulator``: per-actuator design on the CheungManipulator FMU at --poses poses."""
    import json
    import tempfile

    from motiontwin.fmus import build
    from motiontwin.harness.recording import atomic_write_texts
    from motiontwin.ident import tuning_manipulator as tm

    plant_model = build.load_model(PLANT_CLASS)
    defaults = {v.name: float(v.start) for v in plant_model.parameters if v.name in _PLANT_KEYS}
    flexible = None if args.rigid else parse_plant((args.plant or [""])[0], defaults,
                                                                      "--plant #1")
    poses = tm.workspace_poses(args.poses)
    with tempfile.TemporaryDirectory(prefix="motiontwin-tune-") as tmp:
        fmu = args.plant_fmu or build.build_fmu(build.load_model(tm.MANIPULATOR_CLASS), tmp, "3.0").path
        design = tm.tune_manipulator(fmu, poses, flexible, args.ts, spec, args.delay, **_tune_options(args))
    labels = [f"pose {k}: x={p[0] * 1e3:.1f} y={p[1] * 1e3:.1f} z={p[2] * 1e3:.1f} mm" for k, p in enumerate(poses)]
    for name, result, plants in zip(tm.ACTUATORS, design.results, design.plants):
        print(f"actuator {name}")
        print(format_margins(result, plants))
        print("parameters: " + ", ".join(f"{k}={v:.6g}" for k, v in result.parameters.items()))
    print("coupled closed loop, 1 - spectral radius per pose (> 0 is stable): without gravity "
          + ", ".join(f"{1 - r:.2e}" for r in design.radius_without_gravity) + "; with gravity "
          + ", ".join(f"{1 - r:.2e}" for r in design.radius_with_gravity))
    print("coupled closed loop, slowest time constant -Ts/ln(radius) per pose [ms]: without gravity "
          + ", ".join(f"{slowest_time_constant(np.array([r]), args.ts) * 1e3:.3g}"
                      for r in design.radius_without_gravity) + "; with gravity "
          + ", ".join(f"{slowest_time_constant(np.array([r]), args.ts) * 1e3:.3g}"
                      for r in design.radius_with_gravity))
    for line in design.infeasible:
        print(f"infeasible spec: {line}")
    doc = design.as_dict()
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        files = {out: json.dumps(doc, indent=2) + "\n"}
        files |= {_suffixed(out, a): json.dumps(d, indent=2) + "\n" for a, d in doc["joints"].items()}
        atomic_write_texts(files)
        print("\n".join(str(p) for p in files))
    plots = args.plots
    if plots:
        from motiontwin.ident.tuning_plots import write_loop_figure

        for name, result, plants in zip(tm.ACTUATORS, design.results, design.plants):
            print(write_loop_figure(Path(plots) / f"tuning_manipulator_{name}.png", result.parameters, plants,
                                    args.delay, labels, f"CheungManipulator actuator {name} (FMU linearised, "
                                    f"{'rigid' if flexible is None else 'times eq. (8) H(s)'})", spec,
                                    result.margins))
    stable = max(design.radius_without_gravity + design.radius_with_gravity) < 1
    if args.fmu_out and not design.infeasible and stable:
        for name, result in zip(tm.ACTUATORS, design.results):
            print(_write_controller_fmu(args, result.parameters, {"method": doc["method"], "actuator": name,
                                                                   "poses": doc["poses"], "spec": asdict(spec),
                                                                   "margins": doc["joints"][name]["margins"]},
                                        _suffixed(Path(args.fmu_out), name)))
    return 0 if not design.infeasible and stable else 2


def cli_tune(args) -> int:
    """Handler of ``motiontwin tune`` (arguments: see the report / harness.cli). Exit code 2 if infeasible.

    Options added after the first parser (read with defaults): ``--manipulator`` with ``--poses N`` and
    ``--rigid`` (per-actuator design on the CheungManipulator FMU), ``--plots DIR`` (Bode/Nyquist/sensitivity
    PNG per joint), ``--no-feedforward`` and ``--no-jerk`` (keep Kv, Ka, Kj at the FMU defaults / Kj = 0),
    ``--tau-max`` [s] (bound on the slowest closed-loop time constant; inf: unconstrained)."""
    import json

    from motiontwin.fmus import build
    from motiontwin.harness.recording import atomic_write_texts

    tau_max = args.tau_max
    spec = TuningSpec(args.gm, args.pm_min, args.pm_max, args.ms, args.s_below_bw, args.bw_min,
                      None if tau_max is None or not math.isfinite(tau_max) else tau_max)
    if args.manipulator:
        return _cli_manipulator(args, spec)
    if args.plant_fmu:  # each --plant gives start values of the FMU, linearised from its directional derivatives
        from motiontwin.harness.linearize import linearize

        plants = [linearize(args.plant_fmu, [args.plant_input], [args.plant_output], _start_values(t, k))
                  for k, t in enumerate(args.plant or [""])]
    else:
        plant_model = build.load_model(PLANT_CLASS)
        defaults = {v.name: float(v.start) for v in plant_model.parameters if v.name in _PLANT_KEYS}
        plants = [parse_plant(t, defaults, f"--plant #{k + 1}") for k, t in enumerate(args.plant or [""])]
        if len(plants) == 1 and (args.gain_spread or args.resonance_spread):
            plants = position_sets(plants[0], args.gain_spread, args.resonance_spread)
    try:
        result = tune(plants, args.ts, spec, args.delay, **_tune_options(args))
        feasible = True
    except InfeasibleSpecError as err:
        print(f"infeasible spec: {err}")
        result, feasible = err.result, False
    print(format_margins(result, plants))
    print("parameters: " + ", ".join(f"{k}={v:.6g}" for k, v in result.parameters.items()))
    if args.compare_table2:
        rows = table2_comparison(plants[len(plants) // 2], args.ts, args.delay, result)
        print(format_comparison(rows))
        print(comparison_markdown(rows))
    doc = result.as_dict() | {"plants": [asdict(p) if isinstance(p, JointModel) else str(p) for p in plants]}
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_texts({Path(args.out): json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    plots = args.plots
    if plots:
        from motiontwin.ident.tuning_plots import write_loop_figure

        labels = [f"set {k}: K={p.gain:.3g}" if isinstance(p, JointModel) else f"set {k}"
                  for k, p in enumerate(plants)]
        print(write_loop_figure(Path(plots) / "tuning_joint.png", result.parameters, plants, args.delay, labels,
                                "CheungJoint (eqs. 6-8) at the actuator-position sets", spec, result.margins))
    if args.fmu_out and feasible:
        out = _write_controller_fmu(args, result.parameters, {"method": doc["method"], "spec": doc["spec"],
                                                              "plants": doc["plants"], "margins": doc["margins"]},
                                    args.fmu_out)
        print(out)
    return 0 if feasible else 2
