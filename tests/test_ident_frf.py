"""Cheung's joint model: FRF (H1, swept sine, acceleration from encoder) fit and PEM of L(s).

Truth simulated with scipy.signal.lsim on the continuous model with a zero-order-hold input (independent
of the python-control c2d used inside the fit). Noise: encoder resolution 0.1 um plus white 0.2 um.
"""
import numpy as np
import pytest
import scipy.signal

from motiontwin.ident.frf import (
    JointModel,
    acceleration_from_position,
    estimate_frf,
    fit_joint_frf,
    fit_low_frequency_model,
    second_difference_response,
)

FS = 2000.0  # Cheung's controller rate
TRUTH = JointModel(50.0, 20.0, ((2 * np.pi * 220, 0.04),), ((2 * np.pi * 150, 0.03),))
RESOLUTION = 1e-7


def _simulate(u: np.ndarray, rng) -> np.ndarray:
    tf = TRUTH.transfer_function()
    t = np.arange(u.size) / FS
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, t, interp=False)
    q = q + 2e-7 * rng.standard_normal(q.size)
    return np.round(q / RESOLUTION) * RESOLUTION


def test_second_difference_response_matches_its_fft():
    impulse = np.zeros(64)
    impulse[[0, 1, 2]] = [1.0, -2.0, 1.0]
    f = np.fft.rfftfreq(64, 1 / FS)
    h = np.fft.rfft(impulse) * FS**2 * np.exp(2j * np.pi * f / FS)  # centre the stencil
    np.testing.assert_allclose(h, second_difference_response(f, FS), atol=1e-6 * FS**2)


def test_swept_sine_fit_recovers_gain_alpha_and_mode_frequencies():
    rng = np.random.default_rng(0)
    t = np.arange(int(60 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=0.5, f1=500, t1=t[-1], method="logarithmic")
    q = _simulate(u, rng)
    frf = estimate_frf(u[1:-1], acceleration_from_position(q, FS), FS, 4096)
    assert np.median(frf.band(100, 400).coherence) > 0.95
    fit = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9)
    m = fit.model
    assert m.gain == pytest.approx(TRUTH.gain, rel=0.02)
    assert m.alpha == pytest.approx(TRUTH.alpha, rel=0.02)
    assert m.resonances[0][0] == pytest.approx(TRUTH.resonances[0][0], rel=0.02)
    assert m.antiresonances[0][0] == pytest.approx(TRUTH.antiresonances[0][0], rel=0.02)
    assert m.resonances[0][1] == pytest.approx(TRUTH.resonances[0][1], rel=0.1)
    assert fit.rms_log_error < 0.05


def test_fit_without_hold_model_is_biased():
    """The ZOH matters at 2 kHz: ignoring it (continuous P) misplaces the modes by more than 2 %."""
    rng = np.random.default_rng(1)
    t = np.arange(int(30 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=20, f1=500, t1=t[-1], method="logarithmic")
    frf = estimate_frf(u[1:-1], acceleration_from_position(_simulate(u, rng), FS), FS, 4096)
    exact = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9,
                          initial=TRUTH).model
    naive = fit_joint_frf(frf, output="acceleration", sample_rate=FS, min_coherence=0.9,
                          initial=TRUTH, zero_order_hold=False).model
    err = lambda m: abs(m.resonances[0][0] / TRUTH.resonances[0][0] - 1)
    assert err(exact) < 0.005 and err(naive) > 4 * err(exact)


def test_low_coherence_is_reported():
    rng = np.random.default_rng(2)
    frf = estimate_frf(rng.standard_normal(8192), rng.standard_normal(8192), FS, 1024)
    with pytest.raises(ValueError, match="too little excitation"):
        fit_joint_frf(frf, sample_rate=FS, min_coherence=0.9)


