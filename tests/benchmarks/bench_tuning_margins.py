"""Benchmark (not a test): the margins of the tuned joint loop, ``tuning.loop_margins`` (exact crossovers by
Brent's method on the loop, the response in one batched solve) against what python-control does with the same
loop on the same dense grid (its point-by-point evaluation, then ``control.stability_margins`` on the response:
a spline root-finding), side by side in one run.

Loops: the Table 2 d1 design and six designs with Kp, Ki, Kd scaled by 0.3-3 (seeded), each on the three
position sets (``tuning.position_sets``) of the CheungJoint's start values, 8000 points up to Nyquist. Printed
per loop: both times and the GM, PM and crossovers of each; at the end the largest differences.

Run: .venv/bin/python tests/benchmarks/bench_tuning_margins.py [--smoke]   (--smoke: the d1 design, one set)
Ratio: the summed time of ``loop_margins`` over python-control's (the baseline).
"""
from __future__ import annotations

import math
import sys
import time
import warnings
from pathlib import Path

import control
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from motiontwin.ident import tuning  # noqa: E402
from motiontwin.ident.frf import JointModel  # noqa: E402
from motiontwin.ident.tuning.spec import cheung_joint_defaults, joint_model_from_fields  # noqa: E402
from motiontwin.ident.tuning import margins as tuning_margins  # noqa: E402
from ratios import ratio, smoke  # noqa: E402

POINTS = 8000


def python_control(parameters: dict[str, float], plant: JointModel) -> tuple[float, float, float, float]:
    """(GM [dB], PM [deg], phase and gain crossover [Hz]) as python-control gives them for the same loop."""
    loop = tuning_margins.loop_system(parameters, plant, 1)
    w = 2 * np.pi * tuning_margins.frequency_grid(loop.dt, POINTS)
    response = np.asarray(loop(np.exp(1j * w * loop.dt))).reshape(-1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, _, wpc, wgc, _ = control.stability_margins((np.abs(response), np.degrees(np.angle(response)), w))
    return 20 * math.log10(gm) if np.isfinite(gm) else math.inf, pm, wpc / (2 * np.pi), wgc / (2 * np.pi)


def main() -> None:
    quick = smoke()
    nominal = joint_model_from_fields({}, cheung_joint_defaults())   # MotionTwin.Plants.CheungJoint's start values
    rng = np.random.default_rng(0)
    base = tuning.controller_defaults()
    designs = [base] + ([] if quick else [
        dict(base, Kp=base["Kp"] * rng.uniform(0.3, 3), Ki=base["Ki"] * rng.uniform(0.3, 3),
             Kd=base["Kd"] * rng.uniform(0.3, 3)) for _ in range(6)])
    plants = tuning.position_sets(nominal)[1:2] if quick else tuning.position_sets(nominal)
    ours_s = theirs_s = 0.0
    worst = np.zeros(4)
    for parameters in designs:
        for plant in plants:
            t0 = time.perf_counter()
            m = tuning.loop_margins(parameters, plant, points=POINTS)
            t1 = time.perf_counter()
            theirs = python_control(parameters, plant)
            t2 = time.perf_counter()
            ours = (m.gm_db, m.pm_deg, m.phase_crossover_hz, m.gain_crossover_hz)
            ours_s, theirs_s = ours_s + t1 - t0, theirs_s + t2 - t1
            worst = np.maximum(worst, np.abs(np.subtract(ours, theirs)))
            print(f"loop_margins {t1 - t0:.3f} s: GM {ours[0]:.6f} dB, PM {ours[1]:.6f} deg at {ours[3]:.4f} Hz | "
                  f"python-control {t2 - t1:.3f} s: GM {theirs[0]:.6f} dB, PM {theirs[1]:.6f} deg "
                  f"at {theirs[3]:.4f} Hz")
    print(f"largest differences: GM {worst[0]:.2e} dB, PM {worst[1]:.2e} deg, phase crossover {worst[2]:.2e} Hz, "
          f"gain crossover {worst[3]:.2e} Hz; {len(designs) * len(plants)} loops, {ours_s:.2f} s against "
          f"{theirs_s:.2f} s")
    ratio("tuning.loop_margins_time", ours_s / theirs_s,
          "python-control on the same loop and grid (point-by-point response, stability_margins)")


if __name__ == "__main__":
    main()
