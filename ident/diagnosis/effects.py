"""Candidate effects (the issue-7 vocabulary) and the augmented Modelica model that adds them to a plant.

The augmented class instantiates the nominal class as ``plant`` and drives its input with
``plant.<input> = u_applied - sum(F_effect)``, the library's sign convention ``m*der(v) = u - d*v - F_effect``
(a positive effect force opposes positive motion). Force laws come from ``MotionTwin.Effects`` functions,
copied next to the written model so that the folder is self-contained; structural effects (an extra
mass, a Pade input delay, a position-dependent mass) add states or terms. Effects write the plant's position
and velocity as ``$x`` and ``$v``; they become the plant's own states (:class:`plant_roles.PlantRoles`),
so the augmented model does not depend on how the plant names them. Positions, velocities and the
:class:`Context` are in the plant's state coordinates (``position_gain`` converts them to the measured
output). Units: SI (m, s, N, kg, Hz).
"""
from __future__ import annotations

import math
import shutil
import string
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.build import MODELICA_DIR
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, PlantRoles, declaration_line

LIBRARY = MODELICA_DIR / "MotionTwin"
FRICTION = "friction"


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


@dataclass
class Param:
    name: str            # Modelica name (prefixed by the effect)
    unit: str
    description: str
    bounds: tuple[float, float]
    fitted: bool = True


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


def _p(name: str, unit: str, text: str, lo: float, hi: float, fitted: bool = True) -> Param:
    return Param(name, unit, text, (lo, hi), fitted)


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


