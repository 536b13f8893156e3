"""Force, transmission, actuator and sensor laws of the independent truth simulator, written from the
literature and NOT from the diagnosis' candidates (``ident.diagnosis.effects``) nor from the Modelica library
(``MotionTwin.Effects``): a benchmark built from these laws cannot be passed by writing the same equations.

Every law acts on numpy arrays with one entry per simulated lane (several runs integrated side by side) and
has a per-lane ``gain`` (1: the law acts, 0: it is absent), so that a run with and a run without the effect
share one integration. Sign convention: a force law returns the force on the moving body along +x.
Units: SI (linear: m, m/s, N, kg; rotary: rad, rad/s, N.m, kg.m2).

References: B. Armstrong-Helouvry, P. Dupont, C. Canudas de Wit, "A survey of models, analysis tools and
compensation methods for the control of machines with friction", Automatica 30(7), 1994 (Coulomb + static +
Stribeck curve); C. Canudas de Wit, H. Olsson, K. J. Astrom, P. Lischinsky, "A new model for control of
systems with friction", IEEE TAC 40(3), 1995 (LuGre); K. H. Hunt, F. R. E. Crossley, "Coefficient of
restitution interpreted as damping in vibroimpact", J. Appl. Mech. 1975 (contact without adhesion).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: velocity scale of the regularised sign v/sqrt(v^2 + eps^2) [m/s or rad/s]: 50x narrower than the
#: library's tanh(v/5e-3), near the ideal discontinuous sign, still smooth enough for RK4 at Ts/2
V_EPS = 1e-4


NO_STATES = np.zeros((0, 1))   # the state derivatives of a law without states


def smooth_sign(v: np.ndarray, eps: float = V_EPS) -> np.ndarray:
    """sign(v) regularised algebraically (not tanh): v / sqrt(v^2 + eps^2)."""
    return v / np.sqrt(v * v + eps * eps)


def stribeck_curve(v: np.ndarray, fc: float, fs: float, vs: float, delta: float = 2.0) -> np.ndarray:
    """Armstrong-Helouvry's steady friction magnitude g(v) = Fc + (Fs - Fc) exp(-|v/vs|^delta) [N]."""
    ratio = np.abs(v / vs)
    return fc + (fs - fc) * np.exp(-(ratio * ratio if delta == 2 else ratio ** delta))


