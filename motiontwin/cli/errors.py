"""One line per failure: the CLI's messages for file-system errors, and the checks of output and FMU paths
that run before a subcommand does any work.

A subcommand declares its paths with ``set_defaults``: ``output_files`` and ``output_folders`` (names of
arguments that are written; ``staged_folders`` those of them whose contents are staged in the folder above
and moved in at the end), ``input_fmus`` (arguments that must be FMU archives). :func:`preflight` checks
them, so a read-only target, a file where a folder is expected or a non-zip ``.fmu`` fail in milliseconds,
before a build or a simulation, and nothing is written.
"""
from __future__ import annotations

import argparse
import errno
import os
import re
from pathlib import Path

__all__ = ["PathProblem", "os_error_message", "preflight"]

_INTERNAL_SUFFIXES = (".tmp", ".part", ".bak")  # temporary files of the atomic writers
_STAGING = re.compile(r"\.(.+?)(?:-staging-|\.work-)\w+")  # staging folders beside an output folder


class PathProblem(ValueError):
    """An argument's path cannot be used; the message names the argument, the path and what to do."""


def _shown_path(name: str | os.PathLike | None) -> str | None:
    """The path a user knows: an atomic writer's hidden temporary file is reported as its folder, a file in a
    staging folder (``.OUT-staging-*``, ``.OUT.work-*``) as the output folder ``OUT``."""
    if name is None:
        return None
    path = Path(os.fsdecode(name))
    for k, part in enumerate(path.parts):
        staged = _STAGING.fullmatch(part)
        if staged:
            return str(Path(*path.parts[:k], staged.group(1)))
    if path.name.startswith(".") and path.name.endswith(_INTERNAL_SUFFIXES):
        return str(path.parent)
    return str(path)


def os_error_message(exc: OSError) -> str:
    """One line for an OSError: the path, what is wrong and what to do."""
    path = _shown_path(exc.filename)
    if path is None:
        return str(exc)
    internal = exc.filename is not None and path != os.fsdecode(exc.filename)
    if isinstance(exc, PermissionError) or exc.errno == errno.EROFS:
        what = "permission denied (read-only); choose a writable location or change the permissions"
    elif isinstance(exc, NotADirectoryError):
        what = "a part of this path is a file, not a folder; remove that file or choose another path"
    elif isinstance(exc, IsADirectoryError):
        what = "is a folder where a file is expected; give a file name"
    elif isinstance(exc, FileExistsError):
        what = "already exists and is in the way; remove it or choose another path"
    elif isinstance(exc, FileNotFoundError):
        what = ("folder does not exist; create it first or choose another path" if internal
                else "not found; check the path")
    elif exc.errno == errno.ENOSPC:
        what = "no space left on the device; free space and run again"
    else:
        what = f"{exc.strerror or exc}; check the path"
    if exc.filename2 is not None:
        return f"{path} -> {_shown_path(exc.filename2)}: {what}"
    return f"{path}: {what}"


def _first_existing(path: Path) -> Path:
    """``path`` or its nearest existing ancestor."""
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _writable_location(option: str, path: Path, folder: bool) -> None:
    """Raise :class:`PathProblem` if ``path`` cannot be created or replaced as a file (or folder)."""
    if path.exists():
        if folder and not path.is_dir():
            raise PathProblem(f"{option} {path}: is a file where a folder is expected; remove it or choose "
                              f"another folder")
        if not folder and path.is_dir():
            raise PathProblem(f"{option} {path}: is a folder where a file is expected; give a file name")
    existing = _first_existing(path if folder else path.parent)
    if not existing.is_dir():
        raise PathProblem(f"{option} {path}: {existing} is a file, not a folder; remove it or choose another "
                          f"path")
    if not os.access(existing, os.W_OK | os.X_OK, effective_ids=os.access in os.supports_effective_ids):
        raise PathProblem(f"{option} {path}: folder {existing} is not writable; choose a writable location or "
                          f"change its permissions")


def _declared(args: argparse.Namespace, kind: str) -> list[tuple[str, str]]:
    """(option, value) of the arguments a subcommand declared as ``kind`` and the user gave."""
    return [("--" + name.replace("_", "-"), getattr(args, name)) for name in getattr(args, kind, ())
            if getattr(args, name, None) is not None]


def preflight(args: argparse.Namespace) -> None:
    """Check the output and FMU arguments a subcommand declared (see the module docstring)."""
    for option, value in _declared(args, "output_files"):
        _writable_location(option, Path(value), folder=False)
    for option, value in _declared(args, "output_folders"):
        _writable_location(option, Path(value), folder=True)
    for option, value in _declared(args, "staged_folders"):
        _writable_location(f"{option} (staged in the folder above)", Path(value).absolute().parent, folder=True)
    for _, value in _declared(args, "input_fmus"):
        from motiontwin.fmus.archive import read_description  # imports fmpy: only for a command given an FMU

        read_description(value)
