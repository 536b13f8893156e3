"""Benchmark (not a test): the same held-out bundles of the independent truth simulator diagnosed with their
controller and without it (``controller`` removed: the prediction-error predictor of ident.observer stands in),
and whether the named effects agree (issue 23, item 2).

For every case it prints the expected answer, the answers with and without the controller, whether those two agree,
the observer's bandwidth as the diagnosis fitted it, and both validation RMS (the predictor's is a free run of the
model corrected by the observer, so it is lower than a free run; the two are not the same measure).

Run: .venv/bin/python tests/benchmarks/bench_unknown_controller.py [BENCH_DIR] [--set heldout|tuning]
[--case NAME ...] (bundles are generated into BENCH_DIR/SET by ``python -m motiontwin.ident.benchmarks.independent
generate BENCH_DIR --set SET --case A,B`` when missing).
--smoke: one Coulomb bundle of 0.5 s + 0.25 s in a temporary folder, the vocabulary cut to coulomb_friction and
time_delay (bench_independent's smoke size): the with/without path only.
Ratio: the fraction of cases whose named effects agree with and without the controller (baseline: all of them).
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from bench_independent import SMOKE_CASES, answers, smoke_bundles
from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import diagnose_bundle
from ratios import ratio

DEFAULT_CASES = ("params_quiet", "offset", "coulomb", "cogging")


def without_controller(bundle: Path, target: Path) -> Path:
    """A copy of ``bundle`` whose experiment.json has no ``controller`` (its recordings keep r and u_ext, unused)."""
    shutil.copytree(bundle, target)
    exp = json.loads((target / "experiment.json").read_text())
    del exp["controller"]
    (target / "experiment.json").write_text(json.dumps(exp, indent=2) + "\n")
    return target


def diagnosed(bundle: Path) -> tuple[list[str], float, float, str]:
    """Answers, validation RMS, wall seconds of one diagnosis (answers ["(stopped)"] when it raised) and, without
    a controller, the observer's bandwidth as the diagnosis fitted it ("" with a controller)."""
    t0 = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            doc = diagnose_bundle(bundle, Path(tmp) / "out")
    except Exception as exc:    # a diagnosis that stops is a result of the benchmark
        print(f"  {bundle.name}: stopped: {type(exc).__name__}: {str(exc)[:200]}", flush=True)
        return ["(stopped)"], float("nan"), time.perf_counter() - t0, ""
    ctrl = doc.get("controller") or {}
    bandwidth = (f"{ctrl['bandwidth_hz']:.3g} Hz{' (bound)' if 'bound' in ctrl.get('bandwidth_from', '') else ''}"
                 if ctrl.get("kind") == "unknown" else "")
    return answers(doc), doc["validation"]["augmented_rms"], time.perf_counter() - t0, bandwidth


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("bench", nargs="?", type=Path, default=Path(tempfile.gettempdir()) / "mt-independent-bench")
    parser.add_argument("--set", default="heldout", choices=sorted(independent.SET_SEEDS))
    parser.add_argument("--case", action="append", default=None)
    parser.add_argument("--smoke", action="store_true", help="one short bundle: only proves the path runs")
    args = parser.parse_args()
    cases = args.case or list(DEFAULT_CASES)
    folder = args.bench / args.set
    smoke_dir = smoke_bundles(SMOKE_CASES[-1:]) if args.smoke else None
    if smoke_dir:
        folder = Path(smoke_dir.name)
        cases = [SMOKE_CASES[-1][0]]
    missing = [c for c in cases if not (folder / c / "experiment.json").is_file()]
    if missing:
        independent.generate(args.bench, args.set, missing)
    print(f"{'case':16s} {'expected':22s} {'with controller':28s} {'without controller':28s} agree "
          f"{'val RMS with / without':>24s} {'wall s':>11s}  observer")
    agree = 0
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            truth = json.loads((folder / f"{case}.truth.json").read_text())
            known, rms_known, wall_known, _ = diagnosed(folder / case)
            unknown, rms_unknown, wall_unknown, bandwidth = diagnosed(without_controller(folder / case,
                                                                                        Path(tmp) / case))
            same = set(known) == set(unknown)
            agree += same
            print(f"{case:16s} {','.join(truth['expected']) or '(none)':22s} {','.join(known) or '(none)':28s} "
                  f"{','.join(unknown) or '(none)':28s} {'yes' if same else 'NO ':5s} "
                  f"{rms_known:11.3g} / {rms_unknown:<11.3g} {wall_known:5.0f}/{wall_unknown:<5.0f}  {bandwidth}",
                  flush=True)
    print(f"same effects named with and without the controller: {agree} of {len(cases)}")
    ratio("unknown_controller.fraction_agreeing", agree / max(len(cases), 1),
          "the same effects named with the controller for every case")
    if smoke_dir:
        smoke_dir.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
