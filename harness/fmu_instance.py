"""One Co-Simulation FMU (FMI 2.0 or 3.0) extracted once per process and instantiated through fmpy,
with a logger that keeps each instance's messages, so errors can say what the FMU reported.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import tempfile
import weakref
from collections import deque
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from fmpy import extract

from motiontwin.fmus.archive import read_description
from motiontwin.harness.scratch import process_folder
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.fmi3 import FMU3Slave

REAL_TYPES = ("Real", "Float64")
STATUS = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]


class PortError(ValueError):
    """A port name does not exist or cannot be used where it appears."""


class FMUCallError(RuntimeError):
    """An FMU returned an error: says which FMU, which call, at which time, and what it logged."""

    def __init__(self, instance: str, function: str, status: int, time: float, messages: list[str]):
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        logged = "\n  ".join(messages) if messages else "(the FMU logged no message)"
        super().__init__(f"FMU '{instance}': {function} returned {label} at t = {time:.9g} s. "
                         f"Logged messages:\n  {logged}")
        self.instance = instance
        self.function = function
        self.status = status
        self.time = time
        self.messages = messages

    def __reduce__(self) -> tuple[type, tuple[str, str, int, float, list[str]]]:
        """Rebuilt from its fields, so it crosses process boundaries (a Dask or process-pool worker)."""
        return FMUCallError, (self.instance, self.function, self.status, self.time, self.messages)


# ---------------------------------------------------------------------------------------------
# extraction cache (once per process)

_EXTRACTED: dict[tuple[int, str, int, int], str] = {}   # (pid, FMU file version) -> folder


def extracted_fmu(path: str | Path) -> str:
    """Folder holding the unzipped FMU; unzipped at most once per process and FMU file version, into this
    process's :func:`harness.scratch.process_folder` (removed when the process ends)."""
    path = Path(path).resolve()
    stat = path.stat()
    key = (os.getpid(), str(path), stat.st_mtime_ns, stat.st_size)
    if key not in _EXTRACTED:
        _EXTRACTED[key] = str(extract(str(path), unzipdir=tempfile.mkdtemp(dir=process_folder())))
    return _EXTRACTED[key]


# ---------------------------------------------------------------------------------------------
# one FMU instance


