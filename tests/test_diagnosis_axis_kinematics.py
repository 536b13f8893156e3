"""Axes whose outputs are expressions of the states (issue 24 item 2): the Hexapod in leg coordinates.

References are independent of the diagnosis: harness.kinematics' numpy inverse kinematics of the Hexapod and
a central finite difference of it along a pose trajectory."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.build import MODELICA_DIR
from motiontwin.harness import kinematics
from motiontwin.harness.recording import make_recording
from motiontwin.ident import loopstart, oeloop, startvalues
from motiontwin.ident.benchmarks import multi_axis_truth as truth
from motiontwin.ident.diagnosis import axis_kinematics, structure
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.bundle import BundleError, read_axes_controller, read_axes_plant

pytestmark = pytest.mark.timeout(120)

HEXAPOD_AXES = [{"input": f"tau{j}", "output": f"L{j}"} for j in range(1, 7)]
POSE = np.array([0.01, -0.02, 0.82, 0.03, -0.02, 0.05])
POSE_DOT = np.array([0.05, 0.02, -0.03, 0.2, -0.1, 0.3])


def _state(pose: np.ndarray, pose_dot: np.ndarray) -> np.ndarray:
    """Hexapod states [p, angles, v, w] of a pose moving at ``pose_dot`` (w = H(angles) angle rates)."""
    return np.concatenate([pose, pose_dot[:3], kinematics.angular_velocity_map(pose[3:]) @ pose_dot[3:]])


def _leg_rates(pose: np.ndarray, pose_dot: np.ndarray, h: float = 1e-6) -> np.ndarray:
    return (kinematics.hexapod_inverse(pose + h * pose_dot) - kinematics.hexapod_inverse(pose - h * pose_dot)) / (2 * h)


@pytest.fixture(scope="module")
def hexapod(tmp_path_factory):
    return read_axes_plant({"class": "MotionTwin.Plants.Hexapod", "axes": HEXAPOD_AXES},
                           tmp_path_factory.mktemp("hexapod"), "experiment.json")


def test_hexapod_legs_are_expression_axes(hexapod) -> None:
    assert [a.expression for a in hexapod.axes] == [True] * 6
    assert "position L3(states)" in hexapod.axes[2].describe()


def test_generated_leg_functions_match_inverse_kinematics(hexapod, tmp_path: Path) -> None:
    """The Modelica functions an effect on leg 3 is written with, through the front end: the leg length is
    the numpy inverse kinematics, the leg velocity its finite-difference rate along the motion."""
    augmented.write_axes_structure(hexapod, [], {}, tmp_path)
    calls = axis_kinematics.substitutions(hexapod.model, hexapod.axes[2])
    inputs = "".join(f"  plant.tau{j} = 0;\n" for j in range(1, 7))
    (tmp_path / "Probe.mo").write_text(f"model Probe\n  {hexapod.class_name} plant;\n  output Real pos;\n"
                                       f"  output Real vel;\nequation\n{inputs}  pos = {calls['x']};\n"
                                       f"  vel = {calls['v']};\nend Probe;\n", encoding="utf-8")
    probe = symbolic.build(frontend.load(tmp_path, "Probe", (MODELICA_DIR,)))
    out = {c.var.name: c.expr for c in probe.computed}
    fn = ca.Function("probe", [probe.x, probe.p], [out["pos"], out["vel"]])
    p = [float(v.start) for v in probe.parameters]
    names = [s.name for s in probe.states]
    order = [names.index(f"plant.{n}") for n in ("px", "py", "pz", "a", "b", "c", "vx", "vy", "vz", "wx", "wy", "wz")]
    x = np.zeros(len(names))
    x[order] = _state(POSE, POSE_DOT)
    pos, vel = (float(v) for v in fn(x, p))
    assert pos == pytest.approx(kinematics.hexapod_inverse(POSE)[2], abs=1e-12)
    assert vel == pytest.approx(_leg_rates(POSE, POSE_DOT)[2], rel=1e-7)
    assert abs(vel) > 0.01


def test_effect_on_a_leg_is_a_force_along_it(hexapod, tmp_path: Path) -> None:
    """Coulomb friction on leg 3 changes the pose accelerations as the same force subtracted from leg 3's
    actuator force (J^T F in pose coordinates), with the leg's finite-difference velocity."""
    ctx = effect_models.Context(1e-3, 0.7, 0.9, 0.1, 10.0)
    effect = structure.on_axis(effect_models.VOCABULARY["coulomb_friction"](ctx), hexapod.axes[2], hexapod.model)
    augmented.write_axes_structure(hexapod, [("L3", effect)], {q.name: float(np.mean(q.bounds)) for q in effect.params},
                                   tmp_path)
    model = augmented.load_structure(tmp_path)
    params = [v.name for v in model.parameters]
    p = np.array([float(v.start) for v in model.parameters])
    p[params.index("L3_coulomb_Fc")], p[params.index("L3_coulomb_v_eps")] = 2.0, 0.05
    fn = ca.Function("f", [model.x, model.u, model.p], [model.dx, ca.jacobian(model.dx, model.u)])
    x = _state(POSE, POSE_DOT)
    u = np.array([10.0, -5.0, 3.0, 7.0, 0.0, 1.0])
    with_effect, gain = fn(x, u, p)
    p[params.index("L3_coulomb_Fc")] = 0.0
    without, _ = fn(x, u, p)
    force = 2.0 * np.tanh(_leg_rates(POSE, POSE_DOT)[2] / 0.05)
    np.testing.assert_allclose(np.array(with_effect - without).ravel(), -force * np.array(gain)[:, 2],
                               atol=1e-9 * float(np.max(np.abs(gain))))


