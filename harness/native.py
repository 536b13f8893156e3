"""The compiled inner loop of the master (``native_loop.c``): built once with the C compiler into a
cache folder keyed by the source hash, loaded with ctypes, and given the master's plan as C structs.

Nothing here knows about models: the plan (value references, slots in the flat value buffer, gains,
log columns) comes from :class:`harness.master.Master`, the FMI functions from the FMUs' shared
libraries as loaded by fmpy. Times in seconds.
"""

from __future__ import annotations

import ctypes
import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np

from motiontwin.fmus import clib

SOURCE = Path(__file__).with_name("native_loop.c")
CALLS = ("get", "set", "step", "terminate")

_LOG = logging.getLogger(__name__)
_LOCK = threading.Lock()
_LIBRARY: list[Any] = []  # [] not tried yet, [None] unavailable, [CDLL] loaded

_int_p = ctypes.POINTER(ctypes.c_int)
_uint_p = ctypes.POINTER(ctypes.c_uint)
_double_p = ctypes.POINTER(ctypes.c_double)


class CFMU(ctypes.Structure):
    """One FMU of the plan (``mt_fmu`` in native_loop.c)."""

    _fields_ = [("fmi3", ctypes.c_int), ("m", ctypes.c_int), ("component", ctypes.c_void_p),
                ("get", ctypes.c_void_p), ("set", ctypes.c_void_p), ("do_step", ctypes.c_void_p),
                ("read_vrs", _uint_p), ("n_read_vrs", ctypes.c_size_t), ("read_values", _double_p),
                ("n_read_values", ctypes.c_size_t),
                ("input_vrs", _uint_p), ("n_inputs", ctypes.c_size_t), ("input_values", _double_p),
                ("port_start", _int_p), ("source_slots", _int_p), ("source_gains", _double_p),
                ("profile", ctypes.c_int), ("step_seconds", ctypes.c_double)]


class CLog(ctypes.Structure):
    """One log group (``mt_log``)."""

    _fields_ = [("m", ctypes.c_int), ("data", _double_p), ("n_columns", ctypes.c_int),
                ("n_pre", ctypes.c_int), ("pre_slots", _int_p), ("pre_columns", _int_p),
                ("n_post", ctypes.c_int), ("post_slots", _int_p), ("post_columns", _int_p)]


class CFailure(ctypes.Structure):
    """Where the loop stopped (``mt_failure``): FMU index, call (see CALLS), tick, FMI status."""

    _fields_ = [("fmu", ctypes.c_int), ("call", ctypes.c_int), ("tick", ctypes.c_long), ("status", ctypes.c_int)]


def _build() -> Path | None:
    """Compile native_loop.c (once per source, compiler and flags); None without a working C compiler."""
    try:
        return clib.cached_library({SOURCE.name: SOURCE.read_text()}, "native", "native_loop")
    except clib.CompileError as exc:
        _LOG.debug("the master uses its Python loop: %s", exc)
        return None


def library() -> Any | None:
    """The loaded compiled loop, or None when it cannot be built here (then logged once at debug)."""
    with _LOCK:
        if not _LIBRARY:
            path = _build()
            lib = None
            if path is not None:
                try:
                    lib = ctypes.CDLL(str(path))
                except OSError as exc:
                    _LOG.debug("loading %s failed, the master uses its Python loop: %s", path, exc)
            if lib is not None:
                lib.mt_run_ticks.restype = ctypes.c_int
                lib.mt_run_ticks.argtypes = [
                    ctypes.POINTER(CFMU), ctypes.c_int, ctypes.POINTER(CLog), ctypes.c_int, _double_p,
                    _double_p, ctypes.c_int, ctypes.c_int, ctypes.c_long, ctypes.c_long, ctypes.c_long,
                    ctypes.c_double, ctypes.c_double, ctypes.POINTER(CFailure)]
            _LIBRARY.append(lib)
        return _LIBRARY[0]


