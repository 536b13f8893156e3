"""One sweep, three executors (in-process, spawned process pool, Dask LocalCluster): identical results
in the same order, and each equal to a direct run of the same case on a fresh master; the process pool
survives a worker killed at any instant, the hand-off of a result included."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness.executor import RunFailed, make_executor, run_sweep
from motiontwin.harness.master import Master
from motiontwin.harness.system import load_system
from tests import worker_faults
from tests.test_master import P_LOOP


@pytest.fixture()
def short_loop(gemseo_fmus: Path, tmp_path: Path) -> Path:
    path = tmp_path / "loop.toml"
    path.write_text(P_LOOP.format(fmus=gemseo_fmus).replace("stop_time = 0.2", "stop_time = 0.02"))
    return path


def cases() -> list[dict]:
    out = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        out.append({"inputs": {"r": float(rng.uniform(-0.5, -0.3)), "u_ext": rng.normal(0.0, 20.0, 2001)},
                    "parameters": {"ctrl.add.k1": 5000.0 + 500.0 * seed}})
    return out


def private_temp(monkeypatch: pytest.MonkeyPatch, folder: Path) -> Path:
    """This process and the workers it starts from now on put their temporary files in ``folder``."""
    folder.mkdir()
    monkeypatch.setenv("TMPDIR", str(folder))
    monkeypatch.setattr(tempfile, "tempdir", None)
    return folder


def test_executors_give_identical_results_in_case_order(short_loop: Path, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """... and leave no temporary file behind once closed (unzipped FMUs of the workers, Dask's scratch)."""
    system = load_system(short_loop)
    sweep = cases()
    with Master(system) as fresh:
        direct = [fresh.run(**case) for case in sweep]
    temp = private_temp(monkeypatch, tmp_path / "temp")
    results = {}
    for kind in ("inprocess", "process", "dask"):
        with make_executor(kind, workers=2) as executor:
            results[kind] = run_sweep(system, sweep, executor)
        assert list(temp.iterdir()) == [], kind
    for kind, logs in results.items():
        assert len(logs) == len(sweep), kind
        for expected, got in zip(direct, logs):
            for group in expected:
                np.testing.assert_array_equal(got[group], expected[group], err_msg=kind)
    # the cases really differ, so the order check above is meaningful
    assert not np.array_equal(direct[0]["slow"]["plant.y"], direct[1]["slow"]["plant.y"])


def test_unknown_executor_and_case_keys(short_loop: Path) -> None:
    with pytest.raises(ValueError, match="unknown executor 'cluster'"):
        make_executor("cluster")
    with pytest.raises(ValueError, match=r"unknown keys \['seed'\]"):
        run_sweep(short_loop, [{"seed": 1}])


KILLS = 49   # workers killed per sweep, at each of worker_faults.INSTANTS in turn
SWEEP_BOUND = 150.0   # [s] a sweep with every kill, on a busy 2-core machine (about 20 s idle)


def _killing_items(folder: Path) -> list[tuple[int, str, str]]:
    folder.mkdir()
    return [(i, worker_faults.INSTANTS[i % len(worker_faults.INSTANTS)], str(folder / f"{i}")) for i in range(KILLS)]


def test_worker_killed_at_any_instant_loses_only_its_run_and_never_hangs(tmp_path: Path) -> None:
    """49 runs, each killing its worker (SIGKILL) the first time it is tried: before it starts, while it
    computes, while its result is pickled, and inside the hand-off of its 8 MB result (in the length header,
    after 64 KiB, half, all but the last byte). Without retries every run is named as failed with how its
    worker ended; with one retry every result is whole and in place; each sweep ends within a bound."""
    with make_executor("process", workers=2) as executor:
        t0 = time.monotonic()
        first = dict(executor.imap(worker_faults.run, _killing_items(tmp_path / "once"), retries=0))
        seconds_once = time.monotonic() - t0
        t0 = time.monotonic()
        second = dict(executor.imap(worker_faults.run, _killing_items(tmp_path / "retried"), retries=1))
        seconds_retried = time.monotonic() - t0
        assert sorted(executor.map(abs, [-3, 2, -1])) == [1, 2, 3]   # the pool works on after the kills
    assert sorted(first) == sorted(second) == list(range(KILLS))
    for i, result in first.items():
        assert isinstance(result, RunFailed), (i, result)
        assert result.error == "its worker process died once (last: killed by SIGKILL)", (i, result)
    for i, result in second.items():
        assert not isinstance(result, RunFailed), (i, result)
        assert result[0] == i
        np.testing.assert_array_equal(result[1], worker_faults.expected(i))
    assert seconds_once < SWEEP_BOUND and seconds_retried < SWEEP_BOUND, (seconds_once, seconds_retried)


def test_process_workers_live_across_runs(tmp_path: Path) -> None:
    """Workers are spawned once and serve run after run (their master_for cache stays warm)."""
    with make_executor("process", workers=2) as executor:
        pids = executor.map(worker_faults.pid, range(8)) + executor.map(worker_faults.pid, range(8))
    assert len(set(pids)) == 2
