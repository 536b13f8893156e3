"""Forked worker processes for the diagnosis' independent fits (the candidates' screenings and full fits, the
floor's noise replicates): each worker inherits the bundle and the current fit, and is sent only a job token
and a name. The results do not depend on the worker count (each fit is deterministic)."""
from __future__ import annotations

import concurrent.futures
import itertools
import multiprocessing
import os
import threading
from typing import Callable

from motiontwin.harness.interrupt import raise_if_terminated

_TOKENS = itertools.count()  # job tokens (itertools.count is thread-safe in CPython)
#: jobs by token (a function of a name: a candidate, a replicate): forked workers inherit the table and are sent only
#: (token, name); every call adds its own token and removes it, so concurrent diagnoses do not collide
_JOBS: dict[int, Callable] = {}


def _run_job(token: int, name: str):
    return _JOBS[token](name)


def map_jobs(job: Callable[[str], object], names: list[str]) -> list:
    """``[job(name) for name in names]`` in forked worker processes (:func:`worker_count`; they share the
    bundle and the current fit), in the order of ``names``; in-process with one worker. ``job`` returns
    what pickles (fits, numbers), not compiled loops."""
    token = next(_TOKENS)
    _JOBS[token] = job
    workers = min(worker_count(), len(names))
    try:
        if workers > 1:
            with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) \
                    as pool:
                results = list(pool.map(_run_job, [token] * len(names), names))
            raise_if_terminated()   # a SIGTERM Python could only print (it landed in a fork hook as a worker started)
            return results
        return [job(name) for name in names]
    finally:
        del _JOBS[token]


def worker_count() -> int:
    """Processes for the diagnosis' independent fits: ``MOTIONTWIN_DIAGNOSIS_WORKERS`` or the machine's cores
    (at most 4); 1 runs in-process, as does every diagnosis outside the main thread (forking a threaded
    process can deadlock). The results do not depend on it (each fit is deterministic)."""
    if threading.current_thread() is not threading.main_thread():
        return 1
    value = os.environ.get("MOTIONTWIN_DIAGNOSIS_WORKERS")
    count = int(value) if value and value.isdigit() else min(4, os.cpu_count() or 1)
    return max(1, count) if "fork" in multiprocessing.get_all_start_methods() else 1
