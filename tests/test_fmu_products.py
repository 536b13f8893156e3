"""FMUs are products: valgrind-clean through a full FMI life cycle, and identical results in third-party
co-simulation engines (libcosimpy = Open Simulation Platform's libcosim; ecospy = ecos)."""
from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy
import pytest

from motiontwin.fmus import package

C_DRIVER = Path(__file__).parent / "c" / "fmi_cycle.c"
FORCE = 3.0
STEP = 1e-3
STEPS = 500


@pytest.fixture(scope="session")
def cycle_driver(tmp_path_factory: pytest.TempPathFactory) -> Path:
    exe = tmp_path_factory.mktemp("driver") / "fmi_cycle"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-g", "-O0", "-std=c99", "-D_DEFAULT_SOURCE", f"-I{headers}", str(C_DRIVER), "-o",
                    str(exe), "-ldl"], check=True, timeout=300)
    return exe


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="valgrind not installed (make sysdeps installs it)")
def test_valgrind_memcheck_full_life_cycle(built_fmus, cycle_driver, tmp_path):
    for (name, version), path in built_fmus.items():
        md = fmpy.read_model_description(str(path))
        unzip = tmp_path / f"{name}-{version}"
        zipfile.ZipFile(path).extractall(unzip)
        lib = unzip / "binaries" / package.PLATFORM_DIR[version] / f"{md.coSimulation.modelIdentifier}.so"
        inputs = [v for v in md.modelVariables if v.causality == "input"]
        nx = len(md.derivatives) if version == "2.0" else len(md.derivatives)
        nvr = max(v.valueReference for v in md.modelVariables) + 1
        token = md.guid
        proc = subprocess.run(
            ["valgrind", "--error-exitcode=99", "--leak-check=full", "--errors-for-leak-kinds=definite,indirect",
             "-q", str(cycle_driver), str(lib), version[0], token, str(nvr), str(inputs[0].valueReference),
             str(nx)], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, f"{name} FMI {version}:\n{proc.stderr[-3000:]}"


def fmpy_reference(path: Path) -> float:
    result = fmpy.simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=STEPS * STEP, output_interval=STEP,
                               start_values={"u": FORCE}, output=["q"])
    return float(result["q"][-1])


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_ecospy_runs_the_fmu_identically(built_fmus, version):
    ecospy = pytest.importorskip("ecospy")
    path = built_fmus["FrictionJoint", version]
    structure = ecospy.EcosSimulationStructure()
    structure.add_model("joint", str(path))
    structure.add_parameter_set("force", {"joint::u": FORCE})
    with ecospy.EcosSimulation(structure=structure, step_size=STEP) as sim:
        sim.init(parameter_set="force")
        sim.step(STEPS)
        q = sim.get_real("joint::q")
    assert q == pytest.approx(fmpy_reference(path), rel=1e-9, abs=1e-12)


def test_libcosim_runs_the_fmi2_fmu_identically(built_fmus):
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    path = built_fmus["FrictionJoint", "2.0"]
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    execution = CosimExecution.from_step_size(step_size=int(STEP * 1e9))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(path), instance_name="joint"))
    execution.real_initial_value(index, vr["u"], FORCE)
    execution.simulate_until(target_time=int(STEPS * STEP * 1e9))
    q = observer.last_real_values(index, [vr["q"]])[0]
    assert q == pytest.approx(fmpy_reference(path), rel=1e-9, abs=1e-12)
