"""``motiontwin tune``: tune the robust joint controller."""
from __future__ import annotations

import argparse
from pathlib import Path


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
    from motiontwin.ident.tuning import cli_tune

    check_options(args)
    return cli_tune(args)


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
