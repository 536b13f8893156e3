"""The wiring of a co-simulation: which FMU port feeds which, in which stepping order, and where every value
lives in the one flat float64 buffer that the FMUs read into and write from (see :mod:`harness.master` for how
a run uses it). Everything here is checked before anything runs: unknown ports (with the available ones),
unit mismatches, steps that are not integer multiples of the base step or of an FMU's Ts.

Buffer layout: ``[read slots per FMU][input slots per FMU][external inputs]``.
"""
from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .fmu_instance import REAL_TYPES, FMUInstance, PortError
from .system import INPUT_NAMESPACE, System, split_port
from .units import units_compatible, variable_unit


class UnitMismatchError(ValueError):
    """Two connected ports declare different units."""


class StepError(ValueError):
    """A communication or log step is not an integer multiple of the base step or of an FMU's Ts."""


# ---------------------------------------------------------------------------------------------
# planning helpers


def integer_ratio(value: float, unit: float) -> int | None:
    ratio = value / unit
    n = round(ratio)
    return n if n >= 1 and abs(ratio - n) <= 1e-9 * max(1.0, abs(ratio)) else None


def stepping_order(names: list[str], edges: list[tuple[str, str]], sampled: Mapping[str, bool]) -> list[str]:
    """Gauss-Seidel order from data-flow edges (producer, consumer); see the module docstring."""
    before: dict[str, set[str]] = {n: set() for n in names}  # before[b] = FMUs that must precede b
    for a, b in edges:
        if a == b:
            continue
        if sampled[b] and not sampled[a]:
            before[a].add(b)
        else:
            before[b].add(a)
    order: list[str] = []
    remaining = list(names)
    while remaining:
        ready = [n for n in remaining if not (before[n] & set(remaining))]
        chosen = ready[0] if ready else remaining[0]
        order.append(chosen)
        remaining.remove(chosen)
    return order


@dataclass
class _Slot:
    """Where a logged signal lives in the flat value buffer and when it is snapshot."""

    index: int
    after_step: bool


class _Gather:
    """How an FMU's inputs are formed from the flat value buffer: input ``i`` is the sum over its
    sources ``j`` (``port_start[i] <= j < port_start[i + 1]``) of ``gains[j] * values[slots[j]]``,
    added in source order. The compiled loop does the same operations in the same order, so both
    give bit-identical results."""

    def __init__(self, port_start: np.ndarray, slots: np.ndarray, gains: np.ndarray):
        self.port_start, self.slots, self.gains = port_start, slots, gains
        counts = np.diff(port_start)
        self.plain = bool(np.all(counts == 1) and np.all(gains == 1.0))  # every input a copy of one source
        # pass p adds the p-th source of every input having more than p sources
        self.passes = []
        for p in range(int(counts.max()) if counts.size else 0):
            rows = np.flatnonzero(counts > p)
            j = port_start[rows] + p
            self.passes.append((rows, slots[j], gains[j]))

    def into(self, values: np.ndarray, lo: int, hi: int) -> None:
        """Write the FMU's inputs into ``values[lo:hi]``."""
        if hi == lo:
            return
        if self.plain:
            values[lo:hi] = values[self.slots]
            return
        rows, slots, gains = self.passes[0]
        values[lo:hi] = gains * values[slots]
        for rows, slots, gains in self.passes[1:]:
            values[lo + rows] = values[lo + rows] + gains * values[slots]


def _where(system: System) -> str:
    return f"{system.source}: " if system.source else ""


def check_parameter_types(system: System, instances: Mapping[str, FMUInstance], name: str) -> None:
    """A text or true/false in the system file for a numeric FMU parameter is named by file and field."""
    variables = instances[name].variables
    for pname, value in system.fmus[name].parameters.items():
        v = variables.get(pname)
        if v is not None and v.type not in ("String", "Boolean") and isinstance(value, (str, bool)):
            raise PortError(f"{_where(system)}[fmus.{name}.parameters] {pname} = {value!r}: expected a number "
                            f"(the FMU's variable has type {v.type})")


