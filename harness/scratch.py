"""This process's temporary folder: unzipped FMUs and built benchmark FMUs live in it, and it is removed when the
process ends, also a multiprocessing or process-pool worker (which leaves through ``os._exit``, past ``atexit``).
A forked child gets a folder of its own and never removes its parent's."""
from __future__ import annotations

import atexit
import multiprocessing.util
import os
import shutil
import tempfile
from pathlib import Path

_FOLDERS: dict[int, str] = {}   # pid -> its folder


def _remove() -> None:
    folder = _FOLDERS.pop(os.getpid(), None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)


def process_folder() -> Path:
    """The temporary folder of this process (created on first use, under ``tempfile.gettempdir()``)."""
    pid = os.getpid()
    if pid not in _FOLDERS:
        _FOLDERS[pid] = tempfile.mkdtemp(prefix="motiontwin-")
        atexit.register(_remove)
        multiprocessing.util.Finalize(None, _remove, exitpriority=0)
    return Path(_FOLDERS[pid])
