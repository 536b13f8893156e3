"""Channel check (ident.channels, issue 23 item 5): u = controller(r, q) + u_ext before any fit.

Reference: a benchmark bundle whose u the generator computed as controller(r, q_measured) + u_ext in its own
closed-loop simulation; each wrong channel is made from it by a known transformation (u_ext in volts = force/20,
u with its sign flipped, u shifted by 2 samples, u_ext left out of u), so the right answer is known. A correct
bundle must pass, with and without extra white noise on u.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from motiontwin.harness.recording import make_recording, read_recording, write_recording
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.channels import channel_problem, check_channels, controller_responses
from motiontwin.ident.controller import Controller, load_controller
from motiontwin.ident.diagnosis import main


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("channels") / "bundle"
    bench.write_bundle(folder, "gravity_offset", seed=3, durations=(1.5, 1.0), sweep_fraction=0.5)
    return folder


def _edited(rec, **columns):
    cols = {k: rec[k] for k in rec.columns if k != "time"}
    for name, value in columns.items():
        if value is None:
            cols.pop(name)
        else:
            cols[name] = value
    return make_recording(rec.time, cols, sample_time=rec.sample_time)


def test_each_wrong_channel_is_named_and_a_correct_one_passes(bundle):
    ctrl = load_controller(bundle / "experiment.json")
    rec = read_recording(bundle / "train.csv", ["r", "u", "q", "u_ext"])
    u, e = rec["u"], rec["u_ext"]
    assert np.max(np.abs(e)) > 1.0                 # the u_ext sweep is in the recording
    assert channel_problem(rec, ctrl) is None
    noisy = _edited(rec, u=u + 0.02 * np.random.default_rng(1).standard_normal(u.size))
    assert channel_problem(noisy, ctrl) is None    # white noise on u is no mismatch
    volts = check_channels(_edited(rec, u_ext=e / 20), ctrl)[0]
    assert not volts.consistent and volts.ext_gain == pytest.approx(20, rel=1e-6) and volts.delay == 0
    assert "u_ext is scaled by 20" in volts.cause
    flipped = check_channels(_edited(rec, u=-u), ctrl)[0]
    assert not flipped.consistent and "sign flip" in flipped.cause
    late = check_channels(_edited(rec, u=np.r_[u[:2], u[:-2]]), ctrl)[0]
    assert not late.consistent and late.delay == 2 and "delay of 2 samples" in late.cause
    scaled = check_channels(_edited(rec, u=1.5 * u), ctrl)[0]
    assert not scaled.consistent and scaled.gain == pytest.approx(1.5, rel=1e-6) and "1.5 *" in scaled.cause
    without = check_channels(_edited(rec, u=u - e), ctrl)[0]
    assert not without.consistent and "u_ext is not in u" in without.cause
    missing = check_channels(_edited(rec, u_ext=None), ctrl)[0]
    assert not missing.consistent and "missing u_ext" in missing.cause


def test_diagnose_refuses_a_disturbance_channel_in_volts(bundle, tmp_path, capsys):
    wrong = tmp_path / "volts"
    shutil.copytree(bundle, wrong)
    for part in ("train", "validation"):
        rec = read_recording(wrong / f"{part}.csv", ["r", "u", "q", "u_ext"])
        write_recording(wrong / f"{part}.csv", _edited(rec, u_ext=rec["u_ext"] / 20))
    out = tmp_path / "out"
    assert main([str(wrong), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(wrong / "train.csv") in err and "u_ext is scaled by 20" in err and err.count("\n") == 1
    assert not out.exists()


def test_controller_responses_are_scipys_and_kept_by_content():
    """The forced response against scipy.signal.dlsim from rest and the free-response rows against C A^k; kept
    by the contents of the controller and of y: a changed sample or a changed gain gives the new response, not
    the one kept, and what is kept cannot be written to."""
    rng = np.random.default_rng(0)
    A = np.array([[1.0, 1e-3], [0.0, 0.9]])
    B = np.array([[1e-3, -1e-3], [0.2, -0.2]])
    C = np.array([[50.0, 3.0]])
    D = np.array([[400.0, -400.0]])
    ctrl = Controller(1e-3, A, B, C, D)
    y = rng.standard_normal((2, 300))
    p, g = controller_responses(ctrl, y)
    assert controller_responses(ctrl, y)[0] is p
    _, expected, _ = signal.dlsim((A, B, C, D, 1e-3), y.T)
    np.testing.assert_allclose(p[0], expected[:, 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g[0, 17], C[0] @ np.linalg.matrix_power(A, 17), rtol=1e-12)
    assert not p.flags.writeable and not g.flags.writeable
    changed = y.copy()
    changed[1, 100] += 1.0
    p2, _ = controller_responses(ctrl, changed)
    np.testing.assert_array_equal(p2[0, :100], p[0, :100])
    assert p2[0, 100] == pytest.approx(p[0, 100] - 400.0)
    p3, _ = controller_responses(Controller(1e-3, A, B, C, 2 * D), y)
    np.testing.assert_allclose(p3[0] - p[0], (D @ y)[0], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("samples", [500, 3000, 24000])
def test_noise_level_of_white_noise_is_its_standard_deviation_at_any_length(samples: int) -> None:
    """The encoder-noise level the diagnosis weighs and floors with, on white noise of known standard deviation:
    within 3 % on average over 200 draws, for a recording shorter than one Welch segment (the median of one
    periodogram read it 17 % low) as for a long one."""
    from motiontwin.ident.channels import noise_level

    rng = np.random.default_rng(samples)
    levels = [noise_level(2e-8 * rng.standard_normal(samples), 5e-4) for _ in range(200)]
    assert np.mean(levels) == pytest.approx(2e-8, rel=0.03)
