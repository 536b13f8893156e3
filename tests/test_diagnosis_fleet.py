"""A fleet of diagnoses (issue 25, item 4): ``motiontwin diagnose`` on a folder of bundles (in-process) and on a
list of bundles (Dask LocalCluster, 2 workers) gives, per bundle, what a single ``motiontwin diagnose BUNDLE``
gives (the reference: effects, parameters, validation RMS and prediction, the output files); the broken bundle
is recorded with its message while the others finish; the summary rows match the single runs; ``--resume``
keeps the committed bundles and diagnoses only the failed one.

Two short parameters-only bundles (0.5 s + 0.25 s at 2 kHz, different seeds, so a swap of results between
bundles is seen) and a copy of the first with a NaN in its training recording.
"""
from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from motiontwin.cli import main
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.diagnosis import fleet

GOOD = {"axis_a": 41, "axis_b": 42}   # bundle name -> seed
DURATIONS = (0.5, 0.25)


@pytest.fixture(scope="module")
def bundles(tmp_path_factory) -> Path:
    """A folder of three bundles (the generator also writes NAME.truth.json files beside them)."""
    root = tmp_path_factory.mktemp("fleet") / "bundles"
    for name, seed in GOOD.items():
        bench.write_bundle(root / name, "params_only_a", seed=seed, durations=DURATIONS, engine="casadi")
    broken = root / "broken"
    shutil.copytree(root / "axis_a", broken)
    lines = (broken / "train.csv").read_text().splitlines()
    cells = lines[5].split(",")
    cells[3] = "nan"
    lines[5] = ",".join(cells)
    (broken / "train.csv").write_text("\n".join(lines) + "\n")
    (broken / "train.json").unlink(missing_ok=True)
    return root


@pytest.fixture(scope="module")
def singles(bundles, tmp_path_factory) -> dict[str, Path]:
    """The reference: each good bundle through ``motiontwin diagnose BUNDLE --out DIR``."""
    out = tmp_path_factory.mktemp("singles")
    for name in GOOD:
        assert main(["diagnose", str(bundles / name), "--out", str(out / name), "--quiet"]) == 0
    return {name: out / name for name in GOOD}


@pytest.fixture(scope="module")
def inprocess(bundles, tmp_path_factory) -> tuple[Path, int]:
    out = tmp_path_factory.mktemp("inprocess") / "fleet"
    return out, main(["diagnose", str(bundles), "--out", str(out), "--quiet"])


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


def _same_diagnosis(got: Path, expected: Path) -> None:
    """The same effects, parameters, validation RMS and validation prediction (1e-9), and the same files."""
    a = json.loads((got / "diagnosis.json").read_text())
    b = json.loads((expected / "diagnosis.json").read_text())
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]]
    for key in ("nominal_parameters", "augmented_parameters"):
        assert a[key].keys() == b[key].keys()
        for name, value in b[key].items():
            assert a[key][name] == pytest.approx(value, rel=1e-9, abs=1e-15), (key, name)
    for name, value in b["validation"].items():    # None: a figure not computed (the estimation error below the floor)
        assert a["validation"][name] == (None if value is None else pytest.approx(value, rel=1e-9)), name
    np.testing.assert_allclose(np.loadtxt(got / "validation_prediction.csv", delimiter=",", skiprows=1),
                               np.loadtxt(expected / "validation_prediction.csv", delimiter=",", skiprows=1),
                               rtol=1e-9, atol=0)
    assert _files(got) == _files(expected)