def test_point_to_point_pem_recovers_low_frequency_model():
    rng = np.random.default_rng(3)
    n = int(0.2 * FS)
    u = np.zeros(n)
    u[: int(0.035 * FS)] = 0.05  # bang-bang move of about 70 ms, then coast
    u[int(0.035 * FS): int(0.07 * FS)] = -0.05
    rigid = JointModel(TRUTH.gain, TRUTH.alpha)
    tf = rigid.transfer_function()
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, np.arange(n) / FS, interp=False)
    q = np.round((q + 2e-7 * rng.standard_normal(n)) / RESOLUTION) * RESOLUTION
    fit = fit_low_frequency_model(u, q, FS, initial=(10.0, 5.0))
    assert fit.gain == pytest.approx(TRUTH.gain, rel=0.02)
    assert fit.alpha == pytest.approx(TRUTH.alpha, rel=0.02)
    assert np.sqrt(fit.covariance[1, 1]) < 0.02 * TRUTH.alpha


def _sweep_recording(model: JointModel, seed: int):
    """A 40 s logarithmic swept sine through ``model`` (lsim with ZOH input), as a recording in m and N."""
    from motiontwin.harness.recording import make_recording

    rng = np.random.default_rng(seed)
    t = np.arange(int(40 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=0.5, f1=500, t1=t[-1], method="logarithmic")
    tf = model.transfer_function()
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, t, interp=False)
    q = np.round((q + 2e-7 * rng.standard_normal(q.size)) / RESOLUTION) * RESOLUTION
    return make_recording(t, {"u": u, "q": q}, {"u": "N", "q": "m"}, sample_time=1 / FS)


def test_worst_case_over_positions_selects_the_lowest_gain_within_2_percent():
    """Cheung: the model with the lowest gain over the actuator positions is the design model."""
    from motiontwin.ident.frf import frf_document, identify_frf_worst_case

    w = 2 * np.pi
    positions = {  # gain and modes change with the position, as the effective inertia does
        "near.csv": JointModel(55.0, 20.0, ((w * 230, 0.04),), ((w * 160, 0.03),)),
        "far.csv": JointModel(38.0, 18.0, ((w * 200, 0.05),), ((w * 135, 0.03),)),
        "mid.csv": JointModel(46.0, 22.0, ((w * 215, 0.04),), ((w * 150, 0.03),)),
    }
    recordings = [_sweep_recording(m, seed) for seed, m in enumerate(positions.values())]
    worst, notes = identify_frf_worst_case(recordings, list(positions))
    assert notes == []
    assert worst.labels[worst.selected] == "far.csv"
    truth, fit = positions["far.csv"], worst.model
    assert fit.gain == pytest.approx(truth.gain, rel=0.02)
    assert fit.alpha == pytest.approx(truth.alpha, rel=0.02)
    assert fit.resonances[0][0] == pytest.approx(truth.resonances[0][0], rel=0.02)
    assert fit.antiresonances[0][0] == pytest.approx(truth.antiresonances[0][0], rel=0.02)
    for label, f in zip(worst.labels, worst.fits):  # every position is fitted, not only the worst
        assert f.model.gain == pytest.approx(positions[label].gain, rel=0.02)
    table = worst.table().splitlines()
    assert len(table) == 5 and table[2].startswith("* far.csv")
    doc = frf_document(worst, worst.labels)
    assert doc["recording"] == "far.csv" and doc["parameters"]["K"] == fit.gain
    assert set(doc["parameters"]) == {"K", "alpha", "omega", "zeta", "omega_bar", "zeta_bar"}
    assert [row["recording"] for row in doc["worst_case"]["positions"]] == list(positions)
    assert doc["worst_case"]["selected"] == 1


def test_cli_handler_writes_the_worst_case_document(tmp_path, capsys):
    """The proposed `motiontwin identify frf A.csv B.csv --worst-case --out fit.json` handler."""
    import json

    from motiontwin.cli import main
    from motiontwin.harness.recording import write_recording

    w = 2 * np.pi
    models = [JointModel(52.0, 20.0, ((w * 220, 0.04),), ((w * 150, 0.03),)),
              JointModel(41.0, 20.0, ((w * 205, 0.04),), ((w * 140, 0.03),))]
    paths = []
    for k, model in enumerate(models):
        paths.append(tmp_path / f"position{k}.csv")
        write_recording(paths[-1], _sweep_recording(model, 10 + k))
    out = tmp_path / "fit.json"
    args = ["identify", "frf", *map(str, paths), "--segment", "4096", "--out", str(out)]
    assert main([*args, "--worst-case"]) == 0
    doc = json.loads(out.read_text())
    assert doc["recording"] == str(paths[1]) and doc["worst_case"]["selected"] == 1
    assert doc["parameters"]["K"] == pytest.approx(41.0, rel=0.02)
    assert "worst case (lowest K)" in capsys.readouterr().out
    assert main(args) == 1
    assert "pass --worst-case" in capsys.readouterr().err


