"""Benchmark (not a test): a fleet of diagnoses (`motiontwin diagnose BUNDLES --executor dask`) on a Dask
LocalCluster of 2 single-threaded workers against the same fleet on 1 worker (issue 25, item 4: near 2x on this
2-core machine; other jobs on the machine lower it).

The bundles are generated into a temporary folder by the benchmark generator (CasADi truth, seeds 0, 1, ...,
cycling through parameters-only, gravity offset, Coulomb friction and position ripple cases). Each fleet is timed
from the first diagnosis submitted to the summary written (the cluster's start is not counted); both fleets must
name the same effects per bundle.

Run: .venv/bin/python tests/benchmarks/bench_fleet.py [BUNDLES] [--train SECONDS]   (default 8 bundles, 2 s of
training + half as much validation at 2 kHz)
--smoke: 1 bundle of 0.5 s + 0.25 s (parameters only): only proves the path runs.
Ratio: fleet.speedup_2_workers = wall time on 1 worker / wall time on 2 workers (baseline: the same fleet on 1
Dask worker).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from motiontwin.harness.executor import make_executor
from motiontwin.ident.benchmarks import single_axis as benchmark
from motiontwin.ident.diagnosis import fleet
from ratios import ratio, smoke

CASES = ("params_only_a", "gravity_offset", "coulomb_friction", "position_ripple")


def run(bundles: Path, out: Path, workers: int) -> tuple[float, dict[str, list[str]]]:
    """Wall time of the fleet on ``workers`` Dask workers and the effects found per bundle."""
    with make_executor("dask", workers=workers) as executor:
        t0 = time.perf_counter()
        outcome = fleet.run_fleet([bundles], out, executor, executor_name="dask", log=lambda msg: None)
        seconds = time.perf_counter() - t0
    if outcome.failed:
        raise SystemExit(f"bench_fleet: bundles failed: {outcome.failed}")
    manifest = json.loads((out / fleet.MANIFEST).read_text())
    return seconds, {row["bundle"]: row["effects"] for row in manifest["bundles"]}


def main() -> None:
    small = smoke()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundles", nargs="?", type=int, default=8, help="bundles in the fleet (default 8)")
    parser.add_argument("--train", type=float, default=2.0, help="training seconds per bundle (default 2)")
    args = parser.parse_args()
    count, train, cases = (1, 0.5, CASES[:1]) if small else (args.bundles, args.train, CASES)
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        root = Path(tmp)
        for k in range(count):
            case = cases[k % len(cases)]
            benchmark.write_bundle(root / "bundles" / f"b{k:02d}_{case}", case, seed=k, durations=(train, train / 2),
                                   engine="casadi")
        one, found_one = run(root / "bundles", root / "one", 1)
        two, found_two = run(root / "bundles", root / "two", 2)
    same = found_one == found_two
    print(f"{count} bundles of {train:g} s + {train / 2:g} s: 1 worker {one:.1f} s, 2 workers {two:.1f} s; "
          f"same effects per bundle: {same}; load average {os.getloadavg()[0]:.2f}")
    for name, effects in found_two.items():
        print(f"  {name}: {effects or 'none'}")
    if not same:
        raise SystemExit(f"bench_fleet: the fleets differ: {found_one} vs {found_two}")
    ratio("fleet.speedup_2_workers", one / two, "the same fleet on 1 Dask worker")


if __name__ == "__main__":
    main()
