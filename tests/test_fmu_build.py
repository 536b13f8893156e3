"""The Modelica-to-FMU pipeline, against independent references: analytic solutions, fmpy's CVode on
the Model Exchange interface, python-control's Tustin discretisation, fmpy's and fmu-manipulation-toolbox's
validators."""
from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import control
import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

from motiontwin.fmus import build, package
from motiontwin.fmus.frontend import ModelicaError
from tests import fmi_util as fu
from tests.compiler_util import wrapped_compiler

VERSIONS = build.FMI_VERSIONS


def analytic_step(t: np.ndarray, force: float, m: float, d: float) -> np.ndarray:
    """Position of m*q'' = F - d*q' from rest."""
    return force / d * (t - m / d * (1 - np.exp(-d * t / m)))


@pytest.mark.parametrize("version", VERSIONS)
def test_fmpy_validate_has_no_problems(built_fmus, version):
    for (name, v), path in built_fmus.items():
        if v == version:
            assert validate_fmu(str(path)) == [], name


def test_fmutool_check_has_no_errors(built_fmus):
    fmutool = Path(sys.executable).with_name("fmutool")
    for (name, version), path in built_fmus.items():
        proc = subprocess.run([str(fmutool), "-input", str(path), "-check"], capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, f"{name} FMI {version}: {proc.stdout}\n{proc.stderr}"


@pytest.mark.parametrize("version", VERSIONS)
def test_cs_step_response_matches_analytic(built_fmus, version):
    path = built_fmus["LinearMotorJoint", version]
    result = fmpy.simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=1.0, output_interval=1e-3,
                               start_values={"u": 3.0, "m": 1.5, "d": 4.0}, output=["q"])
    expected = analytic_step(result["time"], 3.0, 1.5, 4.0)
    assert np.max(np.abs(result["q"] - expected)) < 1e-7 * np.max(np.abs(expected))


def piecewise_input(times: list[float], values: list[float], stop: float) -> np.ndarray:
    """fmpy input table for a force that jumps at ``times`` (duplicate time rows mark the steps)."""
    rows = [(0.0, values[0])]
    for t, before, after in zip(times, values[:-1], values[1:]):
        rows += [(t, before), (t, after)]
    rows.append((stop, values[-1]))
    return np.array(rows, dtype=[("time", np.float64), ("u", np.float64)])


@pytest.mark.parametrize("version", VERSIONS)
def test_cs_matches_model_exchange_cvode_on_stiff_friction(built_fmus, version):
    """Smoothed Coulomb friction Fc*tanh(v/1e-4): CS (internal Rosenbrock) vs ME + CVode at rtol 1e-10."""
    path = built_fmus["FrictionJoint", version]
    signal = piecewise_input([0.2, 0.5, 0.8], [8.0, -9.0, 3.0, 0.0], 1.2)  # 3 N < Fc: the joint sticks
    kw = dict(stop_time=1.2, output_interval=1e-3, input=signal, output=["q", "v"])
    cs = fmpy.simulate_fmu(str(path), fmi_type="CoSimulation", **kw)
    me = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-10, **kw)
    me_q = np.interp(cs["time"], me["time"], me["q"])
    scale = np.max(np.abs(me["q"]))
    assert scale > 0.02  # the joint really moved
    assert np.max(np.abs(cs["q"] - me_q)) < 1e-6 * scale


@pytest.mark.parametrize("version", VERSIONS)
def test_defaults_equal_xml_start_values_and_every_parameter_is_tunable(built_fmus, version):
    path = built_fmus["FrictionJoint", version]
    md = fmpy.read_model_description(str(path))
    params = [v for v in md.modelVariables if v.causality == "parameter"]
    assert {p.name for p in params} == {"m", "d", "Fc", "v_eps"}
    ld = fu.instantiate(path)
    fu.initialize(ld)
    assert np.array_equal(fu.get(ld, *[p.name for p in params]), [float(p.start) for p in params])
    fu.set_(ld, {"u": 8.0})
    fu.step(ld, 0.0, 0.2)
    q_default = fu.get(ld, "q")[0]
    fu.free(ld)
    for p in params:
        new = float(p.start) * 1.7
        ld = fu.instantiate(path)
        fu.initialize(ld, {p.name: new})
        assert fu.get(ld, p.name)[0] == new, p.name
        fu.set_(ld, {"u": 8.0})
        fu.step(ld, 0.0, 0.2)
        assert abs(fu.get(ld, "q")[0] - q_default) > 1e-9, f"changing {p.name} did not change the output"
        fu.free(ld)


