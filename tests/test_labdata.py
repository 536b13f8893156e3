"""motiontwin import (harness.labdata): lab files -> recordings.

References: .mat, HDF5, MATLAB v7.3 and text files written here from known arrays (scipy.io.savemat, h5py, plain
text), so every imported value is the known array times the stated gain and unit factor; jitter statistics of a
time vector built with a known deviation pattern (steps alternate Ts + d and Ts - d: median Ts, largest and RMS
deviation d); resampling of a straight line (linear interpolation reproduces it exactly at any instant).
"""
import json

import h5py
import numpy as np
import pytest
import scipy.io

from motiontwin.cli import main
from motiontwin.harness import labdata, recording
from motiontwin.harness.recording import RecordingError

TS = 1e-3
N = 1137                       # 4 periods of 250 samples + 137 samples beyond


def _lab_arrays(jitter: float = 2e-8):
    k = np.arange(N)
    time = k * TS + np.where(k % 2 == 1, jitter, 0.0)   # steps alternate TS + jitter, TS - jitter
    pos_mm = 5.0 * np.sin(2 * np.pi * 4.0 * k * TS)        # 4 Hz: 250 samples per period
    cmd_v = 0.25 * np.cos(2 * np.pi * 4.0 * k * TS) + 0.01
    return time, pos_mm, cmd_v


def test_mat_import_maps_columns_applies_gain_and_units_and_reports_jitter(tmp_path):
    time, pos_mm, cmd_v = _lab_arrays()
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"t": time, "pos_enc": pos_mm, "cmd": cmd_v, "note_gain": 3.0})
    result = labdata.import_lab_file(path, mapping={"q": "pos_enc", "u": "cmd"}, units={"u": "V", "q": "mm"},
                                     gains={"u": "40 N/V"}, period=0.25)
    rec = result.recording
    assert rec.names == ["time", "q", "u"]
    assert rec.units == {"time": "s", "q": "m", "u": "N"}
    np.testing.assert_allclose(rec["q"], pos_mm[:1000] * 1e-3, rtol=1e-15, atol=0)
    np.testing.assert_allclose(rec["u"], cmd_v[:1000] * 40.0, rtol=1e-15, atol=0)
    assert np.array_equal(rec.time, time[:1000])
    # jitter computed by hand from the construction: median step TS, every step off by exactly 2e-8 s
    assert result.jitter.sample_time == pytest.approx(TS, rel=1e-12)
    assert result.jitter.max_deviation == pytest.approx(2e-8, rel=1e-6)
    assert result.jitter.rms_deviation == pytest.approx(2e-8, rel=1e-6)
    assert result.jitter.relative == pytest.approx(2e-5, rel=1e-6)
    assert rec.sample_time == pytest.approx(TS, rel=1e-12)
    text = "\n".join(result.notes)
    assert "x 40 N/V (V -> N)" in text and "converted from mm to m (x 0.001)" in text
    assert "trimmed to 4 whole periods of 250 samples (0.25 s): dropped the last 137 samples" in text
    meta = rec.meta["metadata"]["import"]
    assert meta["columns"]["u"] == {"source": "cmd", "raw_unit": "V", "gain": 40.0, "gain_unit": "N/V"}
    assert meta["trimmed"]["dropped_samples_at_end"] == 137


def test_window_then_whole_periods(tmp_path):
    time, pos_mm, cmd_v = _lab_arrays(jitter=0.0)
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"run": {"time": time, "pos": pos_mm, "force": cmd_v}})
    rec = labdata.import_lab_file(path, mapping={"q": "run.pos", "u": "run.force"}, units={"q": "mm"},
                                  window=(0.1, 1.0), period=0.25).recording
    # the window holds samples 100..1000 (901 samples): 3 periods of 250 from t = 0.1 s
    assert rec.time.size == 750
    assert rec.time[0] == pytest.approx(0.1) and rec.time[-1] == pytest.approx(0.849)
    np.testing.assert_array_equal(rec["u"], cmd_v[100:850])


