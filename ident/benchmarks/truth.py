"""The single-axis benchmark's truth: the plant forms, the concealed-effect truth plants (library
``MotionTwin.Effects`` and ``MotionTwin.Benchmarks`` classes), the PID controller, the reference, and the
co-simulation of plant, encoder and controller FMUs by the harness :class:`~harness.master.Master` (or the
CasADi truth of the same loop). :mod:`ident.benchmarks.single_axis` writes bundles from it. Units: SI.
"""
from __future__ import annotations

import math
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.signal as sps

from motiontwin.fmus import build
from motiontwin.harness import measurement
from motiontwin.harness.master import Master
from motiontwin.harness.recording import make_recording
from motiontwin.harness.scratch import process_folder
from motiontwin.harness.system import system_from_dict
from motiontwin.ident.diagnosis.bundle import Controller
from motiontwin.ident.diagnosis.plant_roles import PlantRoles

PLANT_CLASS = "LinearAxis"
PLANT_TEXT = '''model LinearAxis "Direct-drive linear axis: moving mass with viscous damping, m*der(v) = u - d*v"
  parameter Real m(unit = "kg", min = 1e-6) = {m!r} "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = {d!r} "Viscous damping";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity";
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = x;
end LinearAxis;
'''
LEAD = 0.002               # m/rad, screw lead of the gear-ratio plant form


@dataclass(frozen=True)
class PlantForm:
    """How a bundle's nominal plant is written: Modelica template (``{a}``, ``{b}``: the mass-like and
    damping-like values), class, input and output names, the names of the mass-like and damping-like
    parameters and the factor from kg (and N.s/m) to them."""

    text: str
    class_name: str
    input: str = "u"
    output: str = "q"
    mass: str = "m"
    damping: str = "d"
    scale: float = 1.0


PLANT_FORMS = {
    "alias": PlantForm(PLANT_TEXT.replace("{m!r}", "{a!r}").replace("{d!r}", "{b!r}"), PLANT_CLASS),
    "state_output": PlantForm('''model RigidJoint "Rigid moving mass with viscous friction; the output is the position state"
  parameter Real m(unit = "kg") = {a!r} "Moving mass";
  parameter Real d(unit = "N.s/m") = {b!r} "Viscous friction coefficient";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real v(unit = "m/s") "Velocity";
equation
  der(q) = v;
  m*der(v) = u - d*v;
end RigidJoint;
''', "RigidJoint"),
    "gear_ratio": PlantForm('''model BallScrewAxis "Motor angle and speed as states; the table position is the angle times the lead"
  parameter Real J(unit = "kg.m2") = {a!r} "Inertia seen by the motor";
  parameter Real b(unit = "N.m.s/rad") = {b!r} "Viscous damping seen by the motor";
  input Real u(unit = "N") "Axial actuator force";
  output Real q(unit = "m") "Measured table position";
  Real phi(unit = "rad", start = 0) "Motor angle";
  Real w(unit = "rad/s", start = 0) "Motor speed";
equation
  der(phi) = w;
  J*der(w) = %r*u - b*w;
  q = %r*phi;
end BallScrewAxis;
''' % (LEAD, LEAD), "BallScrewAxis", mass="J", damping="b", scale=LEAD ** 2),
    "renamed_in_package": PlantForm('''package Machines "A plant inside a package, with its own names"
  model Carriage "Carriage with input F, output y"
    parameter Real mass(unit = "kg", min = 1e-3) = {a!r} "Carriage mass";
    parameter Real damping(unit = "N.s/m") = {b!r} "Viscous damping";
    input Real F(unit = "N") "Motor force";
    output Real y(unit = "m") "Encoder reading";
    Real pos_m(unit = "m") "Carriage position";
    Real vel_mps(unit = "m/s") "Carriage velocity";
  equation
    der(pos_m) = vel_mps;
    mass*der(vel_mps) = F - damping*vel_mps;
    y = pos_m;
  end Carriage;
end Machines;
''', "Machines.Carriage", input="F", output="y", mass="mass", damping="damping"),
}


#: the Modelica units of a linear plant form and those of the same form on a rotary axis (a gear-ratio form: a
#: joint angle geared down from the motor's, its torque geared up)
ROTARY_UNITS = {"kg": "kg.m2", "N.s/m": "N.m.s/rad", "N": "N.m", "m": "rad", "m/s": "rad/s"}