def function_address(slave: Any, name: str) -> int:
    """Address of an FMI function in the FMU's shared library as fmpy loaded it."""
    return ctypes.cast(getattr(slave.dll, name), ctypes.c_void_p).value


def _ptr(array: np.ndarray, kind: Any) -> Any:
    return array.ctypes.data_as(kind) if array.size else None


class NativePlan:
    """The C structs of one run; keeps every array they point to alive."""

    def __init__(self, fmus: list[dict[str, Any]], logs: list[tuple[int, np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray, np.ndarray]], profile: bool = False):
        """``fmus``: per FMU in stepping order a dict with fmi3, m, component, get/set/step addresses,
        read_vrs, read_values (pointer), n_read_values, input_vrs, input_values (pointer), port_start,
        source_slots, source_gains (or None). ``logs``: (m, data, pre, post, pre_cols, post_cols).
        ``profile``: measure the wall time inside each FMU's doStep (see :meth:`step_seconds`)."""
        self._keep: list[Any] = []
        self.fmus = (CFMU * max(len(fmus), 1))()
        for c, f in zip(self.fmus, fmus):
            read_vrs = self._array(f["read_vrs"], np.uintc)
            input_vrs = self._array(f["input_vrs"], np.uintc)
            port_start = self._array(f["port_start"], np.intc)
            slots = self._array(f["source_slots"], np.intc)
            c.fmi3, c.m, c.component, c.profile = int(f["fmi3"]), int(f["m"]), f["component"], int(profile)
            c.get, c.set, c.do_step = f["get"], f["set"], f["step"]
            c.read_vrs, c.n_read_vrs = _ptr(read_vrs, _uint_p), read_vrs.size
            c.read_values, c.n_read_values = f["read_values"], f["n_read_values"]
            c.input_vrs, c.n_inputs = _ptr(input_vrs, _uint_p), input_vrs.size
            c.input_values = f["input_values"]
            c.port_start, c.source_slots = _ptr(port_start, _int_p), _ptr(slots, _int_p)
            if f["source_gains"] is not None:
                c.source_gains = _ptr(self._array(f["source_gains"], np.float64), _double_p)
        self.n_fmus = len(fmus)
        self.logs = (CLog * max(len(logs), 1))()
        for c, (m, data, pre, post, pre_cols, post_cols) in zip(self.logs, logs):
            assert data.flags.c_contiguous and data.dtype == np.float64
            self._keep.append(data)
            c.m, c.data, c.n_columns = m, data.ctypes.data_as(_double_p), data.shape[1]
            c.n_pre, c.pre_slots = len(pre), _ptr(self._array(pre, np.intc), _int_p)
            c.pre_columns = _ptr(self._array(pre_cols, np.intc), _int_p)
            c.n_post, c.post_slots = len(post), _ptr(self._array(post, np.intc), _int_p)
            c.post_columns = _ptr(self._array(post_cols, np.intc), _int_p)
        self.n_logs = len(logs)
        self.failure = CFailure()

    def step_seconds(self) -> list[float]:
        """Wall time (s) spent inside each FMU's doStep so far, in plan order (0 unless profiling)."""
        return [self.fmus[i].step_seconds for i in range(self.n_fmus)]

    def _array(self, values: Any, dtype: Any) -> np.ndarray:
        array = np.ascontiguousarray(values, dtype=dtype)
        self._keep.append(array)
        return array

    def run_ticks(self, values: Any, external: np.ndarray, external_offset: int, k_start: int, k_end: int,
                  n_steps: int, start_time: float, base_step: float) -> CFailure | None:
        """Run ticks k_start..k_end-1; the failure record if an FMU call failed, else None."""
        assert external.flags.c_contiguous and external.dtype == np.float64
        code = library().mt_run_ticks(
            self.fmus, self.n_fmus, self.logs, self.n_logs, ctypes.cast(values, _double_p),
            external.ctypes.data_as(_double_p), external_offset, external.shape[1], k_start, k_end, n_steps,
            start_time, base_step, ctypes.byref(self.failure))
        return self.failure if code else None
