"""Sweep files: many runs of one system file (Monte Carlo seeds, parameter grids, workspace sweeps),
run through one executor (:mod:`harness.executor`: in-process, process pool or Dask), one recording each.

Sweep file (TOML), paths relative to it::

    system = "joint_loop.toml"      # a harness system file
    log = "log"                     # optional: the log group recorded (default: the first)
    stop_time = 0.5                 # optional: default the system's

    [[case]]
    name = "kp_low"
    [case.parameters]               # per-run overrides "inst.variable" = value
    "ctrl.Kp" = 1.0e5
    [case.inputs]                   # harness.inputs: number, {recording, column} or {experiment, field}
    r = {experiment = "../experiments/point_to_point_5mm.toml", field = "position"}
    [case.noise]                    # seeded white noise added to an input on the base grid
    u_ext = {std = 0.5, seed = 1}

    [grid]                          # optional: every case again for each combination of these values:
    "plant.m" = [1.5, 2.0, 2.5]     # parameters "inst.variable", or
    "input.r" = [0.0, 0.01]         # constant external inputs "input.NAME" (e.g. actuator positions)

    [seeds]                         # optional: every case `count` times, noise seeds first, first + 1, ...
    count = 100
    first = 0

Cases are expanded in the order case x grid x seed; their names get ``-NAME=VALUE`` and ``-sSEED``.
The results do not depend on the executor (:func:`harness.executor.run_sweep`). Units are the FMUs'.
A sweep expands to at most ``MAX_RUNS`` runs, checked before anything is built or run. Case names become file
names: characters other than letters, digits and ``._=+-`` are replaced by ``_`` (no ``/``, no leading dot).

Output folder (:func:`run_to_folder`): one recording ``CASE.csv`` + ``CASE.json`` per run, each written
atomically as soon as its run finishes, and the manifest ``sweep.json`` (format ``motiontwin-sweep``) rewritten
atomically as runs complete: ``status`` (running, interrupted, complete, failed), ``cases`` (the finished
runs in case order, each with the size and sha256 of its two files), ``failed`` (case and error: the FMU's own
message for a value it refuses). A run whose worker process dies is retried (bounded), a run that fails is
reported by name while the others complete. A folder holding a sweep is refused unless ``resume`` (continue the
same sweep: finished runs whose files still have their committed size and checksum are kept, the others run)
or ``overwrite`` (the runs the manifest lists are removed first); both remove the temporary files a killed
sweep left. A folder holding other files is always refused.
"""
from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
import re
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .inputs import InputError, add_input_noise, resolve_input
from .recording import atomic_write_texts, recording_texts, sidecar_path
from .runfolder import Outcome, RunFolder, commit_each, damage, file_records
from .simulation import recording_from_log
from .system import System, check_run_length, load_system

__all__ = ["SweepError", "SweepCase", "Sweep", "load_sweep", "run", "run_to_folder",
           "safe_name", "MAX_RUNS"]

INPUT_PREFIX = "input."   # a [grid] key "input.r" sets the external input r to a constant
MAX_RUNS = 10_000         # runs one sweep file may expand to (cases x grid x seeds)
MANIFEST = "sweep.json"
MANIFEST_FORMAT = "motiontwin-sweep"
_UNSAFE = re.compile(r"[^A-Za-z0-9._=+-]")


class SweepError(ValueError):
    """The sweep file is malformed (the message names the file and the field)."""


@dataclass
class SweepCase:
    """One run: its name and the keyword arguments of :meth:`harness.master.Master.run`."""

    name: str
    inputs: dict[str, Any] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)

    def run_arguments(self, stop_time: float | None) -> dict[str, Any]:
        return {"inputs": self.inputs, "parameters": self.parameters, "stop_time": stop_time}


@dataclass
class Sweep:
    system: System
    cases: list[SweepCase]
    log: str | None = None
    stop_time: float | None = None
    source: Path | None = None


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SweepError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _table(data: dict, key: str, where: str) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise SweepError(f"{where}: '{key}' must be a table")
    return value