def rotary_text(text: str) -> str:
    """A plant form's Modelica text with the units of a rotary axis (``unit = "..."`` attributes only)."""
    return re.sub(r'unit = "([^"]*)"', lambda m: f'unit = "{ROTARY_UNITS.get(m.group(1), m.group(1))}"', text)


def plant_form(which: str, seed: int) -> str:
    """The plant form of a bundle: the library's alias form in the tuning set; held out, the forms in turn
    by seed (consecutive seeds, so every form is diagnosed in the held-out set)."""
    if which == "tuning":
        return "alias"
    return sorted(PLANT_FORMS)[seed % len(PLANT_FORMS)]


TS = 5e-4
PLANT_SUBSTEPS = 4         # plant and encoder communication steps per controller sample
TRUE_M, TRUE_D = 2.0, 15.0
RESOLUTION = 5e-9          # encoder quantum [m]
NOISE = 10e-9              # encoder noise std [m]
V_EPS = 5e-3               # tanh velocity scale of the friction laws [m/s]
PRE_MOVE, PRE_DWELL = 0.5, 1.0   # pre-roll [s]: move from x = 0 to the first reference, then rest

ENCODER = "MotionTwin.Benchmarks.Encoder"
CONTROLLER = "MotionTwin.Benchmarks.LoopController"
RIGID = "MotionTwin.Benchmarks.RigidJoint"

#: laws outside every catalogue (present and coming): truth class, the force written for the CasADi truth
#: (``$x``, ``$v``: the plant's states; parameters prefixed by the law), and the diagnosis' answer "unexplained"
OUTSIDE_LAWS = {
    "quadratic_drag": ("MotionTwin.Benchmarks.QuadraticDragJoint", "drag_c*$v*abs($v)"),
    "position_friction": ("MotionTwin.Benchmarks.PositionFrictionJoint",
                          "(posfric_Fc0 + posfric_k*$x)*tanh($v/posfric_v_eps)"),
}
OUTSIDE_PREFIX = {"quadratic_drag": "drag_", "position_friction": "posfric_"}
CASES = ["params_only_a", "params_only_b", "gravity_offset", "coulomb_friction", "asymmetric_friction",
         "stribeck_friction", "position_ripple", "position_dependent_inertia", "time_delay", "resonance",
         "two_effects", "backlash", "lugre_friction", "actuator_saturation", "cogging", "load_dependent_friction",
         "friction_drift", *OUTSIDE_LAWS]
POLE_PITCH = 0.032          # magnet pole pitch of the cogging case's motor [m] (plant.pole_pitch of its bundle)


@dataclass
class TruthPlant:
    """The truth of a case: a library class, its parameter values and the effects in the contract's terms."""

    class_name: str
    parameters: dict[str, float]
    effects: list[dict] = field(default_factory=list)   # {"name", "parameters" (contract), "model"}


def _effect(name: str, contract: dict[str, float], model: dict[str, float]) -> dict:
    """One true effect: contract parameters plus the equivalent values of the diagnosis' effect model."""
    return {"name": name, "parameters": {**contract, **model}, "contract": contract}