def test_states_from_leg_lengths_and_rates(hexapod) -> None:
    """Newton on the generated leg lengths recovers the pose, the leg rates the twist."""
    t = np.linspace(0.0, 0.2, 5)
    poses = POSE[:, None] + POSE_DOT[:, None] * t
    q = np.column_stack([kinematics.hexapod_inverse(poses[:, k]) for k in range(t.size)])
    qdot = np.column_stack([_leg_rates(poses[:, k], POSE_DOT) for k in range(t.size)])
    p = np.array([float(v.start) for v in hexapod.model.parameters])
    x = axis_kinematics.states_from_outputs(hexapod.model, hexapod.axes, p, q, qdot)
    expected = np.column_stack([_state(poses[:, k], POSE_DOT) for k in range(t.size)])
    np.testing.assert_allclose(x[:6], expected[:6], atol=1e-10)
    np.testing.assert_allclose(x[6:], expected[6:], atol=1e-6)


def test_rate_depending_on_an_input_is_refused(tmp_path: Path) -> None:
    """An output whose time derivative depends on an input is no position: one message naming the axis."""
    (tmp_path / "plant.mo").write_text(
        "model P\n  input Real u1;\n  input Real u2;\n  output Real y1;\n  output Real y2;\n"
        "  Real x1(start = 0, fixed = true);\n  Real x2(start = 0, fixed = true);\n"
        "equation\n  der(x1) = u1;\n  der(x2) = u2;\n  y1 = x1*x2;\n  y2 = x2;\nend P;\n", encoding="utf-8")
    doc = {"class": "P", "modelica": "plant.mo", "axes": [{"input": "u1", "output": "y1"},
                                                          {"input": "u2", "output": "y2"}]}
    with pytest.raises(BundleError, match=r"plant.axes\[0\].*y1.*not a position-level expression"):
        read_axes_plant(doc, tmp_path, "experiment.json")


def _pose_rates(x: np.ndarray) -> np.ndarray:
    """Pose rates [v, angle rates] of a Hexapod state [p, angles, v, w]."""
    return np.concatenate([x[6:9], np.linalg.solve(kinematics.angular_velocity_map(x[3:6]), x[9:12])])


