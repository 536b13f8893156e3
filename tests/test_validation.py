"""motiontwin validate (ident.validation): compare/resid of a fitted model on a new recording.

References: the exact zero-order-hold discretisation of m q'' = u - d q' (scipy.signal.cont2discrete), independent
of the re-simulation's RK4 chain, with seeded white encoder noise, so the right model's fit % is known in closed form,
100 (1 - ||noise|| / ||y - mean y||), and its residual is the white noise; a model with a 10 % mass error must fail the
whiteness test. Closed loop: the same exact plant in a sampled PD loop run here in numpy.
"""
import json

import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.cli import main
from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording, read_recording, write_recording
from motiontwin.ident import validation
from motiontwin.ident.controller import Controller, controller_document

CLASS = "MotionTwin.Plants.LinearMotorJoint"
TS, N = 5e-4, 4000
NOISE = 2e-6


def zoh_plant(m: float, d: float) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([[0.0, 1.0], [0.0, -d / m]])
    b = np.array([[0.0], [1.0 / m]])
    ad, bd, *_ = sps.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), TS, "zoh")
    return ad, bd[:, 0]


def open_loop_data(m: float, d: float, seed: int = 1):
    t = np.arange(N) * TS
    phases = np.random.default_rng(99).uniform(0, 2 * np.pi, 20)
    u = 20 * sum(np.sin(2 * np.pi * (k + 1) * t + p) for k, p in enumerate(phases)) / np.sqrt(20)
    ad, bd = zoh_plant(m, d)
    x, q = np.array([1e-3, 0.02]), np.zeros(N)     # starts at 1 mm, moving at 20 mm/s: both are estimated
    for k in range(N):
        q[k] = x[0]
        x = ad @ x + bd * u[k]
    noise = NOISE * np.random.default_rng(seed).standard_normal(N)
    return t, u, q, noise


def test_right_model_fits_to_the_noise_and_passes_a_wrong_one_fails(tmp_path, capsys):
    t, u, q, noise = open_loop_data(2.6, 14.0)
    path = tmp_path / "new.csv"
    write_recording(path, make_recording(t, {"q": q + noise, "u": u}, sample_time=TS))
    fitted = tmp_path / "oe.json"
    fitted.write_text(json.dumps({"class": CLASS, "parameters": {"m": 2.6, "d": 14.0}}))
    out, plot = tmp_path / "val.json", tmp_path / "val.png"
    assert main(["validate", str(fitted), str(path), "--out", str(out), "--plot", str(plot)]) == 0
    doc = json.loads(out.read_text())
    y = q + noise
    expected_fit = 100 * (1 - np.linalg.norm(noise) / np.linalg.norm(y - y.mean()))
    assert doc["fit_percent"] == pytest.approx(expected_fit, abs=1e-5)
    assert doc["rms"] == pytest.approx(np.sqrt(np.mean(noise ** 2)), rel=0.01)
    assert doc["initial_states"]["x"] == pytest.approx(1e-3, abs=1e-6)     # within half the noise std
    assert doc["initial_states"]["v"] == pytest.approx(0.02, abs=2e-3)
    assert doc["residual_autocorrelation"]["passed"] and doc["input_residual_cross_correlation"]["passed"]
    assert plot.stat().st_size > 10_000
    assert "white" in capsys.readouterr().out
    wrong = tmp_path / "wrong.json"
    assert main(["validate", str(fitted), str(path), "--set", "m=2.86", "--out", str(wrong)]) == 0
    bad = json.loads(wrong.read_text())
    assert bad["fit_percent"] < 95 and not bad["residual_autocorrelation"]["passed"]
    assert "NOT white" in capsys.readouterr().out


def test_autocorrelation_band_and_statistic_by_hand():
    e = np.random.default_rng(3).standard_normal(1000)
    test = validation.autocorrelation_test(e, lags=5)
    e0 = e - e.mean()
    by_hand = np.array([e0[:-k] @ e0[k:] / (e0 @ e0) for k in range(1, 6)])
    np.testing.assert_allclose(test.values, by_hand, rtol=1e-12)
    assert test.band == pytest.approx(2.5758293 / np.sqrt(1000), rel=1e-6)
    assert test.statistic == pytest.approx(1000 * np.sum(by_hand ** 2), rel=1e-12)
    assert test.threshold == pytest.approx(15.0862725, rel=1e-6)        # chi-square 99 % with 5 dof