def test_text_file_with_other_names_semicolons_and_comments(tmp_path):
    time, pos_mm, cmd_v = _lab_arrays(jitter=0.0)
    lines = ["# exported by the lab PC", "% channel list follows", "Zeit;Position_mm;Kraft_kN"]
    lines += [f"{1e3 * a:.17g};{b:.17g};{c:.17g}" for a, b, c in zip(time, pos_mm, cmd_v)]
    path = tmp_path / "lab.txt"
    path.write_text("\n".join(lines) + "\n")
    rec = labdata.import_lab_file(path, time="Zeit", mapping={"q": "Position_mm", "u": "Kraft_kN"},
                                  units={"time": "ms", "q": "mm", "u": "kN"}).recording
    np.testing.assert_allclose(rec.time, time, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(rec["u"], cmd_v * 1e3, rtol=1e-15)
    assert rec.sample_time == pytest.approx(TS, rel=1e-9)


def test_hdf5_and_matlab_v73(tmp_path):
    time, pos_mm, cmd_v = _lab_arrays(jitter=0.0)
    h5 = tmp_path / "lab.h5"
    with h5py.File(h5, "w") as f:
        g = f.create_group("axis")
        g["t"], g["pos"], g["cmd"] = time, pos_mm, cmd_v
    rec = labdata.import_lab_file(h5, time="/axis/t", mapping={"q": "/axis/pos", "u": "/axis/cmd"},
                                  units={"q": "mm", "u": "V"}, gains={"u": "40N/V"}).recording
    np.testing.assert_allclose(rec["u"], 40 * cmd_v, rtol=1e-15)
    # MATLAB v7.3: HDF5 behind a 512-byte MATLAB header, matrices stored transposed (column-major)
    mat = tmp_path / "lab73.mat"
    with h5py.File(mat, "w", userblock_size=512) as f:
        f["time"] = time.reshape(1, -1)
        f["data"] = np.vstack([pos_mm, cmd_v])          # as MATLAB writes an N x 2 matrix
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with open(mat, "r+b") as handle:
        handle.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02" + b"IM")
    source = labdata.read_lab_file(mat)
    assert source.kind == "mat-v7.3"
    rec = labdata.import_lab_file(mat, mapping={"q": "data(:,1)", "u": "data(:,2)"}, units={"q": "mm"}).recording
    np.testing.assert_allclose(rec["q"], pos_mm * 1e-3, rtol=1e-15)
    np.testing.assert_array_equal(rec["u"], cmd_v)
    everything = labdata.import_lab_file(mat).recording          # no mapping: CSV-safe source names
    assert everything.names == ["time", "data_1", "data_2"]
    np.testing.assert_array_equal(everything["data_2"], cmd_v)


def test_resampling_only_on_request_and_stated(tmp_path):
    rng = np.random.default_rng(1)
    time = np.arange(400) * TS + rng.uniform(-2e-5, 2e-5, 400)    # jitter of a few percent of Ts
    path = tmp_path / "lab.csv"
    path.write_text("t,q\n" + "".join(f"{a:.17g},{3.0 + 2.0 * a:.17g}\n" for a in time))
    kept = labdata.import_lab_file(path)
    assert kept.recording.sample_time is None and np.array_equal(kept.recording.time, time)
    assert any("sample_time left null" in n for n in kept.notes)
    result = labdata.import_lab_file(path, resample=True)
    rec = result.recording
    ts = float(np.median(np.diff(time)))
    np.testing.assert_allclose(np.diff(rec.time), ts, rtol=1e-9)
    np.testing.assert_allclose(rec["q"], 3.0 + 2.0 * rec.time, rtol=1e-14)   # a line interpolates exactly
    assert rec.sample_time == pytest.approx(ts)
    assert rec.meta["metadata"]["import"]["resampled"] is True
    assert any("resampled onto the uniform grid" in n for n in result.notes)


@pytest.mark.parametrize("kwargs, fragments", [
    ({"mapping": {"q": "pos"}}, ["lab.mat: no numeric vector 'pos'", "'pos_enc'"]),
    ({"mapping": {"u": "cmd"}, "units": {"u": "mV"}, "gains": {"u": "40 N/V"}},
     ["gain of 'u'", "converts from V", "recorded in mV"]),
    ({"mapping": {"q": "pos_enc"}, "period": 0.2503}, ["not a whole number"]),
    ({"mapping": {"q": "pos_enc"}, "units": {"x": "mm"}}, ["'x'", "not an imported column"]),
    ({"time": "clock"}, ["no numeric vector 'clock'"]),
])
def test_bad_requests_name_file_and_variable(tmp_path, kwargs, fragments):
    time, pos_mm, cmd_v = _lab_arrays()
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"t": time, "pos_enc": pos_mm, "cmd": cmd_v})
    with pytest.raises(ValueError) as info:
        labdata.import_lab_file(path, **kwargs)
    for fragment in fragments:
        assert fragment in str(info.value)


