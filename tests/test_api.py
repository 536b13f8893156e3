"""The Python API (``motiontwin.build_fmu``, ``simulate``, ``identify_*``, ``Recording``): the examples of the
docs page ``docs/python-api.md`` (moved there from the README) run as they stand, and their results match the
values the data were made from (the truth compiled into the FMU, the coefficients of the synthetic joint and
swept-sine data). Recordings round-trip through CSV and MAT."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import motiontwin
from motiontwin.harness.recording import RecordingError

ROOT = Path(__file__).resolve().parents[1]


def docs_python_blocks() -> list[str]:
    """The ```python blocks of the docs page "Python API" (docs/python-api.md), in order."""
    text = (ROOT / "docs" / "python-api.md").read_text(encoding="utf-8")
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


@pytest.fixture
def in_tmp(tmp_path: Path):
    """Run in an empty folder (the examples write build/api/...)."""
    before = Path.cwd()
    os.chdir(tmp_path)
    try:
        yield tmp_path
    finally:
        os.chdir(before)


def test_docs_example_builds_simulates_and_refits_the_compiled_truth(in_tmp: Path) -> None:
    """Block 1: FMU built with m = 1.5, d = 8 -> simulated in Python -> CSV -> output-error refit from the
    library defaults (2, 10) gives back the compiled values; the written JSON holds them."""
    blocks = docs_python_blocks()
    assert len(blocks) == 2
    namespace: dict = {}
    exec(compile(blocks[0], "docs/python-api.md: block 1", "exec"), namespace)
    rec, oe = namespace["rec"], namespace["oe"]
    assert rec.names == ["time", "plant.u", "plant.q"] and rec.units["plant.q"] == "m" and rec.sample_time == 1e-3
    assert oe.parameters == pytest.approx({"m": 1.5, "d": 8.0}, rel=1e-6)
    assert oe.detail.fit.rms_q < 1e-9
    written = (in_tmp / "build" / "api" / "oe.json").read_text()
    assert json.loads(written)["parameters"] == pytest.approx({"m": 1.5, "d": 8.0}, rel=1e-6)
    assert (in_tmp / "build" / "api" / "run.json").is_file()
    # the recording: m q'' + d q' = u from rest, integrated independently of the FMU (scipy)
    from scipy.integrate import solve_ivp

    t = rec["time"]
    u = namespace["force"]
    held = lambda time: u[min(int(time / 1e-3 + 1e-9), u.size - 1)]  # noqa: E731  zero-order hold of the input
    reference = solve_ivp(lambda time, x: [x[1], (held(time) - 8.0 * x[1]) / 1.5], (0, 3.0), [0.0, 0.0],
                          t_eval=t, max_step=1e-4, rtol=1e-10, atol=1e-13).y[0]
    assert np.max(np.abs(rec["plant.q"] - reference)) < 1e-6 * np.max(np.abs(reference))


def test_docs_example_identifies_a_joint_and_a_frequency_response(in_tmp: Path) -> None:
    """Block 2: the inverse-dynamics fit gives the 1.5 kg and 8 N.s/m the force was computed with; the FRF fit
    gives Cheung's K = 50 and the 220 Hz / 150 Hz resonance pair of the simulated model."""
    namespace: dict = {}
    exec(compile(docs_python_blocks()[1], "docs/python-api.md: block 2", "exec"), namespace)
    joint, frf, w = namespace["joint"], namespace["frf"], 2 * np.pi
    assert joint.parameters == pytest.approx({"J": 1.5, "fv": 8.0}, rel=1e-9)
    assert set(joint.std) == {"J", "fv"} and joint.detail.fit.names == ["J", "fv"]
    assert frf.parameters["K"] == pytest.approx(50.0, rel=0.01)
    assert frf.parameters["omega"] / w == pytest.approx(220.0, rel=0.01)
    assert frf.parameters["omega_bar"] / w == pytest.approx(150.0, rel=0.01)


def test_simulate_a_system_file_equals_the_same_system_as_a_dict(tmp_path: Path) -> None:
    """A TOML system file and its dict give the same recording; the file's folder resolves the FMU path."""
    fmu = motiontwin.build_fmu("MotionTwin.Plants.LinearMotorJoint", tmp_path / "fmus", "2.0")
    (tmp_path / "joint.toml").write_text(
        'base_step = 1e-3\nstop_time = 0.5\n[fmus.plant]\npath = "fmus/fmi2/LinearMotorJoint.fmu"\n'
        '[inputs.u]\nunit = "N"\ndefault = 3.0\n[[connections]]\nfrom = "input.u"\nto = "plant.u"\n'
        '[[log]]\nsignals = ["plant.q"]\n')
    from_file = motiontwin.simulate(tmp_path / "joint.toml")
    from_dict = motiontwin.simulate({"base_step": 1e-3, "fmus": {"plant": {"path": str(fmu)}},
                                     "inputs": {"u": {"unit": "N", "default": 3.0}},
                                     "connections": [{"from": "input.u", "to": "plant.u"}],
                                     "log": [{"signals": ["plant.q"]}]}, stop_time=0.5)
    np.testing.assert_array_equal(from_file["plant.q"], from_dict["plant.q"])
    t = from_file["time"]  # closed form of 2 q'' = 3 - 10 q' from rest
    np.testing.assert_allclose(from_file["plant.q"], 0.3 * (t - 0.2 * (1 - np.exp(-5 * t))), atol=1e-9)


def test_recording_round_trips_through_csv_and_mat_and_renames(tmp_path: Path) -> None:
    rec = motiontwin.make_recording(np.arange(5) * 0.5, {"q": [0.0, 1e-3, 2e-3, 1.5e-3, 1e-3], "u": [1, 2, 3, 4, 5]},
                                    sample_time=0.5, seed=7)
    rec.to_csv(tmp_path / "r.csv")
    rec.to_mat(tmp_path / "r.mat")
    for back in (motiontwin.Recording.from_csv(tmp_path / "r.csv"), motiontwin.Recording.from_mat(tmp_path / "r.mat")):
        assert back.names == rec.names and back.units == rec.units and back.meta["seed"] == 7
        np.testing.assert_array_equal(back["q"], rec["q"])
    renamed = rec.renamed({"q": "position"})
    assert renamed.names == ["time", "position", "u"] and renamed.units["position"] == "m"
    with pytest.raises(KeyError, match="no column 'x'"):
        rec.renamed({"x": "y"})
    with pytest.raises(RecordingError, match="r.csv.*'force'"):
        motiontwin.Recording.from_csv(tmp_path / "r.csv", required=("time", "force"))


def test_recording_to_pandas() -> None:
    rec = motiontwin.make_recording([0.0, 0.1], {"q": [0.0, 1.0]})
    try:
        import pandas  # noqa: F401  (only whether it is installed)
    except ImportError:
        with pytest.raises(ImportError, match="pip install pandas"):
            rec.to_pandas()
        return
    frame = rec.to_pandas()
    assert list(frame.columns) == ["q"] and frame.index.name == "time" and frame.attrs["units"]["q"] == "m"


def test_import_motiontwin_is_lazy_and_names_resolve() -> None:
    """``import motiontwin`` loads no library layer and no numpy; every public name resolves on use and has a
    numpy-style docstring; ``diagnose`` is reserved (not there yet)."""
    code = "import sys, motiontwin; print(sorted(m for m in sys.modules if m.startswith(('motiontwin', 'numpy'))))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                            timeout=300).stdout
    assert loaded.strip() == "['motiontwin']"
    for name in motiontwin.__all__:
        assert getattr(motiontwin, name) is not None
    for function in (motiontwin.build_fmu, motiontwin.simulate, motiontwin.identify_joint, motiontwin.identify_oe,
                     motiontwin.identify_frf):
        assert "Parameters\n    ----------" in function.__doc__ and "Returns\n    -------" in function.__doc__
    with pytest.raises(AttributeError, match="no attribute 'diagnose'"):
        motiontwin.diagnose  # noqa: B018
