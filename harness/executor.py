"""One interface for many independent co-simulation runs: in-process, a local process pool, or Dask.

Monte Carlo trials, tuning populations, workspace sweeps and bootstraps are lists of independent
runs. ``executor.map(fn, items)`` runs ``fn(item)`` for every item and returns the results in the
order of ``items`` whichever executor runs them; with the same items (seeds, inputs, parameters)
the results are identical, because every run starts from the same reset/initial state and FMUs
are deterministic. ``fn`` must be picklable (a module-level function or a functools.partial of one)
for the process pool and Dask. ``executor.imap(fn, items, retries)`` yields ``(index, result)`` as runs
finish (a failed run as a :class:`RunFailed`, plain data holding the error's message), so a caller can commit
each result at once; a run lost with a dead worker process is retried, at most ``retries`` times.

* ``InProcessExecutor`` (default): a plain loop in this process.
* ``ProcessPoolExecutor``: worker processes on this machine (started by ``spawn``), each with private pipes, so a
  worker killed at any instant cannot block the others or the caller (the standard library's pool shares a
  result queue whose lock a killed worker can take with it).
* ``DaskExecutor``: a ``dask.distributed`` scheduler at ``scheduler`` ("tcp://host:8786"), or a
  ``LocalCluster`` of single-threaded worker processes when no address is given.

Each worker process (or thread) keeps one :class:`~harness.master.Master` per system
(:func:`harness.master.master_for`), so FMUs are extracted and instantiated once per worker and only
reset between runs.

>>> with make_executor("dask", workers=2) as ex:
...     results = run_sweep("loop.toml", [{"inputs": {"r": 1e-3}, "parameters": {"ctrl.Kp": kp}} for kp in gains], ex)
"""

from __future__ import annotations

import collections
import functools
import multiprocessing
import multiprocessing.connection
import os
import pickle
import shutil
import signal
import struct
import tempfile
import threading
import weakref
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Protocol, Sequence

import numpy as np

from .system import System, load_system

EXECUTORS = ("inprocess", "process", "dask")


class RunFailed:
    """Stands for the result of a run that raised, or whose worker process died ``attempts`` times."""

    def __init__(self, error: str, attempts: int = 1):
        self.error = error
        self.attempts = attempts

    def __repr__(self) -> str:
        return f"RunFailed({self.error!r}, attempts={self.attempts})"


def _failure(exc: BaseException, attempts: int = 1) -> RunFailed:
    return RunFailed(f"{type(exc).__name__}: {exc}", attempts)


class RunError(RuntimeError):
    """A run of :meth:`ProcessPoolExecutor.map` failed (the message holds its error)."""


class Executor(Protocol):
    """Runs ``fn`` over ``items`` and returns the results in item order (``map``), or yields
    ``(index, result)`` as runs finish, a failed run as ``(index, RunFailed)`` (``imap``)."""

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]: ...

    def imap(self, fn: Callable[[Any], Any], items: Sequence[Any],
             retries: int = 2) -> Iterator[tuple[int, Any]]: ...

    def close(self) -> None: ...


class _Closing:
    def __enter__(self):
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        return None


class InProcessExecutor(_Closing):
    """Runs everything in this process, one item after the other."""

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        return [fn(item) for item in items]

    def imap(self, fn: Callable[[Any], Any], items: Sequence[Any], retries: int = 2) -> Iterator[tuple[int, Any]]:
        """Each run as it finishes; a run that raises is a :class:`RunFailed` (no retry: runs are deterministic)."""
        for index, item in enumerate(items):
            try:
                yield index, fn(item)
            except Exception as exc:
                yield index, _failure(exc)


def _ignore_interrupt() -> None:
    """Ctrl-C reaches the whole process group; the parent alone handles it (commits what finished, stops the
    pool), so the workers do not each print a KeyboardInterrupt traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _returning_failures(fn: Callable[[Any], Any], item: Any) -> Any:
    """``fn(item)``, or the error it raised as a :class:`RunFailed`: plain data that crosses any process
    boundary, whatever the exception class (an exception that cannot be unpickled would break the pool)."""
    try:
        return fn(item)
    except Exception as exc:
        return _failure(exc)


def _unreadable(exc: BaseException) -> RunFailed:
    return RunFailed(f"the worker process cannot read the run: {_failure(exc).error}")


_HEADER = struct.Struct("!Q")   # length of the pickled reply that follows, on a worker's private result pipe


def _serve(tasks: Connection, results: Connection, scratch: str) -> None:
    """A worker process: read ``(fn, item)`` from its private task pipe, run it, write the reply (result or
    :class:`RunFailed`) to its private result pipe; stop at None or when the parent is gone. Nothing is shared
    with another worker, so a worker killed at any instant breaks only its own pipes. Its temporary files
    (unzipped FMUs) go to the pool's ``scratch`` folder, which the parent removes, also after a kill."""
    _ignore_interrupt()
    tempfile.tempdir = scratch
    out = results.fileno()
    while True:
        try:
            payload = tasks.recv_bytes()
        except (EOFError, OSError):
            return
        try:
            message = pickle.loads(payload)
        except Exception as exc:
            message = (_unreadable, exc)
        if message is None:
            return
        reply = _returning_failures(*message)
        try:
            data = pickle.dumps(reply, pickle.HIGHEST_PROTOCOL)
        except Exception as exc:
            data = pickle.dumps(RunFailed(f"its result cannot be sent to the parent process: {_failure(exc).error}"))
        view = memoryview(_HEADER.pack(len(data)) + data)
        try:
            while view:
                view = view[os.write(out, view):]
        except OSError:   # the parent is gone or gave the run up
            return


