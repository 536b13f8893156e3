"""identify joint on lab-like data: jittered time stamps, the sidecar's sample time, samples beyond whole periods,
and a heavy prismatic axis with Coulomb friction and a constant force (issue 13: 95 kg, Coulomb ~20 N + offset).

Reference: the truth parameters of the inverse dynamics m*a + d*v + Fc*sign(v) + F0 along an analytic Fourier
trajectory (exact derivatives from harness.excitation), with seeded white noise on position and force.
"""
import json

import numpy as np
import pytest

from motiontwin.cli import main
from motiontwin.harness import recording
from motiontwin.ident.joint import find_period, identify_joint_recording
from motiontwin.ident.maximum_likelihood import identify_joint_ml_recording
from motiontwin.harness.excitation import fourier_trajectory

TRUTH = {"m": 95.0, "d": 60.0, "Fc": 20.6, "F0": -3.2}
FS, F0 = 1000.0, 0.5
N = int(7 * FS / F0) + 1400           # 7 periods and 1.4 s more


def lab_axis(jitter: float = 2e-8, seed: int = 0, sample_time: float | None = 1 / FS) -> recording.Recording:
    """A 95 kg axis around 0.24 m, 2e-8 s clock jitter, 1 um / 2 N noise, sidecar sample time 1 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    motion = fourier_trajectory(t, F0, 0.012 * np.array([1.0, -0.5, 0.3]), 0.012 * np.array([0.4, 0.6, -0.2]), 0.24)
    q, v, a = motion.position, motion.velocity, motion.acceleration
    force = TRUTH["m"] * a + TRUTH["d"] * v + TRUTH["Fc"] * np.tanh(v / 1e-4) + TRUTH["F0"]
    time = t + rng.uniform(-jitter, jitter, N)
    return recording.make_recording(time, {"q": q + 1e-6 * rng.standard_normal(N),
                                           "u": force + 2.0 * rng.standard_normal(N)}, sample_time=sample_time)


def test_default_model_of_a_linear_axis_recovers_mass_coulomb_and_offset(tmp_path, capsys):
    path = tmp_path / "axis.csv"
    recording.write_recording(path, lab_axis())
    out = tmp_path / "fit.json"
    assert main(["identify", "joint", str(path), "--f0", "0.5", "--cutoff", "10", "--min-speed", "0.005",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "sample time 0.001 s from the sidecar's sample_time; time-stamp jitter up to 3.99e-08 s" in printed
    assert "trimmed to 7 whole periods of 2000 samples: dropped the last 1400 samples (1.4 s" in printed
    assert "linear axis (m): friction 'symmetric', gravity 'constant'" in printed
    doc = json.loads(out.read_text())
    assert doc["class"] == "MotionTwin.Plants.PrismaticAxis"
    for name in ("m", "Fc", "F0"):
        assert doc["parameters"][name] == pytest.approx(TRUTH[name], rel=0.02), name
    for name, value in TRUTH.items():
        assert abs(doc["parameters"][name] - value) < 4 * doc["std"][name], name
    # the asymmetric reading of the same axis: Coulomb 20.6 N + offset -3.2 N = 17.4 N / 23.8 N
    assert "fc_pos = fc + F0 = 17.4" in printed and "fc_neg = fc - F0 = 23.8" in printed


def test_revolute_default_on_a_linear_axis_is_meaningless():
    """Why the default changed: sine gravity on metres makes cos(q) nearly constant, collinear with the two
    Coulomb columns; the Coulomb levels then come out in the kN range against a truth of ~20 N."""
    result, _ = identify_joint_recording(lab_axis(), F0, 10.0, min_speed=0.005, friction="asymmetric",
                                         gravity="sine")
    fit = result.fit.as_dict()
    assert result.fit.correlation_condition > 1e8
    assert abs(fit["fc_pos"]) > 1e3 and abs(fit["fc_neg"]) > 1e3


def test_record_problems_are_one_message(tmp_path, capsys):
    rec = lab_axis(jitter=2e-6, sample_time=None)      # 2e-3 of Ts: beyond the format's tolerance
    with pytest.raises(ValueError, match=r"column 'time': steps deviate .* \(motiontwin import --resample\)"):
        identify_joint_recording(rec, F0, 10.0)
    with pytest.raises(ValueError, match=r"f0 = 0.3 Hz is 3333.33333 samples .* not a whole number"):
        identify_joint_recording(lab_axis(), 0.3, 10.0)
    with pytest.raises(ValueError, match=r"hold 1.2 periods of 2000 samples; at least 2 whole periods"):
        short = lab_axis()
        identify_joint_recording(recording.make_recording(short.time[:2400], {k: v[:2400] for k, v in
                                                                              short.columns.items()}), F0, 10.0)
    with pytest.raises(ValueError, match=r"linear position \(m\); the maximum-likelihood fit models a revolute"):
        identify_joint_ml_recording(lab_axis(), F0, 10.0)
    with pytest.raises(SystemExit):
        main(["identify", "joint", "--help"])
    text = capsys.readouterr().out
    for option in ("--friction {auto,asymmetric,symmetric,viscous,none}", "--gravity {auto,sine,constant,none}",
                   "--min-speed", "--nominal-inertia", "--ml", "--cutoff-range", "--out"):
        assert option in text, option


@pytest.mark.parametrize("fs, f0, periods, harmonics", [
    (1000.0, 0.5, 7, (1, 2, 3)),          # the lab axis: 2000 samples per period
    (2000.0, 1 / 3, 3, (1, 2, 3)),        # 6000 samples, 3 periods
    (1000.0, 0.1562, 2.5, (1, 2, 3)),     # 6402.05 samples: the nearest whole number
    (2000.0, 1.0, 5, tuple(range(3, 21))),  # a multisine without its fundamental (harmonics 3..20)
])
def test_the_period_found_in_the_spectrum_is_the_true_one(fs, f0, periods, harmonics):
    """Reference: the period 1/f0 of the synthesised trajectory, in samples, with noise of 1 % of its RMS (100x
    an encoder's on this stroke; at 5 % three slow periods no longer tell 6000 from 5999 samples)."""
    rng = np.random.default_rng(7)
    t = np.arange(int(periods * fs / f0)) / fs
    x = sum(np.sin(2 * np.pi * h * f0 * t + rng.uniform(0, 2 * np.pi)) / h for h in harmonics)
    x = x + 0.01 * np.std(x) * rng.standard_normal(t.size)
    assert find_period(x) == round(fs / f0)


def test_no_period_in_noise_is_one_message():
    with pytest.raises(ValueError, match=r"no period found: no lag up to 2000 samples repeats the signal"):
        find_period(np.random.default_rng(0).standard_normal(4000))


def test_identify_joint_without_f0_on_a_time_column_with_round_off(tmp_path, capsys):
    """1 kHz, no sidecar sample time, time stamps scattered by +-4e-8 s around a median step of 0.000999984 s
    (the issue's recording): the step snaps to the 1 ms clock, the period is found (2000 samples, 0.5 Hz) and
    printed, and the fit recovers the truth as with --f0; --f0 0.5 on the same file works too."""
    rec = lab_axis(jitter=0.0, sample_time=None)
    noise = np.random.default_rng(3).uniform(-4e-8, 4e-8, N - 1)
    time = np.concatenate([[0.0], np.cumsum(0.000999984 + noise - np.median(noise))])
    path = tmp_path / "axis.csv"
    recording.write_recording(path, recording.make_recording(time, dict(rec.columns)))
    assert float(np.median(np.diff(recording.read_recording(path).time))) == pytest.approx(0.000999984, rel=1e-9)
    for f0 in ([], ["--f0", "0.5"]):
        out = tmp_path / "fit.json"
        assert main(["identify", "joint", str(path), *f0, "--cutoff", "10", "--min-speed", "0.005",
                     "--out", str(out)]) == 0, capsys.readouterr().err
        printed = capsys.readouterr().out
        assert "sample time 0.001 s from the median time step 0.000999984 s snapped to the clock" in printed
        assert ("excitation period 2000 samples = 2 s, f0 = 0.5 Hz, found in the spectrum of column 'q' "
                "(no --f0 given)" in printed) == (not f0)
        doc = json.loads(out.read_text())
        for name in ("m", "Fc", "F0"):
            assert doc["parameters"][name] == pytest.approx(TRUTH[name], rel=0.02), name


def test_ml_without_f0_finds_the_period_and_the_same_fit(tmp_path, capsys):
    """identify joint --ml on the band-limited revolute data of tests/test_ident_maximum_likelihood.py (10 periods
    of 0.5 Hz at 200 Hz): without --f0 the period is found (400 samples) and the JSON equals the one with --f0."""
    from tests.test_ident_maximum_likelihood import FS, band_limited_periods

    qs, taus = band_limited_periods(1)
    path = tmp_path / "band.csv"
    recording.write_recording(path, recording.make_recording(np.arange(qs.size) / FS, {"q": qs, "u": taus},
                                                             {"q": "rad", "u": "N.m"}, sample_time=1 / FS))
    docs = []
    for f0 in (["--f0", "0.5"], []):
        out = tmp_path / f"ml{len(f0)}.json"
        assert main(["identify", "joint", str(path), *f0, "--cutoff", "3", "--min-speed", "0.2", "--ml",
                     "--out", str(out)]) == 0, capsys.readouterr().err
        docs.append(json.loads(out.read_text()))
    assert "excitation period 400 samples = 2 s, f0 = 0.5 Hz" in capsys.readouterr().out
    assert docs[0] == docs[1]
