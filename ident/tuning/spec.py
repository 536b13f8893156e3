"""What a tuning of the Cheung & Hung robust joint controller must meet and what it returns: the spec of
eqs. (14)-(18) (:class:`TuningSpec`), the margins of one loop (:class:`LoopMargins`), the result
(:class:`TuningResult`), the constraints a design misses (:func:`violations`), and the plant sets given as
text (``motiontwin tune --plant K=..,omega=..``). The method: ``ident.tuning``.

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Iterable, Sequence

import control
import numpy as np

from motiontwin.ident.frf import JointModel

__all__ = [
    "CONTROLLER_CLASS", "DESIGN_NAMES", "TuningError", "InfeasibleSpecError", "TuningSpec", "LoopMargins",
    "FeedforwardFit", "TuningResult", "violations", "format_margins", "PLANT_CLASS", "joint_model_from_fields",
    "cheung_joint_defaults",
]


CONTROLLER_CLASS = "MotionTwin.Controllers.RobustJointController"

DESIGN_NAMES = ("Kp", "Ki", "Kd", "KL", "fp", "fc", "sigma", "wl", "wh")


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


def _format_violations(found: list[tuple[str, float, float, str]]) -> str:
    """'NAME infeasible: best design reaches V (short by / over by D)' for each missed constraint."""
    def one(name: str, value: float, limit: float, unit: str) -> str:
        u = f" {unit}" if unit else ""
        side = "over" if value > limit else "short"
        return f"{name} infeasible: best design reaches {value:.3g}{u} ({side} by {abs(limit - value):.3g}{u})"
    return "; ".join(one(*v) for v in found)


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

PLANT_CLASS = "MotionTwin.Plants.CheungJoint"

_PLANT_KEYS = ("K", "alpha", "omega", "zeta", "omega_bar", "zeta_bar")


def joint_model_from_fields(fields: dict[str, float], defaults: dict[str, float], where: str = "plant") -> JointModel:
    """A JointModel from CheungJoint field values (``K``, ``alpha``, ``omega``, ``zeta``, ``omega_bar``,
    ``zeta_bar``; SI, rad/s); fields not given take ``defaults`` (the CheungJoint start values)."""
    unknown = sorted(set(fields) - set(_PLANT_KEYS))
    if unknown:
        raise TuningError(f"{where}: field {unknown[0]!r} is not one of {', '.join(_PLANT_KEYS)}")
    values = {**defaults, **fields}
    for key in _PLANT_KEYS:
        lower_ok = values[key] > 0 if key in ("K", "omega", "omega_bar") else values[key] >= 0
        if not (math.isfinite(values[key]) and lower_ok):
            bound = "positive" if key in ("K", "omega", "omega_bar") else "non-negative"
            raise TuningError(f"{where}: field {key!r} = {values[key]!r} must be finite and {bound}")
    if not values["omega"] > values["omega_bar"]:
        raise TuningError(f"{where}: field 'omega' = {values['omega']!r} rad/s must be above 'omega_bar' = "
                          f"{values['omega_bar']!r} rad/s (CheungJoint: the antiresonance lies below the resonance)")
    return JointModel(values["K"], values["alpha"], ((values["omega"], values["zeta"]),),
                      ((values["omega_bar"], values["zeta_bar"]),))


def cheung_joint_defaults() -> dict[str, float]:
    """The start values of ``MotionTwin.Plants.CheungJoint``'s K, alpha, omega, zeta, omega_bar, zeta_bar."""
    from motiontwin.fmus import build

    return {v.name: float(v.start) for v in build.load_model(PLANT_CLASS).parameters if v.name in _PLANT_KEYS}