def _summary(out: Path) -> dict[str, dict[str, str]]:
    with open(out / "summary.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == list(fleet.SUMMARY_COLUMNS)
    return {row["bundle"]: row for row in rows}


def _check_fleet(out: Path, singles: dict[str, Path]) -> None:
    for name, reference in singles.items():
        _same_diagnosis(out / name, reference)
    manifest = json.loads((out / fleet.MANIFEST).read_text())
    assert manifest["status"] == "failed" and manifest["planned"] == 3
    assert [row["bundle"] for row in manifest["bundles"]] == sorted(GOOD)
    for row in manifest["bundles"]:   # every committed file has the recorded size and checksum
        for rel, record in row["files"].items():
            data = (out / rel).read_bytes()
            assert (len(data), hashlib.sha256(data).hexdigest()) == (record["bytes"], record["sha256"])
    [failure] = manifest["failed"]
    assert failure["bundle"] == "broken" and "train.csv" in failure["error"] and "NaN" in failure["error"]
    assert not (out / "broken").exists()
    rows = _summary(out)
    assert sorted(rows) == ["axis_a", "axis_b", "broken"]
    assert rows["broken"]["status"] == "failed" and "NaN" in rows["broken"]["error"]
    for name, reference in singles.items():
        doc = json.loads((reference / "diagnosis.json").read_text())
        row = rows[name]
        assert row["status"] == "ok" and row["error"] == ""
        assert row["effects"] == ";".join(e["name"] for e in doc["effects"])
        assert row["verdict"] == ("missing physics named" if doc["effects"] else "parameters only")
        nominal, augmented = doc["validation"]["nominal_rms"], doc["validation"]["augmented_rms"]
        assert float(row["nominal_rms_m"]) == pytest.approx(nominal, rel=1e-5)
        assert float(row["augmented_rms_m"]) == pytest.approx(augmented, rel=1e-5)
        assert float(row["validation_gain"]) == pytest.approx(nominal / augmented, rel=1e-5)
        assert float(row["seconds"]) > 0
    page = (out / "summary.html").read_text()
    assert page.count("<tr>") == 4 and "train.csv" in page


def test_folder_of_bundles_in_process_equals_single_runs(bundles, singles, inprocess):
    out, code = inprocess
    assert code == 1   # the broken bundle failed, the others were diagnosed
    _check_fleet(out, singles)
    assert not any(p.name.endswith(".truth.json") for p in out.iterdir())


def test_list_of_bundles_on_dask_equals_single_runs(bundles, singles, tmp_path, capsys):
    out = tmp_path / "fleet"
    paths = [str(bundles / name) for name in ("broken", *GOOD)]
    assert main(["diagnose", *paths, "--out", str(out), "--executor", "dask", "--workers", "2", "--quiet"]) == 1
    assert "1 bundle(s) failed: broken" in capsys.readouterr().err
    _check_fleet(out, singles)
    assert json.loads((out / fleet.MANIFEST).read_text())["executor"] == "dask"


def test_resume_keeps_committed_bundles(bundles, inprocess, tmp_path):
    out = tmp_path / "fleet"
    shutil.copytree(inprocess[0], out)
    before = {name: (out / name / "diagnosis.json").stat().st_mtime_ns for name in GOOD}
    lines: list[str] = []
    with pytest.raises(fleet.FleetError, match="holds a fleet .* pass --resume"):
        fleet.run_fleet([bundles], out, log=lines.append)
    outcome = fleet.run_fleet([bundles], out, resume=True, log=lines.append)
    assert sorted(outcome.resumed) == sorted(GOOD) and outcome.completed == []
    assert list(outcome.failed) == ["broken"]
    assert "3 bundles: 2 diagnosed earlier, 1 to diagnose (inprocess)" in lines
    assert {name: (out / name / "diagnosis.json").stat().st_mtime_ns for name in GOOD} == before
    assert sorted(_summary(out)) == ["axis_a", "axis_b", "broken"]
    # what resume would diagnose again: a committed output file changed, or the bundle's own files changed
    row = next(r for r in json.loads((out / fleet.MANIFEST).read_text())["bundles"] if r["bundle"] == "axis_b")
    hashes = {"axis_b": fleet.bundle_sha256(bundles / "axis_b")}
    assert fleet._kept(out, hashes, row) is None
    report = out / "axis_b" / "report.md"
    report.write_text(report.read_text()[:-10])
    assert fleet._kept(out, hashes, row) == f"axis_b/report.md is truncated ({report.stat().st_size} bytes, " \
                                             f"{row['files']['axis_b/report.md']['bytes']} committed)"
    assert fleet._kept(out, {"axis_b": fleet.bundle_sha256(bundles / "axis_a")}, row) == \
        "its bundle's files changed since it was diagnosed"


def test_bad_fleet_arguments_name_the_path_or_option(bundles, tmp_path, capsys):
    assert main(["diagnose", str(bundles / "axis_a"), "--out", str(tmp_path / "o"), "--resume"]) == 1
    assert "--resume: options of a fleet" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(fleet.FleetError, match=f"{empty}: neither a bundle"):
        fleet.find_bundles([bundles, empty])
    twin = tmp_path / "elsewhere" / "axis_a"
    shutil.copytree(bundles / "axis_a", twin)
    with pytest.raises(fleet.FleetError, match="two bundles named 'axis_a'"):
        fleet.find_bundles([bundles, twin])
    assert fleet.is_fleet([bundles]) and not fleet.is_fleet([bundles / "axis_a"])


def test_sigterm_marks_the_fleet_interrupted_and_leaves_no_temporary_files(bundles, tmp_path):
    """A real fleet sent SIGTERM during its diagnoses: exit 143, the resume hint, the manifest and summary
    written with status "interrupted", no staging folder or uncommitted bundle left."""
    out = tmp_path / "fleet"
    proc = subprocess.Popen([sys.executable, "-m", "motiontwin", "diagnose", str(bundles), "--out", str(out),
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / fleet.MANIFEST).exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(2.0)
    assert proc.poll() is None, "the fleet ended too early"
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].endswith("(add --resume to continue)") and "Traceback" not in err
    manifest = json.loads((out / fleet.MANIFEST).read_text())
    assert manifest["status"] == "interrupted"
    committed = [row["bundle"] for row in manifest["bundles"]]
    assert len(committed) < len(GOOD)   # stopped before the end
    # what is there is committed: a bundle's folder only with its manifest row (a diagnosis that finished
    # just before the signal may be), and no staging folder
    assert sorted(p.name for p in out.iterdir()) == sorted([fleet.MANIFEST, "summary.csv", "summary.html",
                                                            *committed])
    for row in manifest["bundles"]:
        assert _files(out / row["bundle"]) == {rel.split("/", 1)[1] for rel in row["files"]}


def test_a_diagnosis_finished_but_not_committed_when_stopped_is_removed(bundles, tmp_path):
    """Stopped after a bundle's diagnosis wrote its folder and before the fleet recorded it (the signal lands
    between the two): the folder is removed, the manifest says "interrupted" and lists nothing."""
    from motiontwin.harness.executor import InProcessExecutor
    from motiontwin.harness.interrupt import Terminated

    class StoppedAfterTheRun(InProcessExecutor):
        def imap(self, fn, items, retries=2):
            fn(items[0])
            raise Terminated

    out = tmp_path / "fleet"
    with pytest.raises(Terminated):
        fleet.run_fleet([bundles / "axis_b"], out, StoppedAfterTheRun(), log=lambda line: None)
    manifest = json.loads((out / fleet.MANIFEST).read_text())
    assert manifest["status"] == "interrupted" and manifest["bundles"] == []
    assert sorted(p.name for p in out.iterdir()) == [fleet.MANIFEST, "summary.csv", "summary.html"]