def resolve_port(system: System, instances: Mapping[str, FMUInstance], port: str, role: str) -> tuple[str, str]:
    """Check a port name; role is 'source', 'input' (a connection target) or 'log'."""
    instance, variable = split_port(port)
    if instance == INPUT_NAMESPACE:
        if variable not in system.inputs:
            raise PortError(f"{_where(system)}unknown external input '{port}'. Declared inputs: "
                            f"{', '.join('input.' + n for n in system.inputs) or '(none: add [inputs.NAME])'}")
        if role == "input":
            raise PortError(f"{_where(system)}'{port}' is an external signal and cannot be a connection target")
        return instance, variable
    if instance not in instances:
        raise PortError(f"{_where(system)}unknown FMU instance '{instance}' in port '{port}'. "
                        f"Instances: {', '.join(instances)}")
    fmu = instances[instance]
    wanted = {"source": ("output",), "input": ("input",)}.get(role)
    v = fmu.variables.get(variable)
    if v is None or (wanted and v.causality not in wanted):
        kind = {"source": "outputs", "input": "inputs"}.get(role)
        if kind:
            available = fmu.ports(kind[:-1])
        else:
            available = fmu.ports("output") + fmu.ports("input")
            kind = "inputs and outputs (any variable can be logged)"
        raise PortError(f"{_where(system)}unknown port '{port}' (used as {role}): FMU '{instance}' "
                        f"has {kind}: {', '.join(available) or '(none)'}")
    if v.type not in REAL_TYPES:
        raise PortError(f"{_where(system)}port '{port}' has type {v.type}; only Real/Float64 "
                        f"variables can be connected or logged")
    if role != "log" and fmu.size(variable) != 1:
        raise PortError(f"{_where(system)}port '{port}' is an array; only scalars can be connected")
    return instance, variable


def port_unit(system: System, instances: Mapping[str, FMUInstance], instance: str, variable: str) -> str | None:
    if instance == INPUT_NAMESPACE:
        return system.inputs[variable].unit
    return variable_unit(instances[instance].variables[variable])


def communication_steps(system: System, instances: Mapping[str, FMUInstance],
                        parameters: Mapping[str, Any]) -> dict[str, int]:
    """Communication step of each FMU in base steps; checks multiples of base_step and Ts."""
    base = system.base_step
    multiples: dict[str, int] = {}
    for name, spec in system.fmus.items():
        fmu = instances[name]
        ts = None
        tsp = spec.ts_parameter
        if tsp in fmu.variables:
            ts = parameters.get(f"{name}.{tsp}", spec.parameters.get(tsp, fmu.start_value(tsp)))
        step = spec.step if spec.step is not None else (float(ts) if ts else base)
        m = integer_ratio(step, base)
        if m is None:
            raise StepError(f"{_where(system)}[fmus.{name}] step = {step:g} s is not an integer multiple "
                            f"of base_step = {base:g} s")
        if ts and integer_ratio(step, float(ts)) is None:
            raise StepError(f"{_where(system)}[fmus.{name}] step = {step:g} s is not an integer multiple "
                            f"of the FMU's sampling period {tsp} = {float(ts):g} s")
        multiples[name] = m
    return multiples


@dataclass
class Wiring:
    """The checked plan of one system: per FMU whether it is sampled and its step in base steps, the
    stepping order, each input's sources with gains, the flat buffer (``values`` is a numpy view of the
    ctypes ``cbuffer``) with each FMU's read and input ranges, the external inputs' range, the gather plan
    per FMU and the log groups (name, step in base steps, columns, slots)."""

    sampled: dict[str, bool]
    multiples: dict[str, int]
    order: list[str]
    targets: dict[str, list[tuple[tuple[str, str], float]]]
    reads: dict[str, list[str]]
    slot: dict[str, int]
    read_ranges: dict[str, tuple[int, int]]
    input_ranges: dict[str, tuple[int, int]]
    input_ports: dict[str, list[str]]
    ext_names: list[str]
    ext_range: tuple[int, int]
    cbuffer: Any
    values: np.ndarray
    gather: dict[str, _Gather]
    logs: list[tuple[str, int, list[str], list[_Slot]]]