def test_fmu_model_from_its_start_values(tmp_path):
    fmu = build.build_fmu(build.load_model(CLASS), tmp_path / "fmus", "2.0").path   # defaults m = 2, d = 10
    t, u, q, noise = open_loop_data(2.0, 10.0, seed=2)
    spec = validation.load_model_spec(fmu)
    assert spec.class_name == CLASS and spec.values == {"m": 2.0, "d": 10.0}
    result = validation.validate(build.load_model(spec.class_name), spec,
                                 make_recording(t, {"q": q + noise, "u": u}, sample_time=TS))
    y = q + noise
    assert result.fit_percent == pytest.approx(100 * (1 - np.linalg.norm(noise) / np.linalg.norm(y - y.mean())),
                                               abs=1e-5)
    assert result.autocorrelation.passed


def closed_loop_data(m: float, d: float, noise: float = 0.0, u_ext: float = 0.0):
    """A sampled PD loop (numpy) around the exact ZOH plant; the controller sees q + noise, u holds u_ext."""
    kp, kd, tau = 2e4, 300.0, 1e-3
    a, b, c, dd, _ = sps.cont2discrete(tuple(np.array([[v]]) for v in (-1 / tau, 1.0, -kd / tau ** 2,
                                                                       kp + kd / tau)), TS, "bilinear")
    ctrl = Controller(TS, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([dd, -dd]))
    t = np.arange(N) * TS
    r = 1e-3 * np.sin(2 * np.pi * 2 * t) + 5e-4 * np.sin(2 * np.pi * 7 * t)
    ext = u_ext * np.sin(2 * np.pi * 13 * t)
    n = noise * np.random.default_rng(5).standard_normal(N)
    ad, bd = zoh_plant(m, d)
    x, z = np.zeros(2), np.zeros(1)
    q, u = np.zeros(N), np.zeros(N)
    for k in range(N):
        y = np.array([r[k], x[0] + n[k]])
        q[k], u[k] = x[0] + n[k], (ctrl.C @ z + ctrl.D @ y).item() + ext[k]
        z = ctrl.A @ z + ctrl.B @ y
        x = ad @ x + bd * u[k]
    return ctrl, {"r": r, "u": u, "q": q, "u_ext": ext}


