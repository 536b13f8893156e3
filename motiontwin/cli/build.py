"""``motiontwin build``: build Modelica classes into FMUs."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _build(args: argparse.Namespace) -> int:
    from motiontwin.fmus import build

    classes = list(args.classes)
    if args.all:
        classes += build.exported_classes(args.modelica)
    if not classes:
        print("motiontwin build: name at least one Modelica class, or --all", file=sys.stderr)
        return 2
    for fmu in build.build(classes, args.modelica, args.out, tuple(args.fmi)):
        print(fmu.path)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    from motiontwin.fmus import DEFAULT_OUT, FMI_VERSIONS, MODELICA_DIR

    p = sub.add_parser("build", help="build Modelica classes into FMI 2.0/3.0 FMUs (ME + CS, with sources)")
    p.add_argument("classes", nargs="*", help="full Modelica class names, e.g. MotionTwin.Plants.LinearMotorJoint")
    p.add_argument("--all", action="store_true", help="every class annotated __motiontwin(export=true)")
    p.add_argument("--modelica", type=Path, default=MODELICA_DIR, help="Modelica library folder or .mo file")
    p.add_argument("--fmi", nargs="+", choices=FMI_VERSIONS, default=list(FMI_VERSIONS), help="FMI versions")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (FMUs go to OUT/fmi2, OUT/fmi3)")
    p.set_defaults(func=_build, output_folders=("out",))
