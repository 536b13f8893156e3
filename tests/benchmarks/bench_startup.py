"""Benchmark (issue 25 item 1): ``motiontwin identify oe`` as a user runs it, whole process against whole
process, beside what an FMPy user writes (scipy ``least_squares`` over ``fmpy.simulate_fmu``, finite-difference
Jacobian; :func:`baseline` below, run as its own process). Same recording (4 s at 2 kHz of the
LinearMotorJoint FMU under a multisine, encoder noise), same start (the Modelica defaults), same bounds.
Ours runs on a warm model cache (the first, cold run is timed and printed too). Runs alternate, medians of
``--repeats``; wall and CPU (user + system of the child) are both printed since the machine is shared.
Also prints the time of ``motiontwin --help`` and ``import motiontwin``.

Run: .venv/bin/python tests/benchmarks/bench_startup.py [--seconds 4] [--repeats 3] [--smoke]
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ratios import ratio

TS = 5e-4
TRUTH = {"m": 2.6, "d": 14.0}
NOISE = 2e-6


def baseline(fmu: str, csv: str) -> None:
    """What an FMPy user writes: one FMU simulation per residual, finite differences, scipy's TRF."""
    import fmpy
    import numpy as np
    from scipy.optimize import least_squares

    data = np.genfromtxt(csv, delimiter=",", names=True)
    signal = np.zeros(data.size, dtype=[("time", float), ("u", float)])
    signal["time"], signal["u"] = data["time"], data["u"]
    ts = float(np.median(np.diff(data["time"])))

    def residual(x: np.ndarray) -> np.ndarray:
        q = fmpy.simulate_fmu(fmu, stop_time=data["time"][-1], step_size=ts, output_interval=ts, input=signal,
                              output=["q"], start_values={"m": x[0], "d": x[1]})["q"]
        return (data["q"] - q) / NOISE

    sol = least_squares(residual, [2.0, 10.0], bounds=([1e-9, 0.0], [np.inf, np.inf]), diff_step=1e-6,
                        x_scale="jac", max_nfev=50)
    print(f"m {sol.x[0]:.6g} d {sol.x[1]:.6g} ({sol.nfev} residuals + finite differences)")


def _make_case(folder: Path, seconds: float) -> tuple[str, str]:
    """The FMU (FMI 2.0, for fmpy) and the recording, noise 2 um."""
    import numpy as np

    sys.path.insert(0, str(Path(__file__).parent))
    from bench_ident_oe import fmpy_q, periodic_multisine

    from motiontwin.fmus import build
    from motiontwin.harness.recording import make_recording, write_recording

    fmu = str(build.build_fmu(build.load_model("MotionTwin.Plants.LinearMotorJoint"), folder, "2.0").path)
    n = int(round(seconds / TS))
    u = periodic_multisine(n, 40, 5.0, seed=0)
    q = fmpy_q(fmu, u, TRUTH) + NOISE * np.random.default_rng(1).standard_normal(n)
    csv = folder / "rec.csv"
    write_recording(csv, make_recording(np.arange(n) * TS, {"u": u, "q": q}))
    return fmu, str(csv)


def _timed(command: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """Wall and CPU seconds (user + system) of one child process, and its last output line."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True, env=env, timeout=1800)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{proc.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, (proc.stdout.strip().splitlines() or [""])[-1]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=4.0, help="recording length [s] (default 4)")
    parser.add_argument("--repeats", type=int, default=3, help="alternating runs of each, medians (default 3)")
    parser.add_argument("--smoke", action="store_true", help="0.5 s recording, one run each (the test suite's)")
    parser.add_argument("--baseline", nargs=2, metavar=("FMU", "CSV"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.baseline:
        return baseline(*args.baseline)
    seconds, repeats = (0.5, 1) if args.smoke else (args.seconds, args.repeats)
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        _compare(Path(tmp), seconds, repeats)


def _compare(folder: Path, seconds: float, repeats: int) -> None:
    """Make the case in ``folder``, time both sides and print the table and the RATIO lines."""
    env = {**os.environ, "XDG_CACHE_HOME": str(folder / "cache")}   # a cold model cache for the first run
    fmu, csv = _make_case(folder, seconds)
    motiontwin = [sys.executable, "-m", "motiontwin"]
    ours_cmd = [*motiontwin, "identify", "oe", csv, "--class", "MotionTwin.Plants.LinearMotorJoint", "--free", "m,d"]
    base_cmd = [sys.executable, __file__, "--baseline", fmu, csv]
    cold = _timed(ours_cmd, env)
    ours, base = [], []
    for _ in range(repeats):
        ours.append(_timed(ours_cmd, env))
        base.append(_timed(base_cmd, env))
    help_ = [_timed([*motiontwin, "--help"], env) for _ in range(repeats)]
    imp = [_timed([sys.executable, "-c", "import motiontwin"], env) for _ in range(repeats)]
    empty = [_timed([sys.executable, "-c", "pass"], env) for _ in range(repeats)]

    def med(runs: list[tuple[float, float, str]], k: int) -> float:
        return statistics.median(r[k] for r in runs)

    print(f"identify oe, LinearMotorJoint m,d, {seconds:g} s at {1 / TS:g} Hz, whole processes, "
          f"median of {repeats}:")
    print(f"  scipy + fmpy     {med(base, 0):6.2f} s wall {med(base, 1):6.2f} s CPU   {base[-1][2]}")
    print(f"  motiontwin       {med(ours, 0):6.2f} s wall {med(ours, 1):6.2f} s CPU   {ours[-1][2]}")
    print(f"  (cold cache)     {cold[0]:6.2f} s wall {cold[1]:6.2f} s CPU")
    print(f"  motiontwin --help {med(help_, 0):.2f} s wall, import motiontwin {med(imp, 0):.2f} s wall, "
          f"python -c pass {med(empty, 0):.2f} s wall")
    ratio("startup.scipy_fmpy_over_identify_oe_wall", med(base, 0) / med(ours, 0), "scipy + fmpy fit, whole process")
    ratio("startup.scipy_fmpy_over_identify_oe_cpu", med(base, 1) / med(ours, 1), "scipy + fmpy fit, whole process")
    ratio("startup.help_over_python_wall", med(help_, 0) / med(empty, 0), "python -c pass")
    ratio("startup.import_over_python_wall", med(imp, 0) / med(empty, 0), "python -c pass")


if __name__ == "__main__":
    main()