def test_acceleration_term_on_a_leg_is_the_leg_acceleration(hexapod, tmp_path: Path) -> None:
    """An effect written with der($v) (position-dependent inertia) on leg 3 builds (the front end's der() of
    the leg-velocity call would differentiate the parameter arguments) and changes the pose accelerations as
    the force slope*(L3 - c)*a3 + slope/2*v3^2 subtracted from tau3, with a3 the finite-difference derivative of
    the numpy leg rate along the augmented model's own motion."""
    ctx = effect_models.Context(1e-3, 0.7, 0.9, 0.1, 10.0)
    effect = structure.on_axis(effect_models.VOCABULARY["position_dependent_inertia"](ctx), hexapod.axes[2],
                               hexapod.model)
    augmented.write_axes_structure(hexapod, [("L3", effect)], {q.name: float(np.mean(q.bounds)) for q in effect.params},
                                   tmp_path)
    model = augmented.load_structure(tmp_path)
    params = [v.name for v in model.parameters]
    p = np.array([float(v.start) for v in model.parameters])
    slope, centre = 3.0, 0.8
    p[params.index("L3_inertia_slope")], p[params.index("L3_inertia_centre")] = slope, centre
    fn = ca.Function("f", [model.x, model.u, model.p], [model.dx, ca.jacobian(model.dx, model.u)])
    x = _state(POSE, POSE_DOT)
    u = np.array([10.0, -5.0, 3.0, 7.0, 0.0, 1.0])
    with_effect = np.array(fn(x, u, p)[0])
    p[params.index("L3_inertia_slope")] = 0.0
    without, gain = (np.array(m) for m in fn(x, u, p))     # the plant's own response to a leg force
    h = 1e-4
    rate = [_leg_rates(y[:6], _pose_rates(y))[2] for y in (x + h * with_effect.ravel(), x - h * with_effect.ravel())]
    accel = (rate[0] - rate[1]) / (2 * h)
    force = slope * (kinematics.hexapod_inverse(POSE)[2] - centre) * accel + 0.5 * slope * _leg_rates(POSE, POSE_DOT)[2] ** 2
    assert abs(force) > 1e-3
    np.testing.assert_allclose((with_effect - without).ravel(), -force * gain[:, 2], rtol=1e-5,
                               atol=1e-6 * float(np.max(np.abs(with_effect - without))))


def test_loop_starts_at_the_recorded_pose(hexapod) -> None:
    """The output-error loop's start (:func:`loopstart.initial_state`) on a Hexapod recording that does not begin at
    the plant's start pose: the pose whose numpy leg lengths are the first recorded ones and the twist whose leg
    rates are their slopes (a recording that starts while the loop still settles against gravity was simulated
    from the start pose, tens of micrometres off on every leg), and a finite controller state."""
    model = hexapod.model
    p = np.array([float(v.start) for v in model.parameters])
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    ts, t = 1e-3, np.arange(40) * 1e-3
    legs = np.column_stack([kinematics.hexapod_inverse(POSE + POSE_DOT * tk) for tk in t])
    targets = {f"L{j + 1}": startvalues.first_samples(legs[j], ts) for j in range(6)}
    x = x0.copy()
    assert loopstart._states_for_outputs(model, targets, x, p)
    signals = structure.axes_signals(hexapod)
    ctrl = read_axes_controller({"kind": "per_axis", "axes": [truth.pid_document(ts, 33.0, 10.0)] * 6}, "test",
                                hexapod.axes)
    columns = {}
    for k, sig in enumerate(signals):
        columns.update({sig.reference: legs[k], sig.output: legs[k], sig.input: np.zeros(t.size)})
    values = {v.name: float(v.start) for v in model.parameters}
    loop = oeloop.Loop(model, ctrl, signals[0].output, [], values, 2, t.size, sim=None, jac=None, ts=ts,
                       axes=tuple(signals))
    s0 = loopstart.initial_state(loop, make_recording(t, columns))
    expected = _state(POSE, POSE_DOT)
    for start in (x, s0[:model.x.numel()]):
        np.testing.assert_allclose(start[:6], expected[:6], atol=1e-10)
        np.testing.assert_allclose(start[6:], expected[6:], atol=1e-6)
    assert s0.size == model.x.numel() + ctrl.n_states and np.all(np.isfinite(s0))
    assert np.max(np.abs(x0[:6] - expected[:6])) > 0.01      # the start pose is elsewhere
    # the Newton and rate functions are built once per model, not for each of a fit's free runs
    assert loopstart._output_functions(model, tuple(targets)) is loopstart._output_functions(model, tuple(targets))
