"""Tolerance-tube regression checks: tube bounds against a brute-force envelope, perturbations and
time shifts, JUnit XML read back with xml.etree, and a suite run end to end on real FMUs."""
from __future__ import annotations

import hashlib
import json
import re
import struct
import time
import zipfile
import xml.etree.ElementTree as ET
from pathlib import Path

import fmpy
import numpy as np
import pytest

from motiontwin.cli import main
from motiontwin.harness import regress
from motiontwin.harness.master import Master
from motiontwin.harness.recording import make_recording, read_recording, write_recording
from motiontwin.harness.regress import Tolerance, compare_signal, load_suite, run_suite, tube, write_junit
from tests.test_master import P_LOOP


def check_junit_schema(root: ET.Element) -> ET.Element:
    """What CI servers read (the Ant JUnit schema as Jenkins, GitLab and the windyroad JUnit.xsd define it):
    <testsuites> of <testsuite> with name, id, package, tests, failures, errors, time, timestamp (no time
    zone), hostname; children <properties>, then <testcase>s (name, classname, time), then <system-out> and
    <system-err>; <failure> and <error> carry a type; the counts agree with the elements. Returns the suite."""
    assert root.tag == "testsuites" and not root.attrib and len(root) == 1
    suite = root[0]
    assert suite.tag == "testsuite"
    for key in ("name", "id", "package", "tests", "failures", "errors", "time", "timestamp", "hostname"):
        assert suite.get(key), key
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}", suite.get("timestamp"))
    assert re.fullmatch(r"\d+(\.\d{1,3})?", suite.get("time"))
    tags = [child.tag for child in suite]
    assert tags[0] == "properties" and tags[-2:] == ["system-out", "system-err"]
    assert set(tags[1:-2]) <= {"testcase"}
    cases = suite.findall("testcase")
    for case in cases:
        assert case.get("name") and case.get("classname") and re.fullmatch(r"\d+(\.\d{1,3})?", case.get("time"))
        assert all(child.tag in ("failure", "error") for child in case) and len(case) <= 1
        assert all(child.get("type") for child in case if child.tag in ("failure", "error"))
    for prop in suite.find("properties"):
        assert prop.tag == "property" and prop.get("name") and prop.get("value") is not None
    assert int(suite.get("tests")) == len(cases)
    assert int(suite.get("failures")) == sum(c.find("failure") is not None for c in cases)
    assert int(suite.get("errors")) == sum(c.find("error") is not None for c in cases)
    return suite


def brute_force_tube(t_ref, y_ref, t, tol: Tolerance):
    """Envelope of the rectangles around a densely resampled reference polyline (vertices included)."""
    dense = np.union1d(np.linspace(t_ref[0], t_ref[-1], 20001), t_ref)
    y_dense = np.interp(dense, t_ref, y_ref)
    delta = max(tol.abs, tol.rel * np.abs(y_ref).max())
    lo, hi = [], []
    for ti in t:
        window = y_dense[np.abs(dense - ti) <= tol.time_shift + 1e-12]
        window = np.append(window, np.interp([ti - tol.time_shift, ti + tol.time_shift], t_ref, y_ref))
        lo.append(window.min() - delta)
        hi.append(window.max() + delta)
    return np.array(lo), np.array(hi)


