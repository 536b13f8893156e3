"""The ``motiontwin`` console script: one entry point, one subcommand per step of the data flow.

Each module of this package parses its subcommands' arguments and calls the library (``motiontwin.fmus``,
``.harness``, ``.ident``) with typed values; errors the library raises become one line on stderr.
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable

from motiontwin.cli import (build, compare, demo, diagnose, identify, labdata, simulate, tune, validate,
                            writeback)

SUBCOMMAND_MODULES = (build, simulate, labdata, identify, validate, writeback, tune, compare, diagnose, demo)


def parser() -> argparse.ArgumentParser:
    """The ``motiontwin`` argument parser with every subcommand."""
    top = argparse.ArgumentParser(prog="motiontwin", description=__doc__.splitlines()[0])
    sub = top.add_subparsers(dest="command", required=True)
    for module in SUBCOMMAND_MODULES:
        module.register(sub)
    return top


def main(argv: list[str] | None = None) -> int:
    from motiontwin.fmus.frontend import ModelicaError
    from motiontwin.fmus.package import BuildError
    from motiontwin.harness.fmu_instance import FMUCallError

    args = parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (ModelicaError, BuildError, FMUCallError, KeyError, ValueError, FileNotFoundError) as exc:
        print(f"motiontwin {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
