"""``motiontwin excite / run / sweep / regress / ssp``: co-simulation jobs: excitation files, system runs, sweeps, regression suites, SSP export."""
from __future__ import annotations

import argparse
from pathlib import Path



def _excite(args: argparse.Namespace) -> int:
    from motiontwin.harness import experiment, recording

    rec = experiment.experiment_recording(experiment.load_experiment(args.experiment))
    for path in recording.write_recording(args.out, rec):
        print(path)
    if args.mat:
        print(recording.write_mat(args.out.with_suffix(".mat"), rec))
    return 0


def _run(args: argparse.Namespace) -> int:
    from motiontwin.harness import recording
    from motiontwin.harness.inputs import input_from_spec
    from motiontwin.harness.master import Master
    from motiontwin.harness.simulation import recording_from_log

    inputs = dict(input_from_spec(spec) for spec in args.input)
    with Master(args.system) as master:
        logs = master.run(inputs=inputs, stop_time=args.stop_time)
        meta = master.metadata()
    rec = recording_from_log(logs, args.log, meta, excited={"inputs": args.input},
                             metadata={"system": str(args.system), "order": meta["order"]})
    for path in recording.write_recording(args.out, rec):
        print(path)
    return 0


def _sweep(args: argparse.Namespace) -> int:
    import sys

    from motiontwin.harness import sweep
    from motiontwin.harness.executor import make_executor

    plan = sweep.load_sweep(args.sweep)
    with make_executor(args.executor, args.workers, args.scheduler) as executor:
        outcome = sweep.run_to_folder(plan, args.out, executor, executor_name=args.executor, resume=args.resume,
                                      overwrite=args.overwrite, retries=args.retries)
    runs = len(outcome.completed)
    rate = f"{runs / outcome.seconds:.1f} runs/s, " if outcome.seconds > 0 else ""
    print(f"{runs} runs in {outcome.seconds:.2f} s ({rate}{args.executor}) -> {args.out}")
    if outcome.failed:
        print(f"motiontwin sweep: {len(outcome.failed)} run(s) failed: {', '.join(outcome.failed)} "
              f"(errors in {args.out / sweep.MANIFEST}; --resume runs them again)", file=sys.stderr)
        return 1
    return 0


def _regress(args: argparse.Namespace) -> int:
    from motiontwin.harness import regress

    return regress.run_suite(args.suite, args.update, args.junit, args.plots)


def _ssp(args: argparse.Namespace) -> int:
    from motiontwin.harness import ssp

    print(ssp.export_ssp(args.system, args.out, args.drop_external_in_sums))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    p = sub.add_parser("excite", help="sample an excitation experiment file into a recording")
    p.add_argument("experiment", type=Path, help="experiment TOML, e.g. harness/experiments/swept_sine_80_500.toml")
    p.add_argument("--out", type=Path, required=True, help="recording CSV (a JSON sidecar is written beside it)")
    p.add_argument("--mat", action="store_true", help="also write a MATLAB .mat file")
    p.set_defaults(func=_excite, output_files=("out",))

    p = sub.add_parser("run", help="co-simulate a system file and write a recording")
    p.add_argument("system", type=Path, help="system description (TOML)")
    p.add_argument("--input", action="append", default=[], metavar="NAME=VALUE|EXPERIMENT.toml[:FIELD]",
                   help="drive external input NAME with a constant or an experiment's signal (FIELD: value, "
                        "position, ...)")
    p.add_argument("--stop-time", type=float, default=None, help="[s] (default: the system file's stop_time)")
    p.add_argument("--log", default=None, help="log group to record (default: the first)")
    p.add_argument("--out", type=Path, required=True, help="recording CSV (a JSON sidecar is written beside it)")
    p.set_defaults(func=_run, output_files=("out",))

    p = sub.add_parser("sweep", help="run the cases of a sweep file (seeds, grids) through an executor")
    p.add_argument("sweep", type=Path, help="sweep file (TOML, see harness/sweep.py)")
    p.add_argument("--executor", default="inprocess", choices=["inprocess", "process", "dask"],
                   help="where the runs go (default inprocess); --scheduler implies dask")
    p.add_argument("--workers", type=int, default=None, help="worker processes (process pool, Dask LocalCluster)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster on this machine)")
    p.add_argument("--out", type=Path, required=True, help="folder: one recording per case + sweep.json")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the sweep in --out: keep its finished runs, run the others")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the sweep in --out (its runs are removed first)")
    p.add_argument("--retries", type=int, default=2,
                   help="times a run whose worker process died is tried again (default 2)")
    p.set_defaults(func=_sweep, output_folders=("out",), resumable=True)

    p = sub.add_parser("regress", help="run a regression suite against reference recordings (tolerance tubes)")
    p.add_argument("suite", type=Path, help="suite file (TOML)")
    p.add_argument("--update", action="store_true", help="rebaseline: rewrite the reference recordings")
    p.add_argument("--junit", type=Path, default=None, help="write JUnit XML here")
    p.add_argument("--plots", type=Path, default=None, help="write a plot per failing signal here")
    p.set_defaults(func=_regress, output_files=("junit",), output_folders=("plots",))

    p = sub.add_parser("ssp", help="export a system file as an SSP archive")
    p.add_argument("system", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--drop-external-in-sums", action="store_true",
                   help="drop external inputs from sum junctions (SSP 1.0 has no sum junctions)")
    p.set_defaults(func=_ssp, output_files=("out",))
