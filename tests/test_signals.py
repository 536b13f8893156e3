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

from motiontwin.cli import _signals


def test_forked_workers_of_a_subcommand_leave_ctrl_c_to_it_and_die_quietly_on_sigterm() -> None:
    def child_dispositions() -> int:
        pid = os.fork()
        if pid == 0:
            ok = signal.getsignal(signal.SIGINT) is signal.SIG_IGN and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
            os._exit(0 if ok else 1)
        return os.waitpid(pid, 0)[1]

    with _signals():
        assert child_dispositions() == 0
    assert child_dispositions() != 0   # outside a subcommand, forks keep Python's handlers


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
