"""The effect models beyond friction-ripple-offset (backlash, LuGre, saturation, cogging, load-dependent
friction, friction drift) through the pipeline's front end, each against a closed form: the dead-zone and
saturation characteristics, the LuGre steady-state Stribeck curve and pre-sliding stiffness, the free motion of
the motor inside the backlash gap and the saturated acceleration (both integrated by CVODES), the cogging
harmonics of the pole pitch, and the drift law of the Coulomb level.
"""
from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import build, symbolic

EFFECTS = "MotionTwin.Effects."


@lru_cache(maxsize=None)
def load(name: str) -> symbolic.SymbolicModel:
    return build.load_model(EFFECTS + name)


def parameters(model: symbolic.SymbolicModel, **override: float) -> dict[str, float]:
    values = dict(zip([v.name for v in model.parameters], model.parameter_values()))
    unknown = set(override) - set(values)
    assert not unknown, unknown
    return {**values, **override}


def vector(model: symbolic.SymbolicModel, values: dict[str, float]) -> np.ndarray:
    return np.array([values[v.name] for v in model.parameters], dtype=float)


def local(model: symbolic.SymbolicModel, name: str) -> ca.Function:
    """A computed variable of the model as a function of (t, x, u, p)."""
    expr = next(c.expr for c in model.computed if c.var.name == name)
    return ca.Function(name, [model.t, model.x, model.u, model.p], [expr])


def ode(model: symbolic.SymbolicModel) -> ca.Function:
    return ca.Function("ode", [model.t, model.x, model.u, model.p], [model.dx])


def integrate(model: symbolic.SymbolicModel, x0: list[float], u: float, p: np.ndarray, times: np.ndarray) -> np.ndarray:
    """States at ``times`` under constant input ``u`` (CVODES, tight tolerances); one row per time."""
    x = ca.SX.sym("x", model.x.numel())
    rhs = ca.Function("f", [model.x, model.u, model.p], [model.dx])(x, u, p)
    solver = ca.integrator("i", "cvodes", {"x": x, "ode": rhs}, 0.0, times,
                           {"reltol": 1e-11, "abstol": 1e-14})
    return np.array(solver(x0=x0)["xf"]).T


# ---------------------------------------------------------------- backlash

def test_backlash_transmits_the_dead_zone_of_the_gap():
    model = load("BacklashJoint")
    prm = parameters(model)
    k, c, b = prm["k"], prm["c"], prm["b"]
    force = local(model, "F_transmission")
    p = vector(model, prm)
    eps = prm["eps"]
    for delta, expected in ((4 * b, k * 3 * b), (-4 * b, -k * 3 * b), (0.5 * b, 0.0), (-0.9 * b, 0.0)):
        # the rounded corners leave at most eps^2/|(|delta| - b)| of deflection away from the corners
        rounding = k * eps**2 / abs(abs(delta) - b)
        assert float(force(0, [delta, 0, 0, 0], 0, p)) == pytest.approx(expected, abs=rounding)
    # damping acts in contact only: relative velocity 0.01 m/s
    assert float(force(0, [4 * b, 0.01, 0, 0], 0, p)) == pytest.approx(k * 3 * b + c * 0.01, rel=1e-6)
    assert abs(float(force(0, [0.5 * b, 0.01, 0, 0], 0, p))) < 1e-4 * c * 0.01
    # at the corner the rounding leaves k*eps/2
    assert float(force(0, [b, 0, 0, 0], 0, p)) == pytest.approx(k * prm["eps"] / 2, rel=1e-3)


def test_backlash_motor_moves_alone_inside_the_gap():
    """From the middle of the gap, a constant force moves the motor as a lone mass m1 with damping d:
    x1(t) = u/d*(t - m1/d*(1 - exp(-d t/m1))), the load stays at rest until contact."""
    model = load("BacklashJoint")
    prm = parameters(model)
    m1, d, b, u = prm["m1"], prm["d"], prm["b"], 1.0
    times = np.linspace(0, 2.5e-3, 6)[1:]
    expected = u / d * (times - m1 / d * (1 - np.exp(-d * times / m1)))
    assert expected[-1] < 0.9 * b  # still inside the gap
    states = integrate(model, [0, 0, 0, 0], u, vector(model, prm), times)
    # the rounded gap corners pass a force of relative size (eps/(b - x1))^2 <= 2e-5 here
    np.testing.assert_allclose(states[:, 0], expected, rtol=3e-5)
    assert np.max(np.abs(states[:, 2])) < 1e-5 * b


# ---------------------------------------------------------------- LuGre

def stribeck(v: float, prm: dict[str, float]) -> float:
    return prm["Fc"] + (prm["Fs"] - prm["Fc"]) * np.exp(-(v / prm["vs"]) ** 2)


