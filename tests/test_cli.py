"""The motiontwin console script: each subcommand reaches its feature and turns bad input into exit code 1
with a message (never a traceback)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness import recording
from motiontwin.cli import main
from motiontwin.harness.master import Master
from tests.test_master import PI_LOOP

STEP_EXPERIMENT = """
sample_time = 1e-4
duration = 0.3
[excitation]
kind = "step"
t_step = 0.05
amplitude = 1e-3
"""


@pytest.fixture
def loop_files(built_fmus: dict, tmp_path: Path) -> tuple[Path, Path]:
    system = tmp_path / "loop.toml"
    system.write_text(PI_LOOP.format(pi=built_fmus["SampledPI", "3.0"], plant=built_fmus["LinearMotorJoint", "2.0"]))
    experiment = tmp_path / "step.toml"
    experiment.write_text(STEP_EXPERIMENT)
    return system, experiment


def test_run_writes_the_recording_the_master_computes(loop_files, tmp_path):
    system, experiment = loop_files
    out = tmp_path / "run.csv"
    assert main(["run", str(system), "--input", f"r={experiment}", "--out", str(out)]) == 0
    rec = recording.read_recording(out, required=("time", "plant.q", "pi.y", "plant.u"))
    t = np.arange(3000) * 1e-4
    with Master(system) as master:
        log = master.run(inputs={"r": (t, np.where(t >= 0.05, 1e-3, 0.0))})["log"]
    np.testing.assert_array_equal(rec["plant.q"], log["plant.q"])
    assert rec.units["plant.q"] == "m"
    assert abs(rec["plant.q"][-1] - 1e-3) < 5e-5  # the PI loop is close to the 1 mm step


def test_run_bad_input_is_a_message_and_no_file(loop_files, tmp_path, capsys):
    system, experiment = loop_files
    out = tmp_path / "bad.csv"
    assert main(["run", str(system), "--input", f"nope={experiment}", "--out", str(out)]) == 1
    assert "nope" in capsys.readouterr().err
    assert not out.exists()


def test_excite_writes_csv_and_mat(tmp_path):
    experiment = Path(__file__).resolve().parents[1] / "harness" / "experiments" / "swept_sine_80_500.toml"
    out = tmp_path / "sweep.csv"
    assert main(["excite", str(experiment), "--out", str(out), "--mat"]) == 0
    rec = recording.read_recording(out, required=("time", "value"))
    assert recording.read_mat(out.with_suffix(".mat")).columns["value"].tolist() == rec["value"].tolist()


def _identify_joint_recording(tmp_path) -> Path:
    """identify joint on a recording of the truth ODE (tests/ident_truth.py); checks the regressor estimates
    against the truth and returns the --out JSON."""
    import json

    from tests.test_ident_joint import NAMES, TRUTH, noisy_periods, simulate_joint_period

    t, q, u = simulate_joint_period()
    qs, us = noisy_periods(q, u, 10, 1e-4, 0.5, np.random.default_rng(3))
    time = np.arange(qs.size) * 1e-3
    path = tmp_path / "joint.csv"
    recording.write_recording(path, recording.make_recording(time, {"q": qs, "u": us}, {"q": "rad", "u": "N.m"},
                                                             sample_time=1e-3))
    out = tmp_path / "fit.json"
    assert main(["identify", "joint", str(path), "--f0", "0.5", "--cutoff", "10", "--min-speed", "0.2",
                 "--out", str(out)]) == 0
    fit = json.loads(out.read_text())
    estimate = np.array([fit["regressor_parameters"][n] for n in NAMES])
    assert np.all(np.abs(estimate - TRUTH) / np.abs(TRUTH) < 0.03)
    assert main(["identify", "joint", str(path), "--position", "nope", "--f0", "0.5", "--cutoff", "10"]) == 1
    return out


def test_identify_joint_recovers_the_truth_from_a_recording(tmp_path):
    """CLI path of inverse-dynamics identification: truth ODE -> recording -> estimates within 3 %."""
    _identify_joint_recording(tmp_path)


def test_identify_joint_then_writeback_into_the_serial_joint_fmu(tmp_path):
    """identify joint --out goes into SerialRobotJoint's start values as it is: the written FMU's friction
    output and its acceleration under a torque equal the truth ODE's (tests/ident_truth.py) within 3 %."""
    import json

    import fmpy

    from motiontwin.fmus import build
    from tests.ident_truth import JOINT_TRUTH, friction_torque

    fit = _identify_joint_recording(tmp_path)
    doc = json.loads(fit.read_text())
    assert doc["class"] == "MotionTwin.Plants.SerialRobotJoint" and set(doc["std"]) == set(doc["parameters"])
    fmu = build.build_fmu(build.load_model("MotionTwin.Plants.SerialRobotJoint"), tmp_path / "fmus", "2.0").path
    written = tmp_path / "fitted.fmu"
    assert main(["writeback", str(fmu), "--values", str(fit), "--out", str(written)]) == 0
    k = float(np.hypot(JOINT_TRUTH["g_sin"], JOINT_TRUTH["g_cos"]))
    q_off = float(np.arctan2(JOINT_TRUTH["g_cos"], JOINT_TRUTH["g_sin"]))
    for w in (-2.0, -0.7, 0.6, 2.5):   # the FMU's friction output vs the truth's friction at that velocity
        res = fmpy.simulate_fmu(str(written), stop_time=1e-6, output_interval=1e-6, output=["f_friction"],
                                start_values={"w": w})
        assert res["f_friction"][0] == pytest.approx(friction_torque(JOINT_TRUTH, w), rel=0.03)
    q0, w0, tau, dt = 0.4, 1.0, 5.0, 1e-3   # M*der(w) = tau - k*sin(q + q_off) - f(w), over a short step
    res = fmpy.simulate_fmu(str(written), stop_time=dt, output_interval=dt, output=["w"],
                            start_values={"q": q0, "w": w0, "tau": tau})
    truth = (tau - k * np.sin(q0 + q_off) - friction_torque(JOINT_TRUTH, w0)) / JOINT_TRUTH["J"]
    assert (res["w"][-1] - w0) / dt == pytest.approx(truth, rel=0.03)