def safe_name(label: str) -> str:
    """``label`` as a file name: characters other than letters, digits and ``._=+-`` become ``_``, and a
    leading dot is dropped, so no name can leave the output folder or hide in it."""
    return _UNSAFE.sub("_", label).lstrip(".") or "_"


MAX_CASE_NAME = 200


def load_sweep(path: str | Path) -> Sweep:
    """Read a sweep file and expand its cases (see the module docstring)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise SweepError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SweepError(f"{path}: {exc}") from None
    unknown = set(data) - {"system", "log", "stop_time", "case", "grid", "seeds"}
    if unknown:
        raise SweepError(f"{path}: unknown field(s) {sorted(unknown)}")
    if not isinstance(data.get("system"), str):
        raise SweepError(f"{path}: missing field 'system' (path of a system file)")
    system = load_system(path.parent / data["system"])
    stop = data.get("stop_time", system.stop_time)
    if stop is None:
        raise SweepError(f"{path}: no stop_time here nor in {data['system']}")
    stop = _number(stop, f"{path}: stop_time")
    if stop <= system.start_time:
        raise SweepError(f"{path}: stop_time {stop!r} s must be after the system's start_time {system.start_time!r} s")
    try:
        n = check_run_length(system.start_time, stop, system.base_step, f"{path}: stop_time")
    except ValueError as exc:
        raise SweepError(str(exc)) from None
    grid_t = system.start_time + np.arange(n + 1) * system.base_step

    grid = _table(data, "grid", f"{path}")
    for name, values in grid.items():
        if not isinstance(values, list) or not values:
            raise SweepError(f"{path}: [grid] '{name}' must be a non-empty list of numbers")
        if name.startswith(INPUT_PREFIX) and name[len(INPUT_PREFIX):] not in system.inputs:
            raise SweepError(f"{path}: [grid] '{name}': no external input '{name[len(INPUT_PREFIX):]}'; "
                             f"inputs: {sorted(system.inputs)}")
    seeds = _table(data, "seeds", f"{path}")
    if set(seeds) - {"count", "first"}:
        raise SweepError(f"{path}: [seeds] takes count and first, got {sorted(seeds)}")
    count = seeds.get("count", 1)
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise SweepError(f"{path}: [seeds] count must be a positive integer, got {count!r}")
    first = seeds.get("first", 0)
    if isinstance(first, bool) or not isinstance(first, int):
        raise SweepError(f"{path}: [seeds] first must be an integer, got {first!r}")

    tables = data.get("case") or [{"name": "run"}]
    if not isinstance(tables, list):
        raise SweepError(f"{path}: 'case' must be an array of tables ([[case]])")
    grid_runs = math.prod(len(values) for values in grid.values())
    total = len(tables) * grid_runs * count
    if total > MAX_RUNS:
        raise SweepError(f"{path}: {len(tables)} case(s) x {grid_runs} grid point(s) x {count} seed(s) "
                         f"([seeds] count) = {total} runs, more than the limit of {MAX_RUNS}; "
                         f"reduce [seeds] count or the [grid] lists, or split the sweep")
    cases: list[SweepCase] = []
    for index, table in enumerate(tables):
        where = f"{path}: [[case]] #{index + 1}"
        if not isinstance(table.get("name"), str):
            raise SweepError(f"{where}: missing field 'name' (string)")
        where = f"{path}: [[case]] '{table['name']}'"
        extra = set(table) - {"name", "inputs", "parameters", "noise"}
        if extra:
            raise SweepError(f"{where}: unknown field(s) {sorted(extra)}; allowed: name, inputs, parameters, noise")
        try:
            inputs = {k: resolve_input(v, path.parent, f"{where}: input '{k}'")
                      for k, v in _table(table, "inputs", where).items()}
        except InputError as exc:
            raise SweepError(str(exc)) from None
        parameters = {k: _number(v, f"{where}: parameter '{k}'")
                      for k, v in _table(table, "parameters", where).items()}
        noise = _table(table, "noise", where)
        for name, spec in noise.items():
            if not isinstance(spec, dict) or set(spec) - {"std", "seed"} or "std" not in spec:
                raise SweepError(f"{where}: noise '{name}' must be {{std = NUMBER, seed = INTEGER}}")
            if name not in system.inputs:
                raise SweepError(f"{where}: noise on '{name}', which is no external input of the system; "
                                 f"inputs: {sorted(system.inputs)}")
        for combo in itertools.product(*grid.values()):
            values = {k: _number(v, f"{path}: [grid] '{k}'") for k, v in zip(grid, combo)}
            suffix = "".join(f"-{k}={v:g}" for k, v in values.items())
            held = {**inputs, **{k[len(INPUT_PREFIX):]: v for k, v in values.items() if k.startswith(INPUT_PREFIX)}}
            overrides = {**parameters, **{k: v for k, v in values.items() if not k.startswith(INPUT_PREFIX)}}
            for s in range(count):
                seed = first + s
                runs = dict(held)
                for name, spec in noise.items():
                    std = _number(spec["std"], f"{where}: noise '{name}' std")
                    offset = spec.get("seed", 0)
                    runs[name] = add_input_noise(held.get(name, system.inputs[name].default), grid_t,
                                                 system.base_step, std, int(offset) + seed)
                label = safe_name(table["name"] + suffix + (f"-s{seed}" if count > 1 else ""))
                cases.append(SweepCase(label, runs, overrides))
    seen: set[str] = set()
    for case in cases:
        if case.name in seen:
            raise SweepError(f"{path}: case name {case.name!r} occurs twice; case names must be unique (after "
                             f"replacing characters other than letters, digits and ._=+- by _)")
        if len(case.name) > MAX_CASE_NAME:   # NAME.csv and NAME.json must be valid file names (255 bytes)
            raise SweepError(f"{path}: case name {case.name[:40]!r}... has {len(case.name)} characters, more than "
                             f"{MAX_CASE_NAME}; shorten the case's name or its grid")
        seen.add(case.name)
    log = data.get("log")
    if log is not None and not isinstance(log, str):
        raise SweepError(f"{path}: log must be the name of a log group")
    return Sweep(system, cases, log, stop, path)


def run(sweep: Sweep, executor: Any = None) -> list[dict[str, np.ndarray]]:
    """Every case of ``sweep`` through ``executor`` (default in-process); logs in case order."""
    from .executor import run_sweep

    return run_sweep(sweep.system, [c.run_arguments(sweep.stop_time) for c in sweep.cases], executor)


def _inside(folder: Path, name: str) -> Path:
    """``folder / name``, refused unless it resolves to a file directly inside ``folder``."""
    path = folder / name
    if path.resolve().parent != folder.resolve():
        raise SweepError(f"{path}: resolves outside the output folder {folder}; rename the case")
    return path


def _fingerprint(sweep: Sweep) -> str:
    """Identifies a sweep: its file's text, its system file's text, the case names, stop time and log group."""
    digest = hashlib.sha256()
    for source in (sweep.source, sweep.system.source):
        if source is not None:
            digest.update(Path(source).read_bytes())
    digest.update(json.dumps([[c.name for c in sweep.cases], sweep.stop_time, sweep.log]).encode())
    return digest.hexdigest()


def _folder(out: Path) -> RunFolder:
    return RunFolder(out, MANIFEST, "sweep", "case", SweepError)


def _remove_case(out: Path, name: str) -> None:
    """Delete a run's recording and sidecar from ``out``."""
    path = _inside(out, f"{name}.csv")
    path.unlink(missing_ok=True)
    sidecar_path(path).unlink(missing_ok=True)


