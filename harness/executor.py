"""One interface for many independent co-simulation runs: in-process, a local process pool, or Dask.

Monte Carlo trials, tuning populations, workspace sweeps and bootstraps are lists of independent
runs. ``executor.map(fn, items)`` runs ``fn(item)`` for every item and returns the results in the
order of ``items`` whichever executor runs them; with the same items (seeds, inputs, parameters)
the results are identical, because every run starts from the same reset/initial state and FMUs
are deterministic. ``fn`` must be picklable (a module-level function or a functools.partial of one)
for the process pool and Dask.

* ``InProcessExecutor`` (default): a plain loop in this process.
* ``ProcessPoolExecutor``: ``concurrent.futures`` with ``spawn``ed workers on this machine.
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
import functools
import multiprocessing
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Protocol, Sequence

import numpy as np

from .master import master_for
from .system import System, load_system

EXECUTORS = ("inprocess", "process", "dask")


class Executor(Protocol):
    """Runs ``fn`` over ``items`` and returns the results in item order."""

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]: ...

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


class ProcessPoolExecutor(_Closing):
    """A pool of ``workers`` spawned processes on this machine (default: one per CPU)."""

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1
        self._pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"))

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

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(kind: str = "inprocess", workers: int | None = None, scheduler: str | None = None) -> Executor:
    """``kind`` is one of "inprocess", "process", "dask" (``scheduler`` implies "dask")."""
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