def test_writeback_rebuilds_the_binary_with_the_new_defaults(built_fmus, tmp_path):
    import hashlib
    import json
    import zipfile

    import fmpy

    from motiontwin.fmus import build
    from tests.test_fmu_build import analytic_step

    for version in ("2.0", "3.0"):
        original = built_fmus["LinearMotorJoint", version]
        before = hashlib.sha256(original.read_bytes()).hexdigest()
        out = tmp_path / f"fitted{version[0]}.fmu"
        values = tmp_path / "fit.json"
        values.write_text(json.dumps({"parameters": {"J": 1.5}, "method": "test", "recording": "r.csv"}))
        assert main(["writeback", str(original), "--values", str(values), "--rename", "J=m", "--set", "d=4.0",
                     "--out", str(out)]) == 0
        assert hashlib.sha256(original.read_bytes()).hexdigest() == before  # the original is untouched
        md = fmpy.read_model_description(str(out))
        starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
        assert starts == {"m": 1.5, "d": 4.0}
        assert md.guid != fmpy.read_model_description(str(original)).guid
        result = fmpy.simulate_fmu(str(out), stop_time=0.5, output_interval=1e-3, start_values={"u": 3.0},
                                   output=["q"])  # nobody sets m or d: the binary's defaults are used
        np.testing.assert_allclose(result["q"], analytic_step(result["time"], 3.0, 1.5, 4.0), rtol=0, atol=1e-8)
        provenance = json.loads(zipfile.ZipFile(out).read("documentation/provenance.json"))
        assert provenance["values"] == {"m": 1.5, "d": 4.0} and provenance["method"] == "test"
        fitted = build.load_model("LinearMotorJointFitted", out.with_suffix(".mo"), (build.MODELICA_DIR,))
        assert {p.name: p.start for p in fitted.parameters} == {"m": 1.5, "d": 4.0}
    assert main(["writeback", str(original), "--set", "m=-1", "--out", str(tmp_path / "bad.fmu")]) == 1
    assert main(["writeback", str(original), "--set", "nope=1", "--out", str(tmp_path / "bad.fmu")]) == 1
    assert not (tmp_path / "bad.fmu").exists()