def test_bad_text_values_name_line_and_column(tmp_path):
    path = tmp_path / "lab.csv"
    path.write_text("t,pos\n0,1\n0.001,nan\n")
    with pytest.raises(RecordingError, match=r"lab.csv, column 'pos', line 3: value nan is not finite"):
        labdata.import_lab_file(path)
    path.write_text("t,pos\n0,1\n0.001,x1\n")
    with pytest.raises(RecordingError, match=r"lab.csv, line 3, column 'pos': 'x1' is not a number"):
        labdata.import_lab_file(path)
    path.write_text("t,pos\n0,1\n0,2\n")
    with pytest.raises(RecordingError, match=r"column 't', line 3: time 0.0 is not greater"):
        labdata.import_lab_file(path)


def test_cli_import_writes_the_recording_and_refuses_without_writing(tmp_path, capsys):
    time, pos_mm, cmd_v = _lab_arrays()
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"t": time, "pos_enc": pos_mm, "cmd": cmd_v})
    out = tmp_path / "rec.csv"
    assert main(["import", str(path), "--column", "q=pos_enc", "--column", "u=cmd", "--unit", "q=mm",
                 "--unit", "u=V", "--gain", "u=40 N/V", "--f0", "4", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "jitter: largest step deviation 2e-08 s" in printed and "dropped the last 137 samples" in printed
    rec = recording.read_recording(out, required=("time", "q", "u"))
    np.testing.assert_allclose(rec["u"], 40 * cmd_v[:1000], rtol=1e-15)
    assert json.loads(out.with_suffix(".json").read_text())["units"]["u"] == "N"
    bad = tmp_path / "bad.csv"
    assert main(["import", str(path), "--column", "q=nothere", "--out", str(bad)]) == 1
    assert "no numeric vector 'nothere'" in capsys.readouterr().err
    assert not bad.exists()


def _polled(step: float, jitter: float, seconds: float, seed: int, start: float = 0.0) -> np.ndarray:
    """Host poll instants from ``start``: steps of ``step`` +- uniform ``jitter``."""
    steps = step + np.random.default_rng(seed).uniform(-jitter, jitter, int(seconds / step))
    return start + np.concatenate([[0.0], np.cumsum(steps)])


def test_resampling_onto_a_given_sample_time_matches_the_exact_samples(tmp_path):
    """A controller at 1 kHz recorded by a host polling every ~2.3 ms: the exact samples of a known smooth
    trajectory at the jittered instants, re-imported with --sample-time 1e-3, equal the trajectory on the
    controller's grid k*1e-3 within linear interpolation's bound h^2/8 max|q''| (h: the largest poll step); two
    recordings of one experiment polled differently, from different first instants, land on the same grid."""
    def q(t):
        return 0.01 * np.sin(2 * np.pi * 2.0 * t) + 0.004 * np.sin(2 * np.pi * 7.0 * t + 1.0)

    q2_max = 0.01 * (2 * np.pi * 2.0) ** 2 + 0.004 * (2 * np.pi * 7.0) ** 2
    grids = []
    for step, seed, start in ((2.312e-3, 1, 0.7e-3), (2.260e-3, 2, 1.9e-3)):
        polled = _polled(step, 0.3e-3, 3.0, seed, start)
        path = tmp_path / f"poll{seed}.csv"
        path.write_text("t,q\n" + "".join(f"{a:.17g},{q(a):.17g}\n" for a in polled))
        kept = labdata.import_lab_file(path)
        assert kept.recording.sample_time is None                      # the jitter is 13 % of a step
        result = labdata.import_lab_file(path, resample=True, sample_time=1e-3)
        rec = result.recording
        assert rec.sample_time == 1e-3
        k0 = 1 if seed == 1 else 2                                   # the first tick at or after the first poll
        np.testing.assert_array_equal(rec.time, (k0 + np.arange(rec.time.size)) * 1e-3)
        bound = np.max(np.diff(polled)) ** 2 / 8 * q2_max
        error = np.max(np.abs(rec["q"] - q(rec.time)))
        assert error <= bound, (error, bound)
        assert error > bound / 100                                    # the bound is not vacuous
        assert np.max(np.abs(rec["q"] - q(rec.time + 1e-3))) > 20 * bound   # one sample off would show
        assert any(f"grid k*0.001 s (given) by linear interpolation ({rec.time.size} samples from {k0 * 1e-3:g} s)"
                   in n for n in result.notes)
        assert rec.meta["metadata"]["import"]["clock"] == {"sample_time": 1e-3, "origin": "given"}
        grids.append(rec.time)
    assert np.array_equal(grids[0][1:], grids[1][:grids[0].size - 1])


def test_a_median_step_within_the_jitter_snaps_to_the_clock(tmp_path, capsys):
    """A 1 kHz recording whose time column scatters by +-4e-8 s with a median step of 0.000999984 s: the sample
    time is the clock's 0.001 s, said so; the same steps without scatter are a real 0.000999984 s clock."""
    noise = np.random.default_rng(3).uniform(-4e-8, 4e-8, 3000)
    noise -= np.median(noise)
    for name, steps in (("scattered", 0.000999984 + noise), ("exact", np.full(3000, 0.000999984))):
        time = np.concatenate([[0.0], np.cumsum(steps)])
        path = tmp_path / f"{name}.csv"
        path.write_text("t,q\n" + "".join(f"{a:.17g},{np.sin(a):.17g}\n" for a in time))
        result = labdata.import_lab_file(path)
        assert result.jitter.sample_time == pytest.approx(0.000999984, rel=1e-9)
        snapped = [n for n in result.notes if "snapped to the clock" in n]
        if name == "scattered":
            assert result.recording.sample_time == 0.001
            assert len(snapped) == 1 and snapped[0].startswith(
                "sample time snapped to the clock 0.001 s: the median step 0.000999984 s is within the jitter (4.")
            assert labdata.import_lab_file(path, resample=True).recording.time[1] == 0.001
        else:
            assert result.recording.sample_time == pytest.approx(0.000999984, rel=1e-12) and not snapped
    assert main(["import", str(tmp_path / "scattered.csv"), "--out", str(tmp_path / "rec.csv")]) == 0
    assert "snapped to the clock 0.001 s" in capsys.readouterr().out
    assert json.loads((tmp_path / "rec.json").read_text())["sample_time"] == 0.001


def test_a_wide_matrix_is_read_by_rows_under_matlabs_index(tmp_path):
    """A 6 x N matrix (six axes, as the KUKA recordings store them) holds its signals in rows: its 2nd axis is
    ``pos(2,:)``, as in MATLAB, not a transposed ``pos(:,2)``; a tall N x 2 matrix keeps ``data(:,2)``."""
    time = np.arange(400) * 1e-3
    wide = np.vstack([np.sin((k + 1) * time) for k in range(6)])
    path = tmp_path / "robot.mat"
    scipy.io.savemat(path, {"t": time, "pos": wide, "data": wide[:2].T})
    result = labdata.import_lab_file(path, mapping={"q": "pos(2,:)", "u": "data(:,2)"}, time="t")
    np.testing.assert_array_equal(result.recording["q"], wide[1])
    np.testing.assert_array_equal(result.recording["u"], wide[1])
    with pytest.raises(RecordingError, match=r"no numeric vector 'pos\(:,2\)'"):
        labdata.import_lab_file(path, mapping={"q": "pos(:,2)"}, time="t")


def test_a_single_precision_time_column_is_on_its_clock(tmp_path):
    """A time column k * float32(0.004) = k * 0.0039999999 s (a MATLAB single, as in the KUKA recordings of
    tests/data/kuka_axis1): its steps do not scatter at all, yet it is the 4 ms clock; given as 0.004 s it is
    accepted without --resample. A clock 1e-6 away (0.0040001 s) is still refused."""
    step = float(np.float32(0.004))
    assert step != 0.004
    time = np.arange(2500) * step
    path = tmp_path / "single.csv"
    path.write_text("t,q\n" + "".join(f"{a:.17g},{np.sin(a):.17g}\n" for a in time))
    assert labdata.import_lab_file(path).recording.sample_time == 0.004
    assert labdata.import_lab_file(path, sample_time=0.004).recording.sample_time == 0.004
    with pytest.raises(ValueError, match="differs from the median step"):
        labdata.import_lab_file(path, sample_time=0.0040001)


def test_a_given_sample_time_off_the_steps_needs_resample(tmp_path, capsys):
    time, pos_mm, cmd_v = _lab_arrays()
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"t": time, "pos_enc": pos_mm})
    assert labdata.import_lab_file(path, sample_time=1e-3).recording.sample_time == 1e-3
    with pytest.raises(ValueError, match=r"sample time 0.00125 s differs from the median step 0.001 s by 0.00025 s, "
                                         r"more than the jitter \(2e-08 s\) and single-precision rounding; "
                                         r"add --resample"):
        labdata.import_lab_file(path, sample_time=1.25e-3)
    out = tmp_path / "rec.csv"
    assert main(["import", str(path), "--sample-time", "0", "--resample", "--out", str(out)]) == 1
    assert "sample time must be > 0 s" in capsys.readouterr().err and not out.exists()