@pytest.mark.parametrize("v", [-0.05, -4e-3, 1e-3, 5e-3, 0.02])
def test_lugre_steady_sliding_follows_the_stribeck_curve(v):
    """At constant velocity the bristles settle at z = sign(v) g(v)/sigma0 and the force is
    g(v) sign(v) + sigma2 v (the Stribeck curve): integrated from z = 0 at the fixed velocity."""
    model = load("LuGreJoint")
    prm = parameters(model)
    p = vector(model, prm)
    f = ode(model)
    z = ca.SX.sym("z")
    dz = f(0, ca.vertcat(0, v, z), 0, p)[2]
    settle = 20 * stribeck(v, prm) / (prm["sigma0"] * abs(v))  # 20 time constants of the bristle decay
    zf = float(ca.integrator("i", "cvodes", {"x": z, "ode": dz}, 0.0, settle,
                             {"reltol": 1e-12, "abstol": 1e-16})(x0=0)["xf"])
    assert zf == pytest.approx(np.sign(v) * stribeck(v, prm) / prm["sigma0"], rel=1e-7)
    friction = float(local(model, "F_effect")(0, [0, v, zf], 0, p))
    assert friction == pytest.approx(np.sign(v) * stribeck(v, prm) + prm["sigma2"] * v, rel=1e-7)


def test_lugre_presliding_is_a_spring_of_stiffness_sigma0():
    """From rest, a displacement small against g/sigma0 deflects the bristles by the displacement itself:
    F = sigma0 * dx (+ the damping terms, zero at the end of a move that has stopped)."""
    model = load("LuGreJoint")
    prm = parameters(model)
    p = vector(model, prm)
    f = ode(model)
    s = ca.SX.sym("s")  # bristle state along the path, with the position as the independent variable
    dz_dx = f(0, ca.vertcat(0, 1e-6, s), 0, p)[2] / 1e-6
    dx = 1e-3 * prm["Fs"] / prm["sigma0"]  # 0.1 % of the breakaway deflection
    zf = float(ca.integrator("i", "cvodes", {"x": s, "ode": dz_dx}, 0.0, dx, {"reltol": 1e-12})(x0=0)["xf"])
    friction = float(local(model, "F_effect")(0, [dx, 0, zf], 0, p))
    assert friction == pytest.approx(prm["sigma0"] * dx, rel=2e-3)


# ---------------------------------------------------------------- saturation

def test_saturation_limits_the_force_and_passes_it_below_the_limit():
    model = load("SaturationJoint")
    prm = parameters(model)
    fmax, m, d = prm["Fmax"], prm["m"], prm["d"]
    p = vector(model, prm)
    times = np.linspace(0, 0.5, 6)[1:]
    for u, delivered in ((3 * fmax, fmax), (-2 * fmax, -fmax), (0.5 * fmax, 0.5 * fmax)):
        states = integrate(model, [0, 0], u, p, times)
        expected_v = delivered / d * (1 - np.exp(-d * times / m))
        np.testing.assert_allclose(states[:, 1], expected_v, rtol=1e-6)


# ---------------------------------------------------------------- cogging

def test_cogging_has_the_harmonics_of_the_pole_pitch():
    model = load("CoggingJoint")
    prm = parameters(model, phase1=0.3, phase2=-1.1)
    p = vector(model, prm)
    force = local(model, "F_effect")
    tau, n = prm["pole_pitch"], prm["n"]
    for x in np.linspace(-0.05, 0.05, 11):
        theta = 2 * np.pi * n * x / tau
        expected = prm["A1"] * np.sin(theta + 0.3) + prm["A2"] * np.sin(2 * theta - 1.1)
        assert float(force(0, [x, 0], 0, p)) == pytest.approx(expected, abs=1e-12)
        assert float(force(0, [x + tau / n, 0], 0, p)) == pytest.approx(expected, abs=1e-12)
        assert float(force(0, [x + tau / (2 * n), 0], 0, p)) != pytest.approx(expected, abs=1e-3)


# ---------------------------------------------------------------- load-dependent friction and drift

def test_load_dependent_friction_rises_with_the_drive_force():
    model = load("LoadDependentFrictionJoint")
    prm = parameters(model)
    p = vector(model, prm)
    force = local(model, "F_effect")
    v = 100 * prm["v_eps"]  # tanh(100) = 1
    for u in (0.0, 10.0, -40.0):
        expected = prm["Fc0"] + prm["mu"] * abs(u)
        assert float(force(0, [0, v], u, p)) == pytest.approx(expected, rel=1e-12)
        assert float(force(0, [0, -v], u, p)) == pytest.approx(-expected, rel=1e-12)


def test_friction_drift_follows_the_warm_up_law():
    model = load("FrictionDriftJoint")
    prm = parameters(model)
    p = vector(model, prm)
    level, force = local(model, "Fc"), local(model, "F_effect")
    v = 100 * prm["v_eps"]
    for t in (0.0, 5.0, prm["tau_drift"], 200.0):
        expected = prm["Fc0"] + prm["dFc"] * (1 - np.exp(-t / prm["tau_drift"]))
        assert float(level(t, [0, v], 0, p)) == pytest.approx(expected, rel=1e-12)
        assert float(force(t, [0, -v], 0, p)) == pytest.approx(-expected, rel=1e-12)
