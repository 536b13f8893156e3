"""Sweep files: expansion into cases (grid x seeds), seeded input noise, results equal to direct master runs
whichever executor runs them, the CLI's recordings, and clear errors for bad files."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness import sweep
from motiontwin.cli import main
from motiontwin.harness.master import Master
from motiontwin.harness.recording import read_recording

SYSTEM = """
base_step = 1e-4
stop_time = 0.05
[fmus.pi]
path = "{pi}"
[fmus.pi.parameters]
Kp = 2000.0
Ki = 20000.0
Kd = 40.0
[fmus.plant]
path = "{plant}"
[inputs.r]
unit = "m"
[inputs.u_ext]
unit = "N"
default = 0.0
[[connections]]
from = ["input.r", "plant.q"]
gains = [1.0, -1.0]
to = "pi.e"
[[connections]]
from = ["pi.y", "input.u_ext"]
to = "plant.u"
[[log]]
name = "log"
signals = ["plant.q", "pi.y"]
step = 1e-3
"""

SWEEP = """
system = "loop.toml"
log = "log"
[[case]]
name = "step"
[case.inputs]
r = 1e-3
[case.noise]
u_ext = {std = 5.0, seed = 7}
[grid]
"plant.m" = [1.5, 2.5]
[seeds]
count = 3
first = 10
"""


@pytest.fixture()
def sweep_file(built_fmus, tmp_path: Path) -> Path:
    (tmp_path / "loop.toml").write_text(SYSTEM.format(pi=built_fmus["SampledPI", "3.0"],
                                                      plant=built_fmus["LinearMotorJoint", "2.0"]))
    path = tmp_path / "sweep.toml"
    path.write_text(SWEEP)
    return path


def test_cases_expand_grid_and_seeds_with_numpy_noise(sweep_file: Path) -> None:
    plan = sweep.load_sweep(sweep_file)
    assert [c.name for c in plan.cases] == [f"step-plant.m={m:g}-s{s}" for m in (1.5, 2.5) for s in (10, 11, 12)]
    n = 501   # 0.05 s on the 1e-4 s base grid, both ends
    for case in plan.cases:
        seed = 7 + int(case.name.rsplit("-s", 1)[1])
        np.testing.assert_array_equal(case.inputs["u_ext"], np.random.default_rng(seed).normal(0.0, 5.0, n))
        assert case.inputs["r"] == 1e-3 and set(case.parameters) == {"plant.m"}


def test_cli_sweep_equals_direct_runs_on_every_executor(sweep_file: Path, tmp_path: Path) -> None:
    plan = sweep.load_sweep(sweep_file)
    with Master(plan.system) as master:
        direct = {c.name: master.run(inputs=c.inputs, parameters=c.parameters)["log"] for c in plan.cases}
    assert not np.array_equal(direct["step-plant.m=1.5-s10"]["plant.q"], direct["step-plant.m=1.5-s11"]["plant.q"])
    for executor in ("inprocess", "process", "dask"):
        out = tmp_path / executor
        assert main(["sweep", str(sweep_file), "--executor", executor, "--workers", "2", "--out", str(out)]) == 0
        summary = json.loads((out / "sweep.json").read_text())
        assert [row["case"] for row in summary["cases"]] == list(direct)
        for name, log in direct.items():
            rec = read_recording(out / f"{name}.csv")
            np.testing.assert_allclose(rec["plant.q"], log["plant.q"], rtol=1e-15, atol=0, err_msg=executor)
            assert rec.units["plant.q"] == "m"


@pytest.mark.parametrize("text, message", [
    ('system = "loop.toml"\nbogus = 1\n', r"unknown field\(s\) \['bogus'\]"),
    ('system = "loop.toml"\n[[case]]\nname = "a"\n[case.noise]\nu_x = {std = 1.0}\n', "no external input"),
    ('system = "loop.toml"\n[[case]]\nname = "a"\n[case.inputs]\nr = {file = "x"}\n', "input 'r'"),
    ('system = "loop.toml"\n[seeds]\ncount = 0\n', "count must be a positive integer"),
])
def test_bad_sweep_files_name_the_field_and_write_nothing(sweep_file: Path, tmp_path: Path, capsys, text: str,
                                                         message: str) -> None:
    bad = sweep_file.with_name("bad.toml")
    bad.write_text(text)
    with pytest.raises(sweep.SweepError, match=message):
        sweep.load_sweep(bad)
    out = tmp_path / "out"
    assert main(["sweep", str(bad), "--out", str(out)]) == 1
    assert str(bad) in capsys.readouterr().err and not out.exists()
