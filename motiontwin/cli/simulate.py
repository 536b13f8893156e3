"""``motiontwin excite / run / sweep / regress / ssp``: co-simulation jobs: excitation files, system runs, sweeps, regression suites, SSP export."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def _excite(args: argparse.Namespace) -> int:
    from motiontwin.harness import excitation, recording

    rec = excitation.experiment_recording(excitation.load_experiment(args.experiment))
    for path in recording.write_recording(args.out, rec):
        print(path)
    if args.mat:
        print(recording.write_mat(args.out.with_suffix(".mat"), rec))
    return 0


def _log_recording(logs: dict[str, np.ndarray], group: str | None, meta: dict, **provenance: object):
    """The recording of one log group of a master run (units and FMUs from ``meta``)."""
    from motiontwin.harness import recording

    group = group or next(iter(logs))
    if group not in logs:
        raise ValueError(f"log group {group!r}: the system logs {sorted(logs)}")
    log = logs[group]
    columns = {name: log[name] for name in log.dtype.names if name != "time"}
    units = {name: meta["units"].get(name) or "" for name in columns}
    return recording.make_recording(log["time"], columns, units, sample_time=float(log["time"][1] - log["time"][0]),
                                    fmus=meta["fmus"], **provenance)


def _run(args: argparse.Namespace) -> int:
    from motiontwin.harness import recording
    from motiontwin.harness.inputs import input_from_spec
    from motiontwin.harness.master import Master

    inputs = dict(input_from_spec(spec) for spec in args.input)
    with Master(args.system) as master:
        logs = master.run(inputs=inputs, stop_time=args.stop_time)
        meta = master.metadata()
    rec = _log_recording(logs, args.log, meta, excited={"inputs": args.input},
                         metadata={"system": str(args.system), "order": meta["order"]})
    for path in recording.write_recording(args.out, rec):
        print(path)
    return 0


def _sweep(args: argparse.Namespace) -> int:
    import json
    import time

    from motiontwin.harness import recording, sweep
    from motiontwin.harness.executor import make_executor
    from motiontwin.harness.master import master_for

    plan = sweep.load_sweep(args.sweep)
    t0 = time.perf_counter()
    with make_executor(args.executor, args.workers, args.scheduler) as executor:
        results = sweep.run(plan, executor)
    seconds = time.perf_counter() - t0
    meta = master_for(plan.system).metadata()
    texts, rows = {}, []
    for case, logs in zip(plan.cases, results):
        rec = _log_recording(logs, plan.log, meta, excited={"sweep": str(args.sweep), "case": case.name},
                             metadata={"system": str(plan.system.source), "parameters": case.parameters})
        texts.update(recording.recording_texts(args.out / f"{case.name}.csv", rec))
        rows.append({"case": case.name, "parameters": case.parameters,
                     "final": {k: float(rec[k][-1]) for k in rec.columns}})
    texts[args.out / "sweep.json"] = json.dumps({"sweep": str(args.sweep), "executor": args.executor,
                                                "runs": len(rows), "seconds": seconds, "cases": rows},
                                               indent=2) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    recording.atomic_write_texts(texts)
    print(f"{len(rows)} runs in {seconds:.2f} s ({len(rows) / seconds:.1f} runs/s, {args.executor}) -> {args.out}")
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
    p.add_argument("--input", action="append", default=[], metavar="NAME=EXPERIMENT.toml[:FIELD]",
                   help="drive external input NAME with an experiment's signal (FIELD: value, position, ...)")
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
    p.set_defaults(func=_sweep, output_folders=("out",))

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