def truth_plant(case: str, scale: float = 1.0, mass: float = TRUE_M, damping: float = TRUE_D) -> TruthPlant:
    """Library model and true values of ``case``; effect sizes are multiplied by ``scale``; ``mass`` [kg] and
    ``damping`` [N.s/m] of the rigid axis (the parameters-only cases)."""
    s = scale
    rigid = {"m": mass, "d": damping}
    if case.startswith("params_only"):
        return TruthPlant(RIGID, rigid)
    if case == "gravity_offset":
        f0 = 1.5 * s
        return TruthPlant("MotionTwin.Effects.OffsetForceJoint", {**rigid, "F0": f0},
                          [_effect(case, {"F0": f0}, {"gravity_F0": f0})])
    if case == "coulomb_friction":
        fc = 0.15 * s
        return TruthPlant("MotionTwin.Effects.CoulombJoint", {**rigid, "Fc": fc, "v_eps": V_EPS},
                          [_effect(case, {"Fc": fc}, {"coulomb_Fc": fc, "coulomb_v_eps": V_EPS})])
    if case == "asymmetric_friction":
        pos, neg = 0.2 * s, 0.06 * s
        return TruthPlant("MotionTwin.Effects.AsymmetricFrictionJoint",
                          {"m": TRUE_M, "d": 0.0, "beta_vp": TRUE_D, "beta_vn": TRUE_D, "beta_cp": pos,
                           "beta_cn": neg, "v_eps": V_EPS},
                          [_effect(case, {"Fc_pos": pos, "Fc_neg": neg},
                                   {"asym_Fc_pos": pos, "asym_Fc_neg": neg, "asym_v_eps": V_EPS})])
    if case == "stribeck_friction":
        fc, fs, vs = 0.08 * s, 0.25 * s, 0.004
        return TruthPlant("MotionTwin.Effects.StribeckJoint", {**rigid, "Fc": fc, "Fs": fs, "vs": vs, "v_eps": V_EPS},
                          [_effect(case, {"Fc": fc, "Fs": fs, "vs": vs},
                                   {"stribeck_Fc": fc, "stribeck_Fs": fs, "stribeck_vs": vs,
                                    "stribeck_v_eps": V_EPS})])
    if case == "position_ripple":
        return _ripple(case, "MotionTwin.Effects.RippleJoint", rigid, 0.5 * s, 0.3 * s, 0.016, [])
    if case == "two_effects":
        f0 = 1.0 * s
        return _ripple("position_ripple", "MotionTwin.Benchmarks.OffsetRippleJoint", {**rigid, "F0": f0},
                       0.4 * s, -0.2 * s, 0.012, [_effect("gravity_offset", {"F0": f0}, {"gravity_F0": f0})])
    if case == "position_dependent_inertia":
        # m(x) = m0*(1 + dm*cos(2*pi*x/0.4)): from m0 + 0.5*s at x = 0 down to m0 at x = 0.1 m
        m0 = TRUE_M - 0.25 * s
        return TruthPlant("MotionTwin.Effects.VariableInertiaJoint",
                          {"m0": m0, "dm": 0.5 * s / m0, "period": 0.4, "d": TRUE_D},
                          [_effect(case, {}, {})])   # mass range filled in from the recorded positions
    if case == "time_delay":
        delay = 2e-4 * s
        return TruthPlant("MotionTwin.Effects.DelayedInputJoint", {**rigid, "T": delay},
                          [_effect(case, {"delay": delay}, {"delay_T": delay})])
    if case == "resonance":
        m2, fa, zeta = 0.1 * s, 220.0, 0.03
        wa = 2 * math.pi * fa
        k, c = m2 * wa ** 2, 2 * zeta * m2 * wa
        mu = TRUE_M * m2 / (TRUE_M + m2)
        w_res = math.sqrt(k / mu)
        return TruthPlant("MotionTwin.Effects.TwoMassJoint", {"m1": TRUE_M, "m2": m2, "k": k, "c": c, "d": TRUE_D},
                          [_effect(case, {"frequency": w_res / (2 * math.pi), "damping": c / (2 * mu * w_res)},
                                   {"resonance_m2": m2, "resonance_fa": fa, "resonance_zeta": zeta})])
    if case == "quadratic_drag":
        c = 32.0 * s
        return TruthPlant(OUTSIDE_LAWS[case][0], {**rigid, "c": c}, [_outside(case, {"c": c}, {"v*|v|": c})])
    if case == "position_friction":
        k = 3.0 * s
        law = {"Fc0": 0.0, "k": k, "v_eps": V_EPS}
        return TruthPlant(OUTSIDE_LAWS[case][0], {**rigid, **law}, [_outside(case, law, {"x*sign(v)": k})])
    if case in NEW_EFFECT_CASES:
        return NEW_EFFECT_CASES[case](s, rigid)
    raise KeyError(f"unknown benchmark case {case!r}; cases: {', '.join(CASES)}")


def _outside(name: str, law: dict[str, float], terms: dict[str, float]) -> dict:
    """A true effect outside the catalogue: its law's parameters, and its terms in the empirical library's
    names (``contract``, what the diagnosis' empirical term should find)."""
    prefix = OUTSIDE_PREFIX[name]
    return {"name": name, "outside_catalogue": True, "parameters": {prefix + k: v for k, v in law.items()},
            "contract": terms}


def outside_effect(true: dict):
    """A true effect outside the catalogue (from :func:`_outside`) as an effect of the augmented model, its
    force written in :data:`OUTSIDE_LAWS` (for the CasADi truth; parameters not fitted, at the true values)."""
    from motiontwin.ident.diagnosis import effects as effect_models

    force = OUTSIDE_LAWS[true["name"]][1]
    params = [effect_models.Param(n, "", f"True law parameter {n}", (v, v), False)
              for n, v in true["parameters"].items()]
    return effect_models.Effect(true["name"], true["name"], params, "", force, [], [], lambda c: [{}],
                                lambda v, c: {}, f"Truth outside the catalogue: F = {force}")


