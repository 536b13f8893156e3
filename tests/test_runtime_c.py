"""The model-agnostic C runtime (fmus/runtime): solver order, sampled-part semantics, errors, FMU state, derivatives.

Complements tests/test_fmu_build.py (which checks CS against ME + CVODE, start values and the state round
trip). References here: an analytic solution (solver order), scipy's Tustin discretisation of the hand-derived
controller equations (sampled part), fmpy's Model Exchange driver (time events), the analytic Jacobian
(directional and adjoint derivatives). Units: SI.
"""
from __future__ import annotations

import ctypes
import math
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.fmi1 import FMICallException
from scipy.signal import cont2discrete

from motiontwin.fmus import build
from tests import fmi_util as fu

RUNTIME = Path(build.__file__).parent / "runtime"
VERSIONS = build.FMI_VERSIONS
JOINT = {"m": 2.0, "d": 10.0, "Fc": 5.0, "v_eps": 1e-4}  # FrictionJoint defaults


@pytest.fixture
def opened():
    """Instances created by a test, freed afterwards."""
    instances: list[fu.Loaded] = []
    yield instances
    for ld in instances:
        ld.fmu.freeInstance()


def _open(opened: list[fu.Loaded], path: Path, kind: str = "cs") -> fu.Loaded:
    ld = fu.instantiate(path, kind)
    opened.append(ld)
    return ld


def _enter_init(ld: fu.Loaded) -> None:
    if ld.md.fmiVersion == "2.0":
        ld.fmu.setupExperiment(startTime=0.0)
        ld.fmu.enterInitializationMode()
    else:
        ld.fmu.enterInitializationMode(startTime=0.0)


def _starts(ld: fu.Loaded, *names: str) -> list[float]:
    """Start values from modelDescription.xml (FMI 2.0 allows no getter before initialisation)."""
    start = {v.name: v.start for v in ld.md.modelVariables}
    return [float(start[n]) for n in names]


def _errors(ld: fu.Loaded) -> list[str]:
    return [m for m in ld.messages if "sample" not in m and "initialized" not in m]


# ---------------------------------------------------------------------------------------------
# Solver


def test_rodas4_converges_with_order_four(tmp_path):
    """Fixed-step RODAS4 on x' = -2 t x^2 (x = 1/(1+t^2)): the error drops by 2^4 per halving of h."""
    lib = tmp_path / "libsolver.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-std=c99", "-o", str(lib), str(RUNTIME / "mt_solver.c"), "-lm"],
                   check=True, timeout=300)
    so = ctypes.CDLL(str(lib))
    dbl = ctypes.POINTER(ctypes.c_double)
    rhs_t = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, dbl, dbl)
    jac_t = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, dbl, dbl, dbl)

    @rhs_t
    def rhs(ctx, t, x, dx):
        dx[0] = -2.0 * t * x[0] ** 2
        return 0

    @jac_t
    def jac(ctx, t, x, J, dfdt):
        J[0] = -4.0 * t * x[0]
        dfdt[0] = -2.0 * x[0] ** 2
        return 0

    solver = ctypes.create_string_buffer(512)  # larger than sizeof(mt_solver)
    assert so.mt_solver_init(solver, 1) == 0
    so.mt_rosenbrock_step.argtypes = [ctypes.c_void_p, rhs_t, jac_t, ctypes.c_void_p, ctypes.c_double,
                                      ctypes.c_double, dbl, dbl, dbl]
    errors = []
    for n in (5, 10, 20, 40, 80):
        x, x_new, estimate = (ctypes.c_double * 1)(1.0), (ctypes.c_double * 1)(), ctypes.c_double()
        for i in range(n):
            assert so.mt_rosenbrock_step(solver, rhs, jac, None, i / n, 1.0 / n, x, x_new, ctypes.byref(estimate)) == 0
            x[0] = x_new[0]
        errors.append(abs(x[0] - 0.5))
    so.mt_solver_free(solver)
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 3.8) & (orders < 4.5)), orders


