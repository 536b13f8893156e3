"""The MotionTwin Modelica library through the pipeline's front end (pymoca -> CasADi).

Each test checks a model against an independent reference: the Python kinematics mirror, an
effective inertia assembled from finite-difference Jacobians and Table 1 masses, energy balances
computed from first principles, the paper's transfer functions and python-control's Tustin map.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import casadi as ca
import control
import numpy as np
import pytest

from motiontwin.fmus import build, frontend, symbolic
from motiontwin.harness import kinematics as kin

LIBRARY = Path(__file__).resolve().parents[1] / "modelica"

#: Every exported (FMU-buildable) class of the library.
EXPORTED = [
    "MotionTwin.Plants.LinearMotorJoint",
    "MotionTwin.Plants.CoulombLinearMotorJoint",
    "MotionTwin.Plants.CheungJoint",
    "MotionTwin.Plants.CheungManipulator",
    "MotionTwin.Plants.CheungKinematicsCheck",
    "MotionTwin.Plants.SerialRobotJoint",
    "MotionTwin.Plants.SerialRobotJointAxis2",
    "MotionTwin.Plants.SerialRobotJointAxis3",
    "MotionTwin.Plants.Hexapod",
    "MotionTwin.Effects.CoulombJoint",
    "MotionTwin.Effects.StribeckJoint",
    "MotionTwin.Effects.AsymmetricFrictionJoint",
    "MotionTwin.Effects.RippleJoint",
    "MotionTwin.Effects.OffsetForceJoint",
    "MotionTwin.Effects.TwoMassJoint",
    "MotionTwin.Effects.DelayedInputJoint",
    "MotionTwin.Effects.VariableInertiaJoint",
    "MotionTwin.Controllers.RobustJointController",
    "MotionTwin.Controllers.RobustJointControllerD1",
    "MotionTwin.Controllers.RobustJointControllerD3",
    "MotionTwin.Controllers.RobustJointControllerD5",
    "MotionTwin.Controllers.RobustJointControllerD7",
    "MotionTwin.Controllers.ComputedTorquePID",
    "MotionTwin.Controllers.StateSpaceController",
    "MotionTwin.Controllers.DiscreteStateSpaceController",
    "MotionTwin.Examples.JointWithRobustController",
    "MotionTwin.Benchmarks.CheungEffects",
    "MotionTwin.Benchmarks.Encoder",
    "MotionTwin.Benchmarks.LoopController",
    "MotionTwin.Benchmarks.OffsetRippleJoint",
    "MotionTwin.Benchmarks.PositionFrictionJoint",
    "MotionTwin.Benchmarks.QuadraticDragJoint",
    "MotionTwin.Benchmarks.RigidJoint",
]
SAMPLED = {n for n in EXPORTED if ".Controllers." in n or n.endswith("LoopController")}


@lru_cache(maxsize=None)
def load(name: str) -> symbolic.SymbolicModel:
    return symbolic.build(frontend.load(LIBRARY, name))


def _pvalues(model: symbolic.SymbolicModel, **override: float) -> np.ndarray:
    names = [v.name for v in model.parameters]
    values = np.array(model.parameter_values(), dtype=float)
    for key, val in override.items():
        values[names.index(key)] = val
    return values


def _fn(model: symbolic.SymbolicModel, expr: ca.SX) -> ca.Function:
    return ca.Function("f", [model.x, model.u, model.p], [expr])


def _linearise(model: symbolic.SymbolicModel, x0: np.ndarray, u0: np.ndarray, p: np.ndarray):
    jac = ca.Function("j", [model.x, model.u, model.p],
                      [ca.jacobian(model.dx, model.x), ca.jacobian(model.dx, model.u),
                       ca.jacobian(model.y, model.x), ca.jacobian(model.y, model.u)])
    return [np.array(m) for m in jac(x0, u0, p)]


def _siso(model: symbolic.SymbolicModel, mats: list[np.ndarray], inp: str, out: str) -> control.StateSpace:
    """Single-input single-output slice of a linearisation (a, b, c, d) by variable names."""
    a, b, c, d = mats
    i = [v.name for v in model.inputs].index(inp)
    o = [cc.var.name for cc in model.computed].index(out)
    return control.ss(a, b[:, [i]], c[[o], :], d[[o]][:, [i]])


def _at(sys, s: complex) -> complex:
    return complex(np.squeeze(sys(s)))


def _output(model: symbolic.SymbolicModel, name: str) -> ca.SX:
    return next(c.expr for c in model.computed if c.var.name == name)


def test_export_annotations_select_exactly_the_fmu_classes():
    assert build.exported_classes(LIBRARY) == sorted(EXPORTED)


@pytest.mark.parametrize("name", EXPORTED)
def test_every_exported_class_loads(name):
    flat = frontend.load(LIBRARY, name)
    model = symbolic.build(flat)
    assert flat.description, f"{name} has no description string"
    assert model.inputs and flat.outputs
    for var in flat.states + flat.algebraics + flat.inputs + flat.parameters:
        assert var.description, f"{name}.{var.name} has no description string"
    assert model.sampled == (name in SAMPLED)
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(model.parameter_values())).ravel()
    if not model.sampled:
        dx = _fn(model, model.dx)(x0, np.zeros(model.u.numel()), model.parameter_values())
        assert np.all(np.isfinite(np.array(dx)))


# ---------------------------------------------------------------- 4-DOF kinematics and dynamics

def test_cheung_kinematic_functions_match_python_mirror():
    model = load("MotionTwin.Plants.CheungKinematicsCheck")
    names = [v.name for v in model.inputs]
    out = _fn(model, model.y)
    out_names = [c.var.name for c in model.computed if c.causality == "output"]
    rng = np.random.default_rng(0)
    poses = [kin.CHEUNG_START_POSE, kin.CHEUNG_END_POSE]
    poses += [kin.CHEUNG_START_POSE + rng.uniform([-0.004, -0.004, -0.001, -0.05], [0.004, 0.004, 0.001, 0.05])
              for _ in range(40)]
    with np.errstate(invalid="ignore"):
        poses = [pose for pose in poses if kin.cheung_in_range(kin.cheung_inverse(pose))]
    assert len(poses) > 10
    for pose in poses:
        d = kin.cheung_inverse(pose)
        u = dict(zip(["d1", "d3", "d5", "d7"], d)) | dict(zip(["xp", "yp", "zp", "thetap"], pose))
        y = np.array(out([], [u[n] for n in names], model.parameter_values())).ravel()
        y = dict(zip([c.var.name for c in model.computed], y))
        assert set(out_names) >= {"x", "theta", "e1", "e7"}
        np.testing.assert_allclose([y["x"], y["y"], y["z"], y["theta"]], kin.cheung_forward(d), rtol=0, atol=1e-12)
        np.testing.assert_allclose([y["e1"], y["e3"], y["e5"], y["e7"]], d, rtol=0, atol=1e-12)


TABLE1 = dict(m_s=0.7, m_a=0.104, m_b=0.094, m_pq=0.034 + 0.019, m10=0.147, m12=0.13, m_e=0.027 + 0.0023)


def _cheung_body_points(d: np.ndarray) -> dict[str, np.ndarray]:
    """3-D positions of the body end points from the Python kinematics (apex at height z - dz)."""
    g = kin.CHEUNG
    (x1, y1), (x2, y2) = kin.cheung_points(d)
    x, y, z, theta = kin.cheung_forward(d)
    return {"S1": np.array([d[0], g.dy, 0]), "S3": np.array([d[1], g.dy, 0]),
            "S5": np.array([g.dx, d[2], 0]), "S7": np.array([g.dx, d[3], 0]),
            "P": np.array([x1, y1, 0]), "Q": np.array([x2, y2, 0]),
            "A": np.array([x, y, z - g.dz]), "theta": np.array([theta])}


def _reference_mass_matrix(d: np.ndarray) -> np.ndarray:
    """M(d) = sum of J^T W J over the Table 1 bodies, Jacobians by central differences."""
    h = 1e-7
    jac = {}
    for i in range(4):
        e = np.zeros(4)
        e[i] = h
        plus, minus = _cheung_body_points(d + e), _cheung_body_points(d - e)
        for key in plus:
            jac.setdefault(key, np.zeros((plus[key].size, 4)))[:, i] = (plus[key] - minus[key]) / (2 * h)
    m = TABLE1

    def rod(mass, a, b):
        return mass / 3 * (jac[a].T @ jac[a] + jac[b].T @ jac[b]) + mass / 6 * (jac[a].T @ jac[b] + jac[b].T @ jac[a])

    mass = m["m_s"] * np.eye(4)
    mass += rod(m["m_a"], "S1", "P") + rod(m["m_b"], "S3", "P") + rod(m["m_a"], "S5", "Q") + rod(m["m_b"], "S7", "Q")
    mass += m["m_pq"] * (jac["P"].T @ jac["P"] + jac["Q"].T @ jac["Q"])
    mass += rod(m["m10"], "P", "A") + rod(m["m12"], "Q", "A") + m["m_e"] * jac["A"].T @ jac["A"]
    return mass


def test_cheung_effective_inertia_matches_jacobian_and_table1_masses():
    model = load("MotionTwin.Plants.CheungManipulator")
    p = model.parameter_values()
    inv_mass = ca.Function("b", [model.x, model.p], [ca.jacobian(model.dx, model.u)[4:, :]])
    poses = [kin.CHEUNG_START_POSE, kin.CHEUNG_END_POSE, np.array([0.090, 0.088, 0.1225, -0.80]),
             np.array([0.088, 0.092, 0.1245, -0.78])]
    diagonals = []
    for pose in poses:
        d = kin.cheung_inverse(pose)
        assert kin.cheung_in_range(d)
        mass_model = np.linalg.inv(np.array(inv_mass(np.concatenate([d, np.zeros(4)]), p)))
        mass_ref = _reference_mass_matrix(d)
        np.testing.assert_allclose(mass_model, mass_ref, rtol=0, atol=1e-6 * np.abs(mass_ref).max())
        diagonals.append(np.diag(mass_ref))
        assert np.abs(mass_ref[0, 1]) > 1e-3  # the joints couple
    assert np.ptp(np.array(diagonals), axis=0).max() > 1e-3  # inertia varies over the workspace


def test_cheung_manipulator_conserves_energy_without_friction():
    """u = 0, c_v = 0: kinetic (reference mass matrix) + potential energy stays constant."""
    model = load("MotionTwin.Plants.CheungManipulator")
    p = _pvalues(model, c_v=0.0)
    ode = ca.Function("f", [model.x, model.p], [ca.substitute(model.dx, model.u, ca.DM.zeros(4))])
    x = ca.SX.sym("x", 8)
    integ = ca.integrator("i", "cvodes", {"x": x, "ode": ode(x, p)}, 0, 0.02, {"abstol": 1e-13, "reltol": 1e-11})
    d0 = kin.cheung_inverse(kin.CHEUNG_START_POSE)
    x0 = np.concatenate([d0, [0.05, -0.03, 0.04, -0.02]])
    x1 = np.array(integ(x0=x0)["xf"]).ravel()

    def energy(state):
        d, v = state[:4], state[4:]
        pts = _cheung_body_points(d)
        height = pts["A"][2]
        pot = 9.81 * ((TABLE1["m10"] + TABLE1["m12"]) / 2 + TABLE1["m_e"]) * height
        return 0.5 * v @ _reference_mass_matrix(d) @ v + pot

    assert np.linalg.norm(x1[:4] - d0) > 5e-4  # it moved
    assert energy(x1) == pytest.approx(energy(x0), rel=1e-6)


# ---------------------------------------------------------------- joint-space model

def test_cheung_joint_poles_and_zeros_are_the_parameters():
    model = load("MotionTwin.Plants.CheungJoint")
    names = [v.name for v in model.parameters]
    values = dict(zip(names, model.parameter_values()))
    mats = _linearise(model, np.zeros(4), np.zeros(1), model.parameter_values())
    a = mats[0]
    sys = _siso(model, mats, "u", "q")
    w, z = values["omega"], values["zeta"]
    wb, zb = values["omega_bar"], values["zeta_bar"]
    expected_poles = [0, -values["alpha"], complex(-z * w, w * np.sqrt(1 - z**2)), complex(-z * w, -w * np.sqrt(1 - z**2))]
    poles = np.sort_complex(np.linalg.eigvals(a))
    np.testing.assert_allclose(poles, np.sort_complex(np.array(expected_poles)), atol=1e-6 * w)
    zeros = sys.zeros()
    assert len(zeros) == 2
    assert np.abs(zeros[0]) == pytest.approx(wb, rel=1e-9)
    assert -zeros[0].real / np.abs(zeros[0]) == pytest.approx(zb, rel=1e-6)
    # and the full transfer function equals eqs. (6)-(8) at a few frequencies
    k, alpha = values["K"], values["alpha"]
    for f in (5.0, 100.0, 300.0, 390.0, 1000.0):
        s = 2j * np.pi * f
        paper = k / (s * (s + alpha)) * (w**2 / wb**2) * (s**2 + 2 * zb * wb * s + wb**2) / (s**2 + 2 * z * w * s + w**2)
        assert _at(sys, s) == pytest.approx(paper, rel=1e-9)


# ---------------------------------------------------------------- hexapod

def _hexapod_energy(state: np.ndarray, prm: dict[str, float]) -> float:
    """Kinetic + potential energy from first principles with harness.kinematics geometry."""
    pos, angles, v, w = state[:3], state[3:6], state[6:9], state[9:12]
    a, b = kin.hexapod_anchors()
    rot = kin.rotation(angles)
    inertia = rot @ np.diag([prm["IxxE"], prm["IyyE"], prm["IzzE"]]) @ rot.T
    energy = 0.5 * prm["mE"] * v @ v + 0.5 * w @ inertia @ w + 9.81 * prm["mE"] * pos[2]
    for j in range(6):
        r = rot @ b[j]
        leg = pos + r - a[j]
        length = np.linalg.norm(leg)
        u = leg / length
        vb = v + np.cross(w, r)
        u_dot = (vb - (u @ vb) * u) / length
        energy += 0.5 * prm["m3"] * vb @ vb + 0.5 * prm["I2"] * u_dot @ u_dot
        energy += 9.81 * (prm["m3"] * (pos[2] + r[2]) + prm["s2"] * u[2])
    return float(energy)


def test_hexapod_leg_lengths_match_python_inverse_kinematics():
    model = load("MotionTwin.Plants.Hexapod")
    out = _fn(model, ca.vertcat(*[_output(model, f"L{j}") for j in range(1, 7)]))
    pose = np.array([0.02, -0.03, 0.82, 0.1, -0.07, 0.2])
    x = np.concatenate([pose, np.zeros(6)])
    np.testing.assert_allclose(np.array(out(x, np.zeros(6), model.parameter_values())).ravel(),
                               kin.hexapod_inverse(pose), rtol=0, atol=1e-13)


def test_hexapod_energy_balance():
    """Work of the leg forces = change of kinetic + potential energy + friction loss (1e-6 relative)."""
    model = load("MotionTwin.Plants.Hexapod")
    names = [v.name for v in model.parameters]
    p = _pvalues(model, v_eps=0.01)
    prm = dict(zip(names, p))
    lengths = ca.vertcat(*[_output(model, f"L{j}") for j in range(1, 7)])
    l_dot = ca.jtimes(lengths, model.x, model.dx)
    coulomb = np.array([prm[f"rc{j}"] for j in range(1, 7)])
    viscous = np.array([prm[f"cv{j}"] for j in range(1, 7)])
    friction = viscous * l_dot + coulomb * ca.tanh(l_dot / prm["v_eps"])
    # leg forces: static hold at home plus a sinusoidal excitation per leg
    x0 = np.concatenate([kin.HEXAPOD_HOME, np.zeros(6)])
    b_mat = np.array(ca.Function("b", [model.x, model.p], [ca.jacobian(model.dx, model.u)])(x0, p))[6:]
    acc0 = np.array(_fn(model, model.dx)(x0, np.zeros(6), p)).ravel()[6:]
    hold = np.linalg.solve(b_mat, -acc0)
    t = ca.SX.sym("t")
    tau = hold + 40 * ca.sin(2 * np.pi * 3 * t + np.arange(6)) + 30 * ca.sin(2 * np.pi * 5 * t + 2 * np.arange(6))
    f = ca.Function("f", [model.x, model.u, model.p], [model.dx, ca.dot(model.u, l_dot), ca.dot(friction, l_dot)])
    x = ca.SX.sym("x", 12)
    dx, power, loss = f(x, tau, p)
    aug = ca.SX.sym("w", 2)
    dae = {"x": ca.vertcat(x, aug), "t": t, "ode": ca.vertcat(dx, power, loss)}
    integ = ca.integrator("i", "cvodes", dae, 0, 0.3, {"reltol": 1e-10, "abstol": 1e-12})
    xf = np.array(integ(x0=np.concatenate([x0, [0, 0]]))["xf"]).ravel()
    work, dissipated = xf[12], xf[13]
    delta_energy = _hexapod_energy(xf[:12], prm) - _hexapod_energy(x0, prm)
    assert np.linalg.norm(xf[:3] - x0[:3]) > 1e-3 and dissipated > 1e-3  # it moved and lost energy
    assert work - dissipated == pytest.approx(delta_energy, rel=1e-6)


# ---------------------------------------------------------------- serial robot joint and effects

def test_serial_robot_joint_friction_and_gravity_follow_eq2_and_eq23():
    model = load("MotionTwin.Plants.SerialRobotJointAxis3")
    prm = dict(zip([v.name for v in model.parameters], model.parameter_values()))
    fric = _fn(model, _output(model, "f_friction"))
    acc = _fn(model, model.dx[1])
    p = model.parameter_values()
    w = 0.5  # >> w_eps: the smoothing is negligible (tanh(500) = 1)
    assert float(fric([0, w], 0, p)) == pytest.approx(prm["beta_vp"] * w + prm["beta_cp"], rel=1e-12)
    assert float(fric([0, -w], 0, p)) == pytest.approx(prm["beta_vn"] * -w - prm["beta_cn"], rel=1e-12)
    assert float(fric([0, 0], 0, p)) == 0
    q = 0.3
    assert float(acc([q, 0], 0, p)) == pytest.approx(-prm["k"] * np.sin(q + np.deg2rad(25)) / 7.4838, rel=1e-12)


def test_pade_delay_joint_matches_second_order_pade():
    model = load("MotionTwin.Effects.DelayedInputJoint")
    prm = dict(zip([v.name for v in model.parameters], model.parameter_values()))
    sys = _siso(model, _linearise(model, np.zeros(4), np.zeros(1), model.parameter_values()), "u", "q")
    t, m, damp = prm["T"], prm["m"], prm["d"]
    for f in (1.0, 50.0, 300.0, 1000.0):
        s = 2j * np.pi * f
        pade = (1 - s * t / 2 + (s * t) ** 2 / 12) / (1 + s * t / 2 + (s * t) ** 2 / 12)
        assert _at(sys, s) == pytest.approx(pade / (s * (m * s + damp)), rel=1e-9)
        if 2 * np.pi * f * t < 1.5:
            assert np.angle(pade / np.exp(-s * t), deg=True) == pytest.approx(0, abs=1.0)


def test_variable_inertia_joint_conserves_energy():
    model = load("MotionTwin.Effects.VariableInertiaJoint")
    p = _pvalues(model, d=0.0)
    prm = dict(zip([v.name for v in model.parameters], p))
    x = ca.SX.sym("x", 2)
    ode = ca.Function("f", [model.x, model.p], [ca.substitute(model.dx, model.u, ca.DM.zeros(1))])(x, p)
    xf = np.array(ca.integrator("i", "cvodes", {"x": x, "ode": ode}, 0, 0.5, {"reltol": 1e-11, "abstol": 1e-13})(x0=[0.01, 0.3])["xf"]).ravel()

    def energy(s):
        return 0.5 * prm["m0"] * (1 + prm["dm"] * np.cos(2 * np.pi * s[0] / prm["period"])) * s[1] ** 2

    assert abs(xf[0] - 0.01) > 0.05
    assert energy(xf) == pytest.approx(energy([0.01, 0.3]), rel=1e-8)


# ---------------------------------------------------------------- controllers

def _robust_reference(prm: dict[str, float]) -> tuple[control.StateSpace, control.StateSpace]:
    """Eqs. (9)-(13) with python-control: feedback path e -> u and feedforward path r_dot -> u.

    Kept as a series of small state-space blocks: one 5th-order transfer function would be too
    ill-conditioned for a 1e-6 comparison after discretisation.
    """
    s = control.tf("s")
    two_pi = 2 * np.pi
    gc = (prm["Kd"] * s**2 + prm["Kp"] * s + prm["Ki"]) / (prm["tau"] * s**2 + s)
    fl = prm["KL"] * (s + two_pi * prm["fc"]) / (s + two_pi * prm["fp"])
    w0sq = two_pi**2 * prm["wl"] * prm["wh"]
    bw = two_pi * abs(prm["wh"] - prm["wl"])
    fn = (s**2 + bw / prm["sigma"] * s + w0sq) / (s**2 + bw * s + w0sq)
    return control.ss(fl) * control.ss(fn) * control.ss(gc), control.ss(fl) * control.ss(fn) * prm["Kv"]


@pytest.mark.parametrize("name", ["MotionTwin.Controllers.RobustJointControllerD1",
                                  "MotionTwin.Controllers.RobustJointControllerD3"])
def test_robust_controller_matches_paper_law_and_tustin(name):
    model = load(name)
    prm = dict(zip([v.name for v in model.parameters], model.parameter_values()))
    mats = _linearise(model, np.zeros(5), np.zeros(5), model.parameter_values())
    inputs = [v.name for v in model.inputs]
    feedback, feedforward = _robust_reference(prm)
    cont_r, cont_v, cont_q = (_siso(model, mats, name, "u") for name in ("r", "r_dot", "q"))
    for f in (1.0, 30.0, 200.0, 390.0, 600.0):
        s = 2j * np.pi * f
        ref = _at(feedback, s)
        assert _at(cont_r, s) == pytest.approx(ref, rel=1e-9)
        assert _at(cont_q, s) == pytest.approx(-ref, rel=1e-9)
        assert _at(cont_v, s) == pytest.approx(_at(feedforward, s), rel=1e-9)
    notch = 2j * np.pi * np.sqrt(prm["wl"] * prm["wh"])
    assert abs(_at(feedback, notch)) < abs(_at(feedback, notch * 0.6))
    # the pipeline's Tustin matrices against python-control's Tustin discretisation of the paper law
    ts = prm["Ts"]
    fns = model.functions()
    assert "sample" in fns
    ad, bd, cd, dd = (np.array(ca.Function("m", [model.p], [m])(model.parameter_values())) for m in (model.Ad, model.Bd, model.Cd, model.Dd))
    held = [c.var.name for c in model.computed].index("u")
    disc_model = control.ss(ad, bd[:, [inputs.index("r")]], cd[[held], :], dd[[held]][:, [inputs.index("r")]], ts)
    disc_ref = control.sample_system(feedback, ts, method="tustin")
    for f in (1.0, 30.0, 200.0, 390.0, 900.0):
        z = np.exp(2j * np.pi * f * ts)
        assert _at(disc_model, z) == pytest.approx(_at(disc_ref, z), rel=1e-6)
        assert _at(disc_model, z) == pytest.approx(_at(feedback, 2 / ts * (z - 1) / (z + 1)), rel=1e-9)


def test_computed_torque_pid_gives_the_designed_error_dynamics():
    """With exact m_hat, d_hat and v_hat -> v (Tf -> 0) the closed loop error poles are a triple pole at 2*pi*20."""
    ctrl = load("MotionTwin.Controllers.ComputedTorquePID")
    prm = dict(zip([v.name for v in ctrl.parameters], ctrl.parameter_values()))
    s = control.tf("s")
    plant = 1 / (s * (prm["m_hat"] * s + prm["d_hat"]))
    k_q = _siso(ctrl, _linearise(ctrl, np.zeros(2), np.zeros(4), _pvalues(ctrl, Tf=1e-7)), "q", "u")
    loop = control.feedback(control.ss(plant), -k_q)
    slow = sorted(loop.poles(), key=abs)[:3]  # the others belong to the 1e-7 s velocity filter
    np.testing.assert_allclose(np.real(np.poly(slow)), np.poly([-2 * np.pi * 20] * 3), rtol=1e-4)


def test_hexapod_regressor_reproduces_the_modelica_dynamics():
    """tau = A(x, v, a) @ p (numpy regressor) for the accelerations the Modelica model computes from tau."""
    model = load("MotionTwin.Plants.Hexapod")
    p = model.parameter_values()
    prm = dict(zip([v.name for v in model.parameters], p))
    theta = np.array([prm[n] for n in kin.HEXAPOD_PARAMETERS])
    rng = np.random.default_rng(3)
    ode = _fn(model, model.dx)
    for _ in range(5):
        pose = kin.HEXAPOD_HOME + rng.uniform(-0.1, 0.1, 6)
        twist = rng.uniform(-0.5, 0.5, 6)
        tau = rng.uniform(-200, 200, 6)
        acc = np.array(ode(np.concatenate([pose, twist]), tau, p)).ravel()[6:]
        regressor = kin.hexapod_regressor(pose, twist, acc, g=prm["g"], v_eps=prm["v_eps"])
        np.testing.assert_allclose(regressor @ theta, tau, rtol=0, atol=1e-9 * np.abs(tau).max())


def test_cheung_manipulator_starts_at_the_paper_start_pose():
    model = load("MotionTwin.Plants.CheungManipulator")
    p = model.parameter_values()
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    pose = _fn(model, ca.vertcat(*[_output(model, n) for n in ("x", "y", "z", "theta")]))
    np.testing.assert_allclose(np.array(pose(x0, np.zeros(4), p)).ravel(), kin.CHEUNG_START_POSE, atol=1e-9)


def test_state_space_controller_default_is_a_pi_and_is_tustin_sampled():
    model = load("MotionTwin.Controllers.StateSpaceController")
    p = model.parameter_values()
    ts = dict(zip([v.name for v in model.parameters], p))["Ts"]
    ad, bd, cd, dd = (np.array(ca.Function("m", [model.p], [m])(p)) for m in (model.Ad, model.Bd, model.Cd, model.Dd))
    disc = control.ss(ad, bd, cd, dd, ts)
    ref = control.sample_system(control.tf([1, 10], [1, 0]), ts, method="tustin")
    for f in (0.1, 10.0, 500.0):
        z = np.exp(2j * np.pi * f * ts)
        assert _at(disc, z) == pytest.approx(_at(ref, z), rel=1e-12)


def test_example_closed_loop_is_stable_and_tracks_steps():
    model = load("MotionTwin.Examples.JointWithRobustController")
    mats = _linearise(model, np.zeros(model.x.numel()), np.zeros(4), model.parameter_values())
    assert np.linalg.eigvals(mats[0]).real.max() < 0
    assert _at(_siso(model, mats, "r", "q"), 1e-9j) == pytest.approx(1.0, abs=1e-6)  # integral action