def _backlash(s: float, rigid: dict[str, float]) -> TruthPlant:
    """Motor 1.4 kg + load 0.6 kg behind a gap of 2*b, contact antiresonance 200 Hz."""
    from motiontwin.ident.diagnosis.effects import BACKLASH_EPS

    m2, fa, zeta, b = 0.6, 200.0, 0.05, 5e-6 * s
    m1 = rigid["m"] - m2
    wa = 2 * math.pi * fa
    k, c = m2 * wa ** 2, 2 * zeta * m2 * wa
    mu = m1 * m2 / (m1 + m2)
    w_res = math.sqrt(k / mu)
    return TruthPlant("MotionTwin.Effects.BacklashJoint",
                      {"m1": m1, "m2": m2, "k": k, "c": c, "b": b, "eps": BACKLASH_EPS, "d": rigid["d"]},
                      [_effect("backlash", {"b": b, "frequency": w_res / (2 * math.pi)},
                               {"backlash_m2": m2, "backlash_fa": fa, "backlash_zeta": zeta, "backlash_b": b,
                                "backlash_eps": BACKLASH_EPS})])


def _lugre(s: float, rigid: dict[str, float]) -> TruthPlant:
    """LuGre in Dahl's form (Fs = Fc, sigma1 = 0), pre-sliding displacement z0 = Fc/sigma0 = 0.1 mm."""
    fc, z0 = 0.15 * s, 1e-4
    return TruthPlant("MotionTwin.Effects.LuGreJoint",
                      {"m": rigid["m"], "d": 0.0, "Fc": fc, "Fs": fc, "vs": 1.0, "sigma0": fc / z0, "sigma1": 0.0,
                       "sigma2": rigid["d"]},
                      [_effect("lugre_friction", {"Fc": fc, "z0": z0, "sigma0": fc / z0},
                               {"lugre_Fc": fc, "lugre_dFs": 0.0, "lugre_vs": 1.0, "lugre_z0": z0,
                                "lugre_sigma1": 0.0})])


SATURATION_EPS = 1e-3       # rounding of the truth's saturation corners [N]


def _saturation(s: float, rigid: dict[str, float]) -> TruthPlant:
    fmax = 3.8 - 0.1 * s     # a larger effect is a lower force limit [N] (3.5 N winds the PID up)
    return TruthPlant("MotionTwin.Effects.SaturationJoint", {**rigid, "Fmax": fmax, "eps": SATURATION_EPS},
                      [_effect("actuator_saturation", {"Fmax": fmax},
                               {"saturation_Fmax": fmax, "saturation_eps": SATURATION_EPS})])


def _cogging(s: float, rigid: dict[str, float]) -> TruthPlant:
    """Three cogging periods per pole pitch (period 10.7 mm) and a second harmonic of 40 %."""
    a1, a2, phase1, phase2, order = 0.4 * s, 0.16 * s, 0.4, -1.0, 3.0
    return TruthPlant("MotionTwin.Effects.CoggingJoint",
                      {**rigid, "pole_pitch": POLE_PITCH, "n": order, "A1": a1, "A2": a2, "phase1": phase1,
                       "phase2": phase2},
                      [_effect("cogging", {"A1": a1, "A2": a2, "n": order, "period": POLE_PITCH / order},
                               {"cogging_a1": a1 * math.cos(phase1), "cogging_b1": a1 * math.sin(phase1),
                                "cogging_a2": a2 * math.cos(phase2), "cogging_b2": a2 * math.sin(phase2),
                                "cogging_pitch": POLE_PITCH, "cogging_n": order})])


def _load_dependent(s: float, rigid: dict[str, float]) -> TruthPlant:
    fc0, mu = 0.08 * s, 0.08 * s
    return TruthPlant("MotionTwin.Effects.LoadDependentFrictionJoint", {**rigid, "Fc0": fc0, "mu": mu, "v_eps": V_EPS},
                      [_effect("load_dependent_friction", {"Fc0": fc0, "mu": mu},
                               {"load_Fc0": fc0, "load_mu": mu, "load_v_eps": V_EPS})])


