"""Benchmark (not a test): the Hexapod diagnosed in leg coordinates (issue 24 item 2), its answer against the
truth and its time per bundle, for the concealed-effect case and the parameters-only control.

Each case is written by :mod:`ident.benchmarks.multi_axis_truth` (the library Hexapod simulated by CasADi,
six PID-controlled legs, 1 kHz, 10 nm encoder noise, mE starting at 11.5 kg against the true 10.2):
``hexapod_coulomb_L3`` (leg 3 with 15 N more Coulomb friction than the nominal model's Table II value, through
the plant's own friction law, not the diagnosis' effect code) and ``hexapod_params_only`` (the same without it),
then diagnosed as by ``motiontwin diagnose`` (without writing its output folder unless ``--write``). Printed
per case: the round-1 location scores, the effects found (name, axis, parameters; the Coulomb level against the
truth's 15 N), the nominal and the augmented refit's parameters against the truth's, the validation RMS per
leg against its noise floor, what is left unexplained, and the diagnosis' wall and CPU time (CPU: this process
and its gcc children). By default the vocabulary is cut to Coulomb friction, its Stribeck form and a gravity
offset (each screened Hexapod structure compiles its own loop, about 20 s of gcc on a cold cache); ``--full``
screens the whole vocabulary (874 s of CPU for the L3 bundle, docs/diagnose-multiaxis.md).

Run: MOTIONTWIN_DIAGNOSIS_WORKERS=1 .venv/bin/python tests/benchmarks/bench_hexapod.py [--train 1.5]
[--case hexapod_coulomb_L3|hexapod_params_only] [--full] [--write] [--smoke]
(--smoke: the L3 case only, 0.5 s + 0.33 s, the vocabulary cut to coulomb_friction, plant.free cut to mE: only
proves the generate-diagnose-print path runs; 14 s on a warm compile cache in session 37. At 0.3 s it took 33 s:
the legs travel so little that the Coulomb smoothing velocity's search limits were widened twice, 12 s.)
Ratios: each case's wall time over the 300 s multi-axis budget, the augmented refit's mE over the truth's, and
on the L3 case the found Coulomb level over 15 N (when an effect is named on L3).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from motiontwin.ident.benchmarks import multi_axis_truth as truth  # the benchmark generator: imported here only
from motiontwin.ident.diagnosis import read_bundle
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.engine import diagnose_bundle_object
from ratios import ratio

CASES = ("hexapod_coulomb_L3", "hexapod_params_only")
KEPT = ("coulomb_friction", "stribeck_friction", "gravity_offset")
FC_EXTRA = 15.0          # N: leg 3's Coulomb friction beyond the nominal model's rc3 (multi_axis_truth.example)
TARGET_S = 300.0         # s: the multi-axis diagnosis budget (issue 16)


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def cut_vocabulary(kept: tuple[str, ...]) -> None:
    """Keep only the effects ``kept`` (this process only)."""
    for table in (effect_models.VOCABULARY, effect_models.NESTED):
        for name in [n for n in table if n not in kept]:
            del table[name]


def run_case(case: str, train: float, root: Path, write: bool, free: list[str] | None = None) -> None:
    """Generate, diagnose and print one case (``write``: also its output folder, the augmented FMU built;
    ``free``: the nominal refit's free parameters instead of the generator's mE and cv1..cv6)."""
    folder = root / case
    t0 = time.perf_counter()
    expected = truth.example(folder, case, train, train * 2 / 3, ts=1e-3)
    if free:
        experiment = json.loads((folder / "experiment.json").read_text())
        experiment["plant"]["free"] = free
        (folder / "experiment.json").write_text(json.dumps(experiment, indent=1))
    print(f"== {case}: {train:g} s + {train * 2 / 3:g} s at 1 kHz, generated in {time.perf_counter() - t0:.1f} s",
          flush=True)
    wall, cpu = time.perf_counter(), cpu_seconds()
    diagnosis = diagnose_bundle_object(read_bundle(folder), progress=lambda m: print("  ", m, flush=True))
    doc = diagnosis.write(root / f"{case}-out") if write else diagnosis.document(root / f"{case}-out")
    wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
    if doc["location"]:
        scores = doc["location"][0]["scores"]
        print("round-1 location (force residual / noise reference):",
              ", ".join(f"{k} {v:.3g}" for k, v in sorted(scores.items(), key=lambda kv: -kv[1])))
    print("truth: " + (f"{FC_EXTRA:g} N more Coulomb friction on L3" if case == "hexapod_coulomb_L3" else
                       "no effect (parameters only)"))
    print("found:", ", ".join(f"{e['name']} on {e['axis']} " + ", ".join(f"{k} = {v:.6g}" for k, v in
                                                                      e["parameters"].items())
                              for e in doc["effects"]) or "-")
    plant = expected["plant_parameters"]
    for label, key in (("nominal refit", "nominal_parameters"), ("augmented refit", "augmented_parameters")):
        fitted = doc[key]
        print(f"{label} vs (truth):", ", ".join(f"{k} {fitted[k]:.6g} ({plant[k]:.6g})" for k in truth.HEXAPOD_FREE
                                               if k in fitted))
    for axis, v in doc["validation"]["per_axis"].items():
        print(f"  {axis}: validation RMS {v['nominal_rms']:.4g} -> {v['augmented_rms']:.4g} m "
              f"(noise floor {v['noise_floor_rms']:.4g} m)")
    print("unexplained:", doc["unexplained"] or "nothing")
    print(f"time per bundle: wall {wall:.1f} s, CPU {cpu:.1f} s; load average {os.getloadavg()[0]:.2f}", flush=True)
    short = case.removeprefix("hexapod_")
    ratio(f"hexapod.{short}.wall_over_target", wall / TARGET_S, f"{TARGET_S:.0f} s multi-axis diagnosis budget")
    ratio(f"hexapod.{short}.mE_over_truth", doc["augmented_parameters"]["mE"] / plant["mE"],
          f"the truth's mE = {plant['mE']:g} kg (augmented refit)")
    coulomb = [e for e in doc["effects"] if e["axis"] == "L3" and "Fc" in e["parameters"]]
    if case == "hexapod_coulomb_L3" and coulomb:
        ratio(f"hexapod.{short}.fc_over_truth", coulomb[0]["parameters"]["Fc"] / FC_EXTRA,
              f"the truth's {FC_EXTRA:g} N on L3")
    print(json.dumps({"case": case, "effects": [(e["name"], e["axis"]) for e in doc["effects"]],
                      "wall_s": round(wall, 1), "cpu_s": round(cpu, 1)}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=float, default=1.5, help="training length [s]; validation is 2/3 of it")
    parser.add_argument("--case", action="append", choices=CASES, help="only this case (repeatable)")
    parser.add_argument("--full", action="store_true", help="screen the whole vocabulary")
    parser.add_argument("--write", action="store_true", help="also write each output folder (the augmented FMU "
                        "built, as motiontwin diagnose does; not in the time per bundle's diagnosis part)")
    parser.add_argument("--smoke", action="store_true", help="a short L3 bundle, one effect: only proves it runs")
    args = parser.parse_args()
    cases, free = tuple(args.case or CASES), None
    if args.smoke:
        cases, args.train, free = ("hexapod_coulomb_L3",), 0.5, ["mE"]
        cut_vocabulary(("coulomb_friction",))
    elif not args.full:
        cut_vocabulary(KEPT)
    print("vocabulary:", ", ".join(effect_models.VOCABULARY), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-hexapod-") as tmp:
        for case in cases:
            run_case(case, args.train, Path(tmp), args.write, free)


if __name__ == "__main__":
    main()