@dataclass
class Law:
    """One law: its name, its parameters (SI) and its number of internal states. Subclasses override the
    hooks they use; the defaults leave the plant unchanged."""

    params: dict[str, float]
    name: str = ""
    n_states: int = 0
    kind: str = "force"            # "force", "actuator", "sensor" or "transmission"
    size: tuple[str, ...] = field(default=())   # parameters scaled together to set the effect's size

    def force(self, x: np.ndarray, v: np.ndarray, s: np.ndarray, gain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force on the body, ds/dt of the law's states ``s`` (n_states, lanes))."""
        return np.zeros_like(x), NO_STATES

    def actuate(self, u: np.ndarray, gain: np.ndarray) -> np.ndarray:
        """The force the plant gets from the command ``u``."""
        return u

    def sense(self, q: np.ndarray, gain: np.ndarray) -> np.ndarray:
        """The position the encoder reports for the true position ``q``."""
        return q

    def scaled(self, factor: float) -> "Law":
        """The same law with its size parameters multiplied by ``factor``."""
        law = type(self)({k: v * factor if k in self.size else v for k, v in self.params.items()})
        law.name = self.name
        return law


class Offset(Law):
    """A constant force F0 (weight on an inclined axis, amplifier offset)."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "offset", size=("F0",))

    def force(self, x, v, s, gain):
        return gain * self.params["F0"] + 0 * x, NO_STATES


class Stribeck(Law):
    """Coulomb + static + Stribeck friction (Armstrong-Helouvry 1994): -g(v) sgn(v); Fs = Fc is Coulomb."""

    def __init__(self, params: dict[str, float]):
        super().__init__({"delta": 2.0, "vs": 1.0, **params}, "stribeck", size=("Fc", "Fs"))
        self.params.setdefault("Fs", self.params["Fc"])

    def force(self, x, v, s, gain):
        p = self.params
        if p["Fs"] == p["Fc"]:
            return -gain * p["Fc"] * smooth_sign(v), NO_STATES
        return -gain * stribeck_curve(v, p["Fc"], p["Fs"], p["vs"], p["delta"]) * smooth_sign(v), NO_STATES


class LuGre(Law):
    """LuGre (Canudas de Wit et al. 1995): dz/dt = v - sigma0 |v| z / g(v), F = -(sigma0 z + sigma1 dz/dt);
    g(v) the Stribeck curve, so that the steady state is the Stribeck friction. The viscous term sigma2 v is
    the axis' own damping."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "lugre", n_states=1, size=("Fc", "Fs"))

    def force(self, x, v, s, gain):
        p = self.params
        z = s[0]
        sigma0 = p["Fc"] / p["z0"]
        dz = v - sigma0 * np.abs(v) * z / stribeck_curve(v, p["Fc"], p["Fs"], p["vs"])
        return -gain * (sigma0 * z + p["sigma1"] * dz), dz[None, :]


class Cogging(Law):
    """Cogging of a permanent-magnet motor: harmonics h = 1, 2 of N periods per pole pitch,
    F = sum_h A_h sin(2 pi h N x / pitch + phi_h)."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "cogging", size=("A1", "A2"))

    def force(self, x, v, s, gain):
        p = self.params
        k = 2 * math.pi * p["N"] / p["pitch"]
        f = p["A1"] * np.sin(k * x + p["phi1"]) + p["A2"] * np.sin(2 * k * x + p["phi2"])
        return gain * f, NO_STATES


class QuadraticDrag(Law):
    """Drag growing with the square of the speed, F = -c v|v| (outside the diagnosis' catalogue)."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "drag", size=("c",))

    def force(self, x, v, s, gain):
        return -gain * self.params["c"] * v * np.abs(v), NO_STATES


class FrictionBump(Law):
    """Coulomb friction concentrated at one place of the rail (a dirty or worn spot, outside the catalogue):
    F = -Fb exp(-((x - x0)/w)^2) sgn(v)."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "friction_bump", size=("Fb",))

    def force(self, x, v, s, gain):
        p = self.params
        return -gain * p["Fb"] * np.exp(-((x - p["x0"]) / p["w"]) ** 2) * smooth_sign(v), NO_STATES


class CurrentLimit(Law):
    """Saturation of the drive's current (force) at +-Fmax: the plant gets clip(u, -Fmax, Fmax) while the
    recording holds the command u."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "current_limit", kind="actuator", size=("Fmax",))

    def actuate(self, u, gain):
        return u + gain * (np.clip(u, -self.params["Fmax"], self.params["Fmax"]) - u)


class EncoderCyclicError(Law):
    """Interpolation (cyclic) error of an incremental encoder, periodic in the signal period lam:
    q_meas = q + a1 sin(2 pi q/lam + phi1) + a2 sin(4 pi q/lam + phi2). A sensor effect: the loop feeds back
    the erroneous position; no force acts."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "encoder_error", kind="sensor", size=("a1", "a2"))

    def sense(self, q, gain):
        p = self.params
        k = 2 * math.pi / p["lam"]
        return q + gain * (p["a1"] * np.sin(k * q + p["phi1"]) + p["a2"] * np.sin(2 * k * q + p["phi2"]))


class Backlash(Law):
    """Dead zone with impacts between the motor (the body) and a load m2 carried through a gap of +-b: the
    contact force is Kelvin-Voigt k p + c dp/dt on the penetration p = |x - xl| - b > 0, clamped at zero (no
    adhesion, as Hunt-Crossley); the encoder reads the load. States: load position and velocity."""

    def __init__(self, params: dict[str, float]):
        super().__init__(params, "backlash", n_states=2, kind="transmission", size=("b",))

    def force(self, x, v, s, gain):
        p = self.params
        xl, vl = s[0], s[1]
        delta, ddelta = x - xl, v - vl
        gap = gain * p["b"]
        pen = np.maximum(np.abs(delta) - gap, 0.0)
        direction = np.sign(delta)
        contact = np.where(pen > 0, np.maximum(p["k"] * pen + p["c"] * ddelta * direction, 0.0), 0.0) * direction
        return -contact, np.vstack([vl, contact / p["m2"]])


#: law name -> class (the names a case lists)
LAWS = {"offset": Offset, "coulomb": Stribeck, "stribeck": Stribeck, "lugre": LuGre, "cogging": Cogging,
        "drag": QuadraticDrag, "friction_bump": FrictionBump, "current_limit": CurrentLimit,
        "encoder_error": EncoderCyclicError, "backlash": Backlash}

#: the answer a correct diagnosis gives for each law: its catalogue name, or "unexplained" outside it
EXPECTED = {"offset": "gravity_offset", "coulomb": "coulomb_friction", "stribeck": "stribeck_friction",
            "lugre": "lugre_friction", "cogging": "cogging", "current_limit": "actuator_saturation",
            "backlash": "backlash", "drag": "unexplained", "friction_bump": "unexplained",
            "encoder_error": "encoder_error"}

#: law -> (truth parameter, the catalogue effect's contract parameter it is compared with, factor from the
#: truth's value to the contract's: the catalogue's F0 is a force opposing +x, this offset one along +x)
MAIN_PARAMETER = {"offset": ("F0", "F0", -1.0), "coulomb": ("Fc", "Fc", 1.0), "stribeck": ("Fs", "Fs", 1.0),
                  "lugre": ("z0", "z0", 1.0), "cogging": ("A1", "A1", 1.0), "current_limit": ("Fmax", "Fmax", 1.0),
                  "backlash": ("b", "b", 1.0), "encoder_error": ("a1", "error_amplitude", 1.0)}


def make_law(name: str, params: dict[str, float]) -> Law:
    """The law ``name`` of :data:`LAWS` with ``params``."""
    law = LAWS[name](dict(params))
    law.name = name
    return law


def coloured_noise(n: int, std: float, tau: float, ts: float, rng: np.random.Generator) -> np.ndarray:
    """First-order low-pass filtered white noise sampled every ``ts`` (exact AR(1) discretisation), stationary
    standard deviation ``std``, time constant ``tau`` [s]; starts in its stationary distribution."""
    a = math.exp(-ts / tau)
    e = rng.standard_normal(n)
    w = np.empty(n)
    w[0] = std * e[0]
    for k in range(1, n):
        w[k] = a * w[k - 1] + std * math.sqrt(1 - a * a) * e[k]
    return w


def quantize(q: np.ndarray, resolution: float) -> np.ndarray:
    """Encoder counts: ``q`` rounded to the nearest multiple of ``resolution`` (none when 0)."""
    return np.round(q / resolution) * resolution if resolution > 0 else q