def _drift(s: float, rigid: dict[str, float]) -> TruthPlant:
    """Coulomb level 0.25 N falling by 0.15 N (x scale) with tau = 3 s from the start of the run (the
    pre-roll's start); the contract is the drift seen from the start of the recordings, after the pre-roll."""
    fc0, dfc, tau = 0.25 * s, -0.15 * s, 3.0
    left = math.exp(-(PRE_MOVE + PRE_DWELL) / tau)
    return TruthPlant("MotionTwin.Effects.FrictionDriftJoint",
                      {**rigid, "Fc0": fc0, "dFc": dfc, "tau_drift": tau, "v_eps": V_EPS},
                      [_effect("friction_drift", {"Fc_start": fc0 + dfc * (1 - left), "dFc": dfc * left, "tau": tau},
                               {"drift_Fc0": fc0, "drift_dFc": dfc, "drift_tau": tau, "drift_v_eps": V_EPS})])


#: the issue-16 effects: case -> truth (scale, rigid axis m and d)
NEW_EFFECT_CASES = {"backlash": _backlash, "lugre_friction": _lugre, "actuator_saturation": _saturation,
                    "cogging": _cogging, "load_dependent_friction": _load_dependent, "friction_drift": _drift}


def _ripple(name: str, class_name: str, base: dict[str, float], a: float, b: float, period: float,
            others: list[dict]) -> TruthPlant:
    """Ripple a*sin(kx) + b*cos(kx) written as the library's A*sin(kx + phase)."""
    amplitude, phase = math.hypot(a, b), math.atan2(b, a)
    effect = _effect(name, {"amplitude": amplitude, "period": period},
                     {"ripple_a": a, "ripple_b": b, "ripple_period": period})
    return TruthPlant(class_name, {**base, "A": amplitude, "period": period, "phase": phase}, others + [effect])


def inertia_range(plant: TruthPlant, q: np.ndarray) -> dict[str, float]:
    """mass_min, mass_max of a VariableInertiaJoint over the positions ``q`` [kg]."""
    p = plant.parameters
    mass = p["m0"] * (1 + p["dm"] * np.cos(2 * math.pi * np.linspace(q.min(), q.max(), 201) / p["period"]))
    return {"mass_min": float(mass.min()), "mass_max": float(mass.max())}


def pid_controller(ts: float = TS, mass: float = TRUE_M, bandwidth: float = 60.0) -> Controller:
    """PID with filtered derivative on e = r - q, Tustin-discretised (scipy cont2discrete, bilinear)."""
    wc = 2 * math.pi * bandwidth
    kp, ti, td, n = mass * wc ** 2 / 3, 4 / wc, 1.5 / wc, 8.0
    num = [kp * ti * td * (1 + 1 / n), kp * (ti + td / n), kp]
    den = [ti * td / n, ti, 0.0]
    a, b, c, d, _ = sps.cont2discrete(sps.tf2ss(num, den), ts, method="bilinear")
    return Controller(ts, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([d, -d]))


def controller_json(ctrl: Controller) -> dict:
    """The bundle's controller object of a discrete state-space law with inputs [r, q] and output u."""
    return {"kind": "discrete_state_space", "Ts": ctrl.Ts, "inputs": ["r", "q"], "outputs": ["u"],
            "A": ctrl.A.tolist(), "B": ctrl.B.tolist(), "C": ctrl.C.tolist(), "D": ctrl.D.tolist()}


def reference(duration: float, rng: np.random.Generator, stroke: float, sweep: float) -> tuple[np.ndarray, ...]:
    """Point-to-point moves (cosine velocity profile) with dwells, then a swept sine on u_ext at rest."""
    t = np.arange(int(round(duration / TS))) * TS
    r = np.zeros_like(t)
    u_ext = np.zeros_like(t)
    moving_end = duration - sweep
    pos, now = stroke * rng.uniform(0.3, 0.7), 0.3
    r[:] = pos
    while now < moving_end - 0.5:
        target = stroke * rng.uniform(0.05, 0.95)
        speed = rng.choice([0.003, 0.01, 0.05, 0.15]) * rng.uniform(0.7, 1.3)
        dur = max(0.08, min(1.5, 2 * abs(target - pos) / speed))
        dur = min(dur, moving_end - 0.2 - now)
        i0, i1 = int(now / TS), int((now + dur) / TS)
        s = (1 - np.cos(np.pi * np.linspace(0, 1, i1 - i0))) / 2
        r[i0:i1] = pos + (target - pos) * s
        r[i1:] = target
        pos = target
        now += dur + rng.uniform(0.1, 0.4)
    i_sweep = int(moving_end / TS)
    ts = t[i_sweep:] - t[i_sweep]
    f0, f1 = 20.0, 600.0
    phase = 2 * np.pi * f0 * sweep / np.log(f1 / f0) * (np.exp(ts / sweep * np.log(f1 / f0)) - 1)
    u_ext[i_sweep:] = 1.5 * np.sin(phase) * np.minimum(1, ts / 0.05)
    return t, r, u_ext