class _Worker:
    """One spawned worker process and the parent's ends of its two private pipes; the result pipe is read
    without blocking, a piece at a time, so the parent never waits on one worker."""

    def __init__(self, context: Any, scratch: str):
        task_end, self.tasks = context.Pipe(duplex=False)
        self.results, result_end = context.Pipe(duplex=False)
        self.process = context.Process(target=_serve, args=(task_end, result_end, scratch), daemon=True)
        self.process.start()
        task_end.close()      # the worker holds the only other ends: its death is EOF / EPIPE here
        result_end.close()
        os.set_blocking(self.results.fileno(), False)
        self.buffer = bytearray()

    def submit(self, payload: bytes) -> None:
        self.tasks.send_bytes(payload)

    def reply(self) -> tuple[bool, Any]:
        """``(True, reply)`` once a whole reply has arrived, ``(False, None)`` while it has not; EOFError when
        the worker is gone before sending it."""
        while True:
            size = _HEADER.unpack_from(self.buffer)[0] if len(self.buffer) >= _HEADER.size else None
            if size is not None and len(self.buffer) >= _HEADER.size + size:
                data = bytes(self.buffer[_HEADER.size:_HEADER.size + size])
                del self.buffer[:_HEADER.size + size]
                try:
                    return True, pickle.loads(data)
                except Exception as exc:
                    return True, RunFailed(f"its result cannot be read: {_failure(exc).error}")
            try:
                chunk = os.read(self.results.fileno(), 1 << 20)
            except BlockingIOError:
                return False, None
            if not chunk:
                raise EOFError
            self.buffer += chunk

    def death(self) -> str:
        """How the worker process ended (after it was found gone)."""
        self.process.join(timeout=5)
        code = self.process.exitcode
        if code is None:
            return "it stopped answering"
        if code < 0:
            return f"killed by {signal.Signals(-code).name}" if -code in signal.valid_signals() else f"signal {-code}"
        return f"exit code {code}"

    def stop(self, wait: float) -> None:
        """Ask the worker to finish (it is idle), then end it if it has not within ``wait`` seconds."""
        try:
            self.tasks.send_bytes(pickle.dumps(None))
        except OSError:
            pass
        self.process.join(timeout=wait)
        if self.process.exitcode is None:
            self.process.kill()
            self.process.join(timeout=5)
        self.tasks.close()
        self.results.close()


class ProcessPoolExecutor(_Closing):
    """A pool of ``workers`` spawned processes on this machine (default: one per CPU), each with its own
    task and result pipes (no queue or lock shared between workers: a worker killed at any instant, even
    in the middle of sending a result, loses only its own run). Every wait is bounded (``watchdog`` seconds)
    and followed by a check of each busy worker, so a dead worker is always noticed. Workers live until
    :meth:`close` and keep their :func:`harness.master.master_for` cache between runs."""

    def __init__(self, workers: int | None = None, watchdog: float = 1.0):
        self.workers = workers or os.cpu_count() or 1
        self.watchdog = watchdog
        self._context = multiprocessing.get_context("spawn")
        self._remove_scratch: weakref.finalize | None = None
        self._idle = [self._spawn() for _ in range(self.workers)]

    def _spawn(self) -> _Worker:
        """A new worker with SIGINT ignored from its start: a spawned interpreter inherits the ignored
        disposition across exec, so a Ctrl-C while it is still importing cannot end it with a traceback."""
        if self._remove_scratch is None or not self._remove_scratch.alive:   # first worker, or after close()
            self._scratch = tempfile.mkdtemp(prefix="motiontwin-pool-")
            self._remove_scratch = weakref.finalize(self, shutil.rmtree, self._scratch, True)
        if threading.current_thread() is not threading.main_thread():
            return _Worker(self._context, self._scratch)
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            return _Worker(self._context, self._scratch)
        finally:
            signal.signal(signal.SIGINT, previous)

    def imap(self, fn: Callable[[Any], Any], items: Sequence[Any], retries: int = 2) -> Iterator[tuple[int, Any]]:
        """Each run as it finishes. When a worker process dies (killed, out of memory, a crash in an FMU) its
        run is tried again in a fresh worker, at most ``retries`` more times, then reported as a
        :class:`RunFailed` naming how the worker ended. A run that raises is not retried."""
        attempts = [0] * len(items)
        queue = collections.deque(range(len(items)))
        busy: dict[_Worker, int] = {}
        try:
            while queue or busy:
                while queue and len(busy) < self.workers:
                    index = queue.popleft()
                    attempts[index] += 1
                    try:
                        payload = pickle.dumps((fn, items[index]), pickle.HIGHEST_PROTOCOL)
                    except Exception as exc:
                        yield index, _failure(exc, attempts[index])
                        continue
                    worker = self._idle.pop() if self._idle else self._spawn()
                    busy[worker] = index
                    try:
                        worker.submit(payload)
                    except OSError:   # it died while idle: found below like any other death
                        pass
                multiprocessing.connection.wait([w.results for w in busy] + [w.process.sentinel for w in busy],
                                                timeout=self.watchdog)
                for worker, index in list(busy.items()):
                    try:
                        done, result = worker.reply()
                        if not done and worker.process.is_alive():
                            continue
                        if not done:
                            done, result = worker.reply()   # it may have finished writing just before it ended
                        if not done:
                            raise EOFError
                    except EOFError:
                        del busy[worker]
                        how = worker.death()
                        worker.stop(0)
                        if attempts[index] > retries:
                            times = "once" if attempts[index] == 1 else f"{attempts[index]} times"
                            yield index, RunFailed(f"its worker process died {times} (last: {how})",
                                                   attempts[index])
                        else:
                            queue.appendleft(index)
                        continue
                    del busy[worker]
                    self._idle.append(worker)
                    if isinstance(result, RunFailed):
                        result.attempts = attempts[index]
                    yield index, result
        finally:
            for worker in busy:   # runs abandoned (the caller stopped early): their workers are ended
                worker.stop(0)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """The results in item order; a run that fails raises :class:`RunError` with its error."""
        items = list(items)
        results: list[Any] = [None] * len(items)
        for index, result in self.imap(fn, items):
            if isinstance(result, RunFailed):
                raise RunError(f"run {index} failed: {result.error}")
            results[index] = result
        return results

    def close(self) -> None:
        for worker in self._idle:
            worker.stop(5)
        self._idle = []
        if self._remove_scratch is not None:
            self._remove_scratch()