@pytest.mark.parametrize("version", VERSIONS)
def test_start_values_compiled_into_the_binary(fmu_dir, version):
    """A rebuilt FMU with new start values uses them by default (what write-back relies on)."""
    model = build.load_model("MotionTwin.Plants.LinearMotorJoint")
    fmu = build.build_fmu(model, fmu_dir / "rebuilt", version, start_values={"m": 1.5, "d": 4.0})
    md = fmpy.read_model_description(str(fmu.path))
    starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
    assert starts == {"m": 1.5, "d": 4.0}
    result = fmpy.simulate_fmu(str(fmu.path), stop_time=0.5, output_interval=1e-3, start_values={"u": 3.0},
                               output=["q"])
    assert np.allclose(result["q"], analytic_step(result["time"], 3.0, 1.5, 4.0), rtol=0, atol=1e-8)


@pytest.mark.parametrize("refused", [(), ("--param=*",)])
def test_a_large_generated_file_is_compiled_with_the_reload_limit_or_plain_o1(tmp_path, monkeypatch, refused):
    """A file of ``package.LARGE_SOURCE_BYTES`` or more (the Hexapod's 1.77 MB model) is compiled with gcc's reload
    limit (``clib.LARGE_SOURCE_FLAGS``); a compiler that refuses the limit compiles it at plain -O1. Either FMU
    gives the analytic step response."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(package, "LARGE_SOURCE_BYTES", 0)      # every file counts as large
    log = wrapped_compiler(tmp_path, monkeypatch, refuse=refused)
    model = build.load_model("MotionTwin.Plants.LinearMotorJoint")
    fmu = build.build_fmu(model, tmp_path / "fmu", "2.0", start_values={"m": 1.5, "d": 4.0})
    compiles = [line.split() for line in log.read_text().splitlines() if "-c" in line.split()]
    limited = [c for c in compiles if "--param=lra-max-considered-reload-pseudos=50" in c]
    assert compiles and all(c[0] == "-O1" for c in compiles)
    assert len(limited) == (len(compiles) / 2 if refused else len(compiles))     # refused: each tried once
    result = fmpy.simulate_fmu(str(fmu.path), stop_time=0.5, output_interval=1e-3, start_values={"u": 3.0},
                               output=["q"])
    assert np.allclose(result["q"], analytic_step(result["time"], 3.0, 1.5, 4.0), rtol=0, atol=1e-8)


@pytest.mark.parametrize("version", VERSIONS)
def test_fmu_state_get_set_and_serialize_round_trip(built_fmus, version):
    path = built_fmus["FrictionJoint", version]
    ld = fu.instantiate(path)
    fu.initialize(ld)
    fu.set_(ld, {"u": 8.0})
    for k in range(10):
        fu.step(ld, 0.01 * k, 0.01)
    f = ld.fmu
    v2 = version == "2.0"
    state = f.getFMUstate() if v2 else f.getFMUState()
    blob = f.serializeFMUstate(state) if v2 else f.serializeFMUState(state)
    for k in range(10, 20):
        fu.step(ld, 0.01 * k, 0.01)
    reference = fu.get(ld, "q", "v")
    restored = f.deSerializeFMUstate(blob) if v2 else f.deserializeFMUState(blob)
    f.setFMUstate(restored) if v2 else f.setFMUState(restored)
    for k in range(10, 20):
        fu.step(ld, 0.01 * k, 0.01)
    assert np.array_equal(fu.get(ld, "q", "v"), reference)
    fu.free(ld)


@pytest.mark.parametrize("version", VERSIONS)
def test_sampled_controller_matches_python_control_tustin(built_fmus, version):
    """Impulse response of the sampled PI+D FMU vs control.sample_system(..., 'tustin') of the same law."""
    kp, ki, kd, tau, ts = 2.0, 30.0, 0.01, 0.002, 0.001
    law = control.tf([kp], [1]) + control.tf([ki], [1, 0]) + control.tf([kd, 0], [tau, 1])
    discrete = control.sample_system(law, ts, method="tustin")
    n = 200
    impulse = np.zeros(n)
    impulse[0] = 1.0
    _, expected = control.forced_response(discrete, np.arange(n) * ts, impulse)
    ld = fu.instantiate(built_fmus["SampledPI", version])
    fu.initialize(ld, {"e": 1.0})
    got = []
    for k in range(n):
        fu.set_(ld, {"e": impulse[k]})
        fu.step(ld, k * ts, ts)
        got.append(fu.get(ld, "y")[0])
    fu.free(ld)
    assert np.max(np.abs(np.array(got) - expected)) < 1e-6 * np.max(np.abs(expected))


@pytest.mark.parametrize("version", VERSIONS)
def test_source_fmu_recompiles_with_fmpy(built_fmus, tmp_path, version):
    src = built_fmus["LinearMotorJoint", version]
    copy = tmp_path / src.name
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(copy, "w") as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item))
    fmpy_cli = Path(sys.executable).with_name("fmpy")
    proc = subprocess.run([str(fmpy_cli), "compile", str(copy)], capture_output=True, text=True, cwd=tmp_path,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = fmpy.simulate_fmu(str(copy), stop_time=0.5, output_interval=1e-3, start_values={"u": 3.0},
                               output=["q"])
    assert np.allclose(result["q"], analytic_step(result["time"], 3.0, 2.0, 10.0), rtol=0, atol=1e-8)


@pytest.mark.parametrize("version", VERSIONS)
def test_non_physical_parameter_is_an_error_through_the_logger(built_fmus, version):
    ld = fu.instantiate(built_fmus["LinearMotorJoint", version])
    with pytest.raises(Exception):
        fu.initialize(ld, {"m": -1.0})
    assert any("m" in msg and "-1" in msg for msg in ld.messages), ld.messages
    ld.fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_nan_input_and_out_of_sequence_calls_are_refused(built_fmus, version):
    ld = fu.instantiate(built_fmus["LinearMotorJoint", version])
    with pytest.raises(Exception):
        fu.step(ld, 0.0, 0.01)  # before initialisation
    assert ld.messages
    fu.initialize(ld)
    ld.messages.clear()
    with pytest.raises(Exception):
        fu.set_(ld, {"u": float("nan")})
    assert any("u" in msg for msg in ld.messages), ld.messages
    ld.fmu.freeInstance()


def test_syntax_error_names_file_line_and_column(tmp_path):
    bad = Path(__file__).parent / "models" / "bad" / "Bad.mo"
    with pytest.raises(ModelicaError, match=r"Bad\.mo:4:\d+: syntax error"):
        build.load_model("Bad", bad)


def test_failed_build_leaves_nothing_behind(tmp_path):
    """A class that fails in the front end stops the build: the classes built before it are not written either."""
    source = Path(__file__).parent / "models" / "FrictionJoint.mo"
    with pytest.raises(ModelicaError, match="class 'Missing' not found"):
        build.build(["FrictionJoint", "Missing"], source, tmp_path / "out", workers=1)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ModelicaError, match=r"Bad\.mo:4:\d+: syntax error"):
        build.build(["Bad"], Path(__file__).parent / "models" / "bad", tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_cli_builds_both_versions(tmp_path):
    from motiontwin.cli import main

    assert main(["build", "MotionTwin.Plants.LinearMotorJoint", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "fmi2" / "LinearMotorJoint.fmu").is_file()
    assert (tmp_path / "fmi3" / "LinearMotorJoint.fmu").is_file()
    assert main(["build", "Nope.Missing", "--out", str(tmp_path)]) == 1
    assert shutil.which("gcc")


@pytest.mark.parametrize("version", VERSIONS)
def test_discrete_state_space_controller_matches_python_control(fmu_dir, version):
    """sampled(method="discrete"): x[k+1] = A x[k] + B u[k] exactly, against control.ss(A, B, C, D, Ts)."""
    source = Path(__file__).parent / "models" / "DiscreteLeadLag.mo"
    model = build.load_model("DiscreteLeadLag", source, (build.MODELICA_DIR,))
    path = build.build_fmu(model, fmu_dir / "discrete", version).path
    a, b, c, d, ts = [[0.9, 0.05], [-0.02, 0.7]], [[0.3], [1.0]], [[2.0, -1.0]], [[0.5]], 1e-3
    u = np.sin(np.arange(300) * 0.05) + (np.arange(300) > 100)
    _, expected = control.forced_response(control.ss(a, b, c, d, ts), np.arange(300) * ts, u)
    ld = fu.instantiate(path)
    fu.initialize(ld, {"u": u[0]})
    got = []
    for k in range(300):
        fu.set_(ld, {"u": u[k]})
        fu.step(ld, k * ts, ts)
        got.append(fu.get(ld, "y")[0])
    fu.free(ld)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
