"""The types of the candidate effects (:mod:`ident.diagnosis.effects`): the :class:`Context` their initialisers
read, a :class:`Param` and an :class:`Effect`, and the helpers the effects share (least squares, the velocity
scale of sign functions, Modelica parameter declarations). Units: SI (m, s, N, kg, Hz)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass
class Context:
    """What the effect initialisers may use: recorded ranges and the inverse-dynamics signals."""

    ts: float
    x_min: float
    x_max: float
    v_max: float
    mass: float                   # refitted nominal mass [kg] (or the equivalent 1/(dv'/du))
    x: np.ndarray | None = None   # filtered position, velocity, acceleration and force residual [N]
    v: np.ndarray | None = None
    a: np.ndarray | None = None
    force: np.ndarray | None = None
    udot: np.ndarray | None = None
    resonance_guess: list[float] = field(default_factory=list)  # candidate frequencies [Hz]
    position_gain: float = 1.0    # measured output per unit of the plant's position state
    u: np.ndarray | None = None   # recorded applied force on the training run [N]
    duration: float = 0.0         # length of the training recording [s]
    pole_pitch: float | None = None   # motor pole pitch (plant.pole_pitch) in the plant's coordinates
    q_residual: np.ndarray | None = None   # the nominal refit's training output residual, in state coordinates


@dataclass
class Param:
    name: str            # Modelica name (prefixed by the effect)
    unit: str
    description: str
    bounds: tuple[float, float]
    fitted: bool = True
    zero: float | None = None   # value at which the effect vanishes (None: the effect vanishes at any value)
    #: (lower, upper): True where the side is a physical limit besides those at 0, +-inf or ``zero``, which
    #: are always physical (:func:`bounds.physical_sides`); other sides are search ranges, widened when hit
    physical: tuple[bool, bool] = (False, False)
    searched: tuple[float, float] | None = None   # the default search range, once a hit widened ``bounds``


@dataclass
class Effect:
    name: str
    family: str
    params: list[Param]
    declarations: str                      # extra declarations (parameters, variables)
    force: str                             # Modelica expression of the opposing force ("" if none)
    equations: list[str]                   # extra equations
    library: list[str]                     # MotionTwin.Effects files used
    initial: Callable[[Context], list[dict[str, float]]]   # starting points for the fit
    contract: Callable[[dict[str, float], Context], dict[str, float]]  # parameters in the contract's terms
    explanation: str
    delays_input: bool = False             # replaces u by a delayed u
    tracks_position: list[str] = field(default_factory=list)   # states starting at the measured position
    tracks_force: list[str] = field(default_factory=list)      # states starting at the held force
    applicable: bool = True                # False: the bundle lacks what the effect needs (not screened)
    min_substeps: int = 1                  # RK4 substeps per sample its fastest state needs at the top speed
    #: force per unit level at small amplitude, of position and velocity (states): compared with the plant's
    #: own parameters' forces so that a physics the plant has is refitted there, not added twice
    regressor: Callable[[Context, np.ndarray, np.ndarray], np.ndarray] | None = None
    #: why fitted values are not this physics ("" when they are), e.g. a friction level below 0 (a force
    #: pushing along the motion): such a fit is not reported as the effect
    unphysical: Callable[[dict[str, float]], str] | None = None
    #: Modelica expression added to the measured output (a sensor error, "" if none): the loop feeds it back,
    #: so it moves the plant through the controller instead of acting on it as a force
    sensor: str = ""


def _p(name: str, unit: str, text: str, lo: float, hi: float, fitted: bool = True, zero: float | None = None,
       physical: tuple[bool, bool] = (False, False)) -> Param:
    return Param(name, unit, text, (lo, hi), fitted, zero, physical)


def vanishing_start(effect: Effect, starts: list[dict[str, float]]) -> dict[str, float]:
    """The effect at its vanishing point (every parameter with a ``zero`` there, the others at the first
    data-driven start or the middle of their bounds): the augmented model then is the current model, so a fit
    from here cannot end above the current model's cost."""
    values = {p.name: float(np.mean(p.bounds)) for p in effect.params if p.fitted}
    values.update(starts[0] if starts else {})
    values.update({p.name: float(p.zero) for p in effect.params if p.zero is not None})
    return values


def _decl(params: list[Param], values: dict[str, float]) -> str:
    return "".join(f'  parameter Real {p.name}(unit = "{p.unit}") = {float(values[p.name])!r} "{p.description}";\n'
                   for p in params)


def _ls(columns: list[np.ndarray], target: np.ndarray) -> np.ndarray:
    mat = np.column_stack(columns)
    return np.linalg.lstsq(mat, target, rcond=None)[0]


def _scale(ctx: Context) -> float:
    """Measured metres per unit of the plant's position state: floors written in m or m/s are divided by it."""
    return abs(ctx.position_gain)


def _v_eps(ctx: Context) -> float:
    return max(1e-5 / _scale(ctx), 2e-3 * ctx.v_max)


def _eps_grid(ctx: Context) -> list[float]:
    """Starting velocity scales of a sign function: the default and two sharper ones (the cost is rough in it:
    from a smooth start the fit can settle with a mass a tenth of the true one), inside the bounds."""
    low = _eps_bounds(ctx)[0]
    return sorted({max(_v_eps(ctx) * k, 2 * low) for k in (1.0, 0.2, 0.04)}, reverse=True)


def _eps_bounds(ctx: Context) -> tuple[float, float]:
    return 1e-5 / _scale(ctx), max(2e-5 / _scale(ctx), 0.05 * ctx.v_max)


def _sign(c: Context) -> np.ndarray:
    return np.tanh(c.v / _v_eps(c))
