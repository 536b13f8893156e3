"""Co-simulation master on third-party FMUs (OpenModelica FMI 2.0 and PythonFMU3 FMI 3.0, shipped
in the gemseo-fmu wheel), against analytic / scipy references of the same closed loops."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from motiontwin.harness import fmu_instance
from motiontwin.harness.fmu_instance import FMUCallError, PortError
from motiontwin.harness.master import Master
from motiontwin.harness.wiring import StepError, UnitMismatchError
from motiontwin.harness.system import SystemFileError, load_system, system_from_dict

def write(tmp_path: Path, text: str, name: str = "system.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def mass_spring(fmus: Path, base_step: float) -> dict:
    """Two OpenModelica subsystems coupled by positions: m1 x1'' = -k1 x1 + k2 (x2 - x1),
    m2 x2'' = -k3 x2 - k2 (x2 - x1), all k and m = 1, x1(0) = 0, v1(0) = 1, x2(0) = 1, v2(0) = 0."""
    return {
        "base_step": base_step, "stop_time": 1.0,
        "fmus": {"s1": {"path": str(fmus / "MassSpringSubSystem1.fmu")},
                 "s2": {"path": str(fmus / "MassSpringSubSystem2.fmu")}},
        "connections": [{"from": "s1.x1", "to": "s2.x1"}, {"from": "s2.x2", "to": "s1.x2"}],
        "log": [{"signals": ["s1.x1", "s1.v1", "s2.x2", "s2.v2"], "step": 1e-2}],
    }


def mass_spring_reference(t: np.ndarray) -> np.ndarray:
    def rhs(_t, y):
        x1, v1, x2, v2 = y
        return [v1, -x1 + (x2 - x1), v2, -x2 - (x2 - x1)]

    return solve_ivp(rhs, (0, t[-1]), [0, 1, 1, 0], rtol=1e-11, atol=1e-12, dense_output=True).sol(t)


def test_two_fmu_loop_converges_to_scipy_solution(gemseo_fmus: Path) -> None:
    errors = []
    for h in (1e-3, 2.5e-4):
        with Master(system_from_dict(mass_spring(gemseo_fmus, h))) as m:
            assert m.order == ["s1", "s2"]
            log = m.run()["log"]
        ref = mass_spring_reference(log["time"])
        errors.append(max(np.abs(log[c] - ref[i]).max() for i, c in enumerate(["s1.x1", "s1.v1", "s2.x2", "s2.v2"])))
    assert errors[0] < 2e-3
    assert errors[1] < 0.35 * errors[0]  # first order in the step (OpenModelica CS uses explicit Euler)


P_LOOP = """
base_step = 1e-5
stop_time = 0.2
[fmus.ctrl]                # OpenModelica "add": y = k1*u1 + k2*u2 = Kp*(r - y_plant), sampled at 1 ms
path = "{fmus}/add.fmu"
step = 1e-3
sampled = true
[fmus.ctrl.parameters]
"add.k1" = 5000.0
"add.k2" = -5000.0
[fmus.plant]               # OpenModelica mass-spring-damper: y'' = -1e4 (y + 0.5) - 10 y' + f
path = "{fmus}/Mass_Damper.fmu"
[inputs.r]
unit = "m"
[inputs.u_ext]
unit = "N"
[[connections]]
from = "input.r"
to = "ctrl.u1"
[[connections]]
from = "plant.y"
to = "ctrl.u2"
[[connections]]
from = ["ctrl.y", "input.u_ext"]
to = "plant.f"
[[log]]
name = "slow"
signals = ["plant.y", "ctrl.y"]
step = 1e-3
[[log]]
name = "fast"
signals = ["plant.f", "ctrl.y", "input.u_ext"]
"""


def sampled_loop_reference(delay: bool) -> np.ndarray:
    """Exact zero-order-hold solution of the P loop (plant discretized with expm at 10 us)."""
    a = np.array([[0.0, 1.0], [-1e4, -10.0]])
    e = expm(np.block([[a, np.eye(2)], [np.zeros((2, 4))]]) * 1e-5)
    phi, gamma = e[:2, :2], e[:2, 2:]
    x, u_previous, out = np.zeros(2), 0.0, [0.0]
    for k in range(200):
        u = 5000.0 * (-0.4 - x[0])
        applied, u_previous = (u_previous if delay else u), u
        for j in range(100):
            force = applied + (50.0 if (k * 100 + j) >= 5000 else 0.0)
            x = phi @ x + gamma @ np.array([0.0, force - 5000.0])
        out.append(x[0])
    return np.array(out)


def test_sampled_controller_first_gives_no_extra_delay(gemseo_fmus: Path, tmp_path: Path) -> None:
    with Master(write(tmp_path, P_LOOP.format(fmus=gemseo_fmus))) as m:
        assert m.order == ["ctrl", "plant"] and m.multiples == {"ctrl": 100, "plant": 1}
        t = m.time_grid()
        logs = m.run(inputs={"r": -0.4, "u_ext": (np.array([0.0, 0.05]), np.array([0.0, 50.0]))})
    slow, fast = logs["slow"], logs["fast"]
    error = np.abs(slow["plant.y"] - sampled_loop_reference(delay=False)).max()
    error_if_delayed = np.abs(slow["plant.y"] - sampled_loop_reference(delay=True)).max()
    assert error < 5e-3 < 0.1 < error_if_delayed
    # controller output at a sample uses the plant output at that same instant (nothing is stepped
    # at the final time, so there the controller output is the one held from the last sample)
    np.testing.assert_allclose(slow["ctrl.y"][:-1], 5000.0 * (-0.4 - slow["plant.y"][:-1]), rtol=1e-12, atol=1e-9)
    assert slow["ctrl.y"][-1] == slow["ctrl.y"][-2]
    # sum junction, and the controller output held between samples
    np.testing.assert_array_equal(fast["plant.f"], fast["ctrl.y"] + fast["input.u_ext"])
    np.testing.assert_array_equal(fast["input.u_ext"], np.where(t >= 0.05 - 1e-12, 50.0, 0.0))
    held = fast["ctrl.y"][:-1].reshape(200, 100)
    assert np.all(held == held[:, :1])
    np.testing.assert_array_equal(fast["time"], t)


F3 = """
base_step = 0.1
stop_time = 1.0
[fmus.f3]                  # FMI 3.0 (PythonFMU3): output = 3 + input at init, then +1 per step
path = "{fmus}/FMU3Model.fmu"
[fmus.add]                 # FMI 2.0 (OpenModelica): y = u1 + u2
path = "{fmus}/add.fmu"
[inputs.a]
[inputs.u_ext]
[[connections]]
from = "input.a"
to = "f3.input"
[[connections]]
from = "f3.output"
to = "add.u1"
[[connections]]
from = "input.u_ext"
to = "add.u2"
[[log]]
signals = ["f3.output", "f3.vector", "add.y"]
"""


def test_fmi3_and_fmi2_mixed_gauss_seidel(gemseo_fmus: Path, tmp_path: Path) -> None:
    u_ext = np.arange(11) * 10.0
    with Master(write(tmp_path, F3.format(fmus=gemseo_fmus))) as m:
        log = m.run(inputs={"a": 2.0, "u_ext": u_ext})["log"]
        again = m.run(inputs={"a": 2.0, "u_ext": u_ext})["log"]
    k = np.arange(11)
    np.testing.assert_array_equal(log["f3.output"], 5.0 + k)
    # add steps after f3 in the same interval: it sees f3's new output and u_ext held over the step
    np.testing.assert_array_equal(log["add.y"], 5.0 + k + np.concatenate([[0.0], u_ext[:-1]]))
    for i in range(5):  # array output, rolled by one each step
        np.testing.assert_array_equal(log[f"f3.vector[{i + 1}]"], (i - k) % 5)
    np.testing.assert_array_equal(log, again)


def test_reset_between_runs_reuses_instances(gemseo_fmus: Path, tmp_path: Path) -> None:
    path = write(tmp_path, P_LOOP.format(fmus=gemseo_fmus).replace("stop_time = 0.2", "stop_time = 0.02"))
    with Master(path) as m:
        slaves = {n: f.slave for n, f in m.instances.items()}
        extracted = len(fmu_instance._EXTRACTED)
        first = m.run(inputs={"r": -0.4, "u_ext": 0.0})
        other = m.run(inputs={"r": 0.3, "u_ext": 10.0}, parameters={"ctrl.add.k1": 100.0})
        repeat = m.run(inputs={"r": -0.4, "u_ext": 0.0})
        assert {n: f.slave for n, f in m.instances.items()} == slaves
        assert len(fmu_instance._EXTRACTED) == extracted
    with Master(path) as fresh:
        reference = fresh.run(inputs={"r": -0.4, "u_ext": 0.0})
    assert not np.array_equal(first["slow"], other["slow"])
    for name in first:
        np.testing.assert_array_equal(first[name], repeat[name])
        np.testing.assert_array_equal(first[name], reference[name])


def test_unknown_port_lists_available_ports(gemseo_fmus: Path, tmp_path: Path) -> None:
    text = P_LOOP.format(fmus=gemseo_fmus).replace('to = "plant.f"', 'to = "plant.force"')
    with pytest.raises(PortError, match=r"unknown port 'plant.force'.*FMU 'plant' has inputs: f"):
        Master(write(tmp_path, text))
    text = P_LOOP.format(fmus=gemseo_fmus).replace('from = "plant.y"', 'from = "plnt.y"')
    with pytest.raises(PortError, match=r"unknown FMU instance 'plnt'.*Instances: ctrl, plant"):
        Master(write(tmp_path, text))
    text = P_LOOP.format(fmus=gemseo_fmus).replace('from = "input.r"', 'from = "input.ref"')
    with pytest.raises(PortError, match=r"unknown external input 'input.ref'. Declared inputs: input.r, input.u_ext"):
        Master(write(tmp_path, text))


def test_unit_mismatch_is_reported(gemseo_fmus: Path, tmp_path: Path) -> None:
    text = P_LOOP.format(fmus=gemseo_fmus).replace('[inputs.u_ext]\nunit = "N"', '[inputs.u_ext]\nunit = "m/s"')
    with pytest.raises(UnitMismatchError, match=r"'input.u_ext' -> 'plant.f': unit 'm/s' does not match 'N'"):
        Master(write(tmp_path, text))
    text = P_LOOP.format(fmus=gemseo_fmus).replace('[inputs.u_ext]\nunit = "N"', '[inputs.u_ext]\nunit = "kg.m/s2"')
    Master(write(tmp_path, text)).close()  # same SI unit written differently


def test_steps_must_be_integer_multiples(gemseo_fmus: Path, tmp_path: Path) -> None:
    text = P_LOOP.format(fmus=gemseo_fmus).replace("step = 1e-3\nsampled", "step = 1.5e-5\nsampled")
    with pytest.raises(StepError, match=r"\[fmus.ctrl\] step = 1.5e-05 s is not an integer multiple of base_step = 1e-05 s"):
        Master(write(tmp_path, text))
    # a sampled FMU's period parameter (here the ramp's duration stands in for a controller's Ts)
    text = f"""