def test_closed_loop_resimulation_reproduces_an_independent_loop(tmp_path):
    ctrl, columns = closed_loop_data(2.6, 14.0)
    del columns["u_ext"]
    path = tmp_path / "loop.csv"
    write_recording(path, make_recording(np.arange(N) * TS, columns, sample_time=TS))
    controller = tmp_path / "ctrl.json"
    controller.write_text(json.dumps(controller_document(ctrl)))
    out = tmp_path / "val.json"
    assert main(["validate", "-", str(path), "--class", CLASS, "--set", "m=2.6", "--set", "d=14",
                 "--controller", str(controller), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["loop"] == "closed" and doc["fit_percent"] > 99.999 and doc["rms"] < 1e-9


def test_bad_input_is_one_message(tmp_path, capsys):
    t, u, q, noise = open_loop_data(2.6, 14.0)
    path = tmp_path / "new.csv"
    write_recording(path, make_recording(t, {"q": q + noise, "u": u}, sample_time=TS))
    assert main(["validate", "-", str(path), "--class", CLASS, "--set", "mass=3"]) == 1
    assert "has no parameter 'mass'; its parameters are m, d" in capsys.readouterr().err
    controller = tmp_path / "ctrl.json"
    controller.write_text(json.dumps(controller_document(Controller(TS, np.zeros((0, 0)), np.zeros((0, 2)),
                                                                    np.zeros((1, 0)), np.array([[1e4, -1e4]])))))
    assert main(["validate", "-", str(path), "--class", CLASS, "--controller", str(controller)]) == 1
    assert "required column 'r' missing" in capsys.readouterr().err
    diagnosis = tmp_path / "multi"      # a multi-axis diagnose output: said so, not "column 'q' missing"
    (diagnosis / "fmu" / "fmi2").mkdir(parents=True)
    (diagnosis / "fmu" / "fmi2" / "Augmented.fmu").write_bytes(b"")
    (diagnosis / "diagnosis.json").write_text(json.dumps({"validation": {"per_axis": {"q1": {}, "q2": {}}}}))
    assert main(["validate", str(diagnosis), str(path)]) == 1
    assert "a multi-axis diagnosis (axes q1, q2); validate re-simulates one axis" in capsys.readouterr().err


def test_identify_oe_and_validate_report_one_rms(tmp_path, capsys):
    """Issue 23 item 6: identify oe and validate of the model it returns, on the same closed-loop recording (with
    u_ext and encoder noise), print and write the same RMS output error; it is the RMS of measured minus the
    validate re-simulation, recomputed here from that re-simulation."""
    ctrl, columns = closed_loop_data(2.6, 14.0, noise=2e-7, u_ext=20.0)
    path = tmp_path / "loop.csv"
    write_recording(path, make_recording(np.arange(N) * TS, columns, sample_time=TS))
    controller = tmp_path / "ctrl.json"
    controller.write_text(json.dumps(controller_document(ctrl)))
    fitted, checked = tmp_path / "oe.json", tmp_path / "val.json"
    assert main(["identify", "oe", str(path), "--class", CLASS, "--free", "m,d", "--set", "m=2", "--set", "d=10",
                 "--controller", str(controller), "--out", str(fitted)]) == 0
    printed_oe = capsys.readouterr().out
    assert main(["validate", str(fitted), str(path), "--controller", str(controller), "--out", str(checked)]) == 0
    printed_val = capsys.readouterr().out
    oe, val = json.loads(fitted.read_text()), json.loads(checked.read_text())
    assert oe["parameters"]["m"] == pytest.approx(2.6, rel=1e-3)
    assert val["rms"] == pytest.approx(oe["rms_output_error"], rel=1e-9)
    assert 1e-7 < val["rms"] < 4e-7                      # about the encoder noise, 2e-7
    line = f"RMS output error {val['rms']:.4g} m ({validation.RMS_DEFINITION}"
    assert line in printed_oe and line in printed_val
    assert "columns r, u_ext -> q, u only checked; channel check: u = controller(r, q) + u_ext within noise" \
        in printed_val
    spec = validation.load_model_spec(fitted)
    again = validation.validate(build.load_model(CLASS), spec, read_recording(path, ["r", "u", "q"]), controller=ctrl)
    assert np.sqrt(np.mean((again.measured - again.simulated) ** 2)) == pytest.approx(oe["rms_output_error"],
                                                                                       rel=1e-9)
    assert main(["validate", str(fitted), str(path), "--controller", str(controller), "--initial-from-data"]) == 0
    assert f"({validation.RMS_FROM_DATA})" in capsys.readouterr().out     # the line says how the run started


def test_parameter_on_its_bound_prints_at_bound(tmp_path, capsys):
    """A negative true damping: the fit holds d on its Modelica minimum 0; the table says "at bound", the JSON has
    no std for d, and m's std is that of a fit with d fixed at 0 (the conditional statistics)."""
    t, u, q, noise = open_loop_data(2.6, -0.5)
    path = tmp_path / "run.csv"
    write_recording(path, make_recording(t, {"q": q + noise, "u": u}, sample_time=TS))
    both, alone = tmp_path / "both.json", tmp_path / "alone.json"
    assert main(["identify", "oe", str(path), "--class", CLASS, "--free", "m,d", "--set", "m=2", "--set", "d=1",
                 "--initial", "rest", "--out", str(both)]) == 0
    printed = capsys.readouterr().out
    row = next(line for line in printed.splitlines() if line.split()[:1] == ["d"])
    assert "at bound 0" in row and "e+" not in row, printed
    doc = json.loads(both.read_text())
    assert doc["at_bound"] == {"d": 0.0} and doc["std"]["d"] is None and doc["parameters"]["d"] == pytest.approx(0)
    assert main(["identify", "oe", str(path), "--class", CLASS, "--free", "m", "--set", "m=2", "--set", "d=0",
                 "--initial", "rest", "--out", str(alone)]) == 0
    ref = json.loads(alone.read_text())
    assert doc["parameters"]["m"] == pytest.approx(ref["parameters"]["m"], rel=1e-6)
    assert doc["std"]["m"] == pytest.approx(ref["std"]["m"], rel=1e-3)
