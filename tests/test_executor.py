"""One sweep, three executors (in-process, spawned process pool, Dask LocalCluster): identical results
in the same order, and each equal to a direct run of the same case on a fresh master."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness.executor import make_executor, run_sweep
from motiontwin.harness.master import Master
from motiontwin.harness.system import load_system
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


def test_executors_give_identical_results_in_case_order(short_loop: Path) -> None:
    system = load_system(short_loop)
    sweep = cases()
    with Master(system) as fresh:
        direct = [fresh.run(**case) for case in sweep]
    results = {}
    for kind in ("inprocess", "process", "dask"):
        with make_executor(kind, workers=2) as executor:
            results[kind] = run_sweep(system, sweep, executor)
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