def test_tune_writes_its_design_and_a_controller_fmu_with_those_defaults(tmp_path):
    import json

    import fmpy

    out, fmu = tmp_path / "tuned.json", tmp_path / "tuned.fmu"
    assert main(["tune", "--popsize", "5", "--maxiter", "10", "--refine", "1", "--tau-max", "0.05", "--out", str(out),
                 "--fmu-out", str(fmu), "--fmi", "2.0"]) == 0
    doc = json.loads(out.read_text())
    assert doc["violations"] == [] and all(m["stable"] and m["gm_db"] >= 7.0 for m in doc["margins"])
    starts = {v.name: float(v.start) for v in fmpy.read_model_description(str(fmu)).modelVariables
              if v.causality == "parameter"}
    for name, value in doc["parameters"].items():
        assert starts[name] == pytest.approx(value, rel=1e-12), name
    assert main(["tune", "--plant", "K=-1", "--popsize", "5", "--maxiter", "2"]) == 1


def test_identify_hexapod_from_a_recording_recovers_the_base_parameters(tmp_path):
    import json

    from motiontwin.ident.hexapod import measure_periods
    from tests.test_ident_hexapod import F0, FS, N_PERIODS, NH, NOISE, _period, base, truth

    _, _, lengths, forces = _period()
    measured_lengths, measured_forces = measure_periods(lengths, forces, N_PERIODS, NOISE, np.random.default_rng(5))
    columns = {f"L{i + 1}": measured_lengths[:, i] for i in range(6)}
    columns.update({f"tau{i + 1}": measured_forces[:, i] for i in range(6)})
    path = tmp_path / "hexapod.csv"
    recording.write_recording(path, recording.make_recording(np.arange(len(measured_lengths)) / FS, columns))
    out = tmp_path / "fit.json"
    assert main(["identify", "hexapod", str(path), "--f0", str(F0), "--cutoff", str(NH * F0), "--out", str(out)]) == 0
    fit = json.loads(out.read_text())
    truth_base = base().from_full(truth().theta())
    estimate = np.array([fit["parameters"][n] for n in base().names])
    assert np.all(np.abs(estimate - truth_base) <= 5 * np.array([fit["std"][n] for n in base().names]))


