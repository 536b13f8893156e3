"""Co-simulation master: steps Co-Simulation FMUs (FMI 2.0 and 3.0) connected by named ports.

Times are in seconds; signal values are in the units the FMUs declare (checked across connections).

How a run works
---------------
* The time grid is ``t_k = start_time + k * base_step``, ``k = 0..N``. Every FMU has a fixed
  communication step ``m * base_step`` (integer ``m``) and starts a step at the ticks ``k`` with
  ``k % m == 0``; its inputs are set just before that step and held over it. When the run
  length is not a multiple of its step, its last step is shortened (refused for FMUs without
  ``canHandleVariableCommunicationStepSize``).
* External signals (``input.NAME``) are arrays over the base grid, held over each base step.
  A connection with several sources is a sum junction: ``to = sum(gain_i * source_i)``,
  e.g. plant force = controller output + u_ext.
* Stepping order inside a tick (Gauss-Seidel): for every connection from FMU A to FMU B,
  A is stepped before B, except when B is *sampled* and A is not: then B goes first.
  A sampled FMU (``sampled = true``, or having the parameter ``Ts``, see ``ts_parameter``) is a
  discrete controller that samples its inputs at the start of ``doStep`` and holds its output
  over the step. Stepping it
  first hands the plant the output held over the same interval (no extra delay), while the
  controller sees the plant output at the start of the interval, as a real sampled loop does.
  Cycles among the remaining constraints are broken in declaration order (that edge then uses
  the value from the previous communication point). ``order = [...]`` in the system file
  overrides all of this.
* Logging at tick ``k`` records the value valid from ``t_k`` on: outputs of continuous FMUs
  before they step at ``t_k``, outputs of sampled FMUs after they step at ``t_k``, inputs as set
  at ``t_k`` and external signals at ``t_k``. Nothing is stepped at the final time ``t_N``, so
  there a sampled FMU's output is the one held from its last sample. Results are numpy
  structured arrays with a ``time`` field and one field per logged signal (the layout
  ``fmpy.simulate_fmu`` returns; array variables give "port[1]", "port[2]", ...), one array per
  log group.
* FMUs are extracted once per process and instantiated once per :class:`Master`. A run starts
  from a common initial state: an FMU with ``canGetAndSetFMUstate`` keeps its state right after
  initialization and later runs restore it (``setFMUstate``) when the start time, its parameter
  overrides and its inputs at the start are unchanged; otherwise (and for FMUs without that
  capability) it is reset (``fmi2Reset``/``fmi3Reset``) and initialized again. Sweeps therefore
  never unzip or load anything twice.
* Errors: unknown ports (with the available ones), unit mismatches, steps that are not integer
  multiples of the base step or of an FMU's Ts raise before anything runs; an FMU call that
  fails raises :class:`FMUCallError` with the FMU, the call, the time and the messages the FMU
  passed to the logger callback (kept per instance).
* Speed: value references are ctypes arrays built once; the FMUs' ``fmi2GetReal`` /
  ``fmi3GetFloat64`` write straight into one preallocated float64 buffer that inputs, outputs,
  external signals and the logs are numpy views of. The ticks run in a compiled loop
  (``native_loop.c``, built with the C compiler ``$CC``/gcc on first use and cached by source hash,
  see :mod:`harness.native`) that calls the FMUs' functions directly and returns to Python between
  chunks of ticks (progress bar) or at the first failing call. Without a C compiler, or with
  ``native=False``, the same plan runs in Python through fmpy's ctypes functions; both give
  bit-identical logs (sums are added in source order, without fused multiply-add).
"""

from __future__ import annotations

import atexit
import ctypes
import math
import threading
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import fmi3Boolean, fmi3Float64
from tqdm import tqdm

from . import native
from .fmu_instance import FMUCallError, FMUInstance, PortError
from .inputs import sample_held
from .system import System, check_run_length, load_system, split_port
from .wiring import StepError, check_parameter_types, communication_steps, integer_ratio, plan_wiring, port_unit