def plan_wiring(system: System, instances: Mapping[str, FMUInstance]) -> Wiring:
    """Resolve and check every port, unit and step of ``system`` and lay out the flat value buffer."""
    sys_ = system
    base = sys_.base_step
    names = list(sys_.fmus)
    sampled = {n: (sys_.fmus[n].sampled if sys_.fmus[n].sampled is not None
                   else sys_.fmus[n].ts_parameter in instances[n].variables) for n in names}
    multiples = communication_steps(system, instances, {})

    # connections: resolve ports, check units and duplicate targets
    targets: dict[str, list[tuple[tuple[str, str], float]]] = {}
    edges: list[tuple[str, str]] = []
    for c in sys_.connections:
        dst = resolve_port(system, instances, c.to, "input")
        if c.to in targets:
            raise PortError(f"{_where(system)}input '{c.to}' is the target of two connections; "
                            f"use one connection with from = [a, b] (a sum junction)")
        dst_unit = port_unit(system, instances, *dst)
        sources = []
        for port, gain in zip(c.sources, c.gains):
            src = resolve_port(system, instances, port, "source")
            src_unit = port_unit(system, instances, *src)
            if not units_compatible(src_unit, dst_unit):
                raise UnitMismatchError(f"{_where(system)}connection '{port}' -> '{c.to}': unit '{src_unit}' "
                                        f"does not match '{dst_unit}'")
            sources.append((src, gain))
            if src[0] != INPUT_NAMESPACE:
                edges.append((src[0], dst[0]))
        targets[c.to] = sources

    order = list(sys_.order) if sys_.order else stepping_order(names, edges, sampled)

    # flat value buffer: [read slots per FMU][input slots per FMU][external inputs]
    logged = [(g, s, resolve_port(system, instances, s, "log")) for g in sys_.logs for s in g.signals]
    reads: dict[str, list[str]] = {n: [] for n in names}
    for sources in targets.values():
        for (inst, var), _ in sources:
            if inst != INPUT_NAMESPACE and var not in reads[inst]:
                reads[inst].append(var)
    for _, port, (inst, var) in logged:
        if inst != INPUT_NAMESPACE and port not in targets and var not in reads[inst]:
            reads[inst].append(var)
    slot: dict[str, int] = {}
    size = 0
    read_ranges: dict[str, tuple[int, int]] = {}
    for n in names:
        lo = size
        for var in reads[n]:
            slot[f"{n}.{var}"] = size
            size += instances[n].size(var)
        read_ranges[n] = (lo, size)
    input_ranges: dict[str, tuple[int, int]] = {}
    input_ports: dict[str, list[str]] = {n: [] for n in names}
    for port in targets:
        input_ports[split_port(port)[0]].append(port)
    for n in names:
        lo = size
        for port in input_ports[n]:
            slot[port] = size
            size += 1
        input_ranges[n] = (lo, size)
    ext_names = list(sys_.inputs)
    ext_range = (size, size + len(ext_names))
    for name in ext_names:
        slot[f"{INPUT_NAMESPACE}.{name}"] = size
        size += 1
    cbuffer = (ctypes.c_double * max(size, 1))()
    values = np.ctypeslib.as_array(cbuffer)

    # gather plan per FMU: input i <- sum over its sources j (in order) of gain_j * value[slot_j]
    gather: dict[str, _Gather] = {}
    for n in names:
        port_start, source_slots, source_gains = [0], [], []
        for port in input_ports[n]:
            merged: dict[int, float] = {}
            for (inst, var), gain in targets[port]:
                s = slot[f"{inst}.{var}"]
                merged[s] = merged.get(s, 0.0) + gain
            source_slots += merged
            source_gains += merged.values()
            port_start.append(len(source_slots))
        gather[n] = _Gather(np.array(port_start, dtype=np.intp), np.array(source_slots, dtype=np.intp),
                                  np.array(source_gains, dtype=float))

    # log plan
    logs = []
    for group in sys_.logs:
        step = group.step if group.step is not None else base
        m = integer_ratio(step, base)
        if m is None:
            raise StepError(f"{_where(system)}[[log]] '{group.name}' step = {step:g} s is not an integer "
                            f"multiple of base_step = {base:g} s")
        columns: list[str] = []
        slots: list[_Slot] = []
        for port in group.signals:
            inst, var = split_port(port)
            width = 1 if inst == INPUT_NAMESPACE else instances[inst].size(var)
            after = (inst == INPUT_NAMESPACE or port in targets or sampled[inst])
            for j in range(width):
                columns.append(port if width == 1 else f"{port}[{j + 1}]")
                slots.append(_Slot(slot[port] + j, after))
        logs.append((group.name, m, columns, slots))
    return Wiring(sampled, multiples, order, targets, reads, slot, read_ranges, input_ranges, input_ports,
                  ext_names, ext_range, cbuffer, values, gather, logs)
