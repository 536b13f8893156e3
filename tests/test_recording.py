"""The recording format: CSV + JSON sidecar and MATLAB .mat round trips, validation errors, atomic writes.

References: the written arrays themselves (round trips must be bit-exact), scipy.io.loadmat and the csv/json
modules reading our files independently, and hand-made bad files with a known faulty row and column.
"""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest
import scipy.io

from motiontwin.harness import recording as rc


def sample_recording(n: int = 200) -> rc.Recording:
    rng = np.random.default_rng(0)
    time = np.arange(n) * 5e-4
    return rc.make_recording(
        time,
        {
            "r": 1e-3 * np.sin(2 * np.pi * 3 * time),
            "u": rng.normal(0, 1.7, n),
            "q": 1e-3 * np.sin(2 * np.pi * 3 * time) + rng.normal(0, 1e-7, n) + 1 / 3,
            "u_ext": np.zeros(n),
        },
        sample_time=5e-4,
        excited="swept sine 80-500 Hz on u_ext",
        fmus=["plant", "controller"],
        parameters={"plant": {"m": 1.25, "d": 0.1}, "controller": {"Kp": 3e4}},
        seed=42,
        metadata={"operator": "test", "position_mm": [10, 20]},
    )


def assert_same(a: rc.Recording, b: rc.Recording) -> None:
    assert a.names == b.names
    for name in a.names:
        assert np.array_equal(a[name], b[name]), name
    assert a.units == b.units
    assert a.meta == b.meta


def test_csv_json_round_trip_is_exact(tmp_path):
    rec = sample_recording()
    csv_path, json_path = rc.write_recording(tmp_path / "run.csv", rec)
    assert json_path == tmp_path / "run.json"
    assert_same(rc.read_recording(csv_path, required=("time", "r", "u", "q")), rec)