def test_dense_lu_with_pivoting_solves_like_numpy(tmp_path):
    """mt_lu_factor/mt_lu_solve on random systems up to 12 x 12 (pivoting happens) vs numpy.linalg.solve."""
    lib = tmp_path / "liblu.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-std=c99", "-o", str(lib), str(RUNTIME / "mt_solver.c"), "-lm"],
                   check=True, timeout=300)
    so = ctypes.CDLL(str(lib))
    rng = np.random.default_rng(3)
    for n in range(1, 13):
        A = rng.normal(size=(n, n))
        b = rng.normal(size=n)
        lu = np.asfortranarray(A).flatten(order="F").astype(float)
        x = b.copy()
        pivot = (ctypes.c_int * n)()
        dbl = ctypes.POINTER(ctypes.c_double)
        assert so.mt_lu_factor(lu.ctypes.data_as(dbl), n, pivot) == 0
        so.mt_lu_solve(lu.ctypes.data_as(dbl), n, pivot, x.ctypes.data_as(dbl))
        assert np.allclose(x, np.linalg.solve(A, b), rtol=1e-10, atol=1e-12), n


def test_cosimulation_of_a_nine_state_closed_loop_matches_cvode(tmp_path):
    """Joint plant + continuous robust controller (9 states, eigenvalues to -4850 1/s and +-2500j 1/s):
    CS (rtol 1e-8) vs ME + CVode (rtol 1e-10), all inputs 0.1, within 1e-6 of each output's peak."""
    model = build.load_model("MotionTwin.Examples.JointWithRobustController")
    path = str(build.build_fmu(model, tmp_path, "3.0").path)
    common = dict(stop_time=0.1, output_interval=1e-3, output=["q", "u"],
                  start_values={"r": 0.1, "r_dot": 0.1, "r_ddot": 0.1, "r_dddot": 0.1})
    cs = simulate_fmu(path, fmi_type="CoSimulation", relative_tolerance=1e-8, **common)
    me = simulate_fmu(path, fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-10, **common)
    for name in ("q", "u"):
        assert np.max(np.abs(cs[name] - me[name])) <= 1e-6 * np.max(np.abs(me[name])), name


