"""What every benchmark script shares: the ``--smoke`` flag (a small size that only proves the script still
runs) and its machine-readable result lines, which `make bench` (run_all.py) collects into one table and
tests/test_benchmarks_smoke.py checks.

A result line is ``RATIO name=value baseline=TEXT``: ``value`` is the measured quantity divided by the
baseline that ``TEXT`` names (a raw fmpy loop, scipy + fmpy, a target time, real time, ...), dimensionless.
"""
from __future__ import annotations

import math
import re
import sys

LINE = re.compile(r"^RATIO (?P<name>[A-Za-z0-9_.-]+)=(?P<value>\S+) baseline=(?P<baseline>.+)$")


def smoke() -> bool:
    """True when the script was started with ``--smoke``; removes the flag from ``sys.argv`` so that the
    script's own positional arguments keep their places."""
    if "--smoke" not in sys.argv:
        return False
    sys.argv.remove("--smoke")
    return True


def ratio(name: str, value: float, baseline: str) -> None:
    """Print one result line (see the module docstring)."""
    print(f"RATIO {name}={value:.6g} baseline={baseline}", flush=True)


def parse(text: str) -> list[tuple[str, float, str]]:
    """The (name, value, baseline) of every result line in a script's output."""
    found = []
    for line in text.splitlines():
        m = LINE.match(line.strip())
        if m:
            found.append((m["name"], float(m["value"]), m["baseline"]))
    return found


def finite(found: list[tuple[str, float, str]]) -> bool:
    """At least one result, every value finite."""
    return bool(found) and all(math.isfinite(v) for _, v, _ in found)
