"""The benchmark scripts cannot rot: each runs in its small ``--smoke`` size as its own process, within a time
limit, exits 0, none of the diagnoses it runs stops ("(stopped)"), it leaves no temporary file behind and prints at
least one ratio line (tests/benchmarks/ratios.py), every value finite; and `make bench`'s runner turns those lines
into its table."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parent / "benchmarks"
sys.path.insert(0, str(BENCH))

import ratios  # noqa: E402
import run_all  # noqa: E402

TIMEOUT_S = 300  # a smoke run takes 1-25 s on an idle core; the limit allows for a loaded machine


@pytest.mark.parametrize("script", run_all.scripts(), ids=lambda p: p.stem)
def test_benchmark_runs_in_smoke_size_and_prints_finite_ratios(script: Path, gemseo_fmus: Path,
                                                               tmp_path: Path) -> None:
    """... and leaves nothing in its temporary folder (unzipped or built FMUs, compile caches, Dask scratch)."""
    env = {**os.environ, "MOTIONTWIN_TEST_FMUS": str(gemseo_fmus), "MOTIONTWIN_DIAGNOSIS_WORKERS": "1",
           "TMPDIR": str(tmp_path)}
    proc = subprocess.run(run_all.command(script, smoke=True), capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=env, cwd=BENCH.parents[1])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "(stopped)" not in proc.stdout, proc.stdout[-3000:]     # a diagnosis it runs raised
    found = ratios.parse(proc.stdout)
    assert found and ratios.finite(found), proc.stdout[-3000:]
    assert all(name.split(".")[0] and baseline.strip() for name, _, baseline in found)
    assert "--smoke" in script.read_text().split('"""')[1], "the docstring documents the smoke size"
    assert list(tmp_path.iterdir()) == []


def test_runner_prints_one_table_with_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_all.main(["--smoke", "--only", "bench_fmu_step"]) == 0
    table = capsys.readouterr().out.split("\nratio ")[1].splitlines()[1:]
    assert [line.split()[0] for line in table] == ["fmu_step.fmpy_over_c", "fmu_step.realtime_factor_c"]
    assert all(line.endswith(" s]") and "tests/benchmarks/bench_fmu_step.py --smoke" in line for line in table)


def test_ratio_lines_are_parsed_and_non_finite_values_flagged() -> None:
    text = "noise\nRATIO a.b=2.5 baseline=raw fmpy loop\nRATIO c=nan baseline=x\n"
    found = ratios.parse(text)
    assert found[0] == ("a.b", 2.5, "raw fmpy loop") and len(found) == 2
    assert not ratios.finite(found) and ratios.finite(found[:1]) and not ratios.finite([])