def test_tube_matches_brute_force_envelope() -> None:
    rng = np.random.default_rng(3)
    t_ref = np.cumsum(rng.uniform(0.001, 0.02, 80))
    y_ref = np.cumsum(rng.normal(0.0, 1.0, 80))
    t = np.sort(rng.uniform(t_ref[0], t_ref[-1], 60))
    tol = Tolerance(abs=0.01, rel=1e-3, time_shift=0.013)
    lo, hi = tube(t_ref, y_ref, t, tol)
    ref_lo, ref_hi = brute_force_tube(t_ref, y_ref, t, tol)
    np.testing.assert_allclose(lo, ref_lo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(hi, ref_hi, rtol=0, atol=1e-12)
    assert np.all(hi - lo >= 2 * 0.01 - 1e-12)


def test_perturbation_outside_tube_fails_and_inside_passes() -> None:
    t = np.linspace(0.0, 1.0, 1001)
    y = np.sin(2 * np.pi * 3 * t)
    tol = Tolerance(abs=1e-3, rel=1e-3, time_shift=0.0)
    assert compare_signal("c", "y", t, y, t, y + 5e-4, tol).passed
    bumped = y + np.where((t >= 0.4) & (t < 0.42), 0.01, 0.0)
    result = compare_signal("c", "y", t, y, t, bumped, tol)
    assert not result.passed
    assert result.violations == 20 and result.first_failure_time == pytest.approx(0.4)
    assert result.max_excess == pytest.approx(0.01 - 1e-3, rel=1e-6)  # delta = max(abs, rel * peak)
    nan = y.copy()
    nan[7] = np.nan
    assert "non-finite value nan at t = 0.007" in compare_signal("c", "y", t, y, t, nan, tol).message
    assert "does not cover" in compare_signal("c", "y", t, y, t[:-10], y[:-10], tol).message


def test_small_time_shift_at_a_step_is_tolerated() -> None:
    t = np.linspace(0.0, 1.0, 10001)
    reference = np.where(t >= 0.5, 1.0, 0.0)
    shifted = np.where(t >= 0.5004, 1.0, 0.0)
    assert compare_signal("c", "s", t, reference, t, shifted, Tolerance(1e-6, 1e-3, time_shift=5e-4)).passed
    strict = compare_signal("c", "s", t, reference, t, shifted, Tolerance(1e-6, 1e-3, time_shift=0.0))
    assert not strict.passed and strict.violations == 4
    too_late = np.where(t >= 0.501, 1.0, 0.0)
    assert not compare_signal("c", "s", t, reference, t, too_late, Tolerance(1e-6, 1e-3, time_shift=5e-4)).passed
    # on a different time grid (result sampled at other instants than the reference)
    t2 = np.linspace(0.0, 1.0, 7001)
    assert compare_signal("c", "s", t, reference, t2, np.where(t2 >= 0.5002, 1.0, 0.0),
                          Tolerance(1e-6, 1e-3, time_shift=5e-4)).passed


def test_junit_xml_counts_failures(tmp_path: Path) -> None:
    t = np.linspace(0.0, 1.0, 101)
    ok = compare_signal("case_a", "x", t, t, t, t, Tolerance())
    bad = compare_signal("case_a", "v", t, t, t, t + 1.0, Tolerance())
    path = write_junit(tmp_path / "out" / "junit.xml", [ok, bad, ok], errors={"case_b": "RuntimeError: boom"})
    root = ET.parse(path).getroot()
    suite = check_junit_schema(root)
    assert suite.get("tests") == "4" and suite.get("failures") == "1" and suite.get("errors") == "1"
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ["x", "v", "x", "run"]
    assert len(root.findall(".//failure")) == 1 and "outside the tube" in root.find(".//failure").get("message")
    assert root.find(".//error").text == "RuntimeError: boom" and root.find(".//error").get("type") == "RuntimeError"


@pytest.mark.parametrize("content, text", [
    ("[[case]\nname = 'a'", "suite.toml: "),                      # TOML syntax error
    ("[tolerance]\nabs = \"x\"", "tolerance abs must be a number >= 0, got 'x'"),
    (None, "cannot read the suite file (No such file or directory)"),
])
def test_unusable_suite_file_exits_2_with_a_junit_error(tmp_path: Path, content: str | None, text: str) -> None:
    """A broken suite file is exit 2 (not 1, a regression) with one errored testcase naming the file."""
    suite = tmp_path / "suite.toml"
    if content is not None:
        suite.write_text(content)
    messages: list[str] = []
    assert run_suite(suite, junit=tmp_path / "junit.xml", log=print, error=messages.append) == 2
    assert len(messages) == 1 and str(suite) in messages[0] and text in messages[0]
    node = check_junit_schema(ET.parse(tmp_path / "junit.xml").getroot())
    error = node.find("testcase/error")
    assert node.get("errors") == "1" and node.get("failures") == "0" and error.get("type") == "SuiteError"
    assert text in error.get("message") and node.find("testcase").get("classname") == str(suite)
    assert main(["regress", str(suite), "--junit", str(tmp_path / "cli.xml")]) == 2
    assert (tmp_path / "cli.xml").is_file()


def content_sha256(fmu: Path) -> str:
    """The documented FMU hash, written out independently: sorted members (name, length, bytes), the
    generation time removed from modelDescription.xml."""
    digest = hashlib.sha256()
    with zipfile.ZipFile(fmu) as zf:
        for info in sorted(zf.infolist(), key=lambda i: i.filename):
            data = zf.read(info)
            if info.filename == "modelDescription.xml":
                start = data.find(b' generationDateAndTime="')
                if start >= 0:
                    data = data[:start] + data[data.index(b'"', start + 24) + 1:]
            digest.update(info.filename.encode() + b"\0" + struct.pack("<Q", len(data)) + data)
    return digest.hexdigest()


def test_fmu_hash_ignores_the_generation_time_and_zip_dates(gemseo_fmus: Path, tmp_path: Path) -> None:
    """Rebuilding an FMU changes its zip dates and generationDateAndTime, not its hash; a changed byte does."""
    source = gemseo_fmus / "add.fmu"
    rebuilt, changed = tmp_path / "rebuilt.fmu", tmp_path / "changed.fmu"
    with zipfile.ZipFile(source) as zf, zipfile.ZipFile(rebuilt, "w") as same, zipfile.ZipFile(changed, "w") as other:
        for info in zf.infolist():
            data = zf.read(info)
            if info.filename == "modelDescription.xml":
                data = re.sub(rb'generationDateAndTime="[^"]*"', b'generationDateAndTime="2031-01-01T00:00:00Z"', data)
            same.writestr(zipfile.ZipInfo(info.filename, (2031, 1, 1, 0, 0, 0)), data)
            other.writestr(info.filename, data + (b" " if info.filename == "modelDescription.xml" else b""))
    assert rebuilt.read_bytes() != source.read_bytes()
    assert regress.fmu_sha256(rebuilt) == regress.fmu_sha256(source) == content_sha256(source)
    assert regress.fmu_sha256(changed) != regress.fmu_sha256(source)


SUITE = """
[tolerance]
abs = 1e-9
rel = 1e-6
time_shift = 0.0
[[case]]
name = "p_loop"
system = "loop.toml"
reference = "refs/p_loop.csv"
log = "slow"
[case.inputs]
r = -0.4
u_ext = {{recording = "excitation.csv", column = "u_ext"}}
[case.parameters]
"ctrl.add.k1" = {k1}
"""


def test_suite_update_then_pass_then_catch_a_change(gemseo_fmus: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "loop.toml").write_text(P_LOOP.format(fmus=gemseo_fmus).replace("stop_time = 0.2", "stop_time = 0.05"))
    t_exc = np.linspace(0.0, 0.05, 51)
    u_exc = np.where(t_exc >= 0.02, 80.0, 0.0)
    write_recording(tmp_path / "excitation.csv", make_recording(t_exc, {"u_ext": u_exc}))
    suite = tmp_path / "suite.toml"
    suite.write_text(SUITE.format(k1=5000.0))
    assert load_suite(suite)[0].tolerance == Tolerance(1e-9, 1e-6, 0.0)
    messages: list[str] = []
    assert run_suite(suite, log=messages.append) == 1  # no reference yet
    assert any("p_loop: ERROR FileNotFoundError: reference" in m and f"run `motiontwin regress {suite} --update`"
               in m for m in messages), messages
    assert run_suite(suite, update=True, junit=tmp_path / "update.xml", log=messages.append) == 0
    updated = check_junit_schema(ET.parse(tmp_path / "update.xml").getroot())
    assert [(c.get("classname"), c.get("name")) for c in updated.findall("testcase")] == [("p_loop", "update")]
    assert (tmp_path / "refs" / "p_loop.csv").is_file() and (tmp_path / "refs" / "p_loop.json").is_file()
    sidecar = json.loads((tmp_path / "refs" / "p_loop.json").read_text())
    for name, fmu in (("plant", "Mass_Damper.fmu"), ("ctrl", "add.fmu")):  # hash and every parameter recorded
        assert sidecar["fmus"][name]["sha256"] == content_sha256(gemseo_fmus / fmu)
        md = fmpy.read_model_description(str(gemseo_fmus / fmu))
        starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter" and v.start}
        overrides = {"add.k1": 5000.0, "add.k2": -5000.0} if name == "ctrl" else {}
        assert starts and sidecar["parameters"][name] == {**starts, **overrides}
    with Master(tmp_path / "loop.toml") as m:  # the reference is the run with the recorded excitation
        direct = m.run(inputs={"r": -0.4, "u_ext": (t_exc, u_exc)}, parameters={"ctrl.add.k1": 5000.0})["slow"]
    reference = read_recording(tmp_path / "refs" / "p_loop.csv")
    np.testing.assert_array_equal(reference["plant.y"], direct["plant.y"])
    assert reference.units["time"] == "s" and reference.meta["fmus"]["plant"]["step"] == pytest.approx(1e-5)
    assert run_suite(suite, junit=tmp_path / "junit.xml", log=messages.append) == 0
    assert ET.parse(tmp_path / "junit.xml").getroot().find("testsuite").get("failures") == "0"

    suite.write_text(SUITE.format(k1=5100.0))  # a changed gain moves the result
    sidecar["units"]["plant.y"] = "m"  # the plots' units come from the reference (the FMU declares none)
    (tmp_path / "refs" / "p_loop.json").write_text(json.dumps(sidecar))
    figures = []
    write_figure = regress.write_figure
    monkeypatch.setattr(regress, "write_figure", lambda path, fig, **kw: (figures.append(fig), write_figure(path, fig, **kw))[1])
    simulate = regress._simulate
    monkeypatch.setattr(regress, "_simulate", lambda *a: (time.sleep(0.5), simulate(*a))[1])
    messages.clear()
    code = run_suite(suite, junit=tmp_path / "junit.xml", plots=tmp_path / "plots", log=messages.append)
    assert code == 1
    suite_node = check_junit_schema(ET.parse(tmp_path / "junit.xml").getroot())
    failed = [c for c in suite_node.findall("testcase") if c.find("failure") is not None]
    names = [c.get("name") for c in failed]
    assert suite_node.get("failures") == str(len(failed)) and "plant.y" in names
    for case in failed:
        plot = tmp_path / "plots" / f"p_loop__{case.get('name')}.png"
        assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert case.find("failure").get("message").endswith(f"; plot: {plot}")
        assert any(m.startswith(f"FAIL p_loop {case.get('name')}") and str(plot) in m for m in messages)
    # the whole case's time, the (slowed) simulation included, is in its testcases
    assert sum(float(c.get("time")) for c in suite_node.findall("testcase")) >= 0.5
    assert float(suite_node.get("time")) >= 0.5
    plant = figures[names.index("plant.y")]
    top, bottom = plant.axes
    assert top.get_ylabel() == "plant.y [m]" and bottom.get_ylabel() == "residual [m]"
    assert {t.get_text() for t in bottom.get_legend().get_texts()} >= {"tube - reference", "result - reference"}
    # the parameters differ from the reference's (the changed gain), and so does a tampered FMU hash
    assert any("parameters differ from the reference's: add.k1 = 5100.0 (reference 5000.0)" in m for m in messages)
    sidecar["fmus"]["plant"]["sha256"] = "0" * 64
    (tmp_path / "refs" / "p_loop.json").write_text(json.dumps(sidecar))
    messages.clear()
    run_suite(suite, junit=tmp_path / "junit.xml", log=messages.append)
    assert any("FMU 'plant' differs from the reference's: sha256" in m and "reference 000000000000" in m
               for m in messages), messages
    out = check_junit_schema(ET.parse(tmp_path / "junit.xml").getroot()).find("system-out").text
    assert "FMU 'plant' differs from the reference's" in out


def test_run_input_takes_a_constant_as_suite_files_do(gemseo_fmus: Path, tmp_path: Path) -> None:
    """`motiontwin run --input r=-0.4 --input u_ext=0` equals the Master run with the same constants."""
    system = tmp_path / "loop.toml"
    system.write_text(P_LOOP.format(fmus=gemseo_fmus).replace("stop_time = 0.2", "stop_time = 0.02"))
    out = tmp_path / "run.csv"
    assert main(["run", str(system), "--input", "r=-0.4", "--input", "u_ext=0", "--out", str(out)]) == 0
    with Master(system) as m:
        direct = m.run(inputs={"r": -0.4, "u_ext": 0.0})["slow"]
    recorded = read_recording(out)
    assert np.max(np.abs(direct["plant.y"])) > 0.1
    np.testing.assert_array_equal(recorded["plant.y"], direct["plant.y"])
    assert main(["run", str(system), "--input", "r=nan", "--out", str(out)]) != 0
