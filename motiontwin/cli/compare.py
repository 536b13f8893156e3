"""``motiontwin compare``: the paper comparison on the coupled 4-DOF plant."""
from __future__ import annotations

import argparse
from pathlib import Path


def _check_options(args: argparse.Namespace) -> None:
    """NaN, non-positive and absurdly long runs are refused before any FMU is built, naming the option."""
    import math

    from motiontwin.comparison import TS
    from motiontwin.harness.system import check_run_length

    for name in ("stop_time", "ct_pole_hz"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"--{name.replace('_', '-')} {value!r}: must be a finite number > 0")
    check_run_length(0.0, args.stop_time, TS, "--stop-time")


def _compare(args: argparse.Namespace) -> int:
    """Run both controllers, print the tables, write recordings, tables and figures."""
    from motiontwin.comparison import MOVE_TIME, PRE_MOVE, SS_WINDOW, run_comparison
    from motiontwin.comparison_report import format_table, write_outputs

    _check_options(args)
    if args.stop_time <= PRE_MOVE + MOVE_TIME + SS_WINDOW:
        raise ValueError(f"--stop-time {args.stop_time:g} s must exceed {PRE_MOVE + MOVE_TIME + SS_WINDOW:g} s "
                         f"(the move plus the steady-state window)")
    result = run_comparison(args.fmu_dir or args.out / "fmus", args.design, args.stop_time, args.ct_pole_hz,
                            table2_reading=args.table2_reading)
    print(format_table(result))
    for path in write_outputs(result, args.out):
        print(path)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    p = sub.add_parser("compare", help="Cheung & Hung's point-to-point comparison on the coupled 4-DOF plant: "
                                       "robust controller vs computed-torque PID, Tables 3/4, Figs. 4-7")
    p.add_argument("--out", type=Path, required=True, help="output folder (recordings, table.txt/json, figures)")
    p.add_argument("--design", action="append", default=[], type=Path, metavar="JSON",
                   help="robust design from 'motiontwin tune --out' (once for all joints, or 4 times: d1 d3 d5 d7)")
    p.add_argument("--stop-time", type=float, default=0.25, help="[s] run length (default 0.25)")
    p.add_argument("--ct-pole-hz", type=float, default=20.0, help="computed-torque triple pole [Hz] (default 20)")
    p.add_argument("--table2-reading", choices=("per-sample", "continuous"), default="per-sample",
                   help="how Table 2's Kp, Ki, Kd are read (default per-sample: Ki/Ts, Kd*Ts)")
    p.add_argument("--fmu-dir", type=Path, default=None, help="where to build the FMUs (default: OUT/fmus)")
    p.set_defaults(func=_compare, output_folders=("out", "fmu_dir"))