class FMUInstance:
    """An extracted, instantiated Co-Simulation FMU with a logger that keeps its messages."""

    def __init__(self, name: str, path: str | Path, debug_logging: bool = False):
        self.name = name
        self.path = Path(path)
        if not self.path.is_file():
            what = "a folder, not an FMU file" if self.path.is_dir() else "file not found"
            raise FileNotFoundError(f"FMU '{name}': {what}: {self.path}")
        self.model_description = md = read_description(self.path)
        if md.coSimulation is None:
            raise ValueError(f"FMU '{name}' ({self.path}) does not support Co-Simulation")
        self.fmi3 = md.fmiVersion.startswith("3")
        self.variables = {v.name: v for v in md.modelVariables}
        self.messages: deque[str] = deque(maxlen=50)
        self.can_reset_state = bool(md.coSimulation.canGetAndSetFMUstate)
        unzipdir = extracted_fmu(self.path)
        kwargs = dict(guid=md.guid, unzipDirectory=unzipdir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        # loggingOn = False still passes warnings and errors to the logger (FMI 2.0/3.0), without
        # the per-call debug messages some exporters emit when it is on.
        try:
            if self.fmi3:
                self.slave = FMU3Slave(**kwargs)
                self.slave.instantiate(loggingOn=debug_logging, logMessage=self._log3)
            else:
                self.slave = FMU2Slave(**kwargs)
                self._callbacks = _fmi2_callbacks(self)
                self.slave.instantiate(callbacks=self._callbacks, loggingOn=debug_logging)
        except Exception as exc:   # fmpy raises a bare Exception when the FMU's instantiate returns NULL
            logged = "; ".join(self.messages) or "nothing"
            raise ValueError(f"FMU '{name}' ({self.path}): {exc}; it logged: {logged}") from None
        self.initialized = False
        self.initial_state: tuple[Any, Any] | None = None

    def _record(self, status: int, category: bytes | None, message: bytes | None) -> None:
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        text = message.decode("utf-8", "replace") if message else ""
        cat = category.decode("utf-8", "replace") if category else ""
        self.messages.append(f"[{label}] {cat}: {text}" if cat else f"[{label}] {text}")

    def _log3(self, env, status, category, message) -> None:
        self._record(status, category, message)

    def variable(self, name: str) -> Any:
        return self.variables[name]

    def size(self, name: str) -> int:
        shape = self.variables[name].shape
        return int(np.prod(shape)) if shape else 1

    def ports(self, causality: str) -> list[str]:
        return [v.name for v in self.variables.values() if v.causality == causality]

    def set_start_values(self, values: Mapping[str, Any]) -> None:
        """Set parameters/start values by name (before initialization), converting by type."""
        for name, value in values.items():
            if name not in self.variables:
                raise PortError(f"FMU '{self.name}' has no variable '{name}' (parameter override). "
                                f"Parameters: {', '.join(self.ports('parameter')) or '-'}; "
                                f"inputs: {', '.join(self.ports('input')) or '-'}")
            v = self.variables[name]
            vr = [v.valueReference]
            s = self.slave
            if v.type in REAL_TYPES:
                (s.setFloat64 if self.fmi3 else s.setReal)(vr, [float(value)])
            elif v.type in ("Integer", "Enumeration") and not self.fmi3:
                s.setInteger(vr, [int(value)])
            elif v.type in ("Int32", "Int16", "Int8", "UInt8", "UInt16", "UInt32", "Int64", "UInt64",
                            "Enumeration"):
                setter = "setInt64" if v.type == "Enumeration" else f"set{v.type}"
                getattr(s, setter)(vr, [int(value)])
            elif v.type == "Boolean":
                s.setBoolean(vr, [bool(value)])
            elif v.type == "String":
                s.setString(vr, [str(value)])
            else:
                raise PortError(f"FMU '{self.name}': cannot set variable '{name}' of type {v.type}")

    def start_value(self, name: str) -> float | None:
        """The start value of a variable from the model description as a float (None if absent)."""
        start = self.variables[name].start
        try:
            return float(start) if start is not None else None
        except (TypeError, ValueError):
            return None

    def save_initial_state(self, key: Any) -> None:
        """Keep the state right after initialization, to start later runs from it."""
        self.free_initial_state()
        self.initial_state = (key, self.slave.getFMUState() if self.fmi3 else self.slave.getFMUstate())

    def restore_initial_state(self) -> None:
        state = self.initial_state[1]
        (self.slave.setFMUState if self.fmi3 else self.slave.setFMUstate)(state)

    def free_initial_state(self) -> None:
        if self.initial_state is not None:
            (self.slave.freeFMUState if self.fmi3 else self.slave.freeFMUstate)(self.initial_state[1])
            self.initial_state = None

    def reset(self) -> None:
        self.free_initial_state()
        self.slave.reset()
        self.initialized = False

    def free(self, terminate: bool = True) -> None:
        """Terminate (unless it failed fatally) and free the instance. The shared library stays
        loaded and the logger callbacks stay alive (fmpy's freeInstance would unload the library):
        FMUs that embed a runtime, e.g. PythonFMU3's Python objects, can leave objects behind whose
        code or logger is called at a later garbage collection."""
        _RETIRED.append((self.slave, getattr(self, "_callbacks", None), getattr(self.slave, "logMessage", None)))
        try:
            self.free_initial_state()
            if self.initialized and terminate:
                self.slave.terminate()
        except FMICallException:
            pass
        self.initialized = False
        if self.slave.component:
            free = self.slave.fmi3FreeInstance if self.fmi3 else self.slave.fmi2FreeInstance
            free(self.slave.component)
            self.slave.component = None
        _FMI2_INSTANCES.pop(getattr(self, "environment", 0), None)


# FMI 2.0 messages are printf-style with variadic arguments, which ctypes cannot receive; fmpy's
# addLoggerProxy formats them in C and forwards them to ONE process-wide Python callback (the last
# one registered). So every FMI 2.0 instance of the harness uses the same, never-freed dispatcher,
# and the instance is identified by the componentEnvironment pointer of its callbacks struct.
# Messages of FMUs that are not ours (e.g. fmpy.simulate_fmu's default callbacks) are printed as
# fmpy's default logger does.
_FMI2_INSTANCES: dict[int, "weakref.ref[FMUInstance]"] = {}
_RETIRED: list[tuple[Any, ...]] = []  # ctypes callbacks of freed instances, never released
_NEXT_ENVIRONMENT = itertools.count(1)


def _dispatch_fmi2(env, instance_name, status, category, message) -> None:
    ref = _FMI2_INSTANCES.get(env or 0)
    fmu = ref() if ref is not None else None
    if fmu is not None:
        fmu._record(status, category, message)
    else:
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        print(f"[{label}] {message.decode('utf-8', 'replace') if message else ''}")


_DISPATCH_FMI2 = fmi2CallbackLoggerTYPE(_dispatch_fmi2)


def _fmi2_callbacks(fmu: "FMUInstance") -> fmi2CallbackFunctions:
    from fmpy import calloc, free
    from fmpy.logging import addLoggerProxy

    environment = next(_NEXT_ENVIRONMENT)
    _FMI2_INSTANCES[environment] = weakref.ref(fmu)
    fmu.environment = environment
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _DISPATCH_FMI2
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    callbacks.componentEnvironment = environment
    addLoggerProxy(ctypes.byref(callbacks))
    return callbacks
