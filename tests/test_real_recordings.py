"""Real recordings, from ``motiontwin import`` to ``motiontwin diagnose`` (issue 23 item 9), against the values
their sources publish.

* A Dynamixel XL330 servo (288:1 gearbox) driving a 0.49 kg pendulum under its firmware position P loop: two
  logs of the BAM project (Apache-2.0; ``tests/data/xl330/SOURCE.md``). The host polls the servo every ~5.3 ms
  with jitter, the servo's loop runs faster: the import resamples onto 5 ms and the controller is given at 1 ms
  (5 updates per sample, the goal held). References: the firmware law documented in BAM's actuator code (duty =
  0.0028774 kp (goal - q)) and the motor constants of BAM's fit (kt/R = 0.06785 N.m/V).
* Axis 1 of a KUKA KR300 industrial robot under its own (undocumented) controller: two trajectories of the
  Robot_Identification repository (MIT; ``tests/data/kuka_axis1/SOURCE.md``), diagnosed with the controller
  unknown. Reference: the source's identified friction law of axis 1.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from motiontwin.cli import main
from motiontwin.harness.recording import read_recording
from motiontwin.ident.channels import channel_problem, check_channels
from motiontwin.ident.controller import read_controller
from motiontwin.ident.diagnosis import pipeline

DATA = Path(__file__).parent / "data" / "xl330"
ROBOT = Path(__file__).parent / "data" / "kuka_axis1"
KT_OVER_R = 0.06785      # N.m/V: BAM's m1 fit at the source commit
ERROR_GAIN = 0.0028774   # duty per (kp rad): (4096 / 2 pi) / (256 * 885), BAM's XL330 actuator code
KP = 200                 # the firmware gain of both logs
SAMPLE_TIME = 0.005      # the grid the host-clocked logs are resampled onto
CONTROLLER_TS = 0.001    # the servo's own loop, faster than the host's polling


def _import(name: str, out: Path) -> Path:
    """``motiontwin import`` of one shipped log: position and goal in rad, the motor voltage to N.m through
    kt/R, onto the 5 ms grid."""
    assert main(["import", str(DATA / f"{name}.csv"), "--column", "q=position", "--unit", "q=rad",
                 "--column", "r=goal_position", "--unit", "r=rad", "--column", "u=motor_volts", "--unit", "u=V",
                 "--gain", f"u={KT_OVER_R} N.m/V", "--resample", "--sample-time", str(SAMPLE_TIME),
                 "--out", str(out)]) == 0
    return out


def _firmware_law(kp: float) -> dict:
    """The documented P law in N.m/rad: kt/R x supply x duty per rad (the supply at its mean over the logs)."""
    volts = np.mean(np.concatenate([np.genfromtxt(DATA / f"{n}.csv", delimiter=",", names=True)["input_volts"]
                                    for n in ("sin_sin_kp200", "sin_time_square_kp200")]))
    gain = KT_OVER_R * volts * ERROR_GAIN * kp
    return {"kind": "discrete_state_space", "Ts": CONTROLLER_TS, "inputs": ["r", "q"], "outputs": ["u"],
            "A": [[0.0]], "B": [[0.0, 0.0]], "C": [[0.0]], "D": [[gain, -gain]]}


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("xl330")
    return {"train": _import("sin_sin_kp200", folder / "train.csv"),
            "validation": _import("sin_time_square_kp200", folder / "validation.csv")}


def test_the_host_clocked_log_is_resampled_and_its_jitter_reported(imported):
    rec = read_recording(imported["train"])
    assert rec.sample_time == SAMPLE_TIME
    np.testing.assert_allclose(np.diff(rec.time), SAMPLE_TIME, rtol=1e-9)
    notes = json.loads(imported["train"].with_suffix(".json").read_text())["metadata"]["import"]
    raw = np.genfromtxt(DATA / "sin_sin_kp200.csv", delimiter=",", names=True)["time"]
    steps = np.diff(raw)
    assert notes["resampled"] and notes["clock"]["sample_time"] == SAMPLE_TIME
    assert notes["jitter"]["sample_time"] == pytest.approx(np.median(steps), rel=1e-12)
    assert notes["jitter"]["max_deviation"] == pytest.approx(np.max(np.abs(steps - np.median(steps))), rel=1e-9)
    assert set(rec.units.values()) >= {"rad", "N.m"}


def test_the_documented_firmware_law_reproduces_the_recorded_force(imported):
    """The channel check against the source's own law: consistent within 1 % in gain; the law with the gain of
    another log (kp 100) is refused, naming the factor 2."""
    rec = read_recording(imported["train"])
    check = check_channels(rec, read_controller(_firmware_law(KP), "law"))[0]
    assert check.consistent and abs(check.gain - 1) < 0.02 and check.delay == 0   # supply read in 0.1 V steps
    problem = channel_problem(rec, read_controller(_firmware_law(KP / 2), "law"))
    assert problem is not None and "gain or unit factor: u = 1.9" in problem


def test_the_real_servo_is_diagnosed_in_rotary_units_with_an_honest_verdict(imported, tmp_path):
    """End to end on the real servo: rotary units throughout, evidence ratios that are statistics, and a verdict
    that holds against what the diagnosis reports. The nominal model (inertia, viscous, gravity) leaves about 9x
    the noise floor on the held-out log; the augmented model must not predict it worse; "unexplained" whenever
    the remainder exceeds the bound of the floor and the parameters' estimation error the report gives.
    The servo's fitted friction laws have sensitivities that explode along the run (Jacobian columns of 1e100);
    their linearised null fell to its chi-square floor and gave Coulomb friction a ratio of 3e6 over it: a null
    from the model's own per-parameter noise power keeps every ratio a plausible statistic (below 1e3)."""
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    for role, path in imported.items():
        shutil.copy(path, bundle / f"{role}.csv")
        shutil.copy(path.with_suffix(".json"), bundle / f"{role}.json")
    shutil.copy(DATA / "ServoPendulum.mo", bundle / "plant.mo")
    shipped = json.loads((DATA / "experiment.json").read_text())     # the docs' bundle: the law, 5 digits
    np.testing.assert_allclose(shipped["controller"]["D"], _firmware_law(KP)["D"], rtol=1e-4)
    shutil.copy(DATA / "experiment.json", bundle / "experiment.json")
    assert main(["diagnose", str(bundle), "--out", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert doc["units"] == {"position": "rad", "velocity": "rad/s", "force": "N.m", "mass": "kg.m2"}
    for effect in doc["effects"]:
        assert not {"N", "m", "m/s", "kg", "N.s/m"} & set(effect["units"].values()), effect
    val = doc["validation"]
    assert val["nominal_rms"] > 5 * val["noise_floor_rms"]
    assert val["augmented_rms"] <= val["nominal_rms"]
    assert max(c["evidence_ratio"] for c in doc["candidates"]) < 1e3, doc["candidates"]
    bound = pipeline.floor_bound(val["noise_floor_rms"], val.get("estimation_rms") or 0.0)
    force_bound = pipeline.floor_bound(val["force_floor_rms"], val.get("force_estimation_rms") or 0.0)
    above = val["augmented_rms"] > bound or val["force_rms"] > force_bound
    if above:
        assert doc["unexplained"] and doc["unexplained"]["status"].startswith("unexplained"), doc["residual_check"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert " mm" not in report and " um" not in report and "[m]" not in report


GEAR_RATIO = 1798 / 7    # axis 1 of the KR300: motor torque -> link torque (the source's Robot_reference_dynamics.m)


def _robot_friction(w: np.ndarray) -> np.ndarray:
    """The source's identified friction of axis 1 on the link side [N.m] at velocity ``w`` [rad/s] (data_ref.mat)."""
    return 4.26357 + 1939.51961 * w + 31.64867 * np.tanh(100 * w) + 318.64387 * np.tanh(1146.09496 * w)


def test_the_robot_axis_is_diagnosed_without_its_controller_and_its_friction_matches_the_source(tmp_path):
    """Axis 1 of the KUKA robot with the controller unknown (a prediction-error predictor): the nominal plant
    (inertia, viscous) misses the Coulomb part of the friction the source identified; the diagnosis adds it, and
    the augmented friction torque (viscous + Coulomb) is within 15 % of the source's law over the recorded speeds
    (the nominal viscous law alone is 44 % below it at 0.1 rad/s). The inertia about axis 1 varies with the pose
    of axes 2 and 3 by +-20 % along these trajectories (the source's model), which no single-axis model holds:
    the remainder must be called unexplained, not parameters."""
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    for role, name in (("train", "A"), ("validation", "B")):
        assert main(["import", str(ROBOT / f"kuka_axis1_{name}.csv"), "--unit", "q=deg", "--unit", "r=deg",
                     "--gain", f"u={GEAR_RATIO!r} N.m/N.m", "--out", str(bundle / f"{role}.csv")]) == 0
    rec = read_recording(bundle / "train.csv")
    assert rec.sample_time == pytest.approx(0.004, rel=1e-12) and rec.units["q"] == "rad"
    shutil.copy(ROBOT / "RotaryAxis.mo", bundle / "plant.mo")
    shutil.copy(ROBOT / "experiment.json", bundle / "experiment.json")
    assert main(["diagnose", str(bundle), "--out", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert [e["name"] for e in doc["effects"]] == ["coulomb_friction"], doc["candidates"]
    # the pose-dependent inertia leaves force residual above the noise after the friction: round two screens
    assert [r["round"] for r in doc["location"]] == [2] and doc["location"][0]["scores"]["q"] > 1.5, doc["location"]
    values = doc["augmented_parameters"]
    speeds = np.array([0.1, 0.2, 0.4])      # rad/s: the recorded peak is 0.44
    ours = values["d"] * speeds + values["coulomb_Fc"] * np.tanh(speeds / values["coulomb_v_eps"])
    np.testing.assert_allclose(ours, _robot_friction(speeds), rtol=0.15)
    val = doc["validation"]
    assert val["augmented_rms"] < 0.8 * val["nominal_rms"]
    # validate reads the diagnosis folder and scores it with the fit's observer (one sized on this recording was
    # 68 % off): the diagnosis' figure, to the initial-state estimate (least squares against the first samples)
    scored = tmp_path / "validate.json"
    assert main(["validate", str(tmp_path / "out"), str(bundle / "validation.csv"), "--controller", "unknown",
                 "--out", str(scored)]) == 0
    assert json.loads(scored.read_text())["rms"] == pytest.approx(val["augmented_rms"], rel=1e-3)
    if val["augmented_rms"] > 2 * val["noise_floor_rms"]:
        assert doc["unexplained"] and doc["unexplained"]["status"].startswith("unexplained"), doc["residual_check"]
