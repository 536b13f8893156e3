"""Signals at the CLI entry: SIGTERM stops any subcommand like Ctrl-C (cleanup runs, exit 143), and the forked
workers of a running subcommand leave Ctrl-C to it (no worker traceback). The sweep's own cases are in
test_sweep.py."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from motiontwin.harness.interrupt import handle_termination


def test_forked_workers_of_a_subcommand_leave_ctrl_c_to_it_and_die_quietly_on_sigterm() -> None:
    def child_dispositions() -> int:
        pid = os.fork()
        if pid == 0:
            ok = signal.getsignal(signal.SIGINT) is signal.SIG_IGN and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
            os._exit(0 if ok else 1)
        return os.waitpid(pid, 0)[1]

    # SIGINT as Python installs it at start-up (a process launched in the background by a non-interactive shell
    # inherits SIGINT ignored, and Python then keeps it so: the check below would see the parent's SIG_IGN)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with handle_termination():
            assert child_dispositions() == 0
        assert child_dispositions() != 0   # outside a subcommand, forks keep Python's handlers
    finally:
        signal.signal(signal.SIGINT, previous)


def test_sigterm_on_diagnose_removes_its_temporary_folder_and_exits_143(tmp_path: Path) -> None:
    """A real ``motiontwin diagnose`` sent SIGTERM a few seconds into its analysis: exit 143, one line naming
    SIGTERM, no ``motiontwin-diagnosis-*`` folder left in its TMPDIR, no output folder."""
    from motiontwin.ident.benchmarks import single_axis as bench

    bundle, temp, out = tmp_path / "bundle", tmp_path / "tmp", tmp_path / "out"
    bench.write_bundle(bundle, "gravity_offset", seed=7, scale=1.5, durations=(4.0, 2.0))
    temp.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "motiontwin", "diagnose", str(bundle), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, TMPDIR=str(temp)))
    deadline = time.monotonic() + 120
    while not list(temp.glob("motiontwin-diagnosis-*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(3.0)
    assert proc.poll() is None and list(temp.glob("motiontwin-diagnosis-*")), "the diagnosis ended too early"
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == ("motiontwin diagnose: terminated (SIGTERM); finished outputs are "
                                            "complete, nothing half-written was kept (run the command again)")
    assert "Traceback" not in err
    assert list(temp.glob("motiontwin-diagnosis-*")) == [] and not out.exists()


def test_a_sigterm_a_library_swallowed_during_the_analysis_publishes_no_output(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGTERM swallowed where Python can only print it (a screening worker's fork hook): the analysis goes on,
    but its finished folder is not published, and the command ends 143 (CI of stop 48 found ``--out`` written)."""
    import motiontwin.ident.diagnosis as diagnosis
    from motiontwin.cli import main
    from motiontwin.ident.diagnosis import pipeline

    class Finished:
        def write(self, folder: str) -> dict:
            staging = tmp_path / "staging"
            staging.mkdir()
            (staging / "diagnosis.json").write_text("{}", encoding="utf-8")
            pipeline._publish(staging, Path(folder))
            return {}

    def analysis(bundle: object, progress: object) -> Finished:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.1)
        except KeyboardInterrupt:
            pass   # swallowed
        return Finished()

    monkeypatch.setattr(diagnosis, "check_sizes", lambda path: None)
    monkeypatch.setattr(diagnosis, "read_bundle", lambda path, allow_outside_paths: None)
    monkeypatch.setattr(diagnosis, "diagnose_bundle_object", analysis)
    (tmp_path / "bundle").mkdir()
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "bundle"), "--out", str(out), "--quiet"]) == 143
    assert not out.exists()


