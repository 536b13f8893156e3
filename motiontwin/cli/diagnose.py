"""``motiontwin diagnose``: mismatch diagnosis of a bundle."""
from __future__ import annotations

import argparse
from pathlib import Path


def _diagnose(args: argparse.Namespace) -> int:
    from motiontwin.ident import diagnosis

    return diagnosis.run(str(args.bundle), str(args.out), args.quiet, args.allow_outside_paths)


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    from motiontwin.ident.bundleformat import BUNDLE_FORMAT

    p = sub.add_parser("diagnose", help="locate and name the physics a recording shows and the model lacks; "
                                        "refit, rebuild the FMU, validate",
                       description="Diagnose the mismatch between a nominal model and closed-loop recordings.\n"
                                   "Before any fit each recording's u is checked against controller(r, q) + u_ext\n"
                                   "(ident.channels); a mismatch beyond noise is refused (exit 2) naming the file\n"
                                   "and the likely cause (gain or unit factor, sign, delay, u_ext scaled or missing).",
                       epilog=BUNDLE_FORMAT, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bundle", type=Path, help="bundle folder with experiment.json, plant .mo, train/validation CSV")
    p.add_argument("--out", type=Path, required=True, help="output folder (diagnosis.json, report.md, FMU, ...)")
    p.add_argument("--quiet", action="store_true", help="do not print progress")
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="read files that experiment.json names outside the bundle folder (refused by default)")
    p.set_defaults(func=_diagnose, output_folders=("out",), staged_folders=("out",))
