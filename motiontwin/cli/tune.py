"""``motiontwin tune``: tune the robust joint controller (``ident.tuning``), print the margins, write the
design JSON, figures and a controller FMU. Exit code 2 if the spec is infeasible."""
from __future__ import annotations

import argparse
import json
import math
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

from motiontwin.cli.arguments import name_values


def _suffixed(path: Path, suffix: str) -> Path:
    """build/x.json, "d1" -> build/x_d1.json."""
    return path.with_name(f"{path.stem}_{suffix}{path.suffix}")


def _plant(text: str, index: int, defaults: dict[str, float]) -> Any:
    """``--plant K=..,omega=..`` (number ``index``) -> a JointModel; missing fields from ``defaults``."""
    from motiontwin.ident.tuning import joint_model_from_fields

    where = f"--plant #{index + 1}"
    return joint_model_from_fields(name_values(text, where), defaults, f"{where} {text!r}")


def _spec(args: argparse.Namespace) -> Any:
    from motiontwin.ident.tuning import TuningSpec

    tau_max = None if args.tau_max is None or not math.isfinite(args.tau_max) else args.tau_max
    return TuningSpec(args.gm, args.pm_min, args.pm_max, args.ms, args.s_below_bw, args.bw_min, tau_max)


def _tune_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of ``tune`` / ``tune_manipulator`` from the command line."""
    return dict(tau=args.tau, seed=args.seed, popsize=args.popsize, maxiter=args.maxiter, refine=args.refine,
                progress=True, feedforward=not args.no_feedforward, jerk=not args.no_jerk)


def _write_json(out: Path, documents: dict[Path, dict]) -> None:
    from motiontwin.harness.recording import atomic_write_texts

    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_texts({path: json.dumps(doc, indent=2) + "\n" for path, doc in documents.items()})
    print("\n".join(str(path) for path in documents))


def _tune_manipulator(args: argparse.Namespace) -> int:
    """``motiontwin tune --manipulator``: per-actuator design on the CheungManipulator FMU at --poses poses."""
    import numpy as np

    from motiontwin.fmus import build
    from motiontwin.ident.tuning import manipulator as tm
    from motiontwin.ident.controller_fmu import write_controller_fmu
    from motiontwin.ident.tuning import cheung_joint_defaults, format_margins, slowest_time_constant

    spec = _spec(args)
    flexible = None if args.rigid else _plant((args.plant or [""])[0], 0, cheung_joint_defaults())
    poses = tm.workspace_poses(args.poses)
    with tempfile.TemporaryDirectory(prefix="motiontwin-tune-") as tmp:
        fmu = args.plant_fmu or build.build_fmu(build.load_model(tm.MANIPULATOR_CLASS), tmp, "3.0").path
        design = tm.tune_manipulator(fmu, poses, flexible, args.ts, spec, args.delay, **_tune_options(args))
    labels = [f"pose {k}: x={p[0] * 1e3:.1f} y={p[1] * 1e3:.1f} z={p[2] * 1e3:.1f} mm" for k, p in enumerate(poses)]
    for name, result, plants in zip(tm.ACTUATORS, design.results, design.plants):
        print(f"actuator {name}")
        print(format_margins(result, plants))
        print("parameters: " + ", ".join(f"{k}={v:.6g}" for k, v in result.parameters.items()))
    print("coupled closed loop, 1 - spectral radius per pose (> 0 is stable): without gravity "
          + ", ".join(f"{1 - r:.2e}" for r in design.radius_without_gravity) + "; with gravity "
          + ", ".join(f"{1 - r:.2e}" for r in design.radius_with_gravity))
    print("coupled closed loop, slowest time constant -Ts/ln(radius) per pose [ms]: without gravity "
          + ", ".join(f"{slowest_time_constant(np.array([r]), args.ts) * 1e3:.3g}"
                      for r in design.radius_without_gravity) + "; with gravity "
          + ", ".join(f"{slowest_time_constant(np.array([r]), args.ts) * 1e3:.3g}"
                      for r in design.radius_with_gravity))
    for line in design.infeasible:
        print(f"infeasible spec: {line}")
    doc = design.as_dict()
    if args.out:
        _write_json(args.out, {args.out: doc} | {_suffixed(args.out, a): d for a, d in doc["joints"].items()})
    if args.plots:
        from motiontwin.ident.tuning.plots import write_loop_figure

        for name, result, plants in zip(tm.ACTUATORS, design.results, design.plants):
            print(write_loop_figure(args.plots / f"tuning_manipulator_{name}.png", result.parameters, plants,
                                    args.delay, labels, f"CheungManipulator actuator {name} (FMU linearised, "
                                    f"{'rigid' if flexible is None else 'times eq. (8) H(s)'})", spec,
                                    result.margins))
    stable = max(design.radius_without_gravity + design.radius_with_gravity) < 1
    if args.fmu_out and not design.infeasible and stable:
        for name, result in zip(tm.ACTUATORS, design.results):
            provenance = {"method": doc["method"], "actuator": name, "poses": doc["poses"], "spec": asdict(spec),
                          "margins": doc["joints"][name]["margins"]}
            print(write_controller_fmu(result.parameters, args.ts, _suffixed(args.fmu_out, name), provenance,
                                       args.fmu, args.fmi))
    return 0 if not design.infeasible and stable else 2


# option -> (lowest value, whether the lowest value itself is allowed); every one must also be finite
_NUMBER_BOUNDS = {"ts": (0.0, False), "tau": (0.0, False), "gain_spread": (0.0, True),
                  "resonance_spread": (0.0, True), "tau_max": (0.0, False)}
_COUNT_BOUNDS = {"delay": 0, "popsize": 1, "maxiter": 1, "refine": 0, "poses": 1}
_FINITE = ("gm", "pm_min", "pm_max", "ms", "s_below_bw", "bw_min")


def check_options(args: argparse.Namespace) -> None:
    """Refuse NaN, infinite and out-of-range tune options before any FMU is built, naming the option."""
    import math

    def refuse(name: str, what: str) -> None:
        raise ValueError(f"--{name.replace('_', '-')} {getattr(args, name)!r}: {what}")

    for name in _FINITE:
        value = getattr(args, name)
        if value is not None and not math.isfinite(value):
            refuse(name, "must be a finite number")
    for name, (low, inclusive) in _NUMBER_BOUNDS.items():
        value = getattr(args, name)
        if value is None or (name == "tau_max" and value == math.inf):
            continue
        if math.isnan(value) or math.isinf(value) or value < low or (value == low and not inclusive):
            refuse(name, f"must be a finite number {'>=' if inclusive else '>'} {low:g}"
                   + (" (or inf: unconstrained)" if name == "tau_max" else ""))
    for name in ("gain_spread", "resonance_spread"):
        if getattr(args, name) >= 1.0:
            refuse(name, "must be below 1 (a fraction of the nominal value)")
    for name, low in _COUNT_BOUNDS.items():
        if getattr(args, name) < low:
            refuse(name, f"must be at least {low}")


def _tune(args: argparse.Namespace) -> int:
    """``motiontwin tune``: one controller on the plant sets (``--plant`` or a linearised ``--plant-fmu``)."""
    from motiontwin.ident.controller_fmu import write_controller_fmu
    from motiontwin.ident.frf import JointModel
    from motiontwin.ident.tuning import (InfeasibleSpecError, cheung_joint_defaults, comparison_markdown,
                                         format_comparison, format_margins, position_sets,
                                         table2_comparison, tune)

    check_options(args)
    if args.manipulator:
        return _tune_manipulator(args)
    spec = _spec(args)
    if args.plant_fmu:  # each --plant gives start values of the FMU, linearised from its directional derivatives
        from motiontwin.harness.linearize import linearize

        plants = [linearize(args.plant_fmu, [args.plant_input], [args.plant_output], name_values(t, f"--plant #{k + 1}"))
                  for k, t in enumerate(args.plant or [""])]
    else:
        defaults = cheung_joint_defaults()
        plants = [_plant(t, k, defaults) for k, t in enumerate(args.plant or [""])]
        if len(plants) == 1 and (args.gain_spread or args.resonance_spread):
            plants = position_sets(plants[0], args.gain_spread, args.resonance_spread)
    try:
        result = tune(plants, args.ts, spec, args.delay, **_tune_options(args))
        feasible = True
    except InfeasibleSpecError as err:
        print(f"infeasible spec: {err}")
        result, feasible = err.result, False
    print(format_margins(result, plants))
    print("parameters: " + ", ".join(f"{k}={v:.6g}" for k, v in result.parameters.items()))
    if args.compare_table2:
        rows = table2_comparison(plants[len(plants) // 2], args.ts, args.delay, result)
        print(format_comparison(rows))
        print(comparison_markdown(rows))
    doc = result.as_dict() | {"plants": [asdict(p) if isinstance(p, JointModel) else str(p) for p in plants]}
    if args.out:
        _write_json(args.out, {args.out: doc})
    if args.plots:
        from motiontwin.ident.tuning.plots import write_loop_figure

        labels = [f"set {k}: K={p.gain:.3g}" if isinstance(p, JointModel) else f"set {k}"
                  for k, p in enumerate(plants)]
        print(write_loop_figure(args.plots / "tuning_joint.png", result.parameters, plants, args.delay, labels,
                                "CheungJoint (eqs. 6-8) at the actuator-position sets", spec, result.margins))
    if args.fmu_out and feasible:
        provenance = {"method": doc["method"], "spec": doc["spec"], "plants": doc["plants"], "margins": doc["margins"]}
        print(write_controller_fmu(result.parameters, args.ts, args.fmu_out, provenance, args.fmu, args.fmi))
    return 0 if feasible else 2


def _plot_tuning(args: argparse.Namespace) -> int:
    """``motiontwin plot-tuning DESIGN --out DIR``: redraw the loop figures of a design file."""
    from motiontwin.ident.tuning.plots import replot_design

    for path in replot_design(args.design, args.out):
        print(path)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    p = sub.add_parser("tune", help="tune the robust joint controller (Cheung eqs. 9-18) on the discrete loop")
    p.add_argument("--plant", action="append", default=[],
                   metavar="K=..,alpha=..,omega=..,zeta=..,omega_bar=..,zeta_bar=..",
                   help="one actuator position (repeat); missing fields from MotionTwin.Plants.CheungJoint [SI, rad/s]")
    p.add_argument("--plant-fmu", type=Path, default=None,
                   help="plant FMU (Model Exchange) linearised per --plant (then NAME=VALUE start values of the FMU)")
    p.add_argument("--plant-input", default="u", help="plant FMU input (default u)")
    p.add_argument("--plant-output", default="q", help="plant FMU output (default q)")
    p.add_argument("--gain-spread", type=float, default=0.3, help="with one --plant: K*(1 -/+ spread) sets")
    p.add_argument("--resonance-spread", type=float, default=0.1, help="with one --plant: resonances *(1 +/- spread)")
    p.add_argument("--ts", type=float, default=5e-4, help="sample period [s] (default 5e-4, 2 kHz)")
    p.add_argument("--delay", type=int, default=1, help="computation delay [samples] (default 1)")
    p.add_argument("--tau", type=float, default=None, help="derivative filter time constant [s] (default 2 Ts)")
    p.add_argument("--gm", type=float, default=7.0, help="GM lower bound [dB] (eq. 14)")
    p.add_argument("--pm-min", type=float, default=45.0, help="PM band lower end [deg] (eq. 15 read as a band)")
    p.add_argument("--pm-max", type=float, default=60.0, help="PM band upper end [deg] (eq. 15: PM <= 60)")
    p.add_argument("--ms", type=float, default=2.0, help="upper bound on max|S| (modulus margin 1/Ms)")
    p.add_argument("--s-below-bw", type=float, default=None, help="upper bound on max|S| below CLBW (eq. 17)")
    p.add_argument("--bw-min", type=float, default=None, help="lower bound on the worst-case CLBW [Hz] (eq. 16)")
    p.add_argument("--tau-max", type=float, default=0.03,
                   help="upper bound on the slowest closed-loop time constant [s] on every plant set (inf: unconstrained)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--popsize", type=int, default=12, help="differential evolution population multiplier")
    p.add_argument("--maxiter", type=int, default=80, help="differential evolution generations")
    p.add_argument("--refine", type=int, default=3, help="Nelder-Mead then SLSQP (gradient) refinements from the best members")
    p.add_argument("--compare-table2", action="store_true", help="print Cheung Table 2 designs beside the tuned one")
    p.add_argument("--out", type=Path, default=None, help="JSON with parameters, spec, margins (writeback reads it)")
    p.add_argument("--fmu", type=Path, default=None, help="controller FMU to write into (default: build one)")
    p.add_argument("--fmi", choices=("2.0", "3.0"), default="3.0", help="FMI version of the built controller FMU")
    p.add_argument("--fmu-out", type=Path, default=None, help="new controller FMU with the tuned start values")
    p.add_argument("--plots", type=Path, default=None,
                   help="folder for Bode/Nyquist/sensitivity PNGs (tuning_joint.png or tuning_manipulator_d1..d7.png)")
    p.add_argument("--manipulator", action="store_true",
                   help="per-actuator design on the CheungManipulator FMU linearised at --poses poses "
                        "(--plant: eq. (8) flexible mode; --plant-fmu: a manipulator FMU)")
    p.add_argument("--poses", type=int, default=5, help="with --manipulator: poses along the workspace segment")
    p.add_argument("--rigid", action="store_true", help="with --manipulator: no eq. (8) flexible mode on the channels")
    p.add_argument("--no-feedforward", action="store_true", help="keep Kv, Ka, Kj at the FMU defaults")
    p.add_argument("--no-jerk", action="store_true", help="fit Kv, Ka only (Kj = 0)")
    p.set_defaults(func=_tune, output_files=("out", "fmu_out"), output_folders=("plots",),
                   input_fmus=("fmu", "plant_fmu"))
    p = sub.add_parser("plot-tuning", help="Bode/Nyquist/sensitivity figures of a 'motiontwin tune --out' design file")
    p.add_argument("design", type=Path, help="JSON written by motiontwin tune --out")
    p.add_argument("--out", type=Path, required=True, help="folder for tuning_*.png")
    p.set_defaults(func=_plot_tuning, output_folders=("out",))