def test_hot_path_functions_match_finite_differences_and_the_sample_function():
    """fmus.codegen.runtime_functions: ode_jac = (ode, central differences of ode in x) on the coupled
    4-DOF plant; sample_matrix S(p) reproduces sample(z, u, p) on random z, u; dfdt dropped (autonomous)."""
    from motiontwin.fmus import codegen
    from tests.conftest import TEST_MODELS

    model = build.load_model("MotionTwin.Plants.CheungManipulator")
    plant = codegen.runtime_functions(model.functions())
    assert "dfdt" not in plant
    rng = np.random.default_rng(11)
    ode, ode_jac = plant["ode"], plant["ode_jac"]
    nx, nu = ode.size1_in(1), ode.size1_in(2)
    start = np.array(model.parameter_values())
    x = np.array(plant["x0"](start)).ravel() + np.r_[np.zeros(nx // 2), rng.normal(scale=0.05, size=nx - nx // 2)]
    u = rng.normal(scale=0.1, size=nu)
    dx, jac = (np.array(v) for v in ode_jac(0.0, x, u, start))
    assert np.allclose(dx.ravel(), np.array(ode(0.0, x, u, start)).ravel(), rtol=1e-14, atol=1e-14)
    step = 1e-6
    fd = np.column_stack([(np.array(ode(0.0, x + step * e, u, start)) - np.array(ode(0.0, x - step * e, u, start)))
                          .ravel() / (2 * step) for e in np.eye(nx)])
    assert np.allclose(jac, fd, rtol=1e-6, atol=1e-6 * np.max(np.abs(fd)))

    name, source = TEST_MODELS["SampledPI"]
    sampled = codegen.runtime_functions(build.load_model(name, source).functions())
    sample, matrix = sampled["sample"], sampled["sample_matrix"]
    nz, nu = sample.size1_in(0), sample.size1_in(1)
    pars = rng.uniform(0.5, 2.0, size=sample.size1_in(2))
    S = np.array(matrix(pars))
    for _ in range(3):
        z, e = rng.normal(size=nz), rng.normal(size=nu)
        expected = np.concatenate([np.array(v).ravel() for v in sample(z, e, pars)])
        assert np.allclose(S @ np.r_[z, e], expected, rtol=1e-12, atol=1e-12 * np.max(np.abs(expected)))


# ---------------------------------------------------------------------------------------------
# Sampled part


def _sampled_pi_reference(kp: float, ki: float, kd: float, tau: float, ts: float) -> tuple[np.ndarray, ...]:
    """scipy's Tustin discretisation of tests/models/SampledPI.mo, written out by hand as (A, B, C, D):
    der(xi) = Ki e, der(xd) = (e - xd)/tau, y = Kp e + xi + Kd (e - xd)/tau."""
    A = np.array([[0.0, 0.0], [0.0, -1.0 / tau]])
    B = np.array([[ki], [1.0 / tau]])
    C = np.array([[1.0, -kd / tau]])
    D = np.array([[kp + kd / tau]])
    Ad, Bd, Cd, Dd, _ = cont2discrete((A, B, C, D), ts, method="bilinear")
    return Ad, Bd, Cd, Dd


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("steps_per_sample", [0.4, 1, 3])
def test_sampled_part_semantics_in_cosimulation(built_fmus, opened, version, steps_per_sample):
    """The sample at t_k = k*Ts uses the input present when the FMU is at t_k (held inside a long step); the
    output is held until the next sample; an input set again at t0 redoes the sample at t0."""
    ld = _open(opened, built_fmus["SampledPI", version])
    kp, ki, kd, tau, ts = _starts(ld, "Kp", "Ki", "Kd", "tau", "Ts")
    Ad, Bd, Cd, Dd = _sampled_pi_reference(kp, ki, kd, tau, ts)
    h = ts / steps_per_sample
    n_steps = 40
    inputs = np.random.default_rng(7).normal(size=n_steps)
    _enter_init(ld)
    fu.set_(ld, {"e": 5.0})
    ld.fmu.exitInitializationMode()
    fu.set_(ld, {"e": inputs[0]})  # event iteration at t0
    z, held = np.zeros(2), []
    for k in range(int(math.ceil(n_steps * h / ts)) + 1):
        e = inputs[min(int(math.floor(k * ts / h + 1e-9)), n_steps - 1)]  # input of the step containing t_k
        held.append((Cd @ z + Dd[:, 0] * e)[0])
        z = Ad @ z + Bd[:, 0] * e
    got, expected = [fu.get(ld, "y")[0]], [held[0]]
    for i in range(n_steps):
        fu.set_(ld, {"e": inputs[i]})
        fu.step(ld, i * h, h)
        got.append(fu.get(ld, "y")[0])
        expected.append(held[int(math.ceil((i + 1) * h / ts - 1e-9)) - 1])  # last sample strictly before t+h
    assert np.allclose(got, expected, rtol=1e-10, atol=1e-12 * np.max(np.abs(expected)))


def _sampled_pi_run(ld: fu.Loaded, inputs: np.ndarray, ts: float) -> np.ndarray:
    """Held output after each of len(inputs) steps of one sample period, the input set before each step."""
    out = []
    for i, e in enumerate(inputs):
        fu.set_(ld, {"e": e})
        fu.step(ld, i * ts, ts)
        out.append(fu.get(ld, "y")[0])
    return np.array(out)


def _sampled_pi_expected(inputs: np.ndarray, kp: float, ki: float, kd: float, tau: float, ts: float) -> np.ndarray:
    """Output held after each one-period step from z = 0 with e = 0 at t0 (see _sampled_pi_run)."""
    Ad, Bd, Cd, Dd = _sampled_pi_reference(kp, ki, kd, tau, ts)
    z = Bd[:, 0] * 0.0
    out = []
    for e in inputs:
        y = (Cd @ z + Dd[:, 0] * e)[0]
        z = Ad @ z + Bd[:, 0] * e
        out.append(y)
    return np.array(out)


@pytest.mark.parametrize("version", VERSIONS)
def test_sampled_part_follows_parameter_changes_after_reset_and_state_restore(built_fmus, opened, version):
    """The runtime evaluates the sample matrix S(p) once and reuses it: a new gain after reset, and the old
    gain again after restoring an FMU state taken before, must both reach the output (scipy Tustin reference)."""
    ld = _open(opened, built_fmus["SampledPI", version])
    f, v2 = ld.fmu, version == "2.0"
    kp, ki, kd, tau, ts = _starts(ld, "Kp", "Ki", "Kd", "tau", "Ts")
    inputs = np.random.default_rng(3).normal(size=12)
    _enter_init(ld)
    f.exitInitializationMode()
    saved = f.getFMUstate() if v2 else f.getFMUState()  # at t0 with the default gains
    default = _sampled_pi_run(ld, inputs, ts)
    f.reset()
    _enter_init(ld)
    fu.set_(ld, {"Kp": 3.0 * kp, "Ki": 0.5 * ki})
    f.exitInitializationMode()
    changed = _sampled_pi_run(ld, inputs, ts)
    f.setFMUstate(saved) if v2 else f.setFMUState(saved)
    restored = _sampled_pi_run(ld, inputs, ts)
    (f.freeFMUstate if v2 else f.freeFMUState)(saved)
    scale = np.max(np.abs(default))
    assert np.allclose(default, _sampled_pi_expected(inputs, kp, ki, kd, tau, ts), rtol=1e-10, atol=1e-12 * scale)
    assert np.allclose(changed, _sampled_pi_expected(inputs, 3.0 * kp, 0.5 * ki, kd, tau, ts), rtol=1e-10,
                       atol=1e-12 * scale)
    assert np.allclose(restored, default, rtol=1e-12, atol=0.0)
    assert np.max(np.abs(changed - default)) > 0.1 * scale


@pytest.mark.parametrize("version", VERSIONS)
def test_sampled_part_model_exchange_matches_cosimulation(built_fmus, version):
    """In Model Exchange the samples are time events (nextEventTime); the held output equals Co-Simulation's."""
    path = str(built_fmus["SampledPI", version])
    ts, t_end = 1e-3, 0.05
    tk = np.arange(0.0, t_end + ts / 2, ts)
    ek = np.sin(2 * np.pi * 10 * tk)
    signal = np.array(list(zip(np.repeat(tk, 2)[1:], np.repeat(ek, 2)[:-1])), dtype=[("time", float), ("e", float)])
    common = dict(input=signal, stop_time=t_end, output_interval=ts, output=["y"])
    cs = simulate_fmu(path, fmi_type="CoSimulation", **common)
    me = simulate_fmu(path, fmi_type="ModelExchange", solver="CVode", **common)
    _, first = np.unique(me["time"], return_index=True)  # left limits at the event instants, as CS reports them
    me = me[first]
    assert len(cs) == len(me) == len(tk) and np.max(np.abs(cs["y"])) > 1.0
    assert np.allclose(cs["y"], me["y"], rtol=1e-12, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Bad input and call sequence


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("name, value, text", [("m", 0.0, "m = 0 is below its minimum 1e-09"),
                                               ("v_eps", -1.0, "v_eps = -1 is below its minimum 1e-12")])
def test_parameter_out_of_range_names_value_and_bound(built_fmus, opened, version, name, value, text):
    ld = _open(opened, built_fmus["FrictionJoint", version])
    _enter_init(ld)
    fu.set_(ld, {name: value})
    with pytest.raises(FMICallException):
        ld.fmu.exitInitializationMode()
    assert any(text in m for m in ld.messages), ld.messages
    with pytest.raises(FMICallException):  # the failed instance refuses to step
        fu.step(ld, 0.0, 1e-3)


@pytest.mark.parametrize("version", VERSIONS)
def test_non_finite_values_are_refused_and_the_instance_stays_usable(built_fmus, opened, version):
    ld = _open(opened, built_fmus["FrictionJoint", version])
    _enter_init(ld)
    with pytest.raises(FMICallException):
        fu.set_(ld, {"d": float("nan")})
    ld.fmu.exitInitializationMode()
    with pytest.raises(FMICallException):
        fu.set_(ld, {"u": float("inf")})
    assert any("parameter d = nan" in m for m in ld.messages), ld.messages
    assert any("input u = inf" in m for m in ld.messages), ld.messages
    assert fu.get(ld, "d")[0] == JOINT["d"]
    fu.set_(ld, {"u": 8.0})
    fu.step(ld, 0.0, 1e-2)
    assert fu.get(ld, "q")[0] > 0


@pytest.mark.parametrize("version", VERSIONS)
def test_diverging_integration_is_an_error_not_a_crash(built_fmus, opened, version):
    ld = _open(opened, built_fmus["FrictionJoint", version])
    _enter_init(ld)
    ld.fmu.exitInitializationMode()
    fu.set_(ld, {"u": 1e308})
    with pytest.raises(FMICallException):
        fu.step(ld, 0.0, 1e12)
    assert any("does not converge" in m and "state" in m for m in ld.messages), ld.messages
    with pytest.raises(FMICallException):  # refused after the error ...
        fu.step(ld, 0.0, 1e-3)
    assert np.all(np.isfinite(fu.get(ld, "q", "v")))  # ... getters still answer


@pytest.mark.parametrize("version", VERSIONS)
def test_out_of_sequence_calls_are_refused(built_fmus, opened, version):
    ld = _open(opened, built_fmus["FrictionJoint", version])
    me = _open(opened, built_fmus["FrictionJoint", version], "me")
    _enter_init(ld)
    ld.fmu.exitInitializationMode()
    with pytest.raises(FMICallException):
        fu.set_(ld, {"m": 3.0})  # a fixed parameter after initialisation
    with pytest.raises(FMICallException):
        fu.step(ld, 0.5, 1e-3)  # not the FMU's time
    with pytest.raises(FMICallException):
        me.fmu.setTime(0.1)  # Model Exchange before initialisation
    assert any("parameter m can only be set before the end of initialization" in m for m in ld.messages)
    assert any("does not match the FMU time" in m for m in ld.messages)
    assert any("illegal call sequence" in m for m in me.messages)


# ---------------------------------------------------------------------------------------------
# FMU state and derivatives


@pytest.mark.parametrize("version", VERSIONS)
def test_fmu_state_of_another_model_or_corrupted_is_rejected(built_fmus, opened, version):
    joint = _open(opened, built_fmus["FrictionJoint", version])
    pi = _open(opened, built_fmus["SampledPI", version])
    v2 = version == "2.0"
    for ld in (joint, pi):
        _enter_init(ld)
        ld.fmu.exitInitializationMode()
    blob = bytes(pi.fmu.serializeFMUstate(pi.fmu.getFMUstate()) if v2 else
                 pi.fmu.serializeFMUState(pi.fmu.getFMUState()))
    deserialize = joint.fmu.deSerializeFMUstate if v2 else joint.fmu.deserializeFMUState
    with pytest.raises(FMICallException):
        deserialize(blob)
    with pytest.raises(FMICallException):
        deserialize(b"garbage" + blob[7:])
    assert any("another model" in m for m in joint.messages), joint.messages
    assert any("bad header" in m for m in joint.messages), joint.messages


@pytest.mark.parametrize("version", VERSIONS)
def test_getters_before_initialization_follow_the_fmi_state_machine(built_fmus, opened, version):
    """FMI 2.0 state tables (sections 3.2.3, 4.2.4): no fmi2Get* and no status getter in Instantiated. FMI 3.0.2
    (state Instantiated): fmi3Get* answers the start values of modelDescription.xml, or what was set since, and
    nothing that must be computed; derivatives and nominals only from Initialization Mode on. Refused calls
    return Error with a message; from Initialization Mode on every getter answers."""
    ld = _open(opened, built_fmus["FrictionJoint", version])
    me = _open(opened, built_fmus["FrictionJoint", version], "me")
    f, vr = ld.fmu, ld.vr
    starts = _starts(ld, "m", "d", "q", "u")
    if version == "2.0":
        refused = {"fmi2GetReal": lambda: f.getReal([vr["m"]]), "fmi2GetInteger": lambda: f.getInteger([vr["m"]]),
                   "fmi2GetBoolean": lambda: f.getBoolean([vr["m"]]), "fmi2GetString": lambda: f.getString([vr["m"]]),
                   "fmi2GetRealStatus": lambda: f.getRealStatus(2),  # fmi2LastSuccessfulTime
                   "fmi2GetRealOutputDerivatives": lambda: f.getRealOutputDerivatives([vr["q"]], [1])}
        for name, call in refused.items():
            with pytest.raises(FMICallException):
                call()
            assert any(m.startswith(f"{name}: illegal call sequence: not allowed in Instantiated (allowed ")
                       for m in ld.messages), (name, ld.messages)
    else:
        assert list(fu.get(ld, "m", "d", "q", "u")) == starts
        fu.set_(ld, {"m": 3.5})
        assert fu.get(ld, "m")[0] == 3.5
        for name in ("a", "der(v)"):
            with pytest.raises(FMICallException):
                fu.get(ld, name)
            assert any(f"fmi3GetFloat64: {name} (value reference {vr[name]}) is a" in m and "without a start value"
                       in m for m in ld.messages), ld.messages
    with pytest.raises(FMICallException):
        buffer = (ctypes.c_double * 2)()
        me.fmu.getNominalsOfContinuousStates(buffer, 2) if version == "3.0" else me.fmu.getDerivatives(buffer, 2)
    assert any("illegal call sequence: not allowed in Instantiated" in m for m in me.messages), me.messages
    _enter_init(ld)
    got = fu.get(ld, "m", "d", "q", "u", "a")
    assert list(got[1:4]) == starts[1:] and got[0] == (starts[0] if version == "2.0" else 3.5)
    assert got[4] == 0.0  # a = (u - d v - Fc tanh(v/v_eps))/m at rest without force


def _state_blob(ld: fu.Loaded) -> bytes:
    f = ld.fmu
    if ld.md.fmiVersion == "2.0":
        return bytes(f.serializeFMUstate(f.getFMUstate()))
    return bytes(f.serializeFMUState(f.getFMUState()))


# Offsets after the token in a serialised state (mt_snapshot.c): mode i32, at_sample i32, sample counter i64,
# t0, t, rtol, h, then x[nx], the x_set flags[nx], u[nu], p[np] as doubles.
STATE_FIELDS = [("mode", 0, "<i", 8, "mode = 8 is no mode of this interface type"),  # Continuous-Time in CS
                ("mode", 0, "<i", 3, "mode = 3 is no mode"),
                ("at_sample", 4, "<i", 7, "at-sample flag = 7 is not 0 or 1"),
                ("k", 8, "<q", -5, "sample counter = -5 is outside"),
                ("t0", 16, "<d", math.inf, "start time = inf is not finite"),
                ("t", 24, "<d", math.nan, "time = nan is not finite"),
                ("rtol", 32, "<d", math.nan, "relative tolerance = nan is not in (0, 1)"),
                ("rtol", 32, "<d", -1e-6, "relative tolerance = -9.9999999999999995e-07 is not in (0, 1)"),
                ("h", 40, "<d", -1.0, "solver step size = -1 is not finite and >= 0"),
                ("x", 48 + 8, "<d", math.inf, "state v = inf is not finite"),
                ("x_set", 48 + 16, "<d", 0.5, "start-value flag of a state = 0.5 is not 0 or 1"),
                ("u", 48 + 32, "<d", math.nan, "input u = nan is not finite"),
                ("p", None, "<d", 0.0, "parameter m = 0 is below its minimum")]


@pytest.mark.parametrize("version", VERSIONS)
def test_deserialized_state_is_validated_field_by_field(built_fmus, opened, version):
    """A serialised state with one field out of its domain (mode enum, flags, counter, times, tolerance, step
    size, a non-finite state or input, a parameter below its minimum) or of the wrong size is refused by
    DeserializeFMUState with the field named; the instance keeps its state and the good blob still restores."""
    ld = _open(opened, built_fmus["FrictionJoint", version])
    v2 = version == "2.0"
    f = ld.fmu
    _enter_init(ld)
    f.exitInitializationMode()
    fu.set_(ld, {"u": 8.0})
    fu.step(ld, 0.0, 0.05)
    blob = _state_blob(ld)
    base = 8 + 8 * 4 + len(ld.md.guid)
    params = sorted((v.valueReference, v.name) for v in ld.md.modelVariables if v.causality == "parameter")
    p_m = 48 + 40 + 8 * [n for _, n in params].index("m")
    deserialize = f.deSerializeFMUstate if v2 else f.deserializeFMUState
    fn = "fmi2DeSerializeFMUstate" if v2 else "fmi3DeserializeFMUState"
    for field, offset, fmt, value, text in STATE_FIELDS:
        at = base + (p_m if offset is None else offset)
        bad = bytearray(blob)
        bad[at:at + struct.calcsize(fmt)] = struct.pack(fmt, value)
        ld.messages.clear()
        with pytest.raises(FMICallException):
            deserialize(bytes(bad))
        assert any(m == f"{fn}: FMU state refused: {text}" or m.startswith(f"{fn}: FMU state refused: {text}")
                   for m in ld.messages), (field, ld.messages)
    with pytest.raises(FMICallException):
        deserialize(blob[:-8])
    assert any(f"FMU state has {len(blob) - 8} bytes, expected {len(blob)}" in m for m in ld.messages)
    q = fu.get(ld, "q")[0]
    state = deserialize(blob)   # the untouched blob restores to where it was taken
    fu.step(ld, 0.05, 0.05)
    assert fu.get(ld, "q")[0] != q
    (f.setFMUstate if v2 else f.setFMUState)(state)
    assert fu.get(ld, "q")[0] == q
    (f.freeFMUstate if v2 else f.freeFMUState)(state)


@pytest.mark.parametrize("version", VERSIONS)
def test_directional_and_adjoint_derivatives_match_the_analytic_jacobian(built_fmus, opened, version):
    ld = _open(opened, built_fmus["FrictionJoint", version])
    v0, u0 = 2e-4, 1.5
    _enter_init(ld)
    fu.set_(ld, {"v": v0, "u": u0})
    ld.fmu.exitInitializationMode()
    m, d, fc, eps = (JOINT[k] for k in ("m", "d", "Fc", "v_eps"))
    dvdot_dv = (-d - fc / eps / math.cosh(v0 / eps) ** 2) / m
    vr = ld.vr
    unknowns = [vr["der(q)"], vr["der(v)"], vr["a"], vr["q"]]
    knowns = [vr["q"], vr["v"], vr["u"]]
    J = np.array([[0.0, 1.0, 0.0], [0.0, dvdot_dv, 1.0 / m], [0.0, dvdot_dv, 1.0 / m], [1.0, 0.0, 0.0]])
    for j in range(3):
        column = ld.fmu.getDirectionalDerivative(unknowns, knowns, list(np.eye(3)[j]))
        assert np.allclose(column, J[:, j], rtol=1e-12, atol=0)
    if version == "3.0":
        for i in range(4):
            row = ld.fmu.getAdjointDerivative(unknowns, knowns, list(np.eye(4)[i]), nSensitivity=len(knowns))
            assert np.allclose(row, J[i], rtol=1e-12, atol=0)
    with pytest.raises(FMICallException):
        ld.fmu.getDirectionalDerivative(unknowns, [vr["m"]], [1.0])
    assert any("m" in msg and "is a parameter" in msg for msg in ld.messages), ld.messages


@pytest.mark.parametrize("version", VERSIONS)
def test_second_free_and_foreign_instance_pointers_are_refused_with_a_message(built_fmus, version, capfd):
    """FreeInstance twice on one instance (a glibc double-free abort before the instance registry), a call on
    the freed instance and calls on a pointer that is no instance: refused with an error, named on stderr."""
    ld = fu.instantiate(built_fmus["FrictionJoint", version], "cs")
    fmu = ld.fmu
    handle = fmu.component
    free, terminate = (fmu.fmi2FreeInstance, fmu.fmi2Terminate) if version == "2.0" else (fmu.fmi3FreeInstance,
                                                                                          fmu.fmi3Terminate)
    free(handle)
    free(handle)
    with pytest.raises(FMICallException):
        terminate(handle)
    foreign = ctypes.create_string_buffer(4096)
    with pytest.raises(FMICallException):
        terminate(ctypes.cast(foreign, ctypes.c_void_p))
    free(ctypes.cast(foreign, ctypes.c_void_p))
    assert foreign.raw == bytes(4096)   # the runtime did not write into it
    err = capfd.readouterr().err
    assert err.count("is no live instance of this FMU") == 4, err
    assert f"fmi{version[0]}FreeInstance: 0x" in err and f"fmi{version[0]}Terminate: 0x" in err
    fresh = fu.instantiate(built_fmus["FrictionJoint", version], "cs")   # the runtime is still usable
    fu.initialize(fresh)
    fu.step(fresh, 0.0, 1e-3)
    fu.free(fresh)
    fmu.freeLibrary()
