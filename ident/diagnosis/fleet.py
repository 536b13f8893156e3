"""A fleet of diagnoses: many bundles (a folder of bundles, or several paths) diagnosed on one
:mod:`harness.executor` executor (in-process, process pool, Dask LocalCluster or scheduler), each diagnosis in
its own process, each bundle's result committed as soon as it finishes.

Output folder ``out``: ``out/NAME/`` per bundle (exactly what ``motiontwin diagnose BUNDLE --out out/NAME``
writes; NAME is the bundle folder's name, characters other than letters, digits and ``._=+-`` replaced by
``_``), the manifest ``fleet.json`` (format ``motiontwin-diagnose-fleet``: status, the finished bundles with the
sha256 of their bundle's files and the size and sha256 of every output file, the failed bundles with their
error) and, at the end, ``summary.csv`` + ``summary.html`` (one row per bundle: status, effects, verdict,
validation RMS nominal and augmented, validation gain = nominal / augmented RMS, seconds, error). The resume,
overwrite and failure rules are those of sweeps (:class:`harness.runfolder.RunFolder`); a finished bundle is also
diagnosed again on resume when its bundle's files changed. With a Dask scheduler on other machines, the bundles
and ``out`` must be on a file system the workers share.
"""
from __future__ import annotations

import contextlib
import csv
import functools
import hashlib
import html
import io
import json
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from motiontwin.harness.recording import atomic_write_texts
from motiontwin.harness.runfolder import Outcome, RunFolder, commit_each, damage, tree_records
from motiontwin.harness.sweep import safe_name

__all__ = ["FleetError", "MANIFEST", "SUMMARY_COLUMNS", "find_bundles", "is_fleet", "run_fleet"]

MANIFEST = "fleet.json"
MANIFEST_FORMAT = "motiontwin-diagnose-fleet"
SUMMARY_COLUMNS = ("bundle", "status", "effects", "verdict", "nominal_rms_m", "augmented_rms_m", "validation_gain",
                   "seconds", "error")
#: atomic writers' temporaries and the staging folders of Diagnosis.write (``.NAME.work-*``) a killed run leaves
_STALE = re.compile(r"^\..+\.([0-9a-f]{32}\.(tmp|bak)|work-\w+)$")
_EXPERIMENT = "experiment.json"


class FleetError(ValueError):
    """The fleet cannot run as given (the message names the path or the option)."""


def is_fleet(paths: Sequence[Path]) -> bool:
    """Several paths, or one folder that is no bundle (no experiment.json) but holds bundle folders."""
    if len(paths) != 1:
        return True
    path = paths[0]
    return path.is_dir() and not (path / _EXPERIMENT).exists() and any(_bundle_folders(path))


def _bundle_folders(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and (p / _EXPERIMENT).is_file())


def find_bundles(paths: Sequence[Path]) -> dict[str, Path]:
    """Output name -> bundle folder, for bundle folders and folders of bundles (their subfolders holding an
    experiment.json, in name order); a path that is neither, or two bundles with one name, is refused."""
    found: dict[str, Path] = {}
    for path in paths:
        if not path.is_dir():
            raise FleetError(f"{path}: not found or not a folder; give bundle folders or folders of bundles")
        folders = [path] if (path / _EXPERIMENT).is_file() else _bundle_folders(path)
        if not folders:
            raise FleetError(f"{path}: neither a bundle (no {_EXPERIMENT}) nor a folder of bundles (no subfolder "
                             f"holds one)")
        for folder in folders:
            name = safe_name(folder.name)
            if name in found:
                raise FleetError(f"{folder} and {found[name]}: two bundles named {name!r}; their results would "
                                 f"share the folder {name}/; rename one")
            found[name] = folder
    return found


