"""Runs for the process-pool tests that end their own worker process at a chosen instant, the first time
each is tried (a marker file remembers it), including inside the hand-off of their result to the parent.
A module of its own, so a respawned worker imports only this and numpy."""
from __future__ import annotations

import os
import pickle
import signal
import threading
import time
from pathlib import Path

import numpy as np

INSTANTS = ("start", "compute", "pickle", "send-header", "send-early", "send-mid", "send-late")
RESULT_BYTES = 8 << 20   # the result's size: its hand-off is many pipe buffers long


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


class _DiesWhenPickled:
    def __reduce__(self):
        _die()


def _die_inside_send(when: str) -> None:
    """From now on, this process dies inside the send of its next reply to the parent (``os.write`` is
    wrapped: the worker's send loop writes as much as it is told it wrote), after the given number of bytes
    of it: half of the pipe's 8-byte length header, 64 KiB, half, or all but the last byte."""
    real, sent = os.write, [0]
    total = 8 + len(pickle.dumps((0, expected(0)), pickle.HIGHEST_PROTOCOL))
    stop = {"send-header": 4, "send-early": 64 << 10, "send-mid": total // 2, "send-late": total - 1}[when]

    def write(fd: int, data) -> int:
        written = real(fd, data[:stop - sent[0]])
        sent[0] += written
        if sent[0] >= stop:
            _die()
        return written

    os.write = write


def expected(index: int) -> np.ndarray:
    return np.full(RESULT_BYTES // 8, float(index))


def run(item: tuple[int, str, str]) -> tuple:
    """``(index, expected(index))``; the first time, the worker dies at instant ``when`` (one of
    :data:`INSTANTS`): before any work, while computing, while pickling its result, or inside the hand-off
    of its result: in the pipe's length header, after 64 KiB, half, or all but the last byte of it."""
    index, when, marker = item
    first = not os.path.exists(marker)
    if first:
        Path(marker).touch()
    if first and when == "start":
        _die()
    result = expected(index)
    if first and when == "compute":
        threading.Timer(0.01, _die).start()
        time.sleep(1.0)
    if first and when == "pickle":
        return index, result, _DiesWhenPickled()
    if first and when.startswith("send"):
        _die_inside_send(when)
    return index, result


def pid(_: object) -> int:
    return os.getpid()