base_step = 1e-3
stop_time = 0.1
[fmus.ramp]
path = "{gemseo_fmus}/ramp.fmu"
ts_parameter = "ramp.duration"
step = 3e-3
[fmus.ramp.parameters]
"ramp.duration" = 2e-3
"""
    with pytest.raises(StepError, match=r"step = 0.003 s is not an integer multiple of the FMU's sampling period ramp.duration = 0.002 s"):
        Master(write(tmp_path, text))
    with Master(write(tmp_path, text.replace("step = 3e-3", "step = 4e-3"))) as m:
        assert m.sampled == {"ramp": True} and m.multiples == {"ramp": 4}
        with pytest.raises(StepError, match="sampling period ramp.duration = 0.003 s"):
            m.run(parameters={"ramp.ramp.duration": 3e-3})


def test_fmu_error_names_fmu_call_time_and_message(gemseo_fmus: Path, tmp_path: Path) -> None:
    with Master(write(tmp_path, F3.format(fmus=gemseo_fmus))) as m:
        with pytest.raises(FMUCallError, match=r"(?s)FMU 'f3': fmi3SetInt64 returned FATAL at t = 0 s.*"
                                               r"7 is not a valid Color"):
            m.run(inputs={"a": 2.0, "u_ext": 0.0}, parameters={"f3.enumeration": 7})
        np.testing.assert_array_equal(m.run(inputs={"a": 2.0, "u_ext": 0.0})["log"]["f3.output"], 5.0 + np.arange(11))
    text = P_LOOP.format(fmus=gemseo_fmus) + '[fmus.plant.parameters]\n"mass.m" = 0.0\n'  # division by zero
    with Master(write(tmp_path, text)) as m:
        with pytest.raises(FMUCallError, match=r"FMU 'plant': fmi2ExitInitializationMode returned ERROR at t = 0 s"):
            m.run(inputs={"r": 0.0, "u_ext": 0.0})


def test_system_file_errors_name_file_field_and_line(tmp_path: Path) -> None:
    path = write(tmp_path, 'base_step = 1e-3\n[fmus.a]\npath = "a.fmu"\nstep = "fast"\n')
    with pytest.raises(SystemFileError, match=r"system.toml, line 2: \[fmus.a\] step: expected a finite number"):
        load_system(path)
    path = write(tmp_path, 'base_step = 1e-3\n[fmus.a]\npath = "a.fmu"\nstep = \n')
    with pytest.raises(SystemFileError, match=r"system.toml: .*line 4"):
        load_system(path)
    path = write(tmp_path, 'base_step = 1e-3\n[fmus.a]\npath = "a.fmu"\n[[connections]]\nfrom = "a.y"\n')
    with pytest.raises(SystemFileError, match=r"\[\[connections\]\] #1 to: expected a port name"):
        load_system(path)
    system = load_system(write(tmp_path, 'base_step = 1e-3\n[fmus.a]\npath = "sub/a.fmu"\n'))
    assert system.fmus["a"].path == tmp_path / "sub" / "a.fmu"


def test_ssp_export_validates_and_runs_in_fmpy_ssp(gemseo_fmus: Path, tmp_path: Path) -> None:
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssd

    from motiontwin.harness.ssp import SSPExportError, export_ssp

    system = system_from_dict(mass_spring(gemseo_fmus, 1e-3), source=tmp_path / "mass_spring.toml")
    path = export_ssp(system, tmp_path / "out" / "mass_spring.ssp")
    assert sorted(p.name for p in path.parent.iterdir()) == ["mass_spring.ssp"]  # no temp file left
    ssd = read_ssd(str(path), validate=True)  # fmpy checks it against the SSP 1.0 XSD
    assert [(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections] == [
        ("s1", "x1", "s2", "x1"), ("s2", "x2", "s1", "x2")]
    result = simulate_ssp(str(path), stop_time=1.0, step_size=1e-3)  # a second master (Jacobi)
    t = result["time"] + 1e-3  # fmpy stores the values after the step with the time before it
    ref = mass_spring_reference(t)
    assert np.abs(result["s1.x1"] - ref[0]).max() < 3e-3
    assert np.abs(result["s2.x2"] - ref[2]).max() < 3e-3

    loop = load_system(write(tmp_path, P_LOOP.format(fmus=gemseo_fmus), "p_loop.toml"))
    with pytest.raises(SSPExportError, match=r"connection to 'plant.f' sums \['ctrl.y', 'input.u_ext'\]"):
        export_ssp(loop, tmp_path / "p_loop.ssp")
    ssd = read_ssd(str(export_ssp(loop, tmp_path / "p_loop.ssp", drop_external_in_sums=True)), validate=True)
    ctrl = next(e for e in ssd.system.elements if e.name == "ctrl")
    values = {p.name: p.value for p in ctrl.parameterBindings[0].parameterValues[0].parameters}
    assert {k: float(v) for k, v in values.items()} == {"add.k1": 5000.0, "add.k2": -5000.0}
    assert [c.name for c in ssd.system.connectors] == ["r"]


PI_LOOP = """
base_step = 1e-4
stop_time = 0.3
[fmus.pi]                  # the project's sampled PI (Tustin), Ts = 1 ms
path = "{pi}"
[fmus.pi.parameters]
Kp = 2000.0
Ki = 20000.0
Kd = 40.0
[fmus.plant]               # the project's joint: m der(v) = u - d v, q = x
path = "{plant}"
[inputs.r]
unit = "m"
[inputs.u_ext]
unit = "N"
default = 0.0
[[connections]]            # e = r - q
from = ["input.r", "plant.q"]
gains = [1.0, -1.0]
to = "pi.e"
[[connections]]            # u = controller output + excitation
from = ["pi.y", "input.u_ext"]
to = "plant.u"
[[log]]
signals = ["plant.q", "pi.y", "plant.u"]
"""


def pi_loop_reference(r: float, u_ext: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """python-control Tustin discretization of Kp + Ki/s + Kd s/(tau s + 1) at 1 ms, and the plant
    (m = 2 kg, d = 10 N s/m) discretized exactly (expm) at 0.1 ms with zero-order-hold force."""
    import control

    s = control.tf("s")
    cd = control.c2d(2000.0 + 20000.0 / s + 40.0 * s / (0.002 * s + 1), 1e-3, "tustin")
    b = np.array(cd.num[0][0], float) / cd.den[0][0][0]
    a = np.array(cd.den[0][0], float) / cd.den[0][0][0]
    e = expm(np.block([[np.array([[0.0, 1.0], [0.0, -5.0]]), np.array([[0.0], [0.5]])], [np.zeros((1, 3))]]) * 1e-4)
    phi, gamma = e[:2, :2], e[:2, 2]
    x, errors, outputs, q, u_log = np.zeros(2), [0.0] * len(b), [0.0] * len(a), [0.0], []
    for k in range(300):
        errors = [r - x[0]] + errors[:-1]
        u = b @ np.array(errors) - a[1:] @ np.array(outputs[: len(a) - 1])
        outputs = [u] + outputs[:-1]
        for j in range(10):
            x = phi @ x + gamma * (u + u_ext[10 * k + j])
            q.append(x[0])
            u_log.append(u)
    return np.array(q), np.array(u_log)


@pytest.mark.parametrize("pi_version, plant_version", [("3.0", "2.0"), ("2.0", "3.0")])
def test_project_fmus_closed_loop_matches_tustin_and_zoh_reference(
        built_fmus: dict, tmp_path: Path, pi_version: str, plant_version: str) -> None:
    text = PI_LOOP.format(pi=built_fmus["SampledPI", pi_version], plant=built_fmus["LinearMotorJoint", plant_version])
    u_ext = np.where(np.arange(3001) >= 1500, 5.0, 0.0)
    q_ref, u_ref = pi_loop_reference(1e-3, u_ext)
    with Master(write(tmp_path, text)) as m:
        assert m.order == ["pi", "plant"] and m.multiples == {"pi": 10, "plant": 1} and m.sampled["pi"]
        first = m.run(inputs={"r": 1e-3, "u_ext": u_ext})["log"]
        assert all(f.initial_state is not None for f in m.instances.values())  # canGetAndSetFMUstate path
        second = m.run(inputs={"r": 1e-3, "u_ext": u_ext})["log"]
    with Master(write(tmp_path, text), reuse_state=False) as m:
        by_reset = m.run(inputs={"r": 1e-3, "u_ext": u_ext})["log"]
    np.testing.assert_allclose(first["plant.q"], q_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(first["pi.y"][:-1], u_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(first["plant.u"], first["pi.y"] + u_ext)
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first, by_reset)


# -- compiled inner loop (harness/native_loop.c) against the Python loop ---------------------------


def run_both(path: Path | dict, **run_kwargs) -> tuple[dict, dict]:
    """Logs of the same runs through the compiled loop and through the Python (fmpy ctypes) loop."""
    system = system_from_dict(path) if isinstance(path, dict) else path
    with Master(system, native=True) as compiled, Master(system, native=False) as python:
        assert compiled.uses_native and not python.uses_native
        return compiled.run(**run_kwargs), python.run(**run_kwargs)


def assert_bit_identical(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for name in a:
        assert a[name].dtype == b[name].dtype
        for column in a[name].dtype.names:  # byte equality: also NaN payloads and the sign of zeros
            assert a[name][column].tobytes() == b[name][column].tobytes(), (name, column)


@pytest.mark.parametrize("pi_version, plant_version", [("3.0", "2.0"), ("2.0", "3.0"), ("3.0", "3.0")])
def test_compiled_loop_bit_identical_on_project_pi_loops(built_fmus: dict, tmp_path: Path,
                                                         pi_version: str, plant_version: str) -> None:
    text = PI_LOOP.format(pi=built_fmus["SampledPI", pi_version], plant=built_fmus["LinearMotorJoint", plant_version])
    u_ext = np.where(np.arange(3001) >= 1500, 5.0, 0.0)
    compiled, python = run_both(write(tmp_path, text), inputs={"r": 1e-3, "u_ext": u_ext})
    assert_bit_identical(compiled, python)
    np.testing.assert_allclose(compiled["log"]["plant.q"], pi_loop_reference(1e-3, u_ext)[0], rtol=0, atol=1e-12)


def test_compiled_loop_bit_identical_multirate_gains_and_short_last_step(built_fmus: dict, tmp_path: Path) -> None:
    # base 50 us; PI at Ts = 1 ms (20 base steps), plant at Ts/4 (5 base steps); the run ends one base step
    # after a plant step, so both FMUs shorten their last step; the sum junctions have non-trivial gains
    text = PI_LOOP.format(pi=built_fmus["SampledPI", "2.0"], plant=built_fmus["LinearMotorJoint", "3.0"])
    text = (text.replace("base_step = 1e-4", "base_step = 5e-5").replace("stop_time = 0.3", "stop_time = 0.30005")
            .replace('path = "{}"\n[inputs.r]'.format(built_fmus["LinearMotorJoint", "3.0"]),
                     'path = "{}"\nstep = 2.5e-4\n[inputs.r]'.format(built_fmus["LinearMotorJoint", "3.0"]))
            .replace('from = ["pi.y", "input.u_ext"]', 'from = ["pi.y", "input.u_ext"]\ngains = [0.7, -1.3]')
            .replace('signals = ["plant.q", "pi.y", "plant.u"]', 'signals = ["plant.q", "pi.y", "plant.u", "input.u_ext"]'))
    text += '[[log]]\nname = "slow"\nstep = 1.5e-4\nsignals = ["plant.q", "pi.e"]\n'
    rng = np.random.default_rng(3)
    u_ext = rng.normal(size=6002) * 3.0
    with Master(write(tmp_path, text)) as m:
        assert m.multiples == {"pi": 20, "plant": 5} and m.grid_size() == 6001
    compiled, python = run_both(write(tmp_path, text), inputs={"r": 1e-3, "u_ext": u_ext})
    assert_bit_identical(compiled, python)
    log = compiled["log"]
    # u = 0.7 y + (-1.3) u_ext, summed in that order at the plant's steps and held over them
    held = (np.arange(6002) // 5) * 5
    u = 0.7 * log["pi.y"][held] + -1.3 * log["input.u_ext"][held]
    np.testing.assert_array_equal(log["plant.u"][:-1], u[:-1])
    assert log["plant.q"][-1] != log["plant.q"][-2]  # the shortened last step was taken
    np.testing.assert_array_equal(compiled["slow"]["plant.q"], log["plant.q"][::3])


def test_compiled_loop_bit_identical_on_fmi3_and_third_party_fmus(gemseo_fmus: Path, tmp_path: Path) -> None:
    compiled, python = run_both(write(tmp_path, F3.format(fmus=gemseo_fmus)),
                                inputs={"a": 2.0, "u_ext": np.arange(11) * 10.0})
    assert_bit_identical(compiled, python)
    np.testing.assert_array_equal(compiled["log"]["f3.output"], 5.0 + np.arange(11))
    compiled, python = run_both(write(tmp_path, P_LOOP.format(fmus=gemseo_fmus)),
                                inputs={"r": -0.4, "u_ext": (np.array([0.0, 0.05]), np.array([0.0, 50.0]))})
    assert_bit_identical(compiled, python)
    assert np.abs(compiled["slow"]["plant.y"] - sampled_loop_reference(delay=False)).max() < 5e-3


def test_compiled_loop_reports_failing_fmu_like_python_loop(built_fmus: dict, tmp_path: Path) -> None:
    # a destabilising gain: the PI output overflows to inf at its second sample (t = 1 ms), which the
    # project runtime refuses in fmi2DoStep with an error message
    text = PI_LOOP.format(pi=built_fmus["SampledPI", "2.0"], plant=built_fmus["LinearMotorJoint", "2.0"])
    text = text.replace("Kp = 2000.0", "Kp = 1e300")
    errors = []
    for native_loop in (True, False):
        with Master(write(tmp_path, text), native=native_loop) as m:
            with pytest.raises(FMUCallError) as info:
                m.run(inputs={"r": 1e-3})
            errors.append(info.value)
            again = m.run(inputs={"r": 1e-3}, parameters={"pi.Kp": 2000.0})["log"]  # the instance is usable
            np.testing.assert_allclose(again["plant.q"], pi_loop_reference(1e-3, np.zeros(3001))[0], atol=1e-12)
    compiled, python = errors
    assert (compiled.instance, compiled.function, compiled.status, compiled.time) == ("pi", "fmi2DoStep", 3, 1e-3)
    assert any("not finite" in message for message in compiled.messages)
    assert str(compiled) == str(python)
    assert "FMU 'pi': fmi2DoStep returned ERROR at t = 0.001 s" in str(compiled)


def test_without_c_compiler_the_python_loop_runs(built_fmus: dict, tmp_path: Path, monkeypatch) -> None:
    from motiontwin.harness import native

    monkeypatch.setenv("CC", "no-such-compiler-motiontwin")
    monkeypatch.setattr(native, "_LIBRARY", [])
    text = PI_LOOP.format(pi=built_fmus["SampledPI", "2.0"], plant=built_fmus["LinearMotorJoint", "2.0"])
    with Master(write(tmp_path, text)) as m:
        assert not m.uses_native
        log = m.run(inputs={"r": 1e-3})["log"]
    np.testing.assert_allclose(log["plant.q"], pi_loop_reference(1e-3, np.zeros(3001))[0], rtol=0, atol=1e-12)


def test_profile_measures_time_inside_do_step(built_fmus: dict, tmp_path: Path) -> None:
    import time

    text = PI_LOOP.format(pi=built_fmus["SampledPI", "3.0"], plant=built_fmus["LinearMotorJoint", "2.0"])
    with Master(write(tmp_path, text), profile=True) as m, Master(write(tmp_path, text)) as plain:
        started = time.perf_counter()
        log = m.run(inputs={"r": 1e-3})["log"]
        wall = time.perf_counter() - started
        assert_bit_identical({"log": log}, {"log": plain.run(inputs={"r": 1e-3})["log"]})
    assert set(m.step_seconds) == {"pi", "plant"}
    assert 0.0 < m.step_seconds["pi"] and 0.0 < m.step_seconds["plant"]
    assert sum(m.step_seconds.values()) < wall
