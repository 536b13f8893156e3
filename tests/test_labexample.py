"""The lab-like recording generator (motiontwin.labexample) and the import -> identify joint path on it.

References: the generator's own construction (1 ms clock +-20 ns, volts, mm, the loop moving at t = 0, 2 whole
periods + 1.3 s) and the truth of the co-simulated PrismaticAxis FMU (95 kg, Coulomb 20.6 N, constant force
-3.2 N): identify joint on the imported file must cover the truth mass within 3 HAC standard deviations.
"""
import json

import numpy as np
import pytest
import scipy.io

from motiontwin import labexample
from motiontwin.cli import main


def test_lab_file_looks_like_lab_data_and_identifies(tmp_path, capsys):
    data = labexample.lab_recording(seed=1, periods=2, extra=1.3, fmu_dir=tmp_path / "fmus")
    n = data["t"].size
    assert n == 9300                                   # 2 periods of 4 s + 1.3 s at 1 kHz
    deviation = data["t"] - np.arange(n) * labexample.TS
    assert np.max(np.abs(deviation)) <= labexample.JITTER and np.std(deviation[1:]) > 0.4 * labexample.JITTER / np.sqrt(3)
    speed = (data["q_true"][5] - data["q_true"][0]) / (5 * labexample.TS)
    assert abs(speed) > 0.005                          # the loop is already moving at t = 0
    assert 231.0 < data["pos_enc"].min() and data["pos_enc"].max() < 249.0     # mm
    assert np.max(np.abs(data["cmd"])) < 10.0          # volts: the force / 40 N/V
    path = tmp_path / "axis.mat"
    scipy.io.savemat(path, {k: v for k, v in data.items() if k != "q_true"})
    rec = tmp_path / "axis.csv"
    assert main(["import", str(path), "--column", "q=pos_enc", "--unit", "q=mm", "--column", "u=cmd", "--unit", "u=V",
                 "--gain", "u=40 N/V", "--out", str(rec)]) == 0
    fit = tmp_path / "joint.json"
    assert main(["identify", "joint", str(rec), "--f0", "0.25", "--cutoff", "5", "--min-speed", "0.02",
                 "--out", str(fit)]) == 0
    assert "dropped the last 1300 samples (1.3 s" in capsys.readouterr().out
    doc = json.loads(fit.read_text())
    truth = labexample.TRUTH
    assert abs(doc["parameters"]["m"] - truth["m"]) < 3 * doc["std_hac"]["m"]
    assert doc["parameters"]["Fc"] == pytest.approx(truth["Fc"], rel=0.15)
    assert doc["parameters"]["F0"] == pytest.approx(truth["F0"], rel=0.3)