def test_identify_frf_recovers_the_joint_model_from_a_swept_sine_recording(tmp_path):
    import json

    import scipy.signal

    from tests.test_ident_frf import FS, TRUTH, _simulate

    t = np.arange(int(60 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=0.5, f1=500, t1=t[-1], method="logarithmic")
    q = _simulate(u, np.random.default_rng(0))
    path = tmp_path / "sweep.csv"
    recording.write_recording(path, recording.make_recording(t, {"u": u, "q": q}, sample_time=1 / FS))
    out = tmp_path / "frf.json"
    assert main(["identify", "frf", str(path), "--out", str(out)]) == 0
    fit = json.loads(out.read_text())["parameters"]
    assert fit["K"] == pytest.approx(TRUTH.gain, rel=0.02)
    assert fit["alpha"] == pytest.approx(TRUTH.alpha, rel=0.02)
    assert fit["omega"] == pytest.approx(TRUTH.resonances[0][0], rel=0.02)
    assert fit["omega_bar"] == pytest.approx(TRUTH.antiresonances[0][0], rel=0.02)


def test_identify_joint_ml_estimates_the_cutoff_and_the_parameters(tmp_path, capsys):
    """identify joint --ml on band-limited data (tests/test_ident_maximum_likelihood.py: 10 harmonics of 0.5 Hz, so the
    likelihood-optimal cut-off lies in [5.0, 5.5) Hz), started at 3 Hz where the plain Gauss-Markov fit is
    far off: the cut-off is found and the parameters match the truth within 4 std, in SerialRobotJoint names."""
    import json

    from tests.ident_truth import JOINT_TRUTH
    from tests.test_ident_maximum_likelihood import FS, NAMES, TRUTH, band_limited_periods

    qs, taus = band_limited_periods(1)
    path = tmp_path / "band.csv"
    recording.write_recording(path, recording.make_recording(np.arange(qs.size) / FS, {"q": qs, "u": taus},
                                                             {"q": "rad", "u": "N.m"}, sample_time=1 / FS))
    out = tmp_path / "ml.json"
    assert main(["identify", "joint", str(path), "--f0", "0.5", "--cutoff", "3", "--min-speed", "0.2", "--ml",
                 "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert 5.0 <= doc["cutoff_frequency"] < 5.5 and doc["cutoff_start"] == 3.0
    estimate = np.array([doc["regressor_parameters"][n] for n in NAMES])
    std = np.array([doc["regressor_std"][n] for n in NAMES])
    assert np.all(np.abs(estimate - TRUTH) < 4 * std), (estimate, TRUTH, std)
    start = np.array([doc["start_regressor_parameters"][n] for n in NAMES])
    assert np.max(np.abs(start / TRUTH - 1)) > 0.5  # the 3 Hz start alone is wrong: the ML step does the work
    assert doc["class"] == "MotionTwin.Plants.SerialRobotJoint"
    assert doc["parameters"]["M"] == pytest.approx(JOINT_TRUTH["J"], rel=0.01)
    assert doc["parameters"]["k"] == pytest.approx(3.0, rel=0.02)
    assert doc["parameters"]["q_off"] == pytest.approx(0.3, abs=0.03)
    capsys.readouterr()
    bad = tmp_path / "bad.json"
    assert main(["identify", "joint", str(path), "--f0", "0.5", "--cutoff", "3", "--ml", "--friction", "symmetric",
                 "--out", str(bad)]) == 1
    assert "--friction" in capsys.readouterr().err and not bad.exists()
    assert main(["identify", "joint", str(path), "--f0", "0.5", "--cutoff", "3", "--cutoff-range", "6", "2",
                 "--ml"]) == 1
    assert "--cutoff-range" in capsys.readouterr().err


def test_identify_projection_removes_the_closed_loop_bias(tmp_path, capsys):
    """identify projection on the closed-loop truth of tests/test_ident_closedloop.py (5 Hz, zeta 0.3, unit
    gain plant under PI, coloured output noise fed back): the projection estimate is within a few % of the
    truth, the naive output-error fit beside it is > 30 % off in gain."""
    import json

    from tests.test_ident_closedloop import A, B, FS, M_CAUSAL, _closed_loop_data

    r, u, y = _closed_loop_data(0)
    path = tmp_path / "loop.csv"
    recording.write_recording(path, recording.make_recording(np.arange(r.size) / FS, {"r": r, "u": u, "y": y},
                                                             sample_time=1 / FS))
    out = tmp_path / "pm.json"
    assert main(["identify", "projection", str(path), "--reference", "r", "--input", "u", "--output", "y",
                 "--nb", "2", "--nf", "2", "--causal", str(M_CAUSAL), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    pole = np.log(np.roots(A)[0]) * FS
    gain, frequency, damping = np.sum(B) / np.sum(A), abs(pole) / (2 * np.pi), -pole.real / abs(pole)
    pm, naive = doc["projection_model"], doc["naive_model"]
    assert pm["static_gain"] == pytest.approx(gain, rel=0.08)
    assert pm["modes"][0]["frequency_hz"] == pytest.approx(frequency, rel=0.03)
    assert pm["modes"][0]["damping"] == pytest.approx(damping, rel=0.15)
    assert abs(naive["static_gain"] / gain - 1) > 0.3
    assert abs(doc["projection"]["correlation"]) < 1e-3
    capsys.readouterr()
    assert main(["identify", "projection", str(path), "--reference", "nope", "--output", "y"]) == 1
    assert "nope" in capsys.readouterr().err
    assert main(["identify", "projection", str(path), "--output", "y", "--nb", "0"]) == 1
    assert "--nb" in capsys.readouterr().err


def _joint_criteria(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[float, float]:
    """cond and log det(Phi^T Phi) of the joint regressor on one sampled period."""
    from motiontwin.ident.joint import joint_regressor

    phi, _ = joint_regressor(q, qd, qdd)
    return float(np.linalg.cond(phi)), float(np.linalg.slogdet(phi.T @ phi)[1])


def test_design_excitation_then_excite_then_identify(tmp_path, capsys):
    """design-excitation -> experiment file -> excite -> recording: the sampled trajectory keeps the limits,
    each criterion beats 20 random designs under the same limits on its own measure (and the other design);
    the truth loop of tests/ident_truth.py driven by the D-optimal file identifies within 3 %."""
    import json

    from motiontwin.harness.excitation import fourier_trajectory
    from motiontwin.harness.experiment import load_experiment
    from motiontwin.ident.excitation_design import ExcitationLimits, random_design
    from tests.test_ident_joint import NAMES, TRUTH, noisy_periods, simulate_joint_period

    limits = ["--q-range", "1.5", "--v-max", "6", "--a-max", "40"]
    criteria = {}
    for criterion in ("cond", "dopt"):
        toml, rec_path = tmp_path / f"{criterion}.toml", tmp_path / f"{criterion}.csv"
        assert main(["design-excitation", "joint", "--criterion", criterion, "--f0", "0.5", "--harmonics", "5",
                     *limits, "--sample-time", "1e-3", "--periods", "10", "--starts", "2", "--target", "r",
                     "--out", str(toml)]) == 0
        assert main(["excite", str(toml), "--out", str(rec_path)]) == 0
        rec = recording.read_recording(rec_path, required=("time", "position", "velocity", "acceleration"))
        assert rec["time"].size == 20000 and load_experiment(toml).target == "r"
        assert np.max(np.abs(rec["position"])) <= 1.5 and np.max(np.abs(rec["velocity"])) <= 6.0
        assert np.max(np.abs(rec["acceleration"])) <= 40.0
        criteria[criterion] = _joint_criteria(rec["position"][:2000], rec["velocity"][:2000],
                                              rec["acceleration"][:2000])
    t = np.arange(2000) * 1e-3
    rng = np.random.default_rng(1)
    randoms = []
    for _ in range(20):
        design = random_design(ExcitationLimits(0.0, 1.5, 6.0, 40.0), 0.5, 5, rng)
        profile = fourier_trajectory(t, 0.5, design.a, design.b, design.q0)
        randoms.append(_joint_criteria(profile.position, profile.velocity, profile.acceleration))
    assert criteria["cond"][0] < min(c for c, _ in randoms) and criteria["cond"][0] < criteria["dopt"][0]
    assert criteria["dopt"][1] > max(d for _, d in randoms) and criteria["dopt"][1] > criteria["cond"][1]

    excitation = load_experiment(tmp_path / "dopt.toml").parameters
    _, q, u = simulate_joint_period(a=np.array(excitation["a"]), b=np.array(excitation["b"]), q0=excitation["q0"])
    qs, us = noisy_periods(q, u, 10, 1e-4, 0.5, np.random.default_rng(3))
    joint = tmp_path / "joint.csv"
    recording.write_recording(joint, recording.make_recording(np.arange(qs.size) * 1e-3, {"q": qs, "u": us},
                                                              {"q": "rad", "u": "N.m"}, sample_time=1e-3))
    fit = tmp_path / "fit.json"
    assert main(["identify", "joint", str(joint), "--f0", "0.5", "--cutoff", "10", "--min-speed", "0.2",
                 "--out", str(fit)]) == 0
    estimate = np.array([json.loads(fit.read_text())["regressor_parameters"][n] for n in NAMES])
    assert np.all(np.abs(estimate / TRUTH - 1) < 0.03), estimate / TRUTH - 1
    capsys.readouterr()
    bad = tmp_path / "bad.toml"
    assert main(["design-excitation", "joint", "--f0", "0.3", "--harmonics", "5", *limits, "--sample-time", "7e-4",
                 "--out", str(bad)]) == 1
    assert "--sample-time" in capsys.readouterr().err and not bad.exists()


def test_the_command_runs_blas_single_threaded_unless_told_otherwise():
    """motiontwin sets one BLAS thread per process (its workers inherit it) before numpy loads; a value the user
    set is kept."""
    import os
    import subprocess
    import sys

    code = ("import motiontwin.cli, numpy, threadpoolctl; "
            "print(max(p['num_threads'] for p in threadpoolctl.threadpool_info() if p['user_api'] == 'blas'))")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                            "MKL_NUM_THREADS")}
    ours = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    theirs = subprocess.run([sys.executable, "-c", code], env={**env, "OPENBLAS_NUM_THREADS": "2"},
                            capture_output=True, text=True, timeout=120)
    assert ours.stdout.split() == ["1"], ours.stderr
    assert theirs.stdout.split() == ["2"], theirs.stderr
