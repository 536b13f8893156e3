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
"""
from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .inputs import InputError, add_input_noise, resolve_input
from .system import System, load_system

__all__ = ["SweepError", "SweepCase", "Sweep", "load_sweep", "run"]

INPUT_PREFIX = "input."   # a [grid] key "input.r" sets the external input r to a constant


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


def load_sweep(path: str | Path) -> Sweep:
    """Read a sweep file and expand its cases (see the module docstring)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
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
    n = round((stop - system.start_time) / system.base_step)
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
                label = table["name"] + suffix + (f"-s{seed}" if count > 1 else "")
                cases.append(SweepCase(label, runs, overrides))
    if len({c.name for c in cases}) != len(cases):
        raise SweepError(f"{path}: case names must be unique")
    log = data.get("log")
    if log is not None and not isinstance(log, str):
        raise SweepError(f"{path}: log must be the name of a log group")
    return Sweep(system, cases, log, stop, path)


def run(sweep: Sweep, executor: Any = None) -> list[dict[str, np.ndarray]]:
    """Every case of ``sweep`` through ``executor`` (default in-process); logs in case order."""
    from .executor import run_sweep

    return run_sweep(sweep.system, [c.run_arguments(sweep.stop_time) for c in sweep.cases], executor)