def _commit_runs(fn, on_result) -> tuple[list[str], BaseException | None]:
    """commit_each over three in-process runs under the CLI's SIGTERM handling: the statuses written, the
    exception it ended with."""
    from motiontwin.harness import runfolder
    from motiontwin.harness.executor import InProcessExecutor

    statuses: list[str] = []
    try:
        with handle_termination():
            runfolder.commit_each(InProcessExecutor(), fn, [0, 1, 2], 0, on_result, lambda i, e: None,
                                  statuses.append)
    except KeyboardInterrupt as exc:
        return statuses, exc
    return statuses, None


def test_a_sigterm_during_a_commit_is_delivered_after_the_run_is_recorded() -> None:
    """SIGTERM between writing a run's files and recording them: the commit completes (files and row
    together), then the run stops as terminated; the third run never starts."""
    from motiontwin.harness.interrupt import Terminated

    recorded: list[int] = []

    def on_result(index: int, result: int) -> None:
        if index == 1:
            os.kill(os.getpid(), signal.SIGTERM)   # the files are written, the row not yet recorded
        recorded.append(result)

    statuses, exc = _commit_runs(lambda item: item * 10, on_result)
    assert isinstance(exc, Terminated)
    assert recorded == [0, 10] and statuses[-1] == "interrupted"


def test_a_sigterm_a_library_swallowed_still_stops_the_runs() -> None:
    """A run whose library catches every exception (here: the Terminated that SIGTERM raised inside it) and
    returns a result: that result is not committed, the runs stop as terminated."""
    from motiontwin.harness.interrupt import Terminated

    def swallowing(item: int) -> int:
        if item == 1:
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1.0)
            except BaseException:
                pass
        return item

    recorded: list[int] = []
    statuses, exc = _commit_runs(swallowing, lambda index, result: recorded.append(result))
    assert isinstance(exc, Terminated)
    assert recorded == [0] and statuses[-1] == "interrupted"


def test_a_sigterm_python_could_only_print_stops_the_run_without_a_traceback() -> None:
    """SIGTERM landing where Python cannot raise (here a destructor; in CI it was logging's ``os.fork`` hook
    while a worker started): no traceback on stderr, and the run still stops as terminated at the next check;
    any other unraisable exception is still printed."""
    script = """if True:
        import gc, os, signal, sys
        from motiontwin.harness.interrupt import Terminated, handle_termination, raise_if_terminated

        class SignalledInDestructor:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGTERM)

        class FailingDestructor:
            def __del__(self):
                raise ValueError("a destructor's own error")

        try:
            with handle_termination():
                SignalledInDestructor()
                gc.collect()
                FailingDestructor()
                gc.collect()
                raise_if_terminated()
        except Terminated:
            sys.exit(143)
    """
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 143, proc.stderr
    assert "Terminated" not in proc.stderr and proc.stderr.count("Traceback") == 1, proc.stderr
    assert "a destructor's own error" in proc.stderr


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_sigterm_swallowed_during_a_diagnosis_stops_it_and_writes_nothing(tmp_path, monkeypatch, workers):
    """A SIGTERM whose exception is swallowed early in a diagnosis (here by its progress callback; in CI by a
    fork hook as a worker started): with workers the next pool raises it, in-process the check before the
    outputs are written does; either way :class:`Terminated` and no output folder (the CLI then exits 143)."""
    from motiontwin.harness.interrupt import Terminated
    from motiontwin.ident.benchmarks import single_axis as bench
    from motiontwin.ident.diagnosis import engine

    bundle, out = tmp_path / "bundle", tmp_path / "out"
    bench.write_bundle(bundle, "gravity_offset", seed=7, scale=1.5, durations=(0.5, 0.25))
    monkeypatch.setenv("MOTIONTWIN_DIAGNOSIS_WORKERS", workers)
    lines: list[str] = []

    def swallowing(line: str) -> None:
        if not lines:
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1.0)
            except Terminated:
                pass
        lines.append(line)

    with pytest.raises(Terminated), handle_termination():
        engine.diagnose_bundle(bundle, out, progress=swallowing)
    assert not out.exists()
    if workers == "2":
        assert not any(line.startswith("validation") for line in lines)   # stopped at the first pool
