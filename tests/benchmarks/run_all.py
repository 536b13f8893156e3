"""`make bench`: run every benchmark script here (bench_*.py), each in its own process, echo its output and end
with one table of the ratio lines they printed (ratios.py), each with the command that produced it.

Run: .venv/bin/python tests/benchmarks/run_all.py [--smoke] [--only bench_NAME ...] [--timeout SECONDS]
Exit code 1 when a script failed or printed no finite ratio.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from ratios import finite, parse  # noqa: E402


def scripts() -> list[Path]:
    """Every benchmark script, in name order."""
    return sorted(HERE.glob("bench_*.py"))


def command(script: Path, smoke: bool) -> list[str]:
    return [sys.executable, str(script), *(["--smoke"] if smoke else [])]


def shown(cmd: list[str]) -> str:
    """The command as a user types it from the repository root."""
    root = HERE.parents[1]
    return " ".join(os.path.relpath(c, root) if os.path.isabs(c) else c for c in cmd)


def run(script: Path, smoke: bool, timeout: float | None) -> tuple[int, str, float]:
    """(exit code, stdout + stderr, wall seconds) of one script; a timeout is exit code -9."""
    start = time.perf_counter()
    try:
        proc = subprocess.run(command(script, smoke), capture_output=True, text=True, timeout=timeout,
                              cwd=HERE.parents[1])
        code, out = proc.returncode, proc.stdout + proc.stderr
    except subprocess.TimeoutExpired as exc:
        parts = [p.decode(errors="replace") if isinstance(p, bytes) else (p or "") for p in (exc.stdout, exc.stderr)]
        code, out = -9, "".join(parts) + f"\ntimed out after {timeout} s"
    return code, out, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="the scripts' small sizes (only proves they run)")
    parser.add_argument("--only", action="append", default=None, metavar="bench_NAME", help="run only these")
    parser.add_argument("--timeout", type=float, default=None, help="per script [s]")
    args = parser.parse_args(argv)
    selected = [s for s in scripts() if not args.only or s.stem in args.only]
    rows, failed = [], []
    for script in selected:
        cmd = shown(command(script, args.smoke))
        print(f"== {cmd}", flush=True)
        code, out, seconds = run(script, args.smoke, args.timeout)
        print(out.rstrip(), flush=True)
        found = parse(out)
        if code != 0 or not finite(found):
            failed.append(f"{cmd} (exit {code}, {len(found)} ratio lines)")
        rows.extend((name, value, baseline, cmd, seconds) for name, value, baseline in found)
    width = max([len(r[0]) for r in rows] + [5])
    print(f"\n{'ratio':<{width}} {'value':>10}  baseline  [command, its wall time]")
    for name, value, baseline, cmd, seconds in rows:
        print(f"{name:<{width}} {value:10.4g}  {baseline}  [{cmd}, {seconds:.0f} s]")
    for line in failed:
        print(f"FAILED: {line}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
