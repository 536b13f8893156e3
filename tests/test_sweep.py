"""Sweep files: expansion into cases (grid x seeds), seeded input noise, results equal to direct master runs
whichever executor runs them, the CLI's recordings, and clear errors for bad files."""
from __future__ import annotations

import hashlib
import json
import threading
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


def _direct_runs(sweep_file: Path) -> dict[str, np.ndarray]:
    plan = sweep.load_sweep(sweep_file)
    with Master(plan.system) as master:
        return {c.name: master.run(**c.run_arguments(plan.stop_time))["log"]["plant.q"] for c in plan.cases}


def _assert_folder_holds(out: Path, direct: dict[str, np.ndarray]) -> None:
    """``out`` holds exactly the recordings of ``direct`` (equal values) and a complete manifest listing them."""
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    assert manifest["status"] == "complete" and manifest["failed"] == []
    assert [row["case"] for row in manifest["cases"]] == list(direct)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [sweep.MANIFEST] + [f"{n}.{ext}" for n in direct for ext in ("csv", "json")])
    for name, q in direct.items():
        np.testing.assert_allclose(read_recording(out / f"{name}.csv")["plant.q"], q, rtol=1e-15, atol=0)


def _kill_workers(out: Path, total: int, kills: int = 1, interval: float = 0.0) -> threading.Thread:
    """A thread that SIGKILLs process-pool workers of this process while they run a case (as an out-of-memory
    killer or a crashing FMU would): once the first recording is in ``out``, the first worker seen running
    (state R in /proc, i.e. computing or sending, not waiting for work), ``kills`` times ``interval`` seconds
    apart, while runs are still missing."""
    import multiprocessing
    import os
    import signal
    import time

    def running(pid: int) -> bool:
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "R"
        except (OSError, IndexError):
            return False

    def kill() -> None:
        deadline, done = time.monotonic() + 120, 0
        while done < kills and time.monotonic() < deadline:
            if out.exists() and any(out.glob("*.csv")) and len(list(out.glob("*.csv"))) < total:
                busy = [w.pid for w in multiprocessing.active_children() if running(w.pid)]
                if busy:
                    os.kill(busy[0], signal.SIGKILL)
                    done += 1
                    time.sleep(interval)
                    continue
            time.sleep(0.002)
        thread.kills = done

    thread = threading.Thread(target=kill)
    thread.start()
    return thread


LONG_SWEEP = SWEEP.replace('log = "log"', 'log = "log"\nstop_time = 1.0').replace("count = 3", "count = 4")


