"""Cheung & Hung's point-to-point comparison on the coupled 4-DOF plant: robust controller vs computed-torque PID.

SI units throughout: time in s, positions in m, angles in rad, forces in N (tables print um, ms, mrad).

What runs (through :class:`harness.master.Master`, controllers at Ts = 5e-4 s, i.e. the paper's 2 kHz):

- plant: ``MotionTwin.Plants.CheungManipulator`` (coupled rigid body, Table 1), starting at rest at the
  paper's start pose (91.4, 91.4, 123.7 mm, -0.7854 rad);
- reference: the substrate move to (95.1, 96.9, 122.3 mm, -0.8 rad) in 70 ms, one quintic per actuator
  through the inverse kinematics (:func:`harness.excitation.end_effector_point_to_point`), after
  ``PRE_MOVE`` s at rest; the controllers take the analytic velocity/acceleration/jerk as feedforward;
- robust: four ``MotionTwin.Controllers.RobustJointController`` channels (eqs. 9-13). Default gains: the
  Table 2 column of each actuator read as the DSP's per-sample PID gains (Ki/Ts, Kd*Ts; see
  :func:`table2_designs`), then Kp, Ki, Kd scaled by one factor so that the closed-loop bandwidth on our
  rigid joint 1/(m s^2 + c_v s) equals the paper's CLBW of that column
  (``ident.tuning.rescale_to_bandwidth``; lag, notch unchanged; tau = 2 Ts). Or design JSON files from
  ``motiontwin tune --out`` (one for all joints, or four).
  Feedforward Kv, Ka (paper units in Table 2, unusable on SI; taken from a design file when it has them) are
  the joint's viscous friction and effective mass divided by the DC gain KL*fc/fp of the lag, so G_f inverts
  the rigid joint at low frequency; Kj = 0. Only the diagonal is fed forward: the coupling of the mass
  matrix and the gravity change along the move are left to the feedback, as in the paper's joint design.
  The plant force is the controller output plus the gravity load at the start pose (the force a settled
  integrator holds before the move), so the loop starts in equilibrium;
- computed torque: four ``MotionTwin.Controllers.ComputedTorquePID`` channels with m_hat = the diagonal of
  the plant's mass matrix at the start pose, d_hat = c_v and a triple closed-loop pole at
  ``CT_POLE_HZ`` = 20 Hz (Kp = 3 w^2, Ki = w^3, Kd = 3 w; on the sampled loop with the 1 ms velocity filter:
  GM 18.6 dB, PM 46.5 deg, i.e. the eq. (14)-(15) spec GM >= 7 dB, PM >= 45 deg, see :func:`ct_loop_margins`),
  plus the coupling, Coriolis and gravity forces of the full model along the reference, i.e. its total
  feedforward is the plant's own inverse dynamics M(r) r'' + c(r, r') + g(r) + c_v r' (computed from the
  plant FMU's Model Exchange equations, :class:`PlantDynamics`). Its feedback uses a velocity estimate
  filtered with Tf = 1 ms, whose lag during the move is most of its dynamic error.

The metrics are those of :mod:`harness.metrics`: per actuator (Table 3) the maximum |r - q| during the
move, the settling time into +-5 um after the end of the move and the steady-state error (mean over the
last ``SS_WINDOW`` s); per end-effector axis (Table 4) the same for ``forward(r) - forward(q)`` with bands
+-5 um (x, y, z) and +-0.2 mrad (theta).

``motiontwin compare --out DIR`` writes into DIR: ``robust.csv/json`` and
``computed_torque.csv/json`` (harness.recording format), ``table.txt``, ``table.json`` and
``comparison_joint_errors.png`` (Figs. 4-7) and ``comparison_end_effector.png`` (written by
:mod:`motiontwin.comparison_report`).
"""
from __future__ import annotations

import ctypes
import math
import tempfile
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from motiontwin.harness import kinematics, metrics
from motiontwin.harness.excitation import end_effector_point_to_point
from motiontwin.harness.fmu_instance import extracted_fmu
from motiontwin.harness.master import Master
from motiontwin.fmus.archive import read_description
from motiontwin.fmus.limits import load_json
from motiontwin.harness.system import System, system_from_dict