class Master:
    """Runs a :class:`~harness.system.System` repeatedly; FMUs are instantiated once.

    >>> master = Master(load_system("loop.toml"))
    >>> logs = master.run(inputs={"r": r_on_base_grid}, stop_time=0.5)
    >>> logs["log"]["plant.x"]

    ``native=False`` runs the ticks in Python instead of the compiled loop (same results, slower);
    ``profile=True`` makes the compiled loop measure the wall time (s) inside each FMU's doStep,
    available after a run as ``step_seconds[name]``.
    """

    def __init__(self, system: System | str | Path, progress: bool | None = None, reuse_state: bool = True,
                 debug_logging: bool = False, native: bool = True, profile: bool = False):
        self.system = system if isinstance(system, System) else load_system(system)
        self.progress = progress
        self.native = native
        self.profile = profile
        self.step_seconds: dict[str, float] = {}
        self.reuse_state = reuse_state
        self.debug_logging = debug_logging
        sys_ = self.system
        self.instances: dict[str, FMUInstance] = {}
        try:
            for spec in sys_.fmus.values():
                self.instances[spec.name] = FMUInstance(spec.name, spec.path, debug_logging)
                check_parameter_types(self.system, self.instances, spec.name)
            self._plan()
        except BaseException:
            self.close()
            raise

    # -- planning ---------------------------------------------------------------------------

    def _where(self) -> str:
        return f"{self.system.source}: " if self.system.source else ""

    def _plan(self) -> None:
        """Check and lay out the wiring (:mod:`harness.wiring`), then bind the fast paths to its buffer."""
        w = plan_wiring(self.system, self.instances)
        self.sampled, self.multiples, self.order, self.values = w.sampled, w.multiples, w.order, w.values
        self._reads, self._read_ranges, self._input_ranges, self._input_ports = (w.reads, w.read_ranges,
                                                                                 w.input_ranges, w.input_ports)
        self._ext_names, self._ext_range, self._cbuffer = w.ext_names, w.ext_range, w.cbuffer
        self._gather, self._logs = w.gather, w.logs
        self._fast_paths()

    def _fast_paths(self) -> None:
        """Bind the low-level fmpy calls with ctypes pointers into the flat buffer, once."""
        self._bound: dict[str, tuple[Callable, Callable, Callable]] = {}
        self._native_fmus: dict[str, dict[str, Any]] = {}
        double_p = ctypes.POINTER(ctypes.c_double)
        for n, fmu in self.instances.items():
            s = fmu.slave
            comp = s.component

            def pointer(lo: int) -> Any:
                return ctypes.cast(ctypes.byref(self._cbuffer, lo * 8), double_p)

            rlo, rhi = self._read_ranges[n]
            ilo, ihi = self._input_ranges[n]
            read_vrs = [fmu.variables[v].valueReference for v in self._reads[n]]
            in_vrs = [fmu.variables[split_port(p)[1]].valueReference for p in self._input_ports[n]]
            rvr = (ctypes.c_uint * max(len(read_vrs), 1))(*read_vrs)
            ivr = (ctypes.c_uint * max(len(in_vrs), 1))(*in_vrs)
            rptr, iptr = pointer(rlo), pointer(ilo)
            nr, ni, nrv, niv = len(read_vrs), len(in_vrs), rhi - rlo, ihi - ilo
            prefix, names = ("fmi3", ("GetFloat64", "SetFloat64", "DoStep")) if fmu.fmi3 else \
                ("fmi2", ("GetReal", "SetReal", "DoStep"))
            gather = self._gather[n]
            self._native_fmus[n] = {
                "fmi3": fmu.fmi3, "component": comp,
                **{key: native.function_address(s, prefix + f) for key, f in zip(("get", "set", "step"), names)},
                "read_vrs": read_vrs, "read_values": rptr, "n_read_values": nrv,
                "input_vrs": in_vrs, "input_values": iptr, "port_start": gather.port_start,
                "source_slots": gather.slots, "source_gains": None if gather.plain else gather.gains,
            }
            if fmu.fmi3:
                get_f, set_f, step_f = s.fmi3GetFloat64, s.fmi3SetFloat64, s.fmi3DoStep
                flags = [fmi3Boolean() for _ in range(3)]
                last = fmi3Float64()
                refs = [ctypes.byref(f) for f in flags] + [ctypes.byref(last)]
                terminate = flags[1]

                def get(get_f=get_f, comp=comp, rvr=rvr, nr=nr, rptr=rptr, nrv=nrv):
                    get_f(comp, rvr, nr, rptr, nrv)

                def put(set_f=set_f, comp=comp, ivr=ivr, ni=ni, iptr=iptr, niv=niv):
                    set_f(comp, ivr, ni, iptr, niv)

                def step(t, h, step_f=step_f, comp=comp, refs=refs, terminate=terminate, name=n, fmu=fmu):
                    step_f(comp, t, h, False, *refs)
                    if terminate.value:
                        raise FMUCallError(name, "fmi3DoStep (terminateSimulation requested)", 0, t,
                                           list(fmu.messages))
            else:
                get_f, set_f, step_f = s.fmi2GetReal, s.fmi2SetReal, s.fmi2DoStep

                def get(get_f=get_f, comp=comp, rvr=rvr, nr=nr, rptr=rptr):
                    get_f(comp, rvr, nr, rptr)

                def put(set_f=set_f, comp=comp, ivr=ivr, ni=ni, iptr=iptr):
                    set_f(comp, ivr, ni, iptr)

                def step(t, h, step_f=step_f, comp=comp):
                    step_f(comp, t, h, 1)
            noop = _noop
            self._bound[n] = (get if nr else noop, put if ni else noop, step)

    # -- running ----------------------------------------------------------------------------

    def grid_size(self, stop_time: float | None = None) -> int:
        """Number of base steps N of a run to ``stop_time`` (the grid has N + 1 points)."""
        sys_ = self.system
        stop = stop_time if stop_time is not None else sys_.stop_time
        if stop is None:
            raise ValueError(f"{self._where()}no stop_time in the system file and none given to run()")
        if not math.isfinite(stop) or stop <= sys_.start_time:
            raise ValueError(f"{self._where()}stop_time = {stop!r} s must be finite and after start_time = "
                             f"{sys_.start_time!r} s")
        check_run_length(sys_.start_time, stop, sys_.base_step, f"{self._where()}stop_time")
        n = integer_ratio(stop - sys_.start_time, sys_.base_step)
        if n is None:
            raise StepError(f"run length {stop - sys_.start_time:g} s is not an integer multiple of "
                            f"base_step = {sys_.base_step:g} s")
        return n

    def time_grid(self, stop_time: float | None = None) -> np.ndarray:
        """The base time grid t_k = start_time + k * base_step, k = 0..N (s)."""
        n = self.grid_size(stop_time)
        return self.system.start_time + np.arange(n + 1) * self.system.base_step

    def _external(self, inputs: Mapping[str, Any] | None, n: int) -> np.ndarray:
        inputs = dict(inputs or {})
        unknown = sorted(set(inputs) - set(self._ext_names))
        if unknown:
            raise PortError(f"unknown external input(s) {unknown}; declared: {self._ext_names}")
        grid = self.system.start_time + np.arange(n + 1) * self.system.base_step
        table = np.empty((n + 1, len(self._ext_names)))
        for j, name in enumerate(self._ext_names):
            if name not in inputs:
                default = self.system.inputs[name].default
                if default is None:
                    raise ValueError(f"external input '{name}' was not supplied to run() and has no default")
                table[:, j] = default
                continue
            value = inputs[name]
            if isinstance(value, tuple) and len(value) == 2:
                t, v = (np.asarray(value[0], float), np.asarray(value[1], float))
                if t.ndim != 1 or t.shape != v.shape or np.any(np.diff(t) <= 0):
                    raise ValueError(f"external input '{name}': (time, values) must be 1-D, equally long, "
                                     f"with increasing time")
                table[:, j] = sample_held(t, v, grid, self.system.base_step)
            else:
                v = np.asarray(value, float)
                if v.ndim == 0:
                    table[:, j] = v
                elif v.shape != (n + 1,):
                    raise ValueError(f"external input '{name}': expected {n + 1} samples on the base grid "
                                     f"(or a (time, values) pair), got shape {v.shape}")
                else:
                    table[:, j] = v
            if not np.all(np.isfinite(table[:, j])):
                raise ValueError(f"external input '{name}' contains NaN or inf")
        return table

    def _initialize(self, parameters: Mapping[str, Any], ext0: np.ndarray) -> None:
        sys_ = self.system
        per_fmu: dict[str, dict[str, Any]] = {n: dict(spec.parameters) for n, spec in sys_.fmus.items()}
        for key, value in parameters.items():
            inst, var = split_port(key)
            if inst not in per_fmu:
                raise PortError(f"parameter override '{key}': unknown FMU instance '{inst}'. "
                                f"Instances: {', '.join(per_fmu)}")
            per_fmu[inst][var] = value
        values = self.values
        for n in self.order:  # start values of read slots, used by FMUs initialized before them
            fmu = self.instances[n]
            lo, _ = self._read_ranges[n]
            for var in self._reads[n]:
                width = fmu.size(var)
                start = per_fmu[n].get(var, fmu.start_value(var) if width == 1 else None)
                values[lo:lo + width] = float(start) if start is not None else 0.0
                lo += width
        elo, ehi = self._ext_range
        values[elo:ehi] = ext0
        t0 = sys_.start_time
        self._time = t0
        for n in self.order:
            fmu = self.instances[n]
            get, put, _ = self._bound[n]
            self._gather_inputs(n)
            lo, hi = self._input_ranges[n]
            key = (t0, repr(sorted(per_fmu[n].items())), values[lo:hi].tobytes())
            if fmu.initial_state is not None and fmu.initial_state[0] == key:
                self._current = (n, "setFMUstate")
                fmu.restore_initial_state()
            else:
                self._current = (n, "reset")
                if fmu.initialized:
                    fmu.reset()
                fmu.messages.clear()
                self._current = (n, "setupExperiment/set start values")
                if not fmu.fmi3:
                    fmu.slave.setupExperiment(startTime=t0)
                fmu.set_start_values(per_fmu[n])
                self._current = (n, "enterInitializationMode")
                if fmu.fmi3:
                    fmu.slave.enterInitializationMode(startTime=t0)
                else:
                    fmu.slave.enterInitializationMode()
                self._current = (n, "set inputs")
                put()
                self._current = (n, "exitInitializationMode")
                fmu.slave.exitInitializationMode()
                fmu.initialized = True
                if fmu.can_reset_state and self.reuse_state:
                    self._current = (n, "getFMUstate")
                    fmu.save_initial_state(key)
            self._current = (n, "get outputs")
            get()

    def _gather_inputs(self, n: str) -> None:
        self._gather[n].into(self.values, *self._input_ranges[n])

    def run(self, inputs: Mapping[str, Any] | None = None, parameters: Mapping[str, Any] | None = None,
            stop_time: float | None = None, progress: bool | None = None) -> dict[str, np.ndarray]:
        """Reset and initialize all FMUs, then step to ``stop_time``.

        ``inputs`` maps external input names to arrays on the base grid (N + 1 samples), scalars,
        or ``(time, values)`` pairs (held from each sample to the next). ``parameters`` maps
        "inst.variable" to values applied on top of the system file's overrides for this run.
        Returns one structured array (``time`` + logged signals) per log group name.
        """
        parameters = dict(parameters or {})
        multiples = communication_steps(self.system, self.instances, parameters) if parameters else self.multiples
        n_steps = self.grid_size(stop_time)
        for name, m in multiples.items():
            cs = self.instances[name].model_description.coSimulation
            if n_steps % m and not cs.canHandleVariableCommunicationStepSize:
                raise StepError(f"run length {n_steps * self.system.base_step:g} s is not a multiple of FMU "
                                f"'{name}''s step {m * self.system.base_step:g} s, and it cannot shorten its last "
                                f"step (canHandleVariableCommunicationStepSize = false)")
        ext = self._external(inputs, n_steps)
        base, t0 = self.system.base_step, self.system.start_time
        logs = []
        for name, m, columns, slots in self._logs:
            rows = n_steps // m + 1
            pre = np.array([s.index for s in slots if not s.after_step], dtype=np.intp)
            post = np.array([s.index for s in slots if s.after_step], dtype=np.intp)
            pre_cols = np.array([i for i, s in enumerate(slots) if not s.after_step], dtype=np.intp)
            post_cols = np.array([i for i, s in enumerate(slots) if s.after_step], dtype=np.intp)
            logs.append((m, np.empty((rows, len(slots))), pre, post, pre_cols, post_cols))

        try:
            self._initialize(parameters, ext[0])
            self._loop(n_steps, ext, logs, base, t0, multiples, progress)
        except FMICallException as exc:
            name, _ = self._current
            error = FMUCallError(name, exc.function, exc.status, self._time, list(self.instances[name].messages))
            if exc.status >= 3:  # Error or Fatal: the instance takes no further run, make a fresh one
                self._reinstantiate(name)
            raise error from None

        results: dict[str, np.ndarray] = {}
        for (name, m, columns, _), (_, data, *_rest) in zip(self._logs, logs):
            dtype = np.dtype([("time", np.float64)] + [(c, np.float64) for c in columns])
            out = np.empty(data.shape[0], dtype=dtype)
            out["time"] = t0 + np.arange(data.shape[0]) * m * base
            for j, c in enumerate(columns):
                out[c] = data[:, j]
            results[name] = out
        return results

    def _loop(self, n_steps: int, ext: np.ndarray, logs: list, base: float, t0: float,
              multiples: Mapping[str, int], progress: bool | None) -> None:
        show = self.progress if progress is None else progress
        # no bar at all when it is off: a tqdm creates a multiprocessing lock, which a process-pool worker
        # killed mid-run would leave for the resource tracker to report as leaked
        bar = None if show is False else tqdm(total=n_steps, unit="step", delay=3.0, leave=False,
                                              desc="co-simulation")
        chunk = max(1000, n_steps // 100)
        run_ticks = self._native_ticks if self.uses_native else self._python_ticks
        try:
            ticks = run_ticks(n_steps, ext, logs, base, t0, multiples)
            for k_start in range(0, n_steps, chunk):
                k_end = min(k_start + chunk, n_steps)
                ticks(k_start, k_end)
                if bar is not None:
                    bar.update(k_end - k_start)
            # final point: inputs as they would be set at t_N, no step
            elo, ehi = self._ext_range
            self.values[elo:ehi] = ext[n_steps]
            self._time = t0 + n_steps * base
            for n in self.order:
                self._gather_inputs(n)
            for m, data, pre, post, pre_cols, post_cols in logs:
                if n_steps % m == 0:
                    data[n_steps // m, pre_cols] = self.values[pre]
                    data[n_steps // m, post_cols] = self.values[post]
        finally:
            if bar is not None:
                bar.close()

    @property
    def uses_native(self) -> bool:
        """True when runs use the compiled inner loop (``native=True`` and a C compiler is available)."""
        return self.native and native.library() is not None

    def _native_ticks(self, n_steps: int, ext: np.ndarray, logs: list, base: float, t0: float,
                      multiples: Mapping[str, int]) -> Callable[[int, int], None]:
        """Ticks k_start..k_end-1 in C (native_loop.c): the plan of :meth:`_python_ticks`."""
        plan = native.NativePlan([dict(self._native_fmus[n], m=multiples[n]) for n in self.order], logs,
                                 self.profile)
        external = np.ascontiguousarray(ext, dtype=np.float64)
        elo = self._ext_range[0]

        def ticks(k_start: int, k_end: int) -> None:
            failure = plan.run_ticks(self._cbuffer, external, elo, k_start, k_end, n_steps, t0, base)
            if self.profile:
                self.step_seconds = dict(zip(self.order, plan.step_seconds()))
            if failure is None:
                return
            name = self.order[failure.fmu]
            self._current = (name, "")
            self._time = t0 + failure.tick * base
            call = native.CALLS[failure.call]
            if call == "terminate":
                raise FMUCallError(name, "fmi3DoStep (terminateSimulation requested)", 0, self._time,
                                   list(self.instances[name].messages))
            fmi3 = self.instances[name].fmi3
            function = {"get": "GetFloat64" if fmi3 else "GetReal", "set": "SetFloat64" if fmi3 else "SetReal",
                        "step": "DoStep"}[call]
            raise FMICallException(function=("fmi3" if fmi3 else "fmi2") + function, status=failure.status)

        return ticks

    def _python_ticks(self, n_steps: int, ext: np.ndarray, logs: list, base: float, t0: float,
                      multiples: Mapping[str, int]) -> Callable[[int, int], None]:
        """Ticks k_start..k_end-1 through fmpy's ctypes functions (the reference for the C loop)."""
        values = self.values
        elo, ehi = self._ext_range
        has_ext = ehi > elo
        plan = []
        for n in self.order:
            get, put, step = self._bound[n]
            lo, hi = self._input_ranges[n]
            plan.append((n, multiples[n], get, put, step, self._gather[n].into, lo, hi, hi > lo))

        def ticks(k_start: int, k_end: int) -> None:
            for k in range(k_start, k_end):
                if has_ext:
                    values[elo:ehi] = ext[k]
                for m, data, pre, post, pre_cols, post_cols in logs:
                    if k % m == 0 and len(pre):
                        data[k // m, pre_cols] = values[pre]
                t = t0 + k * base
                self._time = t
                for n, m, get, put, step, gather, lo, hi, has_in in plan:
                    if k % m:
                        continue
                    self._current = (n, "")
                    if has_in:
                        gather(values, lo, hi)
                        put()
                    step(t, (m if k + m <= n_steps else n_steps - k) * base)
                    get()
                for m, data, pre, post, pre_cols, post_cols in logs:
                    if k % m == 0 and len(post):
                        data[k // m, post_cols] = values[post]

        return ticks

    def _reinstantiate(self, name: str) -> None:
        """After an Error or Fatal status the FMI state machine allows little more than freeInstance (a
        reused instance would refuse every later run): free it and make a fresh instance."""
        self.instances[name].free(terminate=False)
        self.instances[name] = FMUInstance(name, self.system.fmus[name].path, self.debug_logging)
        self._fast_paths()

    # -- bookkeeping ------------------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """What a recording sidecar needs: FMUs, steps, order, parameter overrides."""
        sys_ = self.system
        return {
            "base_step": sys_.base_step,
            "start_time": sys_.start_time,
            "order": list(self.order),
            "fmus": {
                n: {
                    "path": str(spec.path),
                    "model_name": self.instances[n].model_description.modelName,
                    "fmi_version": self.instances[n].model_description.fmiVersion,
                    "step": self.multiples[n] * sys_.base_step,
                    "sampled": self.sampled[n],
                    "parameters": dict(spec.parameters),
                }
                for n, spec in sys_.fmus.items()
            },
            "units": {
                port: port_unit(self.system, self.instances, *split_port(port))
                for group in sys_.logs for port in group.signals
            },
        }

    def close(self) -> None:
        """Terminate and free every FMU instance."""
        for fmu in getattr(self, "instances", {}).values():
            try:
                fmu.free()
            except FMICallException:
                pass
        self.instances = {}

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _noop() -> None:
    return None


_LOCAL = threading.local()
_ALL_MASTERS: list[Master] = []


def master_for(system: System | str | Path) -> Master:
    """A Master for ``system`` cached per process and thread, so sweeps reuse instantiated FMUs."""
    system = system if isinstance(system, System) else load_system(system)
    cache = getattr(_LOCAL, "masters", None)
    if cache is None:
        cache = _LOCAL.masters = {}
    key = system.key()
    if key not in cache:
        cache[key] = Master(system, progress=False)
        _ALL_MASTERS.append(cache[key])
    return cache[key]


def _close_masters() -> None:
    for master in _ALL_MASTERS:
        master.close()
    _ALL_MASTERS.clear()


atexit.register(_close_masters)
