"""Benchmark (not a test): multi-axis `motiontwin diagnose` runtime against the issue-16 budget of 300 s for a
4-DOF CheungManipulator bundle of 10 s training at 2 kHz (plus validation) on this 2-core machine.

Without a bundle folder it writes one with the CasADi truth (:mod:`ident.benchmarks.multi_axis_truth`:
Coulomb friction of 0.5 N concealed on axis q5, encoder noise 10 nm, PID per axis, 10 s + 5 s at 2 kHz);
with a folder (e.g. one of the FMU-truth generator's bundles) it diagnoses that. Prints what was found
against ``truth.json`` (or ``<case>.truth.json``) when present, the per-axis validation RMS, the wall and CPU
time, the ratio to the target and the 1-minute load average.

The Hexapod in leg coordinates (issue 24 item 2: six legs whose lengths are inverse kinematics of the pose
states): ``--case hexapod_coulomb_L3 --train 1.5`` (15 N more Coulomb friction on leg 3 than the nominal model
has, at 1 kHz) and its parameters-only control ``--case hexapod_params_only --train 1.5``.

Process force noise on several axes: ``--case coupled2_coulomb_q2_process --train 4`` and
``--case coupled2_params_only_process --train 4`` (white 0.05 N + 0.05 N at 50 ms on both carriages, not in the
recorded force); each axis's line then also prints the truth's own floor (its validation recording against its
noise-free run).

Run: .venv/bin/python tests/benchmarks/bench_diagnosis_multiaxis.py [BUNDLE_DIR] [--out OUT] [--train 10]
[--case cheung_coulomb_q5|coupled2_coulomb_q2[_process]|coupled2_params_only_process|hexapod_coulomb_L3|
hexapod_params_only] [--smoke]
(--smoke: the two-carriage case, 0.5 s + 0.25 s, the vocabulary cut to coulomb_friction and time_delay: the
generate-diagnose-report path only). Ratios: wall and CPU time over the 300 s target (the baseline).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from motiontwin.ident.diagnosis import diagnose_bundle
from motiontwin.ident.benchmarks import multi_axis_truth as truth  # the benchmark generator: imported here only
from motiontwin.ident.diagnosis import effects as effect_models
from ratios import ratio

TARGET_S = 300.0


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle", nargs="?", help="bundle folder (default: generate the Cheung case)")
    parser.add_argument("--out", help="diagnosis output folder (default: a temporary one)")
    parser.add_argument("--train", type=float, default=10.0, help="generated training length [s]")
    parser.add_argument("--case", default="cheung_coulomb_q5",
                        choices=["cheung_coulomb_q5", "coupled2_coulomb_q2", "coupled2_coulomb_q2_process",
                                 "coupled2_params_only_process", "hexapod_coulomb_L3", "hexapod_params_only"],
                        help="generated example bundle")
    parser.add_argument("--smoke", action="store_true", help="a small two-axis bundle: only proves the path runs")
    args = parser.parse_args()
    if args.smoke:
        args.case, args.train = "coupled2_coulomb_q2", 0.5
        for table in (effect_models.VOCABULARY, effect_models.NESTED):
            for name in [n for n in table if n not in ("coulomb_friction", "time_delay")]:
                del table[name]
    with tempfile.TemporaryDirectory(prefix="bench-multiaxis-") as tmp:
        folder = Path(args.bundle) if args.bundle else Path(tmp) / args.case
        if not args.bundle:
            t0 = time.perf_counter()
            rate = {"ts": 1e-3} if args.case.startswith("hexapod") else {}
            truth.example(folder, args.case, args.train, args.train / 2, **rate)
            print(f"generated {folder} in {time.perf_counter() - t0:.1f} s")
        out = Path(args.out) if args.out else Path(tmp) / "out"
        wall, cpu = time.perf_counter(), cpu_seconds()
        doc = diagnose_bundle(folder, out, progress=lambda m: print(m, flush=True))
        wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
        truths = list(folder.glob("*truth.json")) or list(folder.parent.glob(f"{folder.name}.truth.json"))
        true = json.loads(truths[0].read_text()) if truths else {}
        if true:
            print("truth:", ", ".join(f"{e['name']} on {e['axis']} {e['parameters']}" for e in true["effects"]) or "-")
        print("found:", ", ".join(f"{e['name']} on {e['axis']} {e['parameters']}" for e in doc["effects"]) or "-",
              f"; {doc['unexplained']['status']} on {doc['unexplained'].get('axis')}" if doc.get("unexplained") else "")
        for axis, v in doc["validation"]["per_axis"].items():
            own = true.get("floor_rms", {}).get(axis)
            own_text = f", the truth's own {own:.3g} m" if own else ""
            print(f"  {axis}: validation RMS {v['nominal_rms']:.3g} -> {v['augmented_rms']:.3g} m "
                  f"(noise floor {v['noise_floor_rms']:.3g} m{own_text})")
        print(f"wall {wall:.1f} s, CPU {cpu:.1f} s, target {TARGET_S:.0f} s: ratio {wall / TARGET_S:.2f} (wall), "
              f"{cpu / TARGET_S:.2f} (CPU); load average {os.getloadavg()[0]:.2f}")
        ratio("diagnosis_multiaxis.wall_over_target", wall / TARGET_S, f"{TARGET_S:.0f} s budget for a 4-DOF "
              "bundle of 10 s training at 2 kHz, wall")
        ratio("diagnosis_multiaxis.cpu_over_target", cpu / TARGET_S, f"{TARGET_S:.0f} s budget, CPU")


if __name__ == "__main__":
    main()