PLANT_CLASS = "MotionTwin.Plants.CheungManipulator"
ROBUST_CLASS = "MotionTwin.Controllers.RobustJointController"
CT_CLASS = "MotionTwin.Controllers.ComputedTorquePID"
JOINTS = ("d1", "d3", "d5", "d7")
PORTS = ("1", "3", "5", "7")  # plant ports u1/q1, u3/q3, ...
POSE_AXES = ("x", "y", "z", "theta")
TS = 5e-4
MOVE_TIME = 0.070
PRE_MOVE = 0.010
STOP_TIME = 0.250
SS_WINDOW = 0.050
CT_POLE_HZ = 20.0
CT_TF = 1e-3  # s, ComputedTorquePID velocity-estimate filter (its default)
POSE_BANDS = (metrics.DEFAULT_BAND,) * 3 + (metrics.DEFAULT_THETA_BAND,)
CONTROLLERS = ("computed_torque", "robust")
LABELS = {"computed_torque": "computed-torque PID", "robust": "robust controller"}

# Cheung & Hung, Table 3 (um, ms, um) and Table 4 (ms; um, theta accuracy printed in um in the paper).
PAPER_TABLE3 = {
    "computed_torque": {"max_dynamic_error_um": [140.2, 82.2, 154.0, 140.2],
                        "settling_time_ms": [30.0, 30.5, 34.0, 34.0], "steady_state_error_um": [-1.6, -0.6, 0.8, -1.6]},
    "robust": {"max_dynamic_error_um": [22.4, 9.2, 22.2, 47.0], "settling_time_ms": [5.0, 3.0, 8.0, 3.0],
               "steady_state_error_um": [-2.4, -1.0, -0.4, -0.6]},
}
PAPER_TABLE4 = {
    "computed_torque": {"settling_time_ms": [51.2, 49.6, 36.8, 54.4], "accuracy": [0.0, 0.91, -0.91, -1.82]},
    "robust": {"settling_time_ms": [27.2, 36.8, 7.2, 24.0], "accuracy": [0.0, 0.91, 0.0, -1.82]},
}


# ---------------------------------------------------------------------------------------------- FMUs


def build_fmus(out_dir: str | Path, fmi_version: str = "2.0") -> dict[str, Path]:
    """Build (object cache: fast when unchanged) the plant and both controllers; returns role -> FMU path."""
    from motiontwin.fmus import build

    classes = {"plant": PLANT_CLASS, "robust": ROBUST_CLASS, "computed_torque": CT_CLASS}
    built = build.build(list(classes.values()), out_dir=out_dir, fmi_versions=(fmi_version,), workers=1)
    by_class = {b.identifier: b.path for b in built}
    return {role: Path(by_class[name.rsplit(".", 1)[-1]]) for role, name in classes.items()}