def with_preroll(r: np.ndarray, u_ext: np.ndarray, start: float = 0.0) -> tuple[np.ndarray, np.ndarray, int]:
    """Prepend the pre-roll (cosine move from the plant's rest position ``start`` to r[0], then a dwell);
    returns r, u_ext and its length."""
    n_move, n_dwell = int(round(PRE_MOVE / TS)), int(round(PRE_DWELL / TS))
    move = start + (r[0] - start) * (1 - np.cos(np.pi * np.linspace(0, 1, n_move))) / 2
    pre = n_move + n_dwell
    return (np.concatenate([move, np.full(n_dwell, r[0]), r]), np.concatenate([np.zeros(pre), u_ext]), pre)


# -- FMUs and the co-simulated loop ----------------------------------------------------------------

_BUILT: dict[tuple[str, str], Path] = {}


def truth_fmus(classes: list[str], folder: Path | None = None) -> dict[str, Path]:
    """FMI 2.0 FMUs of ``classes`` (built once per process and folder by the project's pipeline; by default in
    this process's temporary folder, removed when it exits)."""
    folder = Path(folder) if folder is not None else process_folder() / "benchmark-fmus"
    missing = [c for c in dict.fromkeys(classes) if (c, str(folder)) not in _BUILT]
    if missing:
        for fmu, class_name in zip(build.build(missing, out_dir=folder, fmi_versions=("2.0",), workers=1), missing):
            _BUILT[(class_name, str(folder))] = fmu.path
    return {c: _BUILT[(c, str(folder))] for c in classes}


@dataclass(frozen=True)
class LoopAxis:
    """Names of one axis of the benchmark loop: the plant's input and output ports, the controller and encoder
    instances and the external signals (reference, input disturbance, sensor noise) that feed them."""

    input: str
    output: str
    ctrl: str
    enc: str
    r: str
    u_ext: str
    noise: str


SINGLE_AXIS = (LoopAxis("u", "q", "ctrl", "enc", "r", "u_ext", "noise"),)


def loop_axes(ports: list[tuple[str, str]]) -> tuple[LoopAxis, ...]:
    """The names of a multi-axis loop, by the (input, output) ports of the plant; the axis is named by its
    output: instances ``ctrl_q3``, ``enc_q3``, signals ``r_q3``, ``u_ext_u3``, ``noise_q3``."""
    return tuple(LoopAxis(i, o, f"ctrl_{o}", f"enc_{o}", f"r_{o}", f"u_ext_{i}", f"noise_{o}") for i, o in ports)