def test_written_files_are_plain_csv_and_documented_json(tmp_path):
    rec = sample_recording(20)
    rc.write_recording(tmp_path / "run.csv", rec)
    with open(tmp_path / "run.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["time", "r", "u", "q", "u_ext"]
    assert np.array_equal(np.array(rows[1:], dtype=float)[:, 3], rec["q"])
    doc = json.loads((tmp_path / "run.json").read_text())
    assert doc["format"] == "motiontwin-recording" and doc["version"] == 1
    assert doc["columns"] == rows[0]
    assert doc["units"] == {"time": "s", "r": "m", "u": "N", "q": "m", "u_ext": "N"}
    assert doc["sample_time"] == 5e-4 and doc["seed"] == 42
    assert doc["fmus"] == ["plant", "controller"]
    assert doc["parameters"]["plant"]["m"] == 1.25
    assert doc["excited"] == "swept sine 80-500 Hz on u_ext"


def test_csv_without_sidecar_reads_with_default_units(tmp_path):
    path = tmp_path / "train.csv"
    path.write_text("time,r,u,q\n0,0,0,0\n0.0005,1e-6,0.5,2e-7\n0.001,2e-6,0.25,9e-7\n")
    rec = rc.read_recording(path, required=("time", "r", "u", "q"))
    assert rec.units == {"time": "s", "r": "m", "u": "N", "q": "m"}
    np.testing.assert_array_equal(rec["u"], [0, 0.5, 0.25])
    assert rec.sample_time is None and rec.meta["fmus"] == []


def test_mat_round_trip_is_exact_and_layout_documented(tmp_path):
    rec = sample_recording()
    path = rc.write_mat(tmp_path / "run.mat", rec)
    assert_same(rc.read_mat(path), rec)
    raw = scipy.io.loadmat(path, simplify_cells=True)
    assert list(raw["names"]) == ["r", "u", "q", "u_ext"]
    assert raw["data"].shape == (200, 4)
    assert np.array_equal(raw["data"][:, 2], rec["q"])
    assert np.array_equal(raw["time"], rec.time)
    assert json.loads(raw["meta_json"])["seed"] == 42


def test_foreign_lab_mat_files(tmp_path):
    t = np.arange(50) * 1e-3
    flat = tmp_path / "lab.mat"
    scipy.io.savemat(flat, {"t": t, "pos": np.sin(t), "force": np.cos(t), "gain": 3.0})
    rec = rc.read_mat(flat, required=("time", "q", "u"), rename={"pos": "q", "force": "u"})
    assert np.array_equal(rec.time, t) and np.array_equal(rec["q"], np.sin(t))
    assert rec.names == ["time", "q", "u"] and rec.units["q"] == "m"
    nested = tmp_path / "struct.mat"
    scipy.io.savemat(nested, {"run1": {"time": t, "q": t**2}})
    assert np.array_equal(rc.read_mat(nested)["q"], t**2)
    short = tmp_path / "short.mat"
    scipy.io.savemat(short, {"time": t, "q": t[:-1]})
    with pytest.raises(rc.RecordingError, match="'q' has 49 samples, time has 50"):
        rc.read_mat(short)


BAD_FILES = [
    # (csv text, required columns, expected fragments of the message)
    ("time,r,u\n0,0,0\n0.001,0,0\n", ("time", "r", "u", "q"), ["row 1", "'q'", "missing"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,0,0\n0.002,0,nan,0\n0.003,0,0,0\n", (), ["row 4", "'u'", "NaN"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,0,0\n0.002,0,0,0\n0.002,0,0,0\n", (), ["row 5", "'time'", "increasing"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,0,0\n0.002,0,0,0\n0.0015,0,0,0\n", (), ["row 5", "'time'"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,abc,0\n", (), ["row 3", "'u'", "'abc' is not a number"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,,0\n", (), ["row 3", "'u'", "is not a number"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,0\n", (), ["row 3", "3 fields", "header has 4"]),
    ("time,r,u,q\n0,0,0,0\n0.001,0,inf,0\n", (), ["row 3", "'u'", "not finite"]),
    ("r,u,q\n0,0,0\n", (), ["row 1", "'time'", "missing"]),
    ("time,q,q\n0,0,0\n", (), ["row 1", "'q'", "duplicate"]),
    ("", (), ["row 1", "empty file"]),
]


@pytest.mark.parametrize("text,required,fragments", BAD_FILES)
def test_bad_csv_names_file_row_and_column(tmp_path, text, required, fragments):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(rc.RecordingError) as info:
        rc.read_recording(path, required=required)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


@pytest.mark.parametrize(
    "text,fragments",
    [
        # inf in 'u' on line 3 comes before NaN in 'q' on line 5
        ("time,u,q\n0,0,0\n1,inf,0\n2,0,0\n3,0,nan\n", ["row 3", "'u'"]),
        # time going back on line 3 comes before the text on line 4
        ("time,u,q\n0,0,0\n-1,0,0\n2,x,0\n", ["row 3", "'time'"]),
        # inf in 'q' on line 3 comes before NaN in 'u' (an earlier column) on line 4
        ("time,u,q\n0,0,0\n1,0,inf\n2,nan,0\n", ["row 3", "'q'"]),
        # time going back on line 4 comes before NaN in 'u' on line 5
        ("time,u,q\n0,0,0\n1,0,0\n0.5,0,0\n2,nan,0\n", ["row 4", "'time'"]),
        # on the same line the left-most column is reported
        ("time,u,q\n0,0,0\n1,nan,nan\n", ["row 3", "'u'", "NaN"]),
    ],
)
def test_first_problem_in_file_order_is_reported(tmp_path, text, fragments):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(rc.RecordingError) as info:
        rc.read_recording(path)
    for fragment in fragments:
        assert fragment in str(info.value), (fragment, str(info.value))


def test_fmu_details_round_trip(tmp_path):
    fmus = {"plant": {"path": "fmus/plant.fmu", "step": 5e-4, "parameters": {"m": 2.0}}, "ctrl": {"path": "c.fmu"}}
    rec = rc.make_recording([0.0, 1.0], {"q": [0.0, 1.0]}, fmus=fmus)
    rc.write_recording(tmp_path / "run.csv", rec)
    rc.write_mat(tmp_path / "run.mat", rec)
    assert rc.read_recording(tmp_path / "run.csv").meta["fmus"] == fmus
    assert rc.read_mat(tmp_path / "run.mat").meta["fmus"] == fmus


def test_bad_sidecar_is_reported(tmp_path):
    rc.write_recording(tmp_path / "run.csv", sample_recording(10))
    side = tmp_path / "run.json"
    doc = json.loads(side.read_text())
    doc["columns"] = ["time", "r", "u", "q"]
    side.write_text(json.dumps(doc))
    with pytest.raises(rc.RecordingError, match="field 'columns'.*does not match"):
        rc.read_recording(tmp_path / "run.csv")
    side.write_text('{\n  "units": {,\n}')
    with pytest.raises(rc.RecordingError, match=r"run.json, line 2, column 13: invalid JSON"):
        rc.read_recording(tmp_path / "run.csv")


def test_sample_time_mismatch_names_row(tmp_path):
    rec = sample_recording(10)
    rc.write_recording(tmp_path / "run.csv", rec)
    lines = (tmp_path / "run.csv").read_text().splitlines()
    lines.pop(6)  # drop the sample on line 7: the step from line 6 to the new line 7 doubles
    (tmp_path / "run.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(rc.RecordingError, match="row 7, column 'time'.*differs from sample_time"):
        rc.read_recording(tmp_path / "run.csv")


def test_invalid_recording_is_not_written(tmp_path):
    rec = sample_recording(10)
    rec.columns["q"][3] = np.nan
    with pytest.raises(rc.RecordingError, match="row 5, column 'q'"):
        rc.write_recording(tmp_path / "run.csv", rec)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_no_partial_file(tmp_path):
    rec = sample_recording(10)
    rec.meta["metadata"] = {"not_json": object()}
    with pytest.raises(TypeError):
        rc.write_recording(tmp_path / "run.csv", rec)
    assert list(tmp_path.iterdir()) == []


def test_failed_second_replace_restores_previous_pair(tmp_path, monkeypatch):
    old = sample_recording(10)
    rc.write_recording(tmp_path / "run.csv", old)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    new = sample_recording(30)
    real_replace = os.replace
    calls = []

    def failing_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise OSError("disk full")
        return real_replace(src, dst)

    monkeypatch.setattr(rc.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        rc.write_recording(tmp_path / "run.csv", new)
    monkeypatch.setattr(rc.os, "replace", real_replace)
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert after == before  # the old pair intact, no temporary or backup files left
    assert_same(rc.read_recording(tmp_path / "run.csv"), old)


def test_failed_first_write_of_new_pair_leaves_nothing(tmp_path, monkeypatch):
    real_replace = os.replace
    calls = []

    def failing_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise OSError("disk full")
        return real_replace(src, dst)

    monkeypatch.setattr(rc.os, "replace", failing_replace)
    with pytest.raises(OSError):
        rc.write_recording(tmp_path / "run.csv", sample_recording(10))
    assert list(tmp_path.iterdir()) == []


def test_make_recording_rejects_bad_shapes_and_time():
    with pytest.raises(rc.RecordingError, match="column 'q' has shape"):
        rc.make_recording([0, 1, 2], {"q": [0, 1]})
    with pytest.raises(rc.RecordingError, match="row 4, column 'time'"):
        rc.make_recording([0, 1, 1], {"q": [0, 1, 2]})
    with pytest.raises(KeyError, match="no column 'x'"):
        rc.make_recording([0, 1], {"q": [0, 1]})["x"]
