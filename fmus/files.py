"""Atomic file writes for every layer: a new file appears complete or not at all, also across mount points.

Every writer of the package goes through this module (it lives in ``fmus``, the lowest layer, so that ``fmus``
can use it too): :func:`atomic_path` (one file written by a library through a path), :func:`atomic_write_texts`
(several files, all or none) and :func:`move_file` (a finished file into place). Temporary files sit in the
target's own folder, hence on its file system, so the final ``os.replace`` is atomic; a move between file
systems (a staging folder beside an output folder that is a mount point) copies into the target's folder
first and renames there.
"""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import Iterator

__all__ = ["atomic_path", "atomic_write_texts", "move_file", "ordinary_file_mode", "staging_folder"]


def ordinary_file_mode() -> int:
    """The permissions ``open()`` would give a new file under the current umask (0o644 under umask 022);
    ``tempfile.mkstemp`` creates 0o600, which the writers here correct before the rename."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def _named(target: Path) -> Iterator[None]:
    """Give an OSError without a file name (a full disk while writing: ``[Errno 28]``) ``target``'s name."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None or exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror, str(target)) from exc


def _temporary_name(target: Path, suffix: str = ".tmp") -> Path:
    """A hidden, unique name in ``target``'s folder (the CLI reports such a name as its folder)."""
    return target.parent / f".{target.name}.{uuid.uuid4().hex}{suffix}"


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target`` to write to; on success it replaces ``target`` (ordinary
    file mode, fsynced), on any error or interrupt it is removed and ``target`` stays as it was."""
    target = Path(target)
    tmp = _temporary_name(target)
    try:
        with _named(target):
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, ordinary_file_mode()))
            yield tmp
            os.chmod(tmp, ordinary_file_mode())
            with open(tmp, "rb+") as handle:
                os.fsync(handle.fileno())
            os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def move_file(src: str | os.PathLike, target: str | os.PathLike) -> None:
    """Move the finished file ``src`` to ``target`` atomically; across file systems (``EXDEV``) it is copied
    to a temporary file beside ``target`` first, renamed there, and ``src`` is removed."""
    try:
        os.replace(src, target)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        with atomic_path(target) as tmp:
            shutil.copyfile(src, tmp)
        os.unlink(src)


@contextlib.contextmanager
def staging_folder(out: Path) -> Iterator[Path]:
    """A temporary folder to build the contents of the output folder ``out`` in, removed afterwards: beside
    ``out`` when its parent is writable, else (``out`` is e.g. a mount point under a read-only folder) a
    hidden folder inside ``out``. Move the finished files in with :func:`move_file`."""
    out.parent.mkdir(parents=True, exist_ok=True)
    inside = out.is_dir() and not os.access(out.parent, os.W_OK | os.X_OK,
                                            effective_ids=os.access in os.supports_effective_ids)
    with tempfile.TemporaryDirectory(prefix=f".{out.name}-staging-", dir=out if inside else out.parent) as tmp:
        yield Path(tmp)


def atomic_write_texts(files: dict[Path, str | bytes]) -> None:
    """Write several files (text, or bytes written as they are) so that either all new contents appear or none do.

    Each text goes to a temporary file in the target's folder (flushed and fsynced), then all are moved into
    place with os.replace. If a move fails, targets already replaced are restored from hard-link backups of
    their previous contents (or removed if they did not exist), so no partial set of files is left behind.
    """
    temps: dict[Path, Path] = {}
    backups: dict[Path, Path | None] = {}
    done: list[Path] = []
    mode = ordinary_file_mode()
    try:
        for target, text in files.items():
            # the name is recorded before the file exists, so an interrupt at any point leaves no temporary file
            temps[target] = tmp = _temporary_name(target)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
            os.fchmod(fd, mode)
            binary = isinstance(text, bytes)
            with _named(target), (os.fdopen(fd, "wb") if binary
                                  else os.fdopen(fd, "w", encoding="utf-8", newline="")) as handle:
                handle.write(text)
                handle.flush()
                os.fsync(handle.fileno())
        for target in files:
            backups[target] = None
            if target.exists():
                backups[target] = backup = _temporary_name(target, ".bak")
                try:
                    os.link(target, backup)
                except OSError:
                    shutil.copy2(target, backup)
        for target in files:
            os.replace(temps[target], target)
            del temps[target]
            done.append(target)
    except BaseException:
        for target in done:
            backup = backups.get(target)
            if backup is None:
                target.unlink(missing_ok=True)
            else:
                os.replace(backup, target)
                backups[target] = None
        raise
    finally:
        for tmp in temps.values():
            tmp.unlink(missing_ok=True)
        for backup in backups.values():
            if backup is not None:
                backup.unlink(missing_ok=True)
