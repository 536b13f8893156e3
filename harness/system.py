"""System description files: which FMUs, how they are connected, at which steps, what is logged.

A system file is TOML (read with :mod:`tomllib`). Times are in seconds. Example::

    base_step = 1e-4            # s, every communication step and log step is an integer multiple of it
    start_time = 0.0            # s, optional (default 0)
    stop_time = 0.5             # s, default run length (a run may override it)
    order = ["ctrl", "plant"]   # optional: explicit stepping order (default: derived, see harness.master)

    [fmus.ctrl]
    path = "fmus/Controller.fmu"   # relative to this file's folder
    step = 5e-4                    # s, communication step (default: the FMU's Ts parameter, else base_step)
    sampled = true                 # optional; default: true when the FMU has its sampling-period parameter
    ts_parameter = "Ts"            # optional: name of that parameter (default "Ts"); step must be a multiple of it
    [fmus.ctrl.parameters]
    Kp = 2.0e3                     # start value / parameter overrides by variable name

    [fmus.plant]
    path = "fmus/Joint.fmu"
    step = 1e-4

    [inputs.r]                     # external signals supplied per run as arrays over time
    unit = "m"                     # optional, checked against the ports it feeds
    [inputs.u_ext]
    unit = "N"
    default = 0.0                  # optional: used when a run supplies no array for it

    [[connections]]
    from = "input.r"               # "input.NAME" is an external signal, "inst.port" an FMU output
    to = "ctrl.r"
    [[connections]]
    from = "plant.x"
    to = "ctrl.y"
    [[connections]]                # sum junction: plant.F = ctrl.u + u_ext
    from = ["ctrl.u", "input.u_ext"]
    gains = [1.0, 1.0]             # optional, default all 1 (use -1 for a difference)
    to = "plant.F"

    [[log]]
    name = "fast"                  # optional (default "log", "log1", ...)
    signals = ["plant.x", "plant.F", "ctrl.u", "input.r"]
    step = 1e-4                    # s, multiple of base_step (default base_step)

Errors name the file, the TOML table/field and, when it can be found, the line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from motiontwin.fmus.limits import LIMITS, limit, load_toml
from motiontwin.harness.numbers import is_finite_number

INPUT_NAMESPACE = "input"
"""Instance name reserved for external input signals in port names ("input.r")."""


class SystemFileError(ValueError):
    """A system description is malformed; the message names file, field and line when known."""


@dataclass(frozen=True)
class FMUSpec:
    """One FMU instance of a system."""

    name: str
    path: Path
    step: float | None = None
    sampled: bool | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    ts_parameter: str = "Ts"


@dataclass(frozen=True)
class Connection:
    """Input port ``to`` receives the gain-weighted sum of one or more source ports."""

    to: str
    sources: tuple[str, ...]
    gains: tuple[float, ...]


@dataclass(frozen=True)
class InputSpec:
    """An external signal supplied per run (e.g. a reference r(t) or an excitation u_ext(t))."""

    name: str
    unit: str | None = None
    default: float | None = None


@dataclass(frozen=True)
class LogGroup:
    """Signals logged together at one rate."""

    name: str
    signals: tuple[str, ...]
    step: float | None = None


@dataclass(frozen=True)
class System:
    """A parsed system description (see module docstring for the file schema)."""

    base_step: float
    fmus: dict[str, FMUSpec]
    connections: tuple[Connection, ...] = ()
    inputs: dict[str, InputSpec] = field(default_factory=dict)
    logs: tuple[LogGroup, ...] = ()
    start_time: float = 0.0
    stop_time: float | None = None
    order: tuple[str, ...] | None = None
    source: Path | None = None

    def key(self) -> str:
        """A canonical string identifying this system (used to cache masters per process)."""
        return json.dumps(system_to_dict(self), sort_keys=True, default=str)


def split_port(port: str) -> tuple[str, str]:
    """Split "inst.port" at the first dot (variable names may contain dots: "plant.mass.v")."""
    if not isinstance(port, str) or "." not in port:
        raise ValueError(f"port {port!r} is not of the form 'instance.variable'")
    instance, variable = port.split(".", 1)
    return instance, variable


def _line_of(text: str | None, needle: str) -> str:
    if not text:
        return ""
    for number, line in enumerate(text.splitlines(), start=1):
        if needle in line:
            return f", line {number}"
    return ""


class _Context:
    """Builds error messages that name the file, the field and the line."""

    def __init__(self, source: Path | None, text: str | None):
        self.source = source
        self.text = text

    def error(self, where: str, message: str, needle: str | None = None) -> SystemFileError:
        name = str(self.source) if self.source else "<system>"
        line = _line_of(self.text, needle) if needle else ""
        return SystemFileError(f"{name}{line}: {where}: {message}")


def check_run_length(start_time: float, stop_time: float, step: float, where: str) -> int:
    """The number of steps of ``step`` from ``start_time`` to ``stop_time``; ValueError naming ``where``
    when it exceeds the ``steps`` limit of :mod:`fmus.limits` (a typo like 1e300 s would otherwise exhaust
    memory)."""
    steps = (stop_time - start_time) / step
    most = limit("steps")
    if not steps <= most:
        raise ValueError(f"{where} = {stop_time:.9g} s gives {steps:.3g} steps of {step:.9g} s, more than the limit of "
                         f"{most:.0e}; shorten the run or lengthen the step (or raise {LIMITS['steps'].variable})")
    return round(steps)


def _number(ctx: _Context, value: Any, where: str, needle: str | None, positive: bool = False) -> float:
    if not is_finite_number(value):
        raise ctx.error(where, f"expected a finite number, got {value!r}", needle)
    if positive and value <= 0:
        raise ctx.error(where, f"must be > 0, got {value!r}", needle)
    return float(value)


def _check_keys(ctx: _Context, table: dict, allowed: set[str], where: str, needle: str | None) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ctx.error(where, f"unknown field(s) {unknown}; allowed: {sorted(allowed)}", needle or unknown[0])


def system_from_dict(data: dict[str, Any], source: str | Path | None = None, text: str | None = None) -> System:
    """Validate a system description given as a dict (as parsed from TOML); relative FMU paths
    are resolved against the folder of ``source`` (or the working directory)."""
    source = Path(source) if source is not None else None
    ctx = _Context(source, text)
    root = source.parent if source is not None else Path.cwd()
    _check_keys(ctx, data, {"base_step", "start_time", "stop_time", "order", "fmus", "inputs",
                            "connections", "log"}, "top level", None)
    if "base_step" not in data:
        raise ctx.error("top level", "missing required field 'base_step' (s)")
    base_step = _number(ctx, data["base_step"], "base_step", "base_step", positive=True)
    start_time = _number(ctx, data.get("start_time", 0.0), "start_time", "start_time")
    stop_time = data.get("stop_time")
    if stop_time is not None:
        stop_time = _number(ctx, stop_time, "stop_time", "stop_time")
        if stop_time <= start_time:
            raise ctx.error("stop_time", f"must be > start_time ({start_time})", "stop_time")
        try:
            check_run_length(start_time, stop_time, base_step, "stop_time")
        except ValueError as exc:
            raise ctx.error("stop_time", str(exc).removeprefix("stop_time = "), "stop_time") from None

    fmus_table = data.get("fmus")
    if not isinstance(fmus_table, dict) or not fmus_table:
        raise ctx.error("[fmus]", "at least one FMU table [fmus.NAME] with a 'path' is required", "fmus")
    fmus: dict[str, FMUSpec] = {}
    for name, table in fmus_table.items():
        where = f"[fmus.{name}]"
        needle = f"fmus.{name}"
        if name == INPUT_NAMESPACE or "." in name:
            raise ctx.error(where, f"instance name {name!r} is reserved or contains a dot", needle)
        if not isinstance(table, dict):
            raise ctx.error(where, "must be a table", needle)
        _check_keys(ctx, table, {"path", "step", "sampled", "parameters", "ts_parameter"}, where, needle)
        if not isinstance(table.get("path"), str):
            raise ctx.error(where, "missing field 'path' (string, the .fmu file)", needle)
        path = Path(table["path"])
        path = path if path.is_absolute() else (root / path)
        step = table.get("step")
        if step is not None:
            step = _number(ctx, step, f"{where} step", needle, positive=True)
        sampled = table.get("sampled")
        if sampled is not None and not isinstance(sampled, bool):
            raise ctx.error(f"{where} sampled", f"expected true/false, got {sampled!r}", needle)
        parameters = table.get("parameters", {})
        if not isinstance(parameters, dict):
            raise ctx.error(f"{where} parameters", "must be a table of name = value", needle)
        for pname, value in parameters.items():
            if not isinstance(value, (bool, int, float, str)):
                raise ctx.error(f"[fmus.{name}.parameters] {pname}", f"unsupported value {value!r}", pname)
            if isinstance(value, float) and not is_finite_number(value):
                raise ctx.error(f"[fmus.{name}.parameters] {pname}", f"must be a finite number, got {value!r}", pname)
        ts_parameter = table.get("ts_parameter", "Ts")
        if not isinstance(ts_parameter, str):
            raise ctx.error(f"{where} ts_parameter", f"expected a variable name, got {ts_parameter!r}", needle)
        fmus[name] = FMUSpec(name, path, step, sampled, dict(parameters), ts_parameter)

    for key, kind, wanted in (("inputs", dict, "a table [inputs.NAME]"), ("connections", list, "an array of tables "
                              "[[connections]]"), ("log", list, "an array of tables [[log]]")):
        if data.get(key) is not None and not isinstance(data[key], kind):
            raise ctx.error(key, f"must be {wanted}, got {data[key]!r}", key)
    inputs: dict[str, InputSpec] = {}
    for name, table in (data.get("inputs") or {}).items():
        where = f"[inputs.{name}]"
        table = table or {}
        if not isinstance(table, dict):
            raise ctx.error(where, "must be a table", f"inputs.{name}")
        _check_keys(ctx, table, {"unit", "default"}, where, f"inputs.{name}")
        default = table.get("default")
        if default is not None:
            default = _number(ctx, default, f"{where} default", f"inputs.{name}")
        unit = table.get("unit")
        if unit is not None and not isinstance(unit, str):
            raise ctx.error(f"{where} unit", f"expected a string, got {unit!r}", f"inputs.{name}")
        inputs[name] = InputSpec(name, unit, default)

    connections: list[Connection] = []
    for index, table in enumerate(data.get("connections") or []):
        where = f"[[connections]] #{index + 1}"
        if not isinstance(table, dict):
            raise ctx.error(where, "must be a table with 'from' and 'to'")
        _check_keys(ctx, table, {"from", "to", "gains"}, where, None)
        to = table.get("to")
        sources = table.get("from")
        if not isinstance(to, str):
            raise ctx.error(f"{where} to", f"expected a port name 'inst.port', got {to!r}")
        needle = f'"{to}"'
        if isinstance(sources, str):
            sources = [sources]
        if not isinstance(sources, list) or not sources or not all(isinstance(s, str) for s in sources):
            raise ctx.error(f"{where} from", "expected a port name or a list of port names", needle)
        gains = table.get("gains", [1.0] * len(sources))
        if not isinstance(gains, list) or len(gains) != len(sources):
            raise ctx.error(f"{where} gains", f"expected a list of {len(sources)} numbers", needle)
        gains = [_number(ctx, g, f"{where} gains", needle) for g in gains]
        for port in [to, *sources]:
            try:
                split_port(port)
            except ValueError as exc:
                raise ctx.error(where, str(exc), needle) from None
        connections.append(Connection(to, tuple(sources), tuple(gains)))

    logs: list[LogGroup] = []
    for index, table in enumerate(data.get("log") or []):
        where = f"[[log]] #{index + 1}"
        if not isinstance(table, dict):
            raise ctx.error(where, "must be a table with 'signals'")
        _check_keys(ctx, table, {"name", "signals", "step"}, where, None)
        name = table.get("name", "log" if index == 0 else f"log{index}")
        signals = table.get("signals")
        if not isinstance(signals, list) or not signals or not all(isinstance(s, str) for s in signals):
            raise ctx.error(f"{where} signals", "expected a non-empty list of port names")
        step = table.get("step")
        if step is not None:
            step = _number(ctx, step, f"{where} step", None, positive=True)
        logs.append(LogGroup(str(name), tuple(signals), step))
    if len({g.name for g in logs}) != len(logs):
        raise ctx.error("[[log]]", "log group names must be unique")

    order = data.get("order")
    if order is not None:
        if not isinstance(order, list) or not all(isinstance(n, str) for n in order) or sorted(order) != sorted(fmus):
            raise ctx.error("order", f"must list every FMU instance exactly once: {sorted(fmus)}", "order")
        order = tuple(order)

    return System(base_step, fmus, tuple(connections), inputs, tuple(logs), start_time, stop_time, order, source)


def load_system(path: str | Path) -> System:
    """Read and validate a TOML system description file."""
    path = Path(path)
    data, text = load_toml(path, SystemFileError)
    return system_from_dict(data, source=path, text=text)


def system_to_dict(system: System) -> dict[str, Any]:
    """The inverse of :func:`system_from_dict` (FMU paths made absolute)."""
    data: dict[str, Any] = {"base_step": system.base_step, "start_time": system.start_time}
    if system.stop_time is not None:
        data["stop_time"] = system.stop_time
    if system.order is not None:
        data["order"] = list(system.order)
    data["fmus"] = {}
    for spec in system.fmus.values():
        table: dict[str, Any] = {"path": str(Path(spec.path).resolve())}
        if spec.step is not None:
            table["step"] = spec.step
        if spec.sampled is not None:
            table["sampled"] = spec.sampled
        if spec.parameters:
            table["parameters"] = dict(spec.parameters)
        if spec.ts_parameter != "Ts":
            table["ts_parameter"] = spec.ts_parameter
        data["fmus"][spec.name] = table
    if system.inputs:
        data["inputs"] = {
            i.name: {k: v for k, v in (("unit", i.unit), ("default", i.default)) if v is not None}
            for i in system.inputs.values()
        }
    data["connections"] = [{"from": list(c.sources), "to": c.to, "gains": list(c.gains)}
                           for c in system.connections]
    data["log"] = [{"name": g.name, "signals": list(g.signals), **({"step": g.step} if g.step else {})}
                   for g in system.logs]
    return data
