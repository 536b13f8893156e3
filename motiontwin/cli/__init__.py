"""The ``motiontwin`` console script: one entry point, one subcommand per step of the data flow.

Each module of this package parses its subcommands' arguments and calls the library (``motiontwin.fmus``,
``.harness``, ``.ident``) with typed values; errors the library raises become one line on stderr.
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Callable

from motiontwin.harness import BLAS_THREAD_VARIABLES  # numpy-free: set before numpy loads
from motiontwin.harness.interrupt import Terminated, handle_termination, raise_if_terminated

#: One BLAS thread per process unless the user sets one: a diagnosis of a 12 s + 6 s bundle took 34.8 s of CPU
#: (22.9 s wall) with OpenBLAS's threads and 17.0 s (18.1 s wall) without, same result.
for _variable in BLAS_THREAD_VARIABLES:   # before numpy is imported; spawned workers inherit them
    os.environ.setdefault(_variable, "1")

from motiontwin.cli import (build, compare, demo, diagnose, identify, labdata, simulate, tune, validate,  # noqa: E402
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
        build), 130 when interrupted (Ctrl-C), 143 when terminated (SIGTERM). The writers are atomic and
        temporary folders are context managers, so an error or an interruption leaves earlier results
        untouched and no half-written file or temporary folder.
    """
    import zipfile

    from motiontwin.cli.errors import os_error_message, preflight

    args = parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    prefix = f"motiontwin {args.command}"
    try:
        with handle_termination():
            preflight(args)
            code = func(args)
            raise_if_terminated()   # a SIGTERM whose exception a library swallowed still ends the command
            return code
    except KeyboardInterrupt as exc:
        again = "add --resume to continue" if getattr(args, "resumable", False) else "run the command again"
        what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"{prefix}: {what}; finished outputs are complete, nothing half-written was kept ({again})",
              file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except OSError as exc:
        print(f"{prefix}: {os_error_message(exc)}", file=sys.stderr)
        return 1
    except zipfile.BadZipFile as exc:
        print(f"{prefix}: a file given as an FMU or archive is not a zip archive ({exc}); check the paths",
              file=sys.stderr)
        return 1
    except _library_errors() as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 1


# The library's error types by module: a module never imported (fmpy for identification) raised none of them.
LIBRARY_ERRORS = {"motiontwin.fmus.frontend": "ModelicaError", "motiontwin.fmus.package": "BuildError",
                  "motiontwin.harness.fmu_instance": "FMUCallError", "fmpy.fmi1": "FMICallException"}


def _library_errors() -> tuple[type[Exception], ...]:
    """The errors main reports as one line (evaluated when one is raised, so nothing is imported for it)."""
    loaded = tuple(getattr(sys.modules[m], name) for m, name in LIBRARY_ERRORS.items() if m in sys.modules)
    return (KeyError, ValueError, *loaded)


if __name__ == "__main__":
    sys.exit(main())
