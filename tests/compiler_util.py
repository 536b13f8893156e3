"""A C compiler behind a wrapper script, for tests of which flags the builds pass and of their fallbacks."""
from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest

from motiontwin.fmus import clib


def wrapped_compiler(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str = "cc-logged",
                     refuse: tuple[str, ...] = ()) -> Path:
    """Set CC to a wrapper ``name`` around the compiler that appends each command line to the returned log and
    fails, as a compiler that does not know them would, on arguments matching the shell patterns ``refuse``.
    Skips the test when there is no compiler."""
    cc = clib.compiler()
    if cc is None:
        pytest.skip("no C compiler")
    log = tmp_path / f"{name}.log"
    refusal = (f'for a in "$@"; do case "$a" in {"|".join(refuse)}) echo "unknown option $a" >&2; exit 1;; '
               f'esac; done\n' if refuse else "")
    wrapper = tmp_path / name
    wrapper.write_text(f'#!/bin/sh\necho "$*" >> {log}\n{refusal}exec {shutil.which(cc)} "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("CC", wrapper.name)
    return log