def loop_system(plant_fmu: Path, controller_fmu: Path, encoder_fmu: Path, ctrl: Controller | list[Controller],
                plant_parameters: dict[str, float], resolution: float,
                axes: tuple[LoopAxis, ...] = SINGLE_AXIS) -> dict:
    """The harness system description (as a dict) of controller -> plant -> encoder -> controller, one
    controller and one encoder instance per axis (``ctrl``: one controller, or one per axis, same Ts)."""
    ctrls = list(ctrl) if isinstance(ctrl, (list, tuple)) else [ctrl] * len(axes)
    if len(ctrls) != len(axes) or len({c.Ts for c in ctrls}) != 1:
        raise ValueError(f"loop_system: {len(ctrls)} controllers for {len(axes)} axes, sample times "
                         f"{sorted({c.Ts for c in ctrls})} (one controller per axis, one Ts)")
    ts = ctrls[0].Ts
    fast = ts / PLANT_SUBSTEPS
    controllers, encoders, inputs, connections, signals = {}, {}, {}, [], []
    for axis, c in zip(axes, ctrls):
        matrices = {f"{name}[{i + 1},{j + 1}]": float(mat[i, j])
                    for name, mat in zip("ABCD", (c.A, c.B, c.C, c.D))
                    for i in range(mat.shape[0]) for j in range(mat.shape[1])}
        controllers[axis.ctrl] = {"path": str(controller_fmu), "step": ts, "parameters": {**matrices, "Ts": ts}}
        encoders[axis.enc] = {"path": str(encoder_fmu), "step": fast, "parameters": {"resolution": resolution}}
        inputs.update({axis.r: {"unit": "m"}, axis.u_ext: {"unit": "N"}, axis.noise: {"unit": "m"}})
        connections += [
            {"from": f"input.{axis.r}", "to": f"{axis.ctrl}.u[1]"},
            {"from": f"{axis.enc}.y", "to": f"{axis.ctrl}.u[2]"},
            {"from": [f"{axis.ctrl}.y", f"input.{axis.u_ext}"], "to": f"plant.{axis.input}"},
            {"from": f"plant.{axis.output}", "to": f"{axis.enc}.q"},
            {"from": f"input.{axis.noise}", "to": f"{axis.enc}.noise"},
        ]
        signals += [f"input.{axis.r}", f"plant.{axis.input}", f"{axis.enc}.y", f"input.{axis.u_ext}",
                    f"plant.{axis.output}"]
    return {
        "base_step": fast,
        "fmus": {**controllers, "plant": {"path": str(plant_fmu), "step": fast, "parameters": dict(plant_parameters)},
                 **encoders},
        "inputs": inputs,
        "connections": connections,
        "log": [{"name": "samples", "signals": signals, "step": ts}],
    }