def gravity_offset(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        f0 = float(np.median(c.force)) if c.force is not None else 0.0
        return [{"gravity_F0": f0 or 0.1}]
    return Effect("gravity_offset", "gravity_offset",
                  [_p("gravity_F0", "N", "Constant opposing force (gravity or cable offset)", -1e4, 1e4)],
                  "", "gravity_F0", [], [], init,
                  lambda v, c: {"F0": v["gravity_F0"]},
                  "A constant force acts on the axis (gravity on an inclined axis, cable or spring preload): "
                  "at rest the controller must hold it, so the force residual has a non-zero mean that does "
                  "not depend on the direction of motion.")


def _eps_bounds(ctx: Context) -> tuple[float, float]:
    return 1e-5 / _scale(ctx), max(2e-5 / _scale(ctx), 0.05 * ctx.v_max)


def _sign(c: Context) -> np.ndarray:
    return np.tanh(c.v / _v_eps(c))


def coulomb_friction(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        fc = abs(float(_ls([_sign(c), np.ones_like(c.v)], c.force)[0])) if c.force is not None else 0.1
        return [{"coulomb_Fc": max(fc, 1e-3), "coulomb_v_eps": _v_eps(c)}]
    params = [_p("coulomb_Fc", "N", "Coulomb friction level", 0.0, 1e4),
              _p("coulomb_v_eps", "m/s", "Velocity scale of the tanh (presliding)",
                 *_eps_bounds(ctx))]
    return Effect("coulomb_friction", FRICTION, params, "",
                  "MotionTwin.Effects.CoulombFriction($v, coulomb_Fc, coulomb_v_eps)", [],
                  ["CoulombFriction.mo"], init, lambda v, c: {"Fc": v["coulomb_Fc"]},
                  "A friction force of constant magnitude opposes the motion: the force residual jumps with "
                  "the sign of the velocity and is flat in |v|.")


def asymmetric_friction(ctx: Context) -> Effect:
    eps = _v_eps(ctx)

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None:
            return [{"asym_Fc_pos": 0.1, "asym_Fc_neg": 0.1}]
        sp = (1 + _sign(c)) / 2
        moving = np.abs(c.v) > 3 * eps
        a, b = _ls([(_sign(c) * sp)[moving], (_sign(c) * (1 - sp))[moving]], c.force[moving])
        return [{"asym_Fc_pos": max(a, 1e-3), "asym_Fc_neg": max(b, 1e-3), "asym_v_eps": _v_eps(c)}]
    params = [_p("asym_Fc_pos", "N", "Coulomb level for v > 0", 0.0, 1e4),
              _p("asym_Fc_neg", "N", "Coulomb level (magnitude) for v < 0", 0.0, 1e4),
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
    params = [_p("stribeck_Fc", "N", "Coulomb (sliding) friction level", 0.0, 1e4),
              _p("stribeck_Fs", "N", "Static (breakaway) friction level", 0.0, 1e4),
              _p("stribeck_vs", "m/s", "Stribeck velocity", 1e-4 / _scale(ctx), max(ctx.v_max, 1e-3 / _scale(ctx))),
              _p("stribeck_v_eps", "m/s", "Velocity scale of the tanh (presliding)",
                 *_eps_bounds(ctx))]
    return Effect("stribeck_friction", FRICTION, params, "",
                  "MotionTwin.Effects.StribeckFriction($v, stribeck_Fc, stribeck_Fs, stribeck_vs, "
                  "stribeck_v_eps)", [], ["StribeckFriction.mo"], init,
                  lambda v, c: {"Fc": v["stribeck_Fc"], "Fs": v["stribeck_Fs"],
                                "vs": v["stribeck_vs"] * abs(c.position_gain)},
                  "Friction that is higher near standstill than at speed (Stribeck curve): the force residual "
                  "opposes the motion and its magnitude falls with |v| over the first few mm/s.")


def position_ripple(ctx: Context) -> Effect:
    span = max(ctx.x_max - ctx.x_min, 1e-6 / _scale(ctx))

    def init(c: Context) -> list[dict[str, float]]:
        periods = span / np.linspace(0.75, 40, 400)
        if c.force is None:
            return [{"ripple_period": span / 4, "ripple_a": 0.0, "ripple_b": 0.0}]
        best = []
        for period in periods:
            k = 2 * np.pi / period
            cols = [np.sin(k * c.x), np.cos(k * c.x), np.ones_like(c.x), _sign(c)]
            coef, *_ = np.linalg.lstsq(np.column_stack(cols), c.force, rcond=None)
            best.append((float(np.hypot(coef[0], coef[1])), period, coef[0], coef[1]))
        best.sort(reverse=True)
        return [{"ripple_period": p, "ripple_a": a, "ripple_b": b} for _, p, a, b in best[:2]]
    params = [_p("ripple_a", "N", "Sine amplitude of the ripple force", -1e4, 1e4),
              _p("ripple_b", "N", "Cosine amplitude of the ripple force", -1e4, 1e4),
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
                  "function of position with a fixed spatial period, at any speed.")


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
    params = [_p("inertia_slope", "kg/m", "Change of the moving mass per metre", -bound, bound),
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
    lo = ctx.ts / 4

    def init(c: Context) -> list[dict[str, float]]:
        if c.force is None or c.udot is None:
            return [{"delay_T": ctx.ts}]
        tau = float(_ls([c.udot, np.ones_like(c.udot), _sign(c)], c.force)[0])
        return [{"delay_T": float(np.clip(tau, 1.5 * lo, 20 * ctx.ts))}, {"delay_T": ctx.ts}]
    params = [_p("delay_T", "s", "Delay between the commanded and the applied force", lo, 20 * ctx.ts)]
    decl = ('  Real delay_p1(unit = "N", start = 0, fixed = true) "First Pade state";\n'
            '  Real delay_a(unit = "N", start = 0, fixed = true) "Second Pade state, u - u_delayed";\n')
    eqs = ["delay_T*der(delay_p1) = delay_a", "delay_T*der(delay_a) = 12*(u - delay_p1) - 6*delay_a"]
    return Effect("time_delay", "time_delay", params, decl, "", eqs, [], init,
                  lambda v, c: {"delay": v["delay_T"]},
                  "The applied force lags the commanded force (amplifier, communication or computation "
                  "delay), realised as the Pade(2,2) approximant of MotionTwin.Effects.DelayedInputJoint: "
                  "the residual grows with the rate of change of the force and reduces the phase margin.",
                  delays_input=True, tracks_force=["delay_p1"])


def resonance(ctx: Context) -> Effect:
    def init(c: Context) -> list[dict[str, float]]:
        guesses = c.resonance_guess or [0.1 / c.ts]
        starts = []
        for f_res in guesses[:3]:
            starts.append({"resonance_m2": 0.1 * c.mass, "resonance_fa": f_res / math.sqrt(1.1),
                           "resonance_zeta": 0.03})
        return starts
    fmax = 0.45 / ctx.ts
    params = [_p("resonance_m2", "kg", "Mass coupled elastically to the driven mass", 1e-3 * ctx.mass, ctx.mass),
              _p("resonance_fa", "Hz", "Antiresonance frequency sqrt(k/m2)/(2 pi)", 5.0, fmax),
              _p("resonance_zeta", "1", "Damping ratio of the coupling (relative to m2)", 1e-3, 0.5)]
    decl = ('  Real resonance_x2(unit = "m", start = 0, fixed = true) "Position of the coupled mass";\n'
            '  Real resonance_v2(unit = "m/s", start = 0, fixed = true) "Velocity of the coupled mass";\n'
            '  Real resonance_F(unit = "N") "Coupling force on the driven mass";\n')
    k = "resonance_m2*(6.283185307179586*resonance_fa)^2"
    c = "2*resonance_zeta*resonance_m2*6.283185307179586*resonance_fa"
    eqs = ["der(resonance_x2) = resonance_v2",
           "resonance_m2*der(resonance_v2) = resonance_F",
           f"resonance_F = {k}*($x - resonance_x2) + {c}*($v - resonance_v2)"]
    return Effect("resonance", "resonance", params, decl, "resonance_F", eqs, [], init, _resonance_contract,
                  "An unmodelled structural mode: a second mass coupled by a spring and a damper to the driven "
                  "mass (as MotionTwin.Effects.TwoMassJoint); the residual concentrates in a narrow frequency "
                  "band of the swept-sine excitation.", tracks_position=["resonance_x2"])


def _resonance_contract(v: dict[str, float], c: Context) -> dict[str, float]:
    m1, m2 = v.get("plant.m", c.mass), v["resonance_m2"]
    ratio = math.sqrt((m1 + m2) / m1)
    return {"frequency": v["resonance_fa"] * ratio, "damping": v["resonance_zeta"] * ratio}


VOCABULARY: dict[str, Callable[[Context], Effect]] = {
    "gravity_offset": gravity_offset,
    "coulomb_friction": coulomb_friction,
    "asymmetric_friction": asymmetric_friction,
    "stribeck_friction": stribeck_friction,
    "position_ripple": position_ripple,
    "position_dependent_inertia": position_dependent_inertia,
    "time_delay": time_delay,
    "resonance": resonance,
}

NESTED = {"stribeck_friction": "coulomb_friction", "asymmetric_friction": "coulomb_friction"}


def modelica_text(plant_class: str, effects: list[Effect], values: dict[str, float],
                  plant_values: dict[str, float], class_name: str, roles: PlantRoles) -> str:
    """Source text of the augmented class (the nominal class is instantiated as ``plant``; ``roles`` name
    its input, output, position and velocity)."""
    mods = ", ".join(f"{k} = {float(v)!r}" for k, v in plant_values.items())
    names = ", ".join(e.name for e in effects) or "no effect"
    lines = [f'model {class_name} "{plant_class} augmented by the diagnosis with: {names}"',
             '  input Real u(unit = "N") "Commanded actuator force";',
             f'  output Real q(unit = "m") "Measured position (plant.{roles.output})";',
             f'  {plant_class} plant({mods}) "Nominal plant, refitted";']
    body = "".join(_decl(e.params, values) + e.declarations for e in effects)
    lines.append(body.rstrip("\n")) if body else None
    lines.append("equation")
    applied = "u - delay_a" if any(e.delays_input for e in effects) else "u"
    forces = [f"({e.force})" for e in effects if e.force]
    lines.append(f"  plant.{roles.input} = {applied}" + "".join(f" - {f}" for f in forces) + ";")
    lines.extend(f"  plant.{name} = {value!r};" for name, value in roles.held_inputs.items())
    lines.extend(f"  {eq};" for e in effects for eq in e.equations)
    lines.append(f"  q = plant.{roles.output};")
    lines.append(f"end {class_name};")
    text = "\n".join(lines) + "\n"
    return string.Template(text).substitute(x=f"plant.{roles.position}", v=f"plant.{roles.velocity}")


def write_model(folder: Path, plant_text: str, plant_class: str, effects: list[Effect],
                values: dict[str, float], plant_values: dict[str, float], class_name: str,
                roles: PlantRoles) -> Path:
    """Write a self-contained Modelica folder (nominal plant, augmented class, library functions used)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plant.mo").write_text(plant_text, encoding="utf-8")
    path = folder / f"{class_name}.mo"
    path.write_text(modelica_text(plant_class, effects, values, plant_values, class_name, roles),
                    encoding="utf-8")
    used = sorted({f for e in effects for f in e.library})
    if used:
        lib = folder / "MotionTwin"
        (lib / "Effects").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(LIBRARY / "package.mo", lib / "package.mo")
        shutil.copyfile(LIBRARY / "Effects" / "package.mo", lib / "Effects" / "package.mo")
        for name in used:
            shutil.copyfile(LIBRARY / "Effects" / name, lib / "Effects" / name)
    return path


def check_buildable(folder: Path, plant_text: str, plant_path: Path, plant_class: str, roles: PlantRoles,
                    ctx: Context, class_name: str) -> symbolic.SymbolicModel:
    """Build the augmented model of every catalogue effect through the front end before any fitting, so
    that an unsupported plant form stops the diagnosis at once with one message.

    All effects go into one model (one front-end pass); only when it fails is each effect built alone to
    name the one at fault. Raises :class:`plant_roles.PlantFormError` naming the effect, the construct and
    the line of ``plant_path``.

    Parameters
    ----------
    folder : empty scratch folder for the written models.
    plant_text, plant_path, plant_class : the plant file's source, path and the class used.
    roles : where the plant keeps its input, output, position and velocity.
    ctx : recorded ranges (for the effects' parameter bounds).
    class_name : name of the augmented class.

    Returns
    -------
    SymbolicModel
        The augmented model with every effect (written to ``folder / "all"``).
    """
    top = plant_class.split(".")[0]
    if top in (class_name, LIBRARY.name):
        raise PlantFormError(f"{plant_path}, line {declaration_line(plant_text, top)}: the plant's top-level "
                             f"class name {top!r} clashes with the diagnosis' own {class_name!r} or "
                             f"{LIBRARY.name!r}; rename it")
    effects = [factory(ctx) for factory in VOCABULARY.values()]

    def build(chosen: list[Effect], sub: str) -> symbolic.SymbolicModel:
        values = {p.name: float(np.mean(p.bounds)) for e in chosen for p in e.params}
        write_model(folder / sub, plant_text, plant_class, chosen, values, {}, class_name, roles)
        model = load_augmented(folder / sub, class_name)
        states = {s.name for s in model.states}
        missing = [f"plant.{n}" for n in (roles.position, roles.velocity) if f"plant.{n}" not in states]
        if missing:
            raise PlantFormError(f"{', '.join(missing)} is not a state of the augmented model")
        return model

    try:
        return build(effects, "all")
    except (frontend.ModelicaError, PlantFormError, RuntimeError, ValueError, KeyError):
        pass
    for effect in effects:
        try:
            build([effect], effect.name)
        except (frontend.ModelicaError, PlantFormError, RuntimeError, ValueError, KeyError) as exc:
            source = effect.force + " ".join(effect.equations)
            used = [roles.input] + [name for token, name in (("$x", roles.position), ("$v", roles.velocity))
                                    if token in source]
            construct = ", ".join(f"plant.{name}" for name in used)
            line = declaration_line(plant_text, plant_class)
            raise PlantFormError(f"{plant_path}, line {line}: class {plant_class}: the augmented model with "
                                 f"effect {effect.name} (which uses {construct}) cannot be built, so this plant "
                                 f"form is not supported: {exc}") from None
    raise PlantFormError(f"{plant_path}, line {declaration_line(plant_text, plant_class)}: class {plant_class}: "
                         f"the augmented model with all effects cannot be built although each effect alone can")


def load_augmented(folder: Path, class_name: str) -> symbolic.SymbolicModel:
    """The augmented model through the project's front end (the same expressions the FMU runs)."""
    return symbolic.build(frontend.load(folder, class_name))