class DaskExecutor(_Closing):
    """Dask distributed: connect to ``scheduler`` or start a LocalCluster of ``workers`` processes."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None):
        import dask
        from dask.distributed import Client, LocalCluster

        self._cluster = None
        if scheduler:
            self._client = Client(scheduler)
        else:
            self._scratch = tempfile.mkdtemp(prefix="motiontwin-dask-")   # Dask leaves its scratch folder
            self._remove_scratch = weakref.finalize(self, shutil.rmtree, self._scratch, True)
            with dask.config.set({"temporary-directory": self._scratch}):
                self._cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, processes=True,
                                             threads_per_worker=1, dashboard_address=None)
            self._client = Client(self._cluster)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        futures = self._client.map(fn, list(items), pure=False)
        return self._client.gather(futures)

    def imap(self, fn: Callable[[Any], Any], items: Sequence[Any], retries: int = 2) -> Iterator[tuple[int, Any]]:
        """Each run as it finishes; Dask itself reschedules the runs of a worker that died (its
        ``allowed-failures``), a run it gives up on or that raises is a :class:`RunFailed`."""
        from dask.distributed import as_completed

        futures = self._client.map(functools.partial(_returning_failures, fn), list(items), pure=False)
        index = {future.key: i for i, future in enumerate(futures)}
        for future in as_completed(futures):
            try:
                yield index[future.key], future.result()
            except Exception as exc:
                yield index[future.key], _failure(exc)

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
            self._remove_scratch()


def make_executor(kind: str = "inprocess", workers: int | None = None, scheduler: str | None = None) -> Executor:
    """``kind`` is one of "inprocess", "process", "dask" (``scheduler`` implies "dask"); ``workers`` None
    (one per CPU) or a positive integer."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers: expected a positive number of worker processes, got {workers!r}")
    if scheduler and kind != "dask":
        kind = "dask"
    if kind == "inprocess":
        return InProcessExecutor()
    if kind == "process":
        return ProcessPoolExecutor(workers)
    if kind == "dask":
        return DaskExecutor(scheduler, workers)
    raise ValueError(f"unknown executor {kind!r}; choose one of {EXECUTORS}")


def run_case(system: System, case: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """One run of ``system`` in this worker: ``case`` holds the keyword arguments of
    :meth:`harness.master.Master.run` (``inputs``, ``parameters``, ``stop_time``)."""
    allowed = {"inputs", "parameters", "stop_time"}
    unknown = set(case) - allowed
    if unknown:
        raise ValueError(f"sweep case has unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}")
    from .master import master_for   # here, so a worker process starts without loading fmpy

    return master_for(system).run(**case, progress=False)


def run_sweep(system: System | str | Path, cases: Sequence[Mapping[str, Any]],
              executor: Executor | None = None) -> list[dict[str, np.ndarray]]:
    """Run every case of ``system`` and return the logs in case order."""
    system = system if isinstance(system, System) else load_system(system)
    executor = executor or InProcessExecutor()
    return executor.map(functools.partial(run_case, system), cases)
