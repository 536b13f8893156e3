"""Profile one diagnosis (not a test, not run by ``make bench``): ``pipeline.run_axes`` (several axes) or
``pipeline.run`` (one) on a bundle folder under cProfile, the progress lines stamped with the wall and CPU time
so far (CPU = user + system of this process and its finished children, the gcc runs included), then the
effects found and the totals. Set ``MOTIONTWIN_DIAGNOSIS_WORKERS=1`` to keep the screening in this process (its
forked workers' time is otherwise outside the profile) and a fresh ``XDG_CACHE_HOME`` to count the compilation.

Run: .venv/bin/python tests/benchmarks/profile_diagnosis.py BUNDLE_DIR [--profile OUT.prof]
"""
from __future__ import annotations

import argparse
import cProfile
import os
import tempfile
import time
from pathlib import Path

from motiontwin.ident.diagnosis import engine, pipeline
from motiontwin.ident.diagnosis.bundle import read_bundle


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle", type=Path)
    parser.add_argument("--profile", type=Path, help="write the cProfile statistics here (pstats format)")
    args = parser.parse_args()
    wall0, cpu0 = time.perf_counter(), cpu_seconds()

    def progress(message: str) -> None:
        print(f"[{time.perf_counter() - wall0:7.1f} s wall {cpu_seconds() - cpu0:7.1f} s cpu] {message}", flush=True)

    bundle = read_bundle(args.bundle)
    engine.check_bundle_channels(bundle)
    profile = cProfile.Profile()
    run = pipeline.run_axes if bundle.multi_axis else pipeline.run
    with engine._one_blas_thread(), tempfile.TemporaryDirectory(prefix="profile-diagnosis-") as tmp:
        profile.enable()
        try:
            result = run(bundle, Path(tmp), progress)
        finally:
            profile.disable()
            if args.profile:
                profile.dump_stats(args.profile)
    final = result["final"]
    axes = final.axes or [bundle.plant.roles.output] * len(final.effects)
    print("effects:", ", ".join(f"{e.name} on {a}" for a, e in zip(axes, final.effects)) or "-")
    print("remainder:", result["remainder"].get("status"), result["remainder"].get("reason", ""))
    print(f"total: wall {time.perf_counter() - wall0:.1f} s, CPU {cpu_seconds() - cpu0:.1f} s")


if __name__ == "__main__":
    main()