class PlantDynamics:
    """The plant FMU's own equations through its FMI 2.0 Model Exchange interface, at chosen states.

    ``acceleration(d, v, u)`` = der(v); ``mass_matrix(d)`` = inverse of d der(v)/du (exact directional
    derivatives); ``inverse(d, v, a)`` the actuator forces that give acceleration a: M (a - der(v)|u=0).
    """

    def __init__(self, fmu: str | Path, parameters: dict[str, float] | None = None):
        from fmpy.fmi2 import FMU2Model

        self.md = md = read_description(fmu)
        if md.fmiVersion != "2.0" or md.modelExchange is None:
            raise ValueError(f"{fmu}: PlantDynamics needs an FMI 2.0 Model Exchange FMU")
        vr = {v.name: v.valueReference for v in md.modelVariables}
        self._der = [d.variable.valueReference for d in md.derivatives]
        self._n = len(self._der)
        self._u = [vr[f"u{p}"] for p in PORTS]
        self._dv = self._der[4:]
        self.model = FMU2Model(guid=md.guid, unzipDirectory=extracted_fmu(fmu),
                               modelIdentifier=md.modelExchange.modelIdentifier, instanceName="dynamics")
        self.model.instantiate()
        self.model.setupExperiment(startTime=0.0)
        if parameters:
            self.model.setReal([vr[k] for k in parameters], [float(x) for x in parameters.values()])
        self.model.enterInitializationMode()
        self.model.exitInitializationMode()
        self.model.newDiscreteStates()
        self.model.enterContinuousTimeMode()
        self._x = (ctypes.c_double * self._n)()
        self._dx = (ctypes.c_double * self._n)()
        self.model.getContinuousStates(self._x, self._n)
        self.start_state = np.array(self._x)

    def _set(self, d: np.ndarray, v: np.ndarray, u: np.ndarray) -> None:
        self._x[:] = [float(x) for x in np.concatenate([d, v])]
        self.model.setContinuousStates(self._x, self._n)
        self.model.setReal(self._u, [float(x) for x in u])

    def acceleration(self, d: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """der(v) [m/s2] at positions d [m], velocities v [m/s], forces u [N]."""
        self._set(d, v, u)
        self.model.getDerivatives(self._dx, self._n)
        return np.array(self._dx)[4:]

    def mass_matrix(self, d: np.ndarray) -> np.ndarray:
        """M(d) [kg] in actuator coordinates: the inverse of d der(v)/du."""
        self._set(d, np.zeros(4), np.zeros(4))
        columns = [self.model.getDirectionalDerivative(self._dv, self._u, list(np.eye(4)[j])) for j in range(4)]
        return np.linalg.inv(np.array(columns, dtype=float).T)

    def inverse(self, d: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Forces u [N] with der(v) = a at (d, v): M(d) (a - der(v)|u=0), exact since der(v) is affine in u."""
        return self.mass_matrix(d) @ (np.asarray(a, float) - self.acceleration(d, v, np.zeros(4)))

    def close(self) -> None:
        self.model.terminate()
        self.model.freeInstance()

    def __enter__(self) -> "PlantDynamics":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# ---------------------------------------------------------------------------------------------- designs


def lag_dc_gain(design: dict[str, float]) -> float:
    """DC gain KL*fc/fp of F_L (the notch has DC gain 1): what the feedforward is divided by."""
    return design["KL"] * design["fc"] / design["fp"]


def with_feedforward(design: dict[str, float], mass: float, damping: float) -> dict[str, float]:
    """Add Kv, Ka (and Kj = 0) that invert the rigid joint mass*a + damping*v through F_L's DC gain."""
    dc = lag_dc_gain(design)
    return {**design, "Kv": damping / dc, "Ka": mass / dc, "Kj": design.get("Kj", 0.0)}


def table2_designs(masses: Sequence[float], damping: float, ts: float = TS,
                   reading: str = "per-sample") -> list[dict[str, float]]:
    """Table 2 columns d1, d3, d5, d7 on our joints (1/(m s^2 + c_v s)), Kp, Ki, Kd rescaled to the paper's CLBW;
    ``reading`` as :func:`ident.tuning.table2_parameters`."""
    from motiontwin.ident.frf import JointModel
    from motiontwin.ident.tuning import TABLE2, rescale_to_bandwidth, table2_parameters

    designs = []
    for joint, mass in zip(JOINTS, masses):
        params = table2_parameters(joint, ts, reading)
        scaled, gain = rescale_to_bandwidth(params, JointModel(1.0 / mass, damping / mass), TABLE2[joint]["CLBW"])
        designs.append(with_feedforward(scaled, mass, damping) | {"table2_scale": gain})
    return designs


def read_designs(paths: Sequence[str | Path], ts: float = TS) -> list[dict[str, float]]:
    """The controller parameters of ``motiontwin tune --out`` JSON files, checked (one for all four joints or
    one per joint), one dict per joint; read before any FMU is built, so a bad file costs nothing."""
    from motiontwin.ident.tuning import DESIGN_NAMES

    if len(paths) not in (1, 4):
        raise ValueError(f"give one design JSON for all joints or four (d1, d3, d5, d7), got {len(paths)}")
    docs = []
    for path in paths:
        doc = load_json(path)
        params = doc.get("parameters") if isinstance(doc, dict) else None
        if not isinstance(params, dict):
            raise ValueError(f"{path}: field 'parameters' (an object of controller parameters) is missing")
        missing = [k for k in DESIGN_NAMES if k not in params]
        if missing:
            raise ValueError(f"{path}: field 'parameters' lacks {missing}")
        bad = [k for k, v in params.items() if not isinstance(v, (int, float)) or not math.isfinite(v)]
        if bad:
            raise ValueError(f"{path}: field 'parameters' has non-numeric values for {bad}")
        if not math.isclose(float(params.get("Ts", ts)), ts, rel_tol=1e-9):
            raise ValueError(f"{path}: field 'parameters.Ts' = {params['Ts']} s, the comparison samples at {ts} s")
        docs.append({k: float(v) for k, v in params.items()} | {"Ts": ts})
    return docs * 4 if len(docs) == 1 else docs


def load_designs(paths: Sequence[str | Path], masses: Sequence[float], damping: float,
                 ts: float = TS) -> list[dict[str, float]]:
    """Designs from ``motiontwin tune --out`` JSON files (:func:`read_designs`, d1, d3, d5, d7 order).
    Kv/Ka/Kj given in the file are used, otherwise they follow :func:`with_feedforward`."""
    docs = read_designs(paths, ts)
    out = []
    for doc, mass in zip(docs, masses):
        out.append(doc if {"Kv", "Ka"} <= set(doc) else with_feedforward(doc, mass, damping))
    return out


def ct_loop_margins(mass: float, damping: float, gains: dict[str, float], ts: float = TS,
                    tf: float = CT_TF) -> dict[str, float]:
    """Gain [dB] and phase [deg] margins of one ComputedTorquePID channel on the rigid joint 1/(m s^2 + c s):
    plant behind a zero-order hold, controller Tustin-sampled as the FMU is, loop opened at the force."""
    import control

    s = control.tf("s")
    m_hat, d_hat = gains["m_hat"], gains["d_hat"]
    law = m_hat * (gains["Kp"] + gains["Ki"] / s) + (m_hat * gains["Kd"] - d_hat) * s / (tf * s + 1)
    loop = control.c2d(law, ts, "tustin") * control.c2d(control.tf([1.0], [mass, damping, 0.0]), ts, "zoh")
    gm, pm, _, _ = control.margin(loop)
    return {"gm_db": float(20 * np.log10(gm)), "pm_deg": float(pm)}


def robust_loop_margins(design: dict[str, float], mass: float, damping: float) -> dict[str, float]:
    """GM [dB], PM [deg], CLBW [Hz], disk GM [dB] of one robust channel on 1/(m s^2 + c s), no computation
    delay (as the harness runs it: the controller output is applied over the same sample), from
    ``ident.tuning.loop_margins``. A negative GM is a gain-reduction margin at a phase crossover below the
    gain crossover (conditionally stable loop); the disk margin is then the meaningful figure."""
    from motiontwin.ident.frf import JointModel
    from motiontwin.ident.tuning import loop_margins

    params = {k: v for k, v in design.items() if k not in ("table2_scale", "Kv", "Ka", "Kj")}
    m = loop_margins(params, JointModel(1.0 / mass, damping / mass), 0)
    return {"gm_db": m.gm_db, "pm_deg": m.pm_deg, "bandwidth_hz": m.bandwidth_hz, "disk_gm_db": m.disk_gm_db,
            "phase_crossover_hz": m.phase_crossover_hz}


def computed_torque_gains(masses: Sequence[float], damping: float, start: Sequence[float],
                          pole_hz: float = CT_POLE_HZ) -> list[dict[str, float]]:
    """ComputedTorquePID parameters per joint: triple pole at ``pole_hz``, m_hat from M(start), xq at the start."""
    w = 2 * math.pi * pole_hz
    return [{"m_hat": float(m), "d_hat": float(damping), "Kp": 3 * w**2, "Ki": w**3, "Kd": 3 * w,
             "xq": float(d0)} for m, d0 in zip(masses, start)]


# ---------------------------------------------------------------------------------------------- system


def closed_loop_system(fmus: dict[str, Path], controller: str, plant_parameters: dict[str, float] | None = None,
                       base_step: float = TS) -> System:
    """Four channels of ``controller`` ("robust" or "computed_torque") around the coupled plant.

    External inputs per joint j: r_j, rd_j, rdd_j (and rddd_j for the robust one) and the additive force ff_j
    (plant.u_j = c_j.u + ff_j). Log group "log": q, u, r, ff per joint and the pose outputs.
    """
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    derivs = [("r", "r"), ("rd", "r_dot"), ("rdd", "r_ddot")]
    if controller == "robust":
        derivs.append(("rddd", "r_dddot"))
    data: dict[str, Any] = {"base_step": base_step, "fmus": {"plant": {"path": str(fmus["plant"]), "step": base_step,
                                                                         "parameters": dict(plant_parameters or {})}},
                            "inputs": {}, "connections": [], "log": []}
    signals = []
    for j, p in zip(JOINTS, PORTS):
        c = f"c{p}"
        data["fmus"][c] = {"path": str(fmus[controller]), "step": base_step}
        for prefix, port in derivs:
            data["inputs"][f"{prefix}{p}"] = {}
            data["connections"].append({"from": f"input.{prefix}{p}", "to": f"{c}.{port}"})
        data["inputs"][f"ff{p}"] = {"unit": "N", "default": 0.0}
        data["connections"].append({"from": f"plant.q{p}", "to": f"{c}.q"})
        data["connections"].append({"from": [f"{c}.u", f"input.ff{p}"], "to": f"plant.u{p}"})
        signals += [f"plant.q{p}", f"{c}.u", f"input.r{p}", f"input.ff{p}"]
    signals += [f"plant.{a}" for a in POSE_AXES]
    data["log"].append({"name": "log", "signals": signals})
    return system_from_dict(data)


# ---------------------------------------------------------------------------------------------- results


@dataclass
class ControllerRun:
    """One closed-loop run. Arrays over ``time`` (N,); per-joint arrays (N, 4) in d1, d3, d5, d7 order."""

    controller: str
    time: np.ndarray
    reference: np.ndarray
    position: np.ndarray
    force: np.ndarray
    feedforward_force: np.ndarray
    pose: np.ndarray
    pose_reference: np.ndarray
    parameters: list[dict[str, float]]
    wall_time: float

    @property
    def error(self) -> np.ndarray:
        """Joint position error r - q [m], (N, 4)."""
        return self.reference - self.position

    @property
    def pose_error(self) -> np.ndarray:
        """End-effector error forward(r) - forward(q) [m, m, m, rad], (N, 4)."""
        return self.pose_reference - self.pose


@dataclass
class ComparisonResult:
    """Both runs, the move window [t_start, t_end] [s], the target pose and the Table 3/4 metrics.

    ``table``: {controller: {"joints": {metric: [d1, d3, d5, d7]}, "end_effector": {metric: [x, y, z, theta]}}}
    in SI units (m, s, rad); ``paper``: the paper's Table 3/4 figures (um, ms) for the same keys.
    """

    runs: dict[str, ControllerRun]
    t_start: float
    t_end: float
    target_pose: np.ndarray
    table: dict[str, dict[str, dict[str, list[float]]]]
    design_source: str
    margins: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    paper: dict[str, Any] = field(default_factory=lambda: {"table3": PAPER_TABLE3, "table4": PAPER_TABLE4})


def evaluate(run: ControllerRun, t_start: float, t_end: float,
             window: float = SS_WINDOW) -> dict[str, dict[str, list[float]]]:
    """Table 3 (joints) and Table 4 (end-effector) metrics of one run, SI units."""
    t, e, pe = run.time, run.error, run.pose_error
    joints = {
        "max_dynamic_error": list(np.atleast_1d(metrics.max_dynamic_error(t, e, t_start, t_end)).astype(float)),
        "settling_time": [metrics.settling_time(t, e[:, j], t_end) for j in range(4)],
        "steady_state_error": list(np.atleast_1d(metrics.steady_state_error(t, e, window)).astype(float)),
    }
    pose = {
        "max_dynamic_error": list(np.atleast_1d(metrics.max_dynamic_error(t, pe, t_start, t_end)).astype(float)),
        "settling_time": [metrics.settling_time(t, pe[:, k], t_end, POSE_BANDS[k]) for k in range(4)],
        "steady_state_error": list(np.atleast_1d(metrics.steady_state_error(t, pe, window)).astype(float)),
    }
    return {"joints": joints, "end_effector": pose}


def reference_profile(time: np.ndarray, start_pose: np.ndarray = kinematics.CHEUNG_START_POSE,
                      end_pose: np.ndarray = kinematics.CHEUNG_END_POSE, t0: float = PRE_MOVE,
                      move_time: float = MOVE_TIME):
    """Per-actuator quintics of the substrate move on ``time`` (harness.excitation.Profile, (N, 4) arrays)."""
    return end_effector_point_to_point(time, start_pose, end_pose, move_time, t0)


def run_controller(master: Master, controller: str, parameters: list[dict[str, float]], time: np.ndarray,
                   profile: Any, feedforward_force: np.ndarray, stop_time: float) -> ControllerRun:
    """One run of a built closed loop with per-joint controller ``parameters``; returns the logged run."""
    inputs: dict[str, np.ndarray] = {}
    for k, p in enumerate(PORTS):
        inputs[f"r{p}"] = profile.position[:, k]
        inputs[f"rd{p}"] = profile.velocity[:, k]
        inputs[f"rdd{p}"] = profile.acceleration[:, k]
        if controller == "robust":
            inputs[f"rddd{p}"] = profile.jerk[:, k]
        inputs[f"ff{p}"] = feedforward_force[:, k]
    overrides = {f"c{p}.{name}": value for p, design in zip(PORTS, parameters) for name, value in design.items()
                 if name not in ("table2_scale", "Ts")}
    began = _time.perf_counter()
    log = master.run(inputs=inputs, parameters=overrides, stop_time=stop_time, progress=False)["log"]
    wall = _time.perf_counter() - began
    q = np.column_stack([log[f"plant.q{p}"] for p in PORTS])
    r = np.column_stack([log[f"input.r{p}"] for p in PORTS])
    pose = np.column_stack([log[f"plant.{a}"] for a in POSE_AXES])
    pose_ref = np.array([kinematics.cheung_forward(row) for row in r])
    return ControllerRun(controller, log["time"], r, q, np.column_stack([log[f"c{p}.u"] for p in PORTS]),
                         np.column_stack([log[f"input.ff{p}"] for p in PORTS]), pose, pose_ref, parameters, wall)


def run_comparison(fmu_dir: str | Path | None = None, design_files: Sequence[str | Path] = (),
                   stop_time: float = STOP_TIME, ct_pole_hz: float = CT_POLE_HZ,
                   plant_parameters: dict[str, float] | None = None,
                   table2_reading: str = "per-sample") -> ComparisonResult:
    """Build/load the FMUs, run both controllers on the substrate move, evaluate Tables 3 and 4.

    fmu_dir: where the FMUs are built (default: a temporary folder, removed afterwards). design_files:
    ``motiontwin tune --out``
    JSONs for the robust controller (default: Table 2 rescaled, see the module docstring and
    :func:`table2_designs` for ``table2_reading``).
    plant_parameters: CheungManipulator overrides (e.g. ``{"c_v": 0}``), used by both runs and the models.
    """
    if fmu_dir is None:
        with tempfile.TemporaryDirectory(prefix="motiontwin-compare-") as tmp:
            return run_comparison(tmp, design_files, stop_time, ct_pole_hz, plant_parameters, table2_reading)
    if design_files:
        read_designs(design_files)
    fmus = build_fmus(fmu_dir)
    plant_parameters = dict(plant_parameters or {})
    time = np.arange(round(stop_time / TS) + 1) * TS
    profile = reference_profile(time)
    start = profile.position[0]
    with PlantDynamics(fmus["plant"], plant_parameters) as dyn:
        if not np.allclose(dyn.start_state[:4], start, atol=1e-9):
            plant_parameters |= {f"d{p}": float(x) for p, x in zip(PORTS, start)}
        damping = float(plant_parameters.get("c_v", _start_value(fmus["plant"], "c_v")))
        masses = np.diag(dyn.mass_matrix(start)).copy()
        holding = dyn.inverse(start, np.zeros(4), np.zeros(4))
        full = np.array([dyn.inverse(d, v, a) for d, v, a in zip(profile.position, profile.velocity,
                                                                  profile.acceleration)])
    if design_files:
        robust = load_designs(design_files, masses, damping)
        source = "design files: " + ", ".join(map(str, design_files))
    else:
        robust = table2_designs(masses, damping, reading=table2_reading)
        source = f"Table 2 (d1, d3, d5, d7) read {table2_reading}, Kp/Ki/Kd rescaled to the paper's CLBW"
    ct = computed_torque_gains(masses, damping, start, ct_pole_hz)
    ct_ff = full - masses * profile.acceleration - damping * profile.velocity
    feedforward = {"robust": np.broadcast_to(holding, full.shape), "computed_torque": ct_ff}
    params = {"robust": robust, "computed_torque": ct}
    runs = {}
    for controller in CONTROLLERS:
        with Master(closed_loop_system(fmus, controller, plant_parameters), progress=False) as master:
            runs[controller] = run_controller(master, controller, params[controller], time, profile,
                                              feedforward[controller], stop_time)
    t_start, t_end = PRE_MOVE, PRE_MOVE + MOVE_TIME
    table = {c: evaluate(run, t_start, t_end) for c, run in runs.items()}
    margins = {"robust": [robust_loop_margins(d, m, damping) for d, m in zip(robust, masses)],
               "computed_torque": [ct_loop_margins(m, damping, g) for g, m in zip(ct, masses)]}
    return ComparisonResult(runs, t_start, t_end, kinematics.CHEUNG_END_POSE.copy(), table, source, margins)


def _start_value(fmu: Path, name: str) -> float:
    return next(float(v.start) for v in read_description(fmu).modelVariables if v.name == name)
