"""A process's temporary folder (harness.scratch): removed when the process ends, also a multiprocessing worker
that leaves through os._exit; a forked child gets its own and never removes its parent's. Reference: the folders'
existence on disk after the processes ended."""
from __future__ import annotations

import multiprocessing
from pathlib import Path

from motiontwin.harness.scratch import process_folder


def _child(queue) -> None:
    queue.put(str(process_folder()))


def test_a_forked_worker_removes_its_own_folder_and_never_its_parents() -> None:
    parent = process_folder()
    (parent / "kept").write_text("x")
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    worker = context.Process(target=_child, args=(queue,))
    worker.start()
    child = Path(queue.get(timeout=60))
    worker.join(timeout=60)
    assert worker.exitcode == 0
    assert child != parent and not child.exists()      # the worker's own folder went with it
    assert (parent / "kept").is_file()                 # the parent's folder stays while the parent lives