def cosimulate_axes(plant_class: str, plant_parameters: dict[str, float], axes: tuple[LoopAxis, ...],
                    ctrls: list[Controller], r: np.ndarray, u_ext: np.ndarray, noise: np.ndarray,
                    resolution: float = RESOLUTION, fmu_dir: Path | None = None) -> dict[str, np.ndarray]:
    """Closed-loop co-simulation of a plant FMU with one controller and one encoder FMU per axis on the
    controller grid k*Ts, k = 0..n-1. ``r``, ``u_ext``, ``noise``: (n, n_axes) arrays (``noise[k]``: the sensor
    noise of sample k); returns time and, as (n, n_axes) arrays, r, u, q (measured), u_ext and q_true."""
    paths = truth_fmus([plant_class, CONTROLLER, ENCODER], fmu_dir)
    system = system_from_dict(loop_system(paths[plant_class], paths[CONTROLLER], paths[ENCODER], ctrls,
                                          plant_parameters, resolution, axes))
    n = r.shape[0]
    ts = ctrls[0].Ts
    t = np.arange(n) * ts
    # the encoder output read at base tick k*M was computed at tick k*M - 1: give it noise[k] there
    fine = np.minimum((np.arange(n * PLANT_SUBSTEPS + 1) + 1) // PLANT_SUBSTEPS, n - 1)
    signals = {}
    for j, axis in enumerate(axes):
        signals.update({axis.r: (t, r[:, j]), axis.u_ext: (t, u_ext[:, j]), axis.noise: noise[fine, j]})
    with Master(system, progress=False) as master:
        log = master.run(inputs=signals, stop_time=n * ts)["samples"][:n]

    def column(pattern: str) -> np.ndarray:
        return np.column_stack([log[pattern.format(a=axis)] for axis in axes])
    return {"time": t, "r": column("input.{a.r}"), "u": column("plant.{a.input}"), "q": column("{a.enc}.y"),
            "u_ext": column("input.{a.u_ext}"), "q_true": column("plant.{a.output}")}


def cosimulate(plant: TruthPlant, r: np.ndarray, u_ext: np.ndarray, noise: np.ndarray,
               resolution: float = RESOLUTION, ctrl: Controller | None = None,
               fmu_dir: Path | None = None) -> dict[str, np.ndarray]:
    """Closed-loop co-simulation on the controller grid k*Ts, k = 0..n-1; returns r, u, q (measured),
    u_ext and q_true. ``noise[k]`` is the sensor noise of sample k."""
    out = cosimulate_axes(plant.class_name, plant.parameters, SINGLE_AXIS, [ctrl or pid_controller()],
                          r[:, None], u_ext[:, None], noise[:, None], resolution, fmu_dir)
    return {k: v if k == "time" else v[:, 0] for k, v in out.items()}


def casadi_truth(plant: TruthPlant, r: np.ndarray, u_ext: np.ndarray, noise: np.ndarray,
                 substeps: int = 16, ctrl: Controller | None = None) -> dict[str, np.ndarray]:
    """The closed loop of :func:`cosimulate` computed without FMUs: the truth's effects written as the
    diagnosis' own augmented model (the ``MotionTwin.Effects`` functions through the project's front end),
    RK4 with ``substeps`` steps per sample, the controller reading q + noise, no quantisation. Much faster
    to generate (no FMU build, no co-simulation); used by the fast decision tests. Returns r, u, q
    (measured = true + noise), u_ext and q_true on the controller grid, starting at rest at x = 0."""
    from motiontwin.ident import outputerror
    from motiontwin.ident.diagnosis import augmented
    from motiontwin.ident.diagnosis import effects as effect_models

    if plant.class_name.endswith("VariableInertiaJoint"):
        raise ValueError("position_dependent_inertia: the truth (cosine mass) has no exact CasADi counterpart")
    ctx = effect_models.Context(TS, 0.0, 0.1, 0.2, TRUE_M)
    m = plant.parameters.get("m", plant.parameters.get("m1", TRUE_M))
    if plant.class_name.endswith("BacklashJoint"):   # the backlash effect takes its load out of plant.m
        m += plant.parameters["m2"]
    d = plant.parameters["d"] if plant.parameters.get("d") else TRUE_D
    effects, values = [], {"plant.m": m, "plant.d": d}
    for true in plant.effects:
        effect = (outside_effect(true) if true.get("outside_catalogue")
                  else effect_models.VOCABULARY[true["name"]](ctx))
        effects.append(effect)
        values.update({p.name: float(np.mean(p.bounds)) for p in effect.params})
        values.update({k: v for k, v in true["parameters"].items() if k in {p.name for p in effect.params}})
    with tempfile.TemporaryDirectory(prefix="mt-truth-") as folder:
        augmented.write_model(Path(folder), PLANT_TEXT.format(m=m, d=d), PLANT_CLASS, effects, values,
                       {"m": m, "d": d}, "Truth", PlantRoles("u", "q", "x", "v"))
        model = augmented.load_augmented(Path(folder), "Truth")
    n = r.size
    t = np.arange(n) * TS
    loop = outputerror.build_loop(model, ctrl or pid_controller(), "plant.x", [], values, n, substeps=substeps,
                                  with_jacobian=False)
    rec = make_recording(t, {"r": r, "u": np.zeros(n), "q": np.zeros(n), "u_ext": u_ext})
    q_true, u = outputerror.simulate(loop, rec, values, noise=noise)
    return {"time": t, "r": r, "u": u, "q": q_true + noise, "u_ext": u_ext, "q_true": q_true}


def simulate_truth(case: str, t: np.ndarray, r: np.ndarray, u_ext: np.ndarray, rng: np.random.Generator,
                   scale: float, with_effects: bool = True, noise_std: float = NOISE,
                   resolution: float = RESOLUTION, fmu_dir: Path | None = None,
                   engine: str = "fmu", mass: float = TRUE_M, damping: float = TRUE_D,
                   skip: int = 0, truth: TruthPlant | None = None) -> tuple[np.ndarray, ...]:
    """Closed-loop truth (pre-roll and ``skip`` more samples cut off); returns the measured q, the force u and
    the true q. ``engine``: "fmu" (library FMUs co-simulated by the harness, quantised encoder) or "casadi"
    (:func:`casadi_truth`); ``mass``, ``damping``: the rigid axis (the PID is tuned for ``mass``); ``truth``:
    a plant of the caller's own instead of the case's (e.g. two catalogue effects at once)."""
    plant = truth if with_effects and truth is not None else \
        truth_plant(case if with_effects else "params_only_a", scale, mass, damping)
    rr, ue, pre = with_preroll(r, u_ext)
    noise = measurement.add_noise(np.zeros(rr.size), noise_std, rng)
    ctrl = pid_controller(mass=mass)
    if engine == "casadi":
        out = casadi_truth(plant, rr, ue, noise, ctrl=ctrl)
    elif engine == "fmu":
        out = cosimulate(plant, rr, ue, noise, resolution, ctrl=ctrl, fmu_dir=fmu_dir)
    else:
        raise ValueError(f"engine must be 'fmu' or 'casadi', not {engine!r}")
    pre += skip
    return out["q"][pre:], out["u"][pre:], out["q_true"][pre:]


# -- bundles ------------------------------------------------------------------------------------------