def test_killed_workers_are_retried_and_every_run_is_committed(sweep_file: Path, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Workers killed again and again while they run or send a case (up to 3 kills; tests/test_executor.py kills
    at every instant): every run is committed, equal to a direct run, within a bound; the killed workers' unzipped
    FMUs are removed with the pool."""
    import time

    from tests.test_executor import private_temp

    sweep_file.write_text(LONG_SWEEP)
    direct = _direct_runs(sweep_file)
    temp = private_temp(monkeypatch, tmp_path / "temp")
    out = tmp_path / "out"
    killer = _kill_workers(out, len(direct), kills=3, interval=0.05)
    t0 = time.monotonic()
    code = main(["sweep", str(sweep_file), "--executor", "process", "--workers", "2", "--retries", "10",
                 "--out", str(out)])
    seconds = time.monotonic() - t0
    killer.join(timeout=150)
    assert code == 0 and killer.kills >= 1
    _assert_folder_holds(out, direct)
    assert seconds < 150
    assert list(temp.iterdir()) == []


def test_killed_worker_without_retries_fails_its_runs_by_name_and_keeps_the_others(sweep_file: Path,
                                                                                    tmp_path: Path) -> None:
    from motiontwin.harness.executor import make_executor

    sweep_file.write_text(LONG_SWEEP)
    plan = sweep.load_sweep(sweep_file)
    out = tmp_path / "out"
    killer = _kill_workers(out, len(plan.cases))
    with make_executor("process", 2) as executor:
        outcome = sweep.run_to_folder(plan, out, executor, retries=0, log=lambda line: None)
    killer.join(timeout=150)
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    assert 1 <= len(outcome.failed) <= 2   # the runs in the two workers when one died
    assert sorted(outcome.completed + list(outcome.failed)) == sorted(c.name for c in plan.cases)
    assert manifest["status"] == "failed"
    assert {row["case"] for row in manifest["failed"]} == set(outcome.failed)
    assert all("worker process died" in row["error"] for row in manifest["failed"])
    assert {row["case"] for row in manifest["cases"]} == set(outcome.completed)
    assert {p.stem for p in out.glob("*.csv")} == set(outcome.completed)


class _InterruptedAfter:
    """The in-process executor, with Ctrl-C pressed after ``runs`` runs have finished."""

    def __init__(self, runs: int):
        from motiontwin.harness.executor import InProcessExecutor

        self.runs, self.inner = runs, InProcessExecutor()

    def imap(self, fn, items, retries=2):
        for count, pair in enumerate(self.inner.imap(fn, items, retries)):
            if count == self.runs:
                raise KeyboardInterrupt
            yield pair


def test_interrupted_sweep_resumes_and_a_folder_holding_a_sweep_is_refused(sweep_file: Path, tmp_path: Path,
                                                                           capsys) -> None:
    direct = _direct_runs(sweep_file)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        sweep.run_to_folder(sweep.load_sweep(sweep_file), out, _InterruptedAfter(4), log=lambda line: None)
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    assert manifest["status"] == "interrupted" and [r["case"] for r in manifest["cases"]] == list(direct)[:4]
    assert len(list(out.glob("*.csv"))) == 4

    assert main(["sweep", str(sweep_file), "--out", str(out)]) == 1   # neither --resume nor --overwrite
    assert "pass --resume to continue it or --overwrite" in capsys.readouterr().err
    outcome = sweep.run_to_folder(sweep.load_sweep(sweep_file), out, resume=True, log=lambda line: None)
    assert outcome.resumed == list(direct)[:4] and outcome.completed == list(direct)[4:]
    _assert_folder_holds(out, direct)

    other = sweep_file.with_name("other.toml")
    other.write_text(SWEEP.replace('name = "step"', 'name = "other"').replace("count = 3", "count = 2"))
    assert main(["sweep", str(other), "--resume", "--out", str(out)]) == 1
    assert "holds another sweep" in capsys.readouterr().err
    _assert_folder_holds(out, direct)                                 # refused: nothing touched
    assert main(["sweep", str(other), "--overwrite", "--out", str(out)]) == 0
    _assert_folder_holds(out, _direct_runs(other))                    # the stale runs are gone


def test_case_names_stay_inside_the_output_folder(sweep_file: Path, tmp_path: Path) -> None:
    sweep_file.write_text(SWEEP.replace('name = "step"', 'name = "../../escaped/.hidden"')
                          .replace("count = 3", "count = 1").replace('"plant.m" = [1.5, 2.5]', '"plant.m" = [2.0]'))
    assert [c.name for c in sweep.load_sweep(sweep_file).cases] == ["_.._escaped_.hidden-plant.m=2"]
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out"
    assert main(["sweep", str(sweep_file), "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(before + ["out"])
    assert sorted(p.name for p in out.iterdir()) == ["_.._escaped_.hidden-plant.m=2.csv",
                                                     "_.._escaped_.hidden-plant.m=2.json", "sweep.json"]


@pytest.mark.parametrize("text, message", [
    (SWEEP.replace("count = 3", "count = 1000000000"),
     r"1 case(s) x 2 grid point(s) x 1000000000 seed(s) ([seeds] count) = 2000000000 runs"),
    (SWEEP.replace('"plant.m" = [1.5, 2.5]', '"plant.m" = [1.5, 2.5]\n"plant.d" = [' + ", ".join(["1.0"] * 2000) + "]"),
     "1 case(s) x 4000 grid point(s) x 3 seed(s) ([seeds] count) = 12000 runs"),
])
def test_run_count_is_checked_before_anything_runs(sweep_file: Path, tmp_path: Path, capsys, text: str,
                                                  message: str) -> None:
    import time

    sweep_file.write_text(text)
    t0 = time.perf_counter()
    assert main(["sweep", str(sweep_file), "--out", str(tmp_path / "out")]) == 1
    assert time.perf_counter() - t0 < 2.0
    err = capsys.readouterr().err
    assert f"{sweep_file}: {message}, more than the limit of 10000" in err
    assert not (tmp_path / "out").exists()


def test_run_count_is_printed_and_workers_checked(sweep_file: Path, tmp_path: Path, capsys) -> None:
    assert main(["sweep", str(sweep_file), "--workers", "0", "--executor", "process",
                 "--out", str(tmp_path / "w")]) == 1
    assert "workers: expected a positive number of worker processes, got 0" in capsys.readouterr().err
    assert main(["sweep", str(sweep_file), "--out", str(tmp_path / "out")]) == 0
    assert "6 runs (limit 10000): 0 finished earlier, 6 to run" in capsys.readouterr().out


def test_run_stop_time_beyond_the_limit_names_the_option(sweep_file: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.csv"
    assert main(["run", str(sweep_file.with_name("loop.toml")), "--stop-time", "1e300", "--out", str(out)]) == 1
    assert "stop_time = 1e+300 s gives 1e+304 steps of 0.0001 s, more than the limit of 1e+08" in \
        capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("signal_name, executor", [("SIGINT", "process"), ("SIGTERM", "inprocess"),
                                                    ("SIGTERM", "process")])
def test_a_stopped_sweep_exits_130_or_143_with_one_line_and_resumes(sweep_file: Path, tmp_path: Path,
                                                                    signal_name: str, executor: str) -> None:
    """A real Ctrl-C (SIGINT to the process group, as a terminal sends it) or SIGTERM (to the process, as
    ``timeout`` or systemd sends it) during a sweep: exit 130 or 143, one line, manifest "interrupted", no
    temporary file left, and --resume completes the sweep."""
    import os
    import signal
    import subprocess
    import sys
    import time

    sweep_file.write_text(LONG_SWEEP)
    out = tmp_path / "out"
    command = [sys.executable, "-c", "import sys; from motiontwin.cli import main; sys.exit(main())", "sweep",
               str(sweep_file), "--executor", executor, "--workers", "2", "--out", str(out)]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not (out.exists() and any(out.glob("*.csv"))) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    if signal_name == "SIGINT":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    code, what = (130, "interrupted") if signal_name == "SIGINT" else (143, "terminated (SIGTERM)")
    assert proc.returncode == code, err
    assert err.strip().splitlines() == [f"motiontwin sweep: {what}; finished outputs are complete, nothing "
                                        "half-written was kept (add --resume to continue)"]
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    finished = [row["case"] for row in manifest["cases"]]
    assert manifest["status"] == "interrupted" and 1 <= len(finished) < 8
    assert sorted(p.name for p in out.iterdir()) == sorted([sweep.MANIFEST] + [f"{n}.{e}" for n in finished
                                                                                 for e in ("csv", "json")])
    assert main(["sweep", str(sweep_file), "--resume", "--out", str(out)]) == 0
    _assert_folder_holds(out, _direct_runs(sweep_file))


BELOW_MIN = [-1.0, 1.0, -2.0, 1.3, -3.0, 0.7, -4.0, 1.1]   # plant.d has min = 0: four runs the FMU refuses


@pytest.mark.parametrize("executor", ["inprocess", "process", "dask"])
def test_a_run_the_fmu_refuses_is_named_with_its_message_and_spares_the_others(sweep_file: Path, tmp_path: Path,
                                                                              capsys, executor: str) -> None:
    """A grid with four damping values below the FMU's minimum: on every executor the four valid runs are
    committed, equal to direct runs on a fresh master, and the four invalid ones are named with the FMU's
    own message, in sweep.json and on the console (the instance that entered Error is made anew)."""
    sweep_file.write_text(SWEEP.replace('"plant.m" = [1.5, 2.5]', f'"plant.d" = {BELOW_MIN}')
                          .replace("count = 3", "count = 1"))
    plan = sweep.load_sweep(sweep_file)
    valid = {c.name: c for c in plan.cases if c.parameters["plant.d"] >= 0}
    invalid = {c.name: c.parameters["plant.d"] for c in plan.cases if c.parameters["plant.d"] < 0}
    assert len(valid) == len(invalid) == 4
    direct = {}
    for name, case in valid.items():
        with Master(plan.system) as master:
            direct[name] = master.run(**case.run_arguments(plan.stop_time))["log"]["plant.q"]
    out = tmp_path / "out"
    assert main(["sweep", str(sweep_file), "--executor", executor, "--workers", "2", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    assert manifest["status"] == "failed"
    assert [row["case"] for row in manifest["cases"]] == list(valid)
    assert {row["case"] for row in manifest["failed"]} == set(invalid)
    for row in manifest["failed"]:
        message = f"parameter d = {invalid[row['case']]:g} is below its minimum 0"
        assert message in row["error"], row
        assert f"run {row['case']} failed: " in captured.out and message in captured.out
    for name, q in direct.items():
        np.testing.assert_allclose(read_recording(out / f"{name}.csv")["plant.q"], q, rtol=1e-15, atol=0)
    assert {p.stem for p in out.glob("*.csv")} == set(valid)


def test_resume_reruns_runs_whose_files_are_missing_truncated_or_changed_and_cleans_a_killed_sweep(
        sweep_file: Path, tmp_path: Path) -> None:
    """Four runs committed, then: a CSV truncated, a CSV replaced by junk of the same size, a sidecar deleted,
    a temporary file and a "running" status left as a killed sweep leaves them. --resume keeps the one intact
    run, says which runs run again and why, removes the temporary file, and ends with every run as direct."""
    direct = _direct_runs(sweep_file)
    names = list(direct)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        sweep.run_to_folder(sweep.load_sweep(sweep_file), out, _InterruptedAfter(4), log=lambda line: None)
    manifest = json.loads((out / sweep.MANIFEST).read_text())
    row = manifest["cases"][0]
    csv = (out / f"{names[0]}.csv").read_bytes()
    assert row["files"][f"{names[0]}.csv"] == {"bytes": len(csv), "sha256": hashlib.sha256(csv).hexdigest()}
    side = (out / f"{names[0]}.json").read_bytes()
    assert row["files"][f"{names[0]}.json"] == {"bytes": len(side), "sha256": hashlib.sha256(side).hexdigest()}

    (out / f"{names[0]}.csv").write_bytes(csv[:len(csv) // 2])
    junk = (out / f"{names[1]}.csv").read_bytes().replace(b"e-0", b"e-1")
    (out / f"{names[1]}.csv").write_bytes(junk)
    (out / f"{names[2]}.json").unlink()
    stale = out / f".{names[4]}.csv.{'0123456789abcdef' * 2}.tmp"
    stale.write_text("half a recording")
    manifest["status"] = "running"
    (out / sweep.MANIFEST).write_text(json.dumps(manifest))

    lines: list[str] = []
    outcome = sweep.run_to_folder(sweep.load_sweep(sweep_file), out, resume=True, log=lines.append)
    assert outcome.resumed == [names[3]] and outcome.completed == names[:3] + names[4:]
    assert f"run {names[0]} runs again: {names[0]}.csv is truncated ({len(csv) // 2} bytes, {len(csv)} committed)" \
        in lines
    assert f"run {names[1]} runs again: {names[1]}.csv differs from what was committed (sha256)" in lines
    assert f"run {names[2]} runs again: {names[2]}.json is missing" in lines
    assert f"{out}: removed 1 temporary file(s) a killed sweep left: {stale.name}" in lines
    assert f"{out}: the sweep there did not end (status 'running' in sweep.json: its process was killed)" in lines
    assert "6 runs (limit 10000): 1 finished earlier, 5 to run" in lines
    _assert_folder_holds(out, direct)


def test_overwrite_removes_the_temporary_files_of_a_killed_sweep(sweep_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    stale = out / f".{'x'}.json.{'ab' * 16}.tmp"
    stale.write_text("{")
    assert main(["sweep", str(sweep_file), "--out", str(out)]) == 0   # a folder holding only debris is free
    (out / f".sweep.json.{'cd' * 16}.bak").write_text("{}")
    assert main(["sweep", str(sweep_file), "--overwrite", "--out", str(out)]) == 0
    _assert_folder_holds(out, _direct_runs(sweep_file))
