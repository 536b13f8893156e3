"""Diagnosis benchmark generator (issue 7): the truth is a library FMU co-simulated by the harness.

References: a plain fmpy run of the same plant FMU driven by the co-simulation's force (no harness), the
discrete state-space law evaluated in numpy on the *measured* position, harness.measurement.quantize,
the CasADi closed-loop simulation of the diagnosis' own augmented model, and the bundle reader."""
from __future__ import annotations

import json
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave

from motiontwin.harness import measurement
from motiontwin.harness.fmu_instance import extracted_fmu
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.benchmarks.truth import truth_fmus
from motiontwin.ident.diagnosis.bundle import read_bundle


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("benchmark-fmus")


@pytest.fixture(scope="module")
def loop(fmu_dir) -> dict:
    """A 2 s Coulomb-friction run (plus the pre-roll) through controller, plant and encoder FMUs."""
    rng = np.random.default_rng(3)
    t, r, u_ext = bench.reference(2.0, rng, 0.1, 0.5)
    r, u_ext, _ = bench.with_preroll(r, u_ext)
    noise = measurement.add_noise(np.zeros(r.size), bench.NOISE, rng)
    plant = bench.truth_plant("coulomb_friction")
    out = bench.cosimulate(plant, r, u_ext, noise, fmu_dir=fmu_dir)
    return {"plant": plant, "noise": noise, **out}


def _fmpy_plant(path: Path, parameters: dict[str, float], u: np.ndarray, ts: float) -> np.ndarray:
    """Position of the plant FMU at k*ts driven by u held over each ts (fmpy's FMI 2.0 API, no harness)."""
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipdir = extracted_fmu(path)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="reference")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.setReal([vr[k] for k in parameters], list(parameters.values()))
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    q = np.empty(u.size)
    for k, force in enumerate(u):
        q[k] = slave.getReal([vr["q"]])[0]
        slave.setReal([vr["u"]], [float(force)])
        slave.doStep(k * ts, ts)
    slave.terminate()
    slave.freeInstance()
    return q


def test_recorded_position_is_the_plant_fmu_driven_by_the_recorded_force(loop, fmu_dir):
    path = truth_fmus([loop["plant"].class_name], fmu_dir)[loop["plant"].class_name]
    q_ref = _fmpy_plant(path, loop["plant"].parameters, loop["u"], bench.TS)
    assert np.max(np.abs(q_ref - loop["q_true"])) < 1e-11          # integrator tolerance, not the noise
    assert np.max(np.abs(q_ref - loop["q"]) - np.abs(loop["noise"])) <= bench.RESOLUTION / 2 + 1e-11
    assert np.max(np.abs(loop["q_true"] - loop["r"])) > 1e-6      # the loop actually moved the axis


def test_measurement_is_quantised_noisy_and_read_by_the_controller(loop):
    expected = measurement.quantize(loop["q_true"] + loop["noise"], bench.RESOLUTION)
    assert np.array_equal(loop["q"], expected)
    ctrl = bench.pid_controller()

    def control_law(position: np.ndarray) -> np.ndarray:
        z, u = np.zeros(ctrl.n_states), np.empty(position.size)
        for k in range(position.size):
            y = np.array([loop["r"][k], position[k]])
            u[k] = (ctrl.C @ z + ctrl.D @ y).item() + loop["u_ext"][k]
            z = ctrl.A @ z + ctrl.B @ y
        return u
    assert np.max(np.abs(control_law(loop["q"]) - loop["u"])) < 1e-8
    # reading the true position instead would change the force by D*noise, about 6 mN
    assert np.max(np.abs(control_law(loop["q_true"]) - loop["u"])) > 1e-3


def test_bundle_contract_and_truth_sidecar(tmp_path, fmu_dir):
    folder = tmp_path / "bundles" / "two_effects"
    truth = bench.write_bundle(folder, "two_effects", seed=5, scale=1.2, durations=(2.0, 1.0), fmu_dir=fmu_dir)
    bundle = read_bundle(folder)
    assert bundle.experiment["plant"] == {"modelica": "plant.mo", "class": "LinearAxis", "input": "u", "output": "q"}
    assert np.allclose(bundle.controller.A, bench.pid_controller().A)
    for part, n in (("train", 4000), ("validation", 2000)):
        rec = getattr(bundle, part)
        assert rec.time.size == n and np.allclose(np.diff(rec.time), bench.TS)
        assert set(rec.columns) >= {"r", "u", "q", "u_ext"}
        counts = rec["q"] / bench.RESOLUTION
        assert np.max(np.abs(counts - np.round(counts))) < 1e-6     # on the encoder grid
        assert abs(rec["u"][0] - truth["truth_model"]["parameters"]["F0"]) < 0.6   # at rest: holds F0 + ripple
    saved = json.loads((folder.parent / "two_effects.truth.json").read_text())
    assert [e["name"] for e in saved["effects"]] == ["gravity_offset", "position_ripple"]
    assert saved["effects"][0]["contract"]["F0"] == pytest.approx(1.2)
    assert saved["effects"][1]["contract"]["amplitude"] == pytest.approx(1.2 * np.hypot(0.4, 0.2))
    assert 0 < saved["concealment"]["max_abs_m"] < 10e-6           # concealed: a few micrometres at most


def test_fmu_truth_equals_casadi_simulation_of_the_augmented_model(fmu_dir):
    result = bench.verify("time_delay", seed=4, duration=3.0, fmu_dir=fmu_dir)
    assert result["max_abs_m"] < 1e-3 * bench.NOISE                 # far below the encoder noise
    assert result["max_q_m"] > 0.01