def _prepare_folder(sweep: Sweep, out: Path, fingerprint: str, resume: bool, overwrite: bool,
                    log: Callable[[str], None]) -> dict[str, dict[str, Any]]:
    """Check ``out`` against resume/overwrite; remove stale runs if overwriting; return the rows kept, each
    verified against the size and checksum the manifest holds for its files (a run that fails is run again)."""
    return _folder(out).prepare(fingerprint, {c.name for c in sweep.cases}, resume, overwrite, log,
                                functools.partial(_remove_case, out),
                                lambda row: damage(row.get("files"), functools.partial(_inside, out)))


def run_to_folder(sweep: Sweep, out: str | Path, executor: Any = None, *, executor_name: str = "inprocess",
                  resume: bool = False, overwrite: bool = False, retries: int = 2,
                  log: Callable[[str], None] = print) -> Outcome:
    """Run every case of ``sweep`` and commit each run's recording to ``out`` as soon as it finishes.

    Parameters
    ----------
    sweep:
        From :func:`load_sweep`.
    out:
        Output folder (see the module docstring for its layout and the manifest).
    executor:
        A :mod:`harness.executor` executor (default in-process); ``executor_name`` is recorded in the manifest.
    resume:
        Continue the same sweep in ``out``: runs the manifest lists as finished are kept if their files still
        have the size and checksum committed, the others run (and ``log`` says which and why).
    overwrite:
        Replace the sweep in ``out``: the runs its manifest lists are removed first.
    retries:
        How often a run whose worker process died is tried again before it is reported as failed.
    log:
        Receives the run count before anything runs, one line per failed run, and what resume or overwrite
        cleaned (stale temporary files, runs whose files are missing or changed).

    Returns
    -------
    Outcome
        Runs finished now, runs kept from before, failed runs (name -> error), seconds.
    """
    from .executor import InProcessExecutor, run_case
    from .master import master_for

    out = Path(out)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise SweepError(f"retries: expected a non-negative integer, got {retries!r}")
    targets = {case.name: _inside(out, f"{case.name}.csv") for case in sweep.cases}
    fingerprint = _fingerprint(sweep)
    rows = _prepare_folder(sweep, out, fingerprint, resume, overwrite, log)
    todo = [case for case in sweep.cases if case.name not in rows]
    log(f"{len(sweep.cases)} runs (limit {MAX_RUNS}): {len(rows)} finished earlier, {len(todo)} to run")
    meta = master_for(sweep.system).metadata()   # opens the FMUs: a bad one fails before out is created
    out.mkdir(parents=True, exist_ok=True)
    resumed = list(rows)
    completed: list[str] = []
    failed: dict[str, str] = {}
    t0 = time.perf_counter()
    order = {case.name: k for k, case in enumerate(sweep.cases)}

    def write_manifest(status: str) -> None:
        doc = {"format": MANIFEST_FORMAT, "version": 1, "sweep": str(sweep.source), "fingerprint": fingerprint,
               "executor": executor_name, "status": status, "planned": len(sweep.cases), "runs": len(rows),
               "seconds": time.perf_counter() - t0,
               "cases": [rows[name] for name in sorted(rows, key=order.__getitem__)],
               "failed": [{"case": name, "error": error} for name, error in failed.items()]}
        atomic_write_texts({out / MANIFEST: json.dumps(doc, indent=2) + "\n"})

    write_manifest("running")
    if not todo:
        write_manifest("complete")
        return Outcome(completed, resumed, failed, 0.0)
    executor = executor or InProcessExecutor()
    arguments = [case.run_arguments(sweep.stop_time) for case in todo]

    def commit(index: int, result: dict[str, np.ndarray]) -> None:
        case = todo[index]
        rec = recording_from_log(result, sweep.log, meta, excited={"sweep": str(sweep.source), "case": case.name},
                                 metadata={"system": str(sweep.system.source), "parameters": case.parameters})
        texts = recording_texts(targets[case.name], rec)
        atomic_write_texts(texts)
        rows[case.name] = {"case": case.name, "parameters": case.parameters,
                           "final": {k: float(rec[k][-1]) for k in rec.columns}, "files": file_records(texts)}
        completed.append(case.name)

    def fail(index: int, error: str) -> None:
        failed[todo[index].name] = error
        log(f"run {todo[index].name} failed: {error}")

    commit_each(executor, functools.partial(run_case, sweep.system), arguments, retries, commit, fail,
                write_manifest)
    return Outcome(completed, resumed, failed, time.perf_counter() - t0)
