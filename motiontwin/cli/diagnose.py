"""``motiontwin diagnose``: mismatch diagnosis of a bundle, or of a fleet of bundles on an executor."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

FLEET_OPTIONS = ("executor", "workers", "scheduler", "resume", "overwrite", "retries")

FLEET_HELP = """\
fleet mode: several bundle folders, or a folder whose subfolders are bundles, are diagnosed on an executor
(--executor inprocess|process|dask, --workers, --scheduler ADDRESS as for `motiontwin sweep`; on a process
pool or Dask each diagnosis runs in its own worker process). OUT/NAME/ receives each bundle's results as it
finishes, OUT/fleet.json the manifest (failures per bundle), OUT/summary.csv and OUT/summary.html one row per
bundle (effects, verdict, validation RMS and gain, seconds, status); --resume keeps the bundles already
committed and verified, --overwrite replaces the fleet.
  motiontwin diagnose bundles/ --out fleet --executor dask --workers 2

within one diagnosis, the independent fits (the candidates' screenings and full fits, the floor's noise
replicates) run side by side in forked processes: MOTIONTWIN_DIAGNOSIS_WORKERS of them (default: the cores, at
most 4; 1 runs them in-process). The results do not depend on it.
"""


def _diagnose(args: argparse.Namespace) -> int:
    from motiontwin.ident.diagnosis import fleet

    if fleet.is_fleet(args.bundle):
        args.resumable = True
        return _fleet(args)
    values = {name: getattr(args, name) for name in FLEET_OPTIONS}
    given = [f"--{name}" for name, value in values.items() if value is not None and value is not False]
    if given:
        raise ValueError(f"{', '.join(given)}: options of a fleet (several bundles or a folder of bundles); "
                         f"{args.bundle[0]} is one bundle")
    from motiontwin.ident import diagnosis

    return diagnosis.run(str(args.bundle[0]), str(args.out), args.quiet, args.allow_outside_paths)


def _fleet(args: argparse.Namespace) -> int:
    from motiontwin.harness.executor import make_executor
    from motiontwin.ident.diagnosis import fleet

    kind = "dask" if args.scheduler else args.executor or "inprocess"
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    with make_executor(kind, args.workers, args.scheduler) as executor:
        outcome = fleet.run_fleet(args.bundle, args.out, executor, executor_name=kind, resume=args.resume,
                                  overwrite=args.overwrite, retries=2 if args.retries is None else args.retries,
                                  allow_outside_paths=args.allow_outside_paths, log=log)
    print(f"{len(outcome.completed)} bundle(s) diagnosed in {outcome.seconds:.1f} s ({kind}), "
          f"{len(outcome.resumed)} kept from before, {len(outcome.failed)} failed; summary: {args.out}/summary.csv")
    if outcome.failed:
        print(f"motiontwin diagnose: {len(outcome.failed)} bundle(s) failed: {', '.join(outcome.failed)} "
              f"(errors in {args.out / fleet.MANIFEST}; --resume diagnoses them again)", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    from motiontwin.ident.bundleformat import BUNDLE_FORMAT

    p = sub.add_parser("diagnose", help="locate and name the physics a recording shows and the model lacks; "
                                        "refit, rebuild the FMU, validate",
                       description="Diagnose the mismatch between a nominal model and closed-loop recordings.\n"
                                   "Before any fit each recording's u is checked against controller(r, q) + u_ext\n"
                                   "(ident.channels); a mismatch beyond noise is refused (exit 2) naming the file\n"
                                   "and the likely cause (gain or unit factor, sign, delay, u_ext scaled or missing).\n"
                                   "Controller unknown (no 'controller' in experiment.json, or kind 'unknown'): the\n"
                                   "recordings need only time, u, q; a prediction-error predictor (a PD observer on\n"
                                   "the measured q fitted with the plant, the measured u as disturbance, its start\n"
                                   "estimated in every fit) stands in for the controller and\n"
                                   "the validation RMS is the predictor's (see the format below, docs/diagnose.md).",
                       epilog=BUNDLE_FORMAT + "\n" + FLEET_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bundle", type=Path, nargs="+",
                   help="bundle folder with experiment.json, plant .mo, train/validation CSV; several bundle folders "
                        "or a folder of bundles diagnose a fleet (see below)")
    p.add_argument("--out", type=Path, required=True,
                   help="output folder (diagnosis.json, report.md, FMU, ...; a fleet: one subfolder per bundle, "
                        "fleet.json, summary.csv, summary.html)")
    p.add_argument("--quiet", action="store_true", help="do not print progress")
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="read files that experiment.json names outside the bundle folder (refused by default)")
    fleet = p.add_argument_group("fleet", "options of a fleet of bundles (the executors of `motiontwin sweep`)")
    fleet.add_argument("--executor", default=None, choices=["inprocess", "process", "dask"],
                       help="where the diagnoses go (default inprocess); --scheduler implies dask")
    fleet.add_argument("--workers", type=int, default=None,
                       help="worker processes (process pool, Dask LocalCluster)")
    fleet.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="Dask scheduler, e.g. tcp://host:8786 (workers must share the bundles' and --out's "
                            "file system)")
    again = fleet.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the fleet in --out: keep its committed bundles, diagnose the others")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the fleet in --out (its bundles' results are removed first)")
    fleet.add_argument("--retries", type=int, default=None,
                       help="times a diagnosis whose worker process died is tried again (default 2)")
    p.set_defaults(func=_diagnose, output_folders=("out",), staged_folders=("out",))