def bundle_sha256(folder: Path) -> str:
    """The sha256 of a bundle folder: every file's relative path and contents."""
    h = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            h.update(path.relative_to(folder).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


@dataclass(frozen=True)
class FleetJob:
    """One diagnosis of a fleet: the bundle folder, its output folder and how the screening runs."""

    bundle: str
    out: str
    allow_outside_paths: bool = False
    screen_workers: int | None = None


@contextlib.contextmanager
def _screen_workers(count: int | None) -> Iterator[None]:
    """``MOTIONTWIN_DIAGNOSIS_WORKERS`` set to ``count`` for one diagnosis (None: unchanged)."""
    if count is None:
        yield
        return
    key = "MOTIONTWIN_DIAGNOSIS_WORKERS"
    previous = os.environ.get(key)
    os.environ[key] = str(count)
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = previous


def diagnose_job(job: FleetJob) -> dict[str, Any]:
    """Diagnose one bundle into its output folder (in a worker); its diagnosis.json document and seconds."""
    from motiontwin.ident.diagnosis import check_sizes
    from motiontwin.ident.diagnosis.bundle import read_bundle
    from motiontwin.ident.diagnosis.engine import diagnose_bundle_object

    t0 = time.perf_counter()
    with _screen_workers(job.screen_workers):
        check_sizes(Path(job.bundle))
        document = diagnose_bundle_object(read_bundle(job.bundle, job.allow_outside_paths)).write(job.out)
    return {"document": document, "seconds": time.perf_counter() - t0}


def summary_fields(document: dict[str, Any]) -> dict[str, Any]:
    """A finished diagnosis's row of the summary: effects, verdict, validation RMS and gain."""
    effects = ";".join(e["name"] + (f"@{e['axis']}" if "axis" in e else "") for e in document["effects"])
    unexplained = document.get("unexplained")
    verdict = (f"unexplained: {unexplained['status']}" if unexplained
               else "missing physics named" if effects
               else "not confirmed: " + ";".join(c["effect"] for c in document["not_confirmed"])
               if document.get("not_confirmed") else "parameters only")
    val = document["validation"]
    nominal, augmented = val.get("nominal_rms"), val.get("augmented_rms")
    gain = nominal / augmented if nominal is not None and augmented else None
    return {"effects": effects, "verdict": verdict, "nominal_rms_m": nominal, "augmented_rms_m": augmented,
            "validation_gain": gain}


def _cell(value: Any) -> str:
    if value is None:
        return ""
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def summary_texts(rows: list[dict[str, Any]]) -> tuple[str, str]:
    """summary.csv and summary.html of the fleet's rows (``SUMMARY_COLUMNS``)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(SUMMARY_COLUMNS)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in SUMMARY_COLUMNS])
    head = "".join(f"<th>{c}</th>" for c in SUMMARY_COLUMNS)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(row.get(c)))}</td>" for c in SUMMARY_COLUMNS)
                   + "</tr>\n" for row in rows)
    page = (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>Diagnosis fleet</title></head><body>\n"
            f"<h1>Diagnosis fleet: {len(rows)} bundle(s)</h1>\n<table border=\"1\">\n<tr>{head}</tr>\n{body}"
            f"</table>\n</body></html>\n")
    return buffer.getvalue(), page


def _inside(out: Path, name: str) -> Path:
    """``out / name``, refused unless it resolves inside ``out``."""
    path = out / name
    if not path.resolve().is_relative_to(out.resolve()) or path.resolve() == out.resolve():
        raise FleetError(f"{path}: resolves outside the output folder {out}; not a fleet manifest of motiontwin")
    return path


def _remove_bundle(out: Path, name: str) -> None:
    """Delete a bundle's output folder."""
    shutil.rmtree(_inside(out, name), ignore_errors=True)


def _kept(out: Path, hashes: dict[str, str], row: dict[str, Any]) -> str | None:
    """Why a finished bundle is diagnosed again on resume (None: kept)."""
    if row.get("bundle_sha256") != hashes[row["bundle"]]:
        return "its bundle's files changed since it was diagnosed"
    return damage(row.get("files"), functools.partial(_inside, out))


def run_fleet(paths: Sequence[str | os.PathLike], out: str | os.PathLike, executor: Any = None, *,
              executor_name: str = "inprocess", resume: bool = False, overwrite: bool = False, retries: int = 2,
              allow_outside_paths: bool = False, log: Callable[[str], None] = print) -> Outcome:
    """Diagnose every bundle of ``paths`` (bundle folders or folders of bundles) into ``out`` (see the module
    docstring), committing each as it finishes; ``executor`` a :mod:`harness.executor` executor (default
    in-process), ``resume``/``overwrite``/``retries`` as for sweeps (:func:`harness.sweep.run_to_folder`);
    ``log`` receives the plan, one line per finished or failed bundle and what resume cleaned."""
    from motiontwin.harness.executor import InProcessExecutor

    out = Path(out)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise FleetError(f"retries: expected a non-negative integer, got {retries!r}")
    bundles = find_bundles([Path(p) for p in paths])
    hashes = {name: bundle_sha256(folder) for name, folder in bundles.items()}
    folder = RunFolder(out, MANIFEST, "fleet", "bundle", FleetError, _STALE, rows="bundles")
    rows = folder.prepare(None, list(bundles), resume, overwrite, log, functools.partial(_remove_bundle, out),
                          functools.partial(_kept, out, hashes))
    todo = [name for name in bundles if name not in rows]
    log(f"{len(bundles)} bundles: {len(rows)} diagnosed earlier, {len(todo)} to diagnose ({executor_name})")
    out.mkdir(parents=True, exist_ok=True)
    for name in todo:   # what a killed run left of a bundle it had not committed
        _remove_bundle(out, name)
    resumed, completed, failed = list(rows), [], {}
    t0 = time.perf_counter()

    def write_manifest(status: str) -> None:
        finished = [rows[n] for n in bundles if n in rows]
        doc = {"format": MANIFEST_FORMAT, "version": 1, "fleet": ", ".join(str(p) for p in paths),
               "executor": executor_name, "status": status, "planned": len(bundles),
               "seconds": time.perf_counter() - t0, "bundles": finished,
               "failed": [{"bundle": n, "source": str(bundles[n]), "error": e} for n, e in failed.items()]}
        texts: dict[Path, str] = {out / MANIFEST: json.dumps(doc, indent=2) + "\n"}
        if status != "running":
            table = [{**rows[n], "status": "ok"} if n in rows else {"bundle": n, "status": "failed", "error": failed[n]}
                     for n in bundles if n in rows or n in failed]
            texts[out / "summary.csv"], texts[out / "summary.html"] = summary_texts(table)
        atomic_write_texts(texts)

    def commit(index: int, result: dict[str, Any]) -> None:
        name = todo[index]
        rows[name] = {"bundle": name, "source": str(bundles[name]), "bundle_sha256": hashes[name],
                      **summary_fields(result["document"]), "seconds": result["seconds"],
                      "files": tree_records(out / name, out)}
        completed.append(name)
        log(f"bundle {name}: {rows[name]['verdict']}, effects {rows[name]['effects'] or 'none'} "
            f"({result['seconds']:.1f} s)")

    def fail(index: int, error: str) -> None:
        failed[todo[index]] = error
        log(f"bundle {todo[index]} failed: {error}")

    write_manifest("running")
    if not todo:
        write_manifest("complete")
        return Outcome(completed, resumed, failed, 0.0)
    executor = executor or InProcessExecutor()
    screen = None if isinstance(executor, InProcessExecutor) else 1   # the bundles share the cores, not the fits
    # absolute paths: a worker of a remote scheduler runs in another folder
    jobs = [FleetJob(str(bundles[n].absolute()), str(out.absolute() / n), allow_outside_paths, screen) for n in todo]
    try:
        commit_each(executor, diagnose_job, jobs, retries, commit, fail, write_manifest)
    except KeyboardInterrupt:   # a diagnosis that finished its folder but was not committed leaves nothing
        for name in todo:
            if name not in rows:
                _remove_bundle(out, name)
        raise
    return Outcome(completed, resumed, failed, time.perf_counter() - t0)