CHEUNG_DEFAULTS = JointModel(1.0, 10.0, ((2450.0, 0.05),), ((1885.0, 0.05),))  # CheungJoint FMU defaults


def _recording_through(model: JointModel, t: np.ndarray, u: np.ndarray, seed: int):
    """``u`` (held, ZOH) through ``model`` by lsim, with the encoder noise and resolution, in m and N."""
    from motiontwin.harness.recording import make_recording

    tf = model.transfer_function()
    _, q, _ = scipy.signal.lsim((tf.num[0][0], tf.den[0][0]), u, t - t[0], interp=False)
    q = np.round((q + 2e-7 * np.random.default_rng(seed).standard_normal(q.size)) / RESOLUTION) * RESOLUTION
    return make_recording(t, {"u": u, "q": q}, {"u": "N", "q": "m"}, sample_time=1 / FS)


def test_cli_80_500_hz_sweep_with_point_to_point_move_recovers_cheung_joint_within_2_percent(tmp_path, capsys):
    """Cheung's split: the 80-500 Hz sweep (harness/experiments/swept_sine_80_500.toml, 2.2 s) gives the mass
    line and the pair, a point-to-point move gives alpha by PEM (`identify frf SWEEP --low-frequency MOVE`).
    Without the move alpha is held (given or default) and the output says so."""
    import json
    from pathlib import Path

    from motiontwin.harness import experiment
    from motiontwin.cli import main
    from motiontwin.harness.recording import write_recording
    from motiontwin.ident.frf import DEFAULT_ALPHA

    root = Path(__file__).resolve().parents[1]
    sig = experiment.load_experiment(root / "harness/experiments/swept_sine_80_500.toml").generate()
    sweep, move = tmp_path / "sweep.csv", tmp_path / "move.csv"
    write_recording(sweep, _recording_through(CHEUNG_DEFAULTS, sig["time"], sig["value"], 20))
    t = np.arange(int(0.2 * FS)) / FS
    u = np.where(t < 0.035, 4.0, np.where(t < 0.07, -4.0, 0.0))  # about 5 mm in 70 ms, then coast
    write_recording(move, _recording_through(CHEUNG_DEFAULTS, t, u, 21))
    out = tmp_path / "frf.json"
    assert main(["identify", "frf", str(sweep), "--low-frequency", str(move), "--out", str(out)]) == 0
    assert "from the point-to-point PEM" in capsys.readouterr().out
    fit = json.loads(out.read_text())["parameters"]
    assert fit["K"] == pytest.approx(CHEUNG_DEFAULTS.gain, rel=0.02)
    assert fit["alpha"] == pytest.approx(CHEUNG_DEFAULTS.alpha, rel=0.02)
    assert fit["omega"] == pytest.approx(CHEUNG_DEFAULTS.resonances[0][0], rel=0.02)
    assert fit["omega_bar"] == pytest.approx(CHEUNG_DEFAULTS.antiresonances[0][0], rel=0.02)

    assert main(["identify", "frf", str(sweep), "--alpha", "12", "--out", str(out)]) == 0
    assert "alpha = 12 1/s held as given" in capsys.readouterr().out
    fit = json.loads(out.read_text())["parameters"]
    assert fit["alpha"] == 12.0 and fit["K"] == pytest.approx(CHEUNG_DEFAULTS.gain, rel=0.02)

    assert main(["identify", "frf", str(sweep), "--out", str(out)]) == 0
    assert "alpha is not determined by the sweep band" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["parameters"]["alpha"] == DEFAULT_ALPHA and "held at the default" in doc["notes"][0]
    assert doc["parameters"]["omega"] == pytest.approx(CHEUNG_DEFAULTS.resonances[0][0], rel=0.02)
    assert main(["identify", "frf", str(sweep), "--segment", "4096"]) == 1  # one segment: coherence == 1
    assert "1 Welch average(s)" in capsys.readouterr().err
