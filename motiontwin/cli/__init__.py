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
    from motiontwin.fmus.limits import limits_help

    top = argparse.ArgumentParser(prog="motiontwin", description=__doc__.splitlines()[0], epilog=limits_help())
    sub = top.add_subparsers(dest="command", required=True)
    for module in SUBCOMMAND_MODULES:
        module.register(sub)
    return top


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; every expected failure is one line on stderr.

    Returns
    -------
    int
        0 on success, 1 on an error (bad input, a path that cannot be read or written, a failing FMU or
        build), 130 when interrupted (Ctrl-C). The writers are atomic, so an error or an interruption leaves
        earlier results untouched and no half-written file.
    """
    import zipfile

    from fmpy.fmi1 import FMICallException

    from motiontwin.cli.errors import os_error_message, preflight
    from motiontwin.fmus.frontend import ModelicaError
    from motiontwin.fmus.package import BuildError
    from motiontwin.harness.fmu_instance import FMUCallError

    args = parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    prefix = f"motiontwin {args.command}"
    try:
        preflight(args)
        return func(args)
    except KeyboardInterrupt:
        again = "add --resume to continue" if args.command == "sweep" else "run the command again"
        print(f"{prefix}: interrupted; finished outputs are complete, nothing half-written was kept ({again})",
              file=sys.stderr)
        return 130
    except OSError as exc:
        print(f"{prefix}: {os_error_message(exc)}", file=sys.stderr)
        return 1
    except zipfile.BadZipFile as exc:
        print(f"{prefix}: a file given as an FMU or archive is not a zip archive ({exc}); check the paths",
              file=sys.stderr)
        return 1
    except (ModelicaError, BuildError, FMUCallError, FMICallException, KeyError, ValueError) as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
