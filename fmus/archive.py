"""Open an ``.fmu`` archive's modelDescription.xml with one clear error naming the file.

fmpy reports a file that is no zip archive as ``BadZipFile('File is not a zip file')``, a zip without
a model description as ``KeyError('modelDescription.xml')`` and a broken XML as a parser error, none of
which names the FMU. :func:`read_description` turns them into :class:`FMUArchiveError` with the path and
what to do, and is what every layer calls before it extracts or instantiates an FMU.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import fmpy

__all__ = ["FMUArchiveError", "check_archive", "read_description"]

DESCRIPTION_NAME = "modelDescription.xml"


class FMUArchiveError(ValueError):
    """A file given as an FMU is not a readable FMU archive; the message names the file."""


def check_archive(path: str | os.PathLike) -> Path:
    """Raise :class:`FMUArchiveError` unless ``path`` is a zip archive holding modelDescription.xml.

    Parameters
    ----------
    path:
        The ``.fmu`` file.

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(2, "FMU file not found", str(path))
    if path.is_dir():
        raise FMUArchiveError(f"{path}: is a folder, not an FMU file; give the .fmu archive")
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except zipfile.BadZipFile:
        raise FMUArchiveError(f"{path}: not an FMU (not a zip archive); rebuild it with 'motiontwin build' "
                              f"or give another file") from None
    if DESCRIPTION_NAME not in names:
        raise FMUArchiveError(f"{path}: not an FMU: the archive holds no {DESCRIPTION_NAME}; rebuild it with "
                              f"'motiontwin build' or give another file")
    return path


def read_description(path: str | os.PathLike) -> Any:
    """fmpy's ``ModelDescription`` of the FMU at ``path``.

    Parameters
    ----------
    path:
        The ``.fmu`` file.

    Returns
    -------
    fmpy.model_description.ModelDescription
        As :func:`fmpy.read_model_description` returns it.

    Raises
    ------
    FMUArchiveError
        The file is no zip archive, lacks modelDescription.xml, or the description is malformed.
    """
    path = check_archive(path)
    try:
        return fmpy.read_model_description(str(path))
    except OSError:
        raise
    except Exception as exc:  # fmpy raises parser errors, KeyError and plain Exception for bad XML
        detail = "; ".join(line.strip(" -") for line in str(exc).splitlines() if line.strip())
        raise FMUArchiveError(f"{path}: malformed {DESCRIPTION_NAME} ({detail}); rebuild the FMU") from None
