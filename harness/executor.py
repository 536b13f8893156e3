"""One interface for many independent co-simulation runs: in-process, a local process pool, or Dask.

Monte Carlo trials, tuning populations, workspace sweeps and bootstraps are lists of independent
runs. ``executor.map(fn, items)`` runs ``fn(item)`` for every item and returns the results in the
order of ``items`` whichever executor runs them; with the same items (seeds, inputs, parameters)
the results are identical, because every run starts from the same reset/initial state and FMUs
are deterministic. ``fn`` must be picklable (a module-level function or a functools.partial of one)
for the process pool and Dask. ``executor.imap(fn, items, retries)`` yields ``(index, result)`` as runs
finish (a failed run as a :class:`RunFailed`), so a caller can commit each result at once; the process pool
restarts itself when a worker dies and retries the runs it lost, at most ``retries`` times.

* ``InProcessExecutor`` (default): a plain loop in this process.
* ``ProcessPoolExecutor``: ``concurrent.futures`` with workers started by ``spawn`` on this machine.
* ``DaskExecutor``: a ``dask.distributed`` scheduler at ``scheduler`` ("tcp://host:8786"), or a
  ``LocalCluster`` of single-threaded worker processes when no address is given.

Each worker process (or thread) keeps one :class:`~harness.master.Master` per system
(:func:`harness.master.master_for`), so FMUs are extracted and instantiated once per worker and only
reset between runs.

>>> with make_executor("dask", workers=2) as ex:
...     results = run_sweep("loop.toml", [{"inputs": {"r": 1e-3}, "parameters": {"ctrl.Kp": kp}} for kp in gains], ex)
"""

from __future__ import annotations

import concurrent.futures
from concurrent.futures.process import BrokenProcessPool
import functools
import multiprocessing
import os
import signal
import threading
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Protocol, Sequence

import numpy as np

from .master import master_for
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
    """Worker initializer: Ctrl-C reaches the whole process group; the parent alone handles it (commits what
    finished, shuts the pool down), so the workers do not each print a KeyboardInterrupt traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class ProcessPoolExecutor(_Closing):
    """A pool of ``workers`` spawned processes on this machine (default: one per CPU)."""

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1
        self._pool = self._new_pool()

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        """A pool whose workers are all started now, with SIGINT ignored: a spawned interpreter inherits the
        ignored disposition across exec, so a Ctrl-C while a worker is still importing cannot end it with a
        traceback (its initializer would come too late); the parent's handler is back once they are forked."""
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=self.workers, initializer=_ignore_interrupt,
                                                      mp_context=multiprocessing.get_context("spawn"))
        if threading.current_thread() is not threading.main_thread():
            return pool
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            for _ in range(self.workers):   # each submit without an idle worker spawns one
                pool.submit(int)
        finally:
            signal.signal(signal.SIGINT, previous)
        return pool

    def imap(self, fn: Callable[[Any], Any], items: Sequence[Any], retries: int = 2) -> Iterator[tuple[int, Any]]:
        """Each run as it finishes. At most ``workers`` runs are in the pool at a time, so when a worker
        process dies (killed, out of memory, a crash in an FMU) the runs that were lost with the pool are the
        ones that were running: the pool is restarted and each of them is tried again, at most ``retries``
        more times, then reported as a :class:`RunFailed`. A run that raises is not retried."""
        attempts = [0] * len(items)
        queue = list(range(len(items)))[::-1]
        pending: dict[concurrent.futures.Future, int] = {}
        while queue or pending:
            broken = False
            while queue and len(pending) < self.workers:
                try:
                    future = self._pool.submit(fn, items[queue[-1]])
                except BrokenProcessPool:  # a worker died since the last run finished
                    broken = True
                    break
                index = queue.pop()
                attempts[index] += 1
                pending[future] = index
            lost: list[int] = []
            done = set() if broken else concurrent.futures.wait(
                pending, return_when=concurrent.futures.FIRST_COMPLETED).done
            for future in done:
                index = pending.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    lost.append(index)
                    continue
                except Exception as exc:
                    result = _failure(exc, attempts[index])
                yield index, result
            if not lost and not broken:
                continue
            for future in concurrent.futures.wait(pending).done:  # the broken pool fails the other runs too
                index = pending.pop(future)
                error = future.exception()
                if isinstance(error, BrokenProcessPool):
                    lost.append(index)
                else:
                    yield index, future.result() if error is None else _failure(error, attempts[index])
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            for index in sorted(lost, reverse=True):
                if attempts[index] > retries:
                    yield index, RunFailed(f"its worker process died {attempts[index]} times", attempts[index])
                else:
                    queue.append(index)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        items = list(items)
        chunk = max(1, len(items) // (4 * self.workers))
        return list(self._pool.map(fn, items, chunksize=chunk))

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor(_Closing):
    """Dask distributed: connect to ``scheduler`` or start a LocalCluster of ``workers`` processes."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None):
        from dask.distributed import Client, LocalCluster

        self._cluster = None
        if scheduler:
            self._client = Client(scheduler)
        else:
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

        futures = self._client.map(fn, list(items), pure=False)
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
    return master_for(system).run(**case, progress=False)


def run_sweep(system: System | str | Path, cases: Sequence[Mapping[str, Any]],
              executor: Executor | None = None) -> list[dict[str, np.ndarray]]:
    """Run every case of ``system`` and return the logs in case order."""
    system = system if isinstance(system, System) else load_system(system)
    executor = executor or InProcessExecutor()
    return executor.map(functools.partial(run_case, system), cases)
