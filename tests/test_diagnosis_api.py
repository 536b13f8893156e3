"""The in-memory diagnosis API (issue 13/14): ``diagnose(plant, controller, train, validation)`` on Modelica text
or a file, a controller object or its JSON, and harness Recording objects; re-entrant.

Reference: the same call made once in a fresh state; a second call in the same process and two concurrent calls
from threads must reproduce its effects and parameters (the loops are compiled per call, no module cache), and
the concealed gravity offset of the generated bundle (its truth sidecar) must be the effect found.
"""
from __future__ import annotations

import concurrent.futures
import json
from pathlib import Path

import pytest

from motiontwin.harness.recording import read_recording
from motiontwin.ident.controller import load_controller
from motiontwin.ident.diagnosis import BundleError, Diagnosis, diagnose
from motiontwin.ident.benchmarks import single_axis as bench


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("api") / "gravity"
    bench.write_bundle(folder, "gravity_offset", seed=31, durations=(2.0, 1.0), engine="casadi")
    truth = json.loads((folder.parent / "gravity.truth.json").read_text())
    return {"folder": folder, "truth": truth, "text": (folder / "plant.mo").read_text(),
            "controller": json.loads((folder / "experiment.json").read_text())["controller"],
            "train": read_recording(folder / "train.csv"), "validation": read_recording(folder / "validation.csv")}


@pytest.fixture(scope="module")
def first(inputs) -> Diagnosis:
    return diagnose(inputs["text"], inputs["controller"], inputs["train"], inputs["validation"])


def _same(a: Diagnosis, b: Diagnosis) -> None:
    assert a.effects == b.effects
    assert a.parameters.keys() == b.parameters.keys()
    for name, value in a.parameters.items():
        assert b.parameters[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name
    assert b.validation["augmented_rms"] == pytest.approx(a.validation["augmented_rms"], rel=1e-9)


def test_finds_the_concealed_effect(first, inputs):
    assert first.effects == ["gravity_offset"]
    f0 = inputs["truth"]["effects"][0]["parameters"]["gravity_F0"]
    assert first.parameters["gravity_F0"] == pytest.approx(f0, rel=0.05)
    assert first.parameters["m"] == pytest.approx(bench.TRUE_M, rel=0.02)
    assert first.validation["augmented_rms"] < 0.5 * first.validation["nominal_rms"]


def test_second_call_and_file_and_controller_object_give_the_same(first, inputs):
    again = diagnose(inputs["folder"] / "plant.mo", load_controller(inputs["folder"] / "experiment.json"),
                     inputs["train"], inputs["validation"], plant_class=bench.PLANT_CLASS)
    _same(first, again)


def test_two_threads_give_the_same_as_one(first, inputs):
    args = (inputs["text"], inputs["controller"], inputs["train"], inputs["validation"])
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda _: diagnose(*args), range(2)))
    for result in results:
        _same(first, result)


def test_write_publishes_report_and_fmu(first, tmp_path):
    doc = first.write(tmp_path / "out")
    assert [e["name"] for e in doc["effects"]] == first.effects
    saved = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert saved["augmented_parameters"]["gravity_F0"] == pytest.approx(first.parameters["gravity_F0"], rel=1e-12)
    assert Path(saved["augmented_fmu"]).is_file() and (tmp_path / "out" / "report.md").is_file()
    assert Path(saved["augmented_model"]).is_file()


def test_bad_in_memory_input_names_the_field(inputs):
    train = inputs["train"]
    with pytest.raises(BundleError, match="neither a Modelica file nor Modelica source"):
        diagnose("no_such_plant.mo", inputs["controller"], train, inputs["validation"])
    with pytest.raises(BundleError, match="'parameters.mass'|no parameter 'mass'"):
        diagnose(inputs["text"], inputs["controller"], train, inputs["validation"], parameters={"mass": 2.0})


class _Stop(Exception):
    pass


def test_a_diagnosis_called_from_python_runs_one_blas_thread(inputs, monkeypatch):
    """Called from Python (not through the command, which sets the variables before numpy loads), the diagnosis
    still runs one BLAS thread, and the caller's setting is back afterwards; a thread count the user set in the
    environment is kept. Reference: threadpoolctl's report of the loaded BLAS libraries."""
    import threadpoolctl

    def blas_threads() -> int:
        return max(p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas")

    def stop(line: str) -> None:
        seen.append(blas_threads())
        raise _Stop

    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        seen: list[int] = []
        with pytest.raises(_Stop):
            diagnose(inputs["text"], inputs["controller"], inputs["train"], inputs["validation"], progress=stop)
        assert seen == [1] and blas_threads() == 2
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
        seen.clear()
        with pytest.raises(_Stop):
            diagnose(inputs["text"], inputs["controller"], inputs["train"], inputs["validation"], progress=stop)
        assert seen == [2]
