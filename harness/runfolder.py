"""A folder of independent runs committed as they finish: what sweeps (:mod:`harness.sweep`) and diagnosis
fleets (:mod:`ident.diagnosis.fleet`) share.

The folder holds one manifest (JSON, rewritten atomically) whose rows name each finished run with the size and
sha256 of its files, and whose ``failed`` rows hold each failed run's error. :meth:`RunFolder.prepare` checks the
folder against resume/overwrite (a folder holding other files is refused), removes the temporary files a killed
run left, and keeps the finished runs whose files still have their committed size and checksum;
:func:`commit_each` runs the others through a :mod:`harness.executor` executor, hands each result to the caller
as it arrives and rewrites the manifest (status running, then complete, failed or interrupted).
"""
from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

__all__ = ["RunFolder", "commit_each", "damage", "digest", "file_records", "tree_records", "MANIFEST_INTERVAL"]

MANIFEST_INTERVAL = 0.5   # [s] least time between two manifest rewrites while runs complete
#: atomic_write_texts' temporaries and backups
STALE_FILES = re.compile(r"^\..+\.[0-9a-f]{32}\.(tmp|bak)$")


def digest(data: bytes) -> dict[str, Any]:
    """Size and sha256 of ``data``."""
    return {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def file_records(texts: dict[Path, str | bytes]) -> dict[str, dict[str, Any]]:
    """File name -> size and sha256 of the bytes :func:`atomic_write_texts` writes for ``texts``."""
    return {path.name: digest(text if isinstance(text, bytes) else text.encode("utf-8"))
            for path, text in texts.items()}


def tree_records(folder: Path, root: Path) -> dict[str, dict[str, Any]]:
    """Path relative to ``root`` (POSIX) -> size and sha256, for every file under ``folder``."""
    return {path.relative_to(root).as_posix(): digest(path.read_bytes())
            for path in sorted(folder.rglob("*")) if path.is_file()}


def damage(files: Any, locate: Callable[[str], Path]) -> str | None:
    """Why a run the manifest lists as finished cannot be kept (None if its files are as committed);
    ``locate`` maps a recorded file name to its path (and refuses one outside the folder)."""
    if not isinstance(files, dict) or not files:
        return "the manifest holds no size and checksum for its files"
    for name, expected in files.items():
        path = locate(name)
        if not path.is_file():
            return f"{name} is missing"
        data = path.read_bytes()
        if len(data) != expected.get("bytes"):
            kind = "truncated" if len(data) < expected.get("bytes", 0) else "changed"
            return f"{name} is {kind} ({len(data)} bytes, {expected.get('bytes')} committed)"
        if hashlib.sha256(data).hexdigest() != expected.get("sha256"):
            return f"{name} differs from what was committed (sha256)"
    return None


@dataclass
class Outcome:
    """What a run over a folder did: items finished now, kept from before (resume), failed (name -> error)."""

    completed: list[str]
    resumed: list[str]
    failed: dict[str, str]
    seconds: float


@dataclass
class RunFolder:
    """The output folder ``out`` of many runs: its manifest file ``manifest``, the word for what it holds
    (``kind``: "sweep", "fleet"), the row field naming a run (``key``), the error raised on a folder that
    cannot be used (``error``), the names of temporary entries a killed run leaves (``stale``) and the manifest
    field listing the finished runs (``rows``)."""

    out: Path
    manifest: str
    kind: str
    key: str
    error: type[Exception]
    stale: re.Pattern = STALE_FILES
    rows: str = "cases"

    def read_manifest(self) -> dict[str, Any] | None:
        """The manifest document, None without one; a malformed one is refused."""
        path = self.out / self.manifest
        if not path.exists():
            return None
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise self.error(f"{path}: line {exc.lineno}, column {exc.colno}: {exc.msg}; not a {self.kind} "
                             f"manifest, choose another --out") from None
        if not isinstance(doc, dict) or not isinstance(doc.get(self.rows), list):
            raise self.error(f"{path}: field '{self.rows}' missing; not a {self.kind} manifest, "
                             f"choose another --out")
        return doc

    def remove_stale(self, previous: dict[str, Any] | None, log: Callable[[str], None]) -> None:
        """Remove the temporary entries a killed run left in the folder and say so, with a "running" status."""
        stale = sorted(p for p in self.out.iterdir() if self.stale.match(p.name))
        for path in stale:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        if stale:
            log(f"{self.out}: removed {len(stale)} temporary file(s) a killed {self.kind} left: "
                f"{', '.join(p.name for p in stale)}")
        if previous is not None and previous.get("status") == "running":
            log(f"{self.out}: the {self.kind} there did not end (status 'running' in {self.manifest}: its process "
                f"was killed)")

    def prepare(self, fingerprint: str | None, names: Sequence[str], resume: bool, overwrite: bool,
                log: Callable[[str], None], remove: Callable[[str], None],
                check: Callable[[dict[str, Any]], str | None]) -> dict[str, dict[str, Any]]:
        """Check the folder against resume/overwrite and return the finished rows kept (run name -> row).

        ``fingerprint``: resume continues only a manifest with the same one (None: any); ``names``: the runs
        planned now; ``remove(name)`` deletes a run's files; ``check(row)`` says why a row cannot be kept
        (None if it can). Overwriting removes every run the manifest lists and the manifest."""
        if resume and overwrite:
            raise self.error(f"resume and overwrite exclude each other: continue the {self.kind} or replace it")
        if not self.out.exists() or not any(self.out.iterdir()):
            return {}
        previous = self.read_manifest()
        if previous is None:
            if all(self.stale.match(p.name) for p in self.out.iterdir()):   # killed before its first manifest
                self.remove_stale(None, log)
                return {}
            raise self.error(f"{self.out}: holds files but no {self.manifest}; choose a new or empty folder for "
                             f"the {self.kind}")
        rows = previous[self.rows]
        label = f"{previous.get(self.kind, '?')}, {len(rows)} finished run(s)"
        if not resume and not overwrite:
            raise self.error(f"{self.out}: holds a {self.kind} ({label}); pass --resume to continue it or "
                             f"--overwrite to replace its runs, or choose another folder")
        if resume and fingerprint is not None and previous.get("fingerprint") != fingerprint:
            raise self.error(f"{self.out}: holds another {self.kind} ({label}); --resume continues only the same "
                             f"sweep file and system; pass --overwrite to replace it or choose another folder")
        self.remove_stale(previous, log)
        if overwrite:
            for row in rows + previous.get("failed", []):
                if isinstance(row, dict) and isinstance(row.get(self.key), str):
                    remove(row[self.key])
            (self.out / self.manifest).unlink()
            return {}
        kept: dict[str, dict[str, Any]] = {}
        for row in rows:
            if not isinstance(row, dict) or row.get(self.key) not in names:
                continue
            why = check(row)
            if why is None:
                kept[row[self.key]] = row
                continue
            log(f"run {row[self.key]} runs again: {why}")
            remove(row[self.key])
        return kept


def commit_each(executor: Any, fn: Callable[[Any], Any], items: Sequence[Any], retries: int,
                on_result: Callable[[int, Any], None], on_failure: Callable[[int, str], None],
                write_manifest: Callable[[str], None]) -> str:
    """Run ``fn`` over ``items`` on ``executor``; hand each result to ``on_result(index, result)`` (each failed
    run's error to ``on_failure``) as it arrives, rewrite the manifest as "running" at most every
    ``MANIFEST_INTERVAL`` seconds and with the final status at the end, also when interrupted; returns it."""
    from .executor import RunFailed
    from .interrupt import raise_if_terminated, uninterrupted

    last_write = time.perf_counter()
    status = "interrupted"
    failed = False
    try:
        for index, result in executor.imap(fn, items, retries):
            raise_if_terminated()   # a SIGTERM whose exception a library swallowed during the run
            with uninterrupted():   # a run's files and its manifest row are committed together
                if isinstance(result, RunFailed):
                    failed = True
                    on_failure(index, result.error)
                else:
                    on_result(index, result)
                if time.perf_counter() - last_write >= MANIFEST_INTERVAL:
                    write_manifest("running")
                    last_write = time.perf_counter()
        status = "failed" if failed else "complete"
    finally:
        with uninterrupted():
            write_manifest(status)
    return status
