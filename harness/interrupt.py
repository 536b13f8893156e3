"""Stopping a long run cleanly: SIGTERM (what ``timeout``, systemd and batch schedulers send) raises
:class:`Terminated` like Ctrl-C raises ``KeyboardInterrupt``, so the same cleanup runs, and a commit of finished
results (:func:`harness.runfolder.commit_each`) is never cut in half by either.

A library that catches broadly can swallow the exception a signal handler raises, and Python only prints one
raised where it cannot propagate (a destructor, an ``os.fork`` hook such as logging's); the termination is
remembered, :func:`raise_if_terminated` raises it again at the next commit, so a run told to stop does stop, and
the printing of such a swallowed :class:`Terminated` (a traceback in the middle of a clean stop) is suppressed.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Any, Callable, Iterator

__all__ = ["Terminated", "handle_termination", "raise_if_terminated", "uninterrupted"]

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is: ``finally`` blocks and context managers remove temporary files
    and folders, a sweep or fleet records "interrupted"."""


_ACTIVE = False       # a handled run is going on in this process: its forked children leave the signals to it
_TERMINATED = False   # SIGTERM arrived during it


def _terminate(signum: int, frame: object) -> None:
    global _TERMINATED
    _TERMINATED = True
    signal.signal(signal.SIGTERM, signal.SIG_IGN)   # a second SIGTERM must not cut the cleanup short
    raise Terminated


def _quiet_child() -> None:
    """In a forked worker of a handled run: Ctrl-C is the parent's to handle (it stops the pool, a worker
    would print a KeyboardInterrupt traceback), SIGTERM ends the worker without Python cleanup."""
    global _ACTIVE, _TERMINATED
    if _ACTIVE:
        _ACTIVE = _TERMINATED = False
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


os.register_at_fork(after_in_child=_quiet_child)


def _quiet_if_terminated(previous_hook: Callable[[Any], object]) -> Callable[[Any], None]:
    """An unraisable-exception hook that drops a :class:`Terminated` (remembered, raised again at the next
    commit) and hands anything else to ``previous_hook``."""
    def hook(unraisable: Any) -> None:   # sys.UnraisableHookArgs
        if not isinstance(unraisable.exc_value, Terminated):
            previous_hook(unraisable)
    return hook


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def handle_termination() -> Iterator[None]:
    """SIGTERM raises :class:`Terminated` inside the block (main thread only: Python delivers signals there);
    the previous handler is back afterwards."""
    global _ACTIVE, _TERMINATED
    if not _main_thread():
        yield
        return
    previous, previous_hook = signal.signal(signal.SIGTERM, _terminate), sys.unraisablehook
    sys.unraisablehook = _quiet_if_terminated(previous_hook)
    _ACTIVE, _TERMINATED = True, False
    try:
        yield
    finally:
        _ACTIVE = _TERMINATED = False   # its SIGTERM was raised by now: calls after the block are not stopped
        signal.signal(signal.SIGTERM, previous)
        sys.unraisablehook = previous_hook


def raise_if_terminated() -> None:
    """Raise :class:`Terminated` if SIGTERM arrived during the handled run and its exception was swallowed."""
    if _TERMINATED:
        raise Terminated


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """Ctrl-C and SIGTERM held back during the block (a commit: files written and recorded in the manifest
    together) and handled right after it. The handlers are swapped, not the signal mask: a process-directed
    signal blocked in the main thread would go to another thread, and Python still runs its handler in the
    main thread at once."""
    if not _main_thread():
        yield
        return
    held: list[int] = []
    previous = {number: signal.signal(number, lambda signum, frame: held.append(signum)) for number in STOP_SIGNALS}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        for number in dict.fromkeys(held):
            handler = previous[number]
            if callable(handler):
                handler(number, None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(number)
