"""Tolerance-tube regression checks: tube bounds against a brute-force envelope, perturbations and
time shifts, JUnit XML read back with xml.etree, and a suite run end to end on real FMUs."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness.master import Master
from motiontwin.harness.recording import make_recording, read_recording, write_recording
from motiontwin.harness.regress import Tolerance, compare_signal, load_suite, run_suite, tube, write_junit
from tests.test_master import P_LOOP


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
    suite = root.find("testsuite")
    assert suite.get("tests") == "4" and suite.get("failures") == "1" and suite.get("errors") == "1"
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ["x", "v", "x", "run"]
    assert len(root.findall(".//failure")) == 1 and "outside the tube" in root.find(".//failure").get("message")
    assert root.find(".//error").text == "RuntimeError: boom"


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


def test_suite_update_then_pass_then_catch_a_change(gemseo_fmus: Path, tmp_path: Path) -> None:
    (tmp_path / "loop.toml").write_text(P_LOOP.format(fmus=gemseo_fmus).replace("stop_time = 0.2", "stop_time = 0.05"))
    t_exc = np.linspace(0.0, 0.05, 51)
    u_exc = np.where(t_exc >= 0.02, 80.0, 0.0)
    write_recording(tmp_path / "excitation.csv", make_recording(t_exc, {"u_ext": u_exc}))
    suite = tmp_path / "suite.toml"
    suite.write_text(SUITE.format(k1=5000.0))
    assert load_suite(suite)[0].tolerance == Tolerance(1e-9, 1e-6, 0.0)
    messages: list[str] = []
    assert run_suite(suite, update=True, log=messages.append) == 0
    assert (tmp_path / "refs" / "p_loop.csv").is_file() and (tmp_path / "refs" / "p_loop.json").is_file()
    with Master(tmp_path / "loop.toml") as m:  # the reference is the run with the recorded excitation
        direct = m.run(inputs={"r": -0.4, "u_ext": (t_exc, u_exc)}, parameters={"ctrl.add.k1": 5000.0})["slow"]
    reference = read_recording(tmp_path / "refs" / "p_loop.csv")
    np.testing.assert_array_equal(reference["plant.y"], direct["plant.y"])
    assert reference.units["time"] == "s" and reference.meta["fmus"]["plant"]["step"] == pytest.approx(1e-5)
    assert run_suite(suite, junit=tmp_path / "junit.xml", log=messages.append) == 0
    assert ET.parse(tmp_path / "junit.xml").getroot().find("testsuite").get("failures") == "0"

    suite.write_text(SUITE.format(k1=5100.0))  # a changed gain moves the result
    code = run_suite(suite, junit=tmp_path / "junit.xml", plots=tmp_path / "plots", log=messages.append)
    assert code == 1
    suite_node = ET.parse(tmp_path / "junit.xml").getroot().find("testsuite")
    failed = [c.get("name") for c in suite_node.findall("testcase") if c.find("failure") is not None]
    assert suite_node.get("failures") == str(len(failed)) and "plant.y" in failed
    for name in failed:
        assert (tmp_path / "plots" / f"p_loop__{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
