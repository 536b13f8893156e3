"""The ``motiontwin`` console script: one entry point, one subcommand per step of the data flow."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable


def _build(args: argparse.Namespace) -> int:
    from fmus import build

    classes = list(args.classes)
    if args.all:
        classes += build.exported_classes(args.modelica)
    if not classes:
        print("motiontwin build: name at least one Modelica class, or --all", file=sys.stderr)
        return 2
    for fmu in build.build(classes, args.modelica, args.out, tuple(args.fmi)):
        print(fmu.path)
    return 0


def _demo(args: argparse.Namespace) -> int:
    from harness import demo

    demo.run(Path(args.out))
    return 0


def _parser() -> argparse.ArgumentParser:
    from fmus.build import DEFAULT_OUT, FMI_VERSIONS, MODELICA_DIR

    parser = argparse.ArgumentParser(prog="motiontwin", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build", help="build Modelica classes into FMI 2.0/3.0 FMUs (ME + CS, with sources)")
    p.add_argument("classes", nargs="*", help="full Modelica class names, e.g. MotionTwin.Plants.LinearMotorJoint")
    p.add_argument("--all", action="store_true", help="every class annotated __motiontwin(export=true)")
    p.add_argument("--modelica", type=Path, default=MODELICA_DIR, help="Modelica library folder or .mo file")
    p.add_argument("--fmi", nargs="+", choices=FMI_VERSIONS, default=list(FMI_VERSIONS), help="FMI versions")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (FMUs go to OUT/fmi2, OUT/fmi3)")
    p.set_defaults(func=_build)

    p = sub.add_parser("demo", help="build the example FMUs and run the example end to end")
    p.add_argument("--out", type=Path, default=Path("build") / "demo")
    p.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    from fmus.frontend import ModelicaError
    from fmus.package import BuildError

    args = _parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (ModelicaError, BuildError, KeyError, ValueError, FileNotFoundError) as exc:
        print(f"motiontwin {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
