"""FMU files get the permissions of any new file (0o644 under umask 022), not mkstemp's 0o600."""
from __future__ import annotations

import os
import stat
import zipfile
from pathlib import Path

import pytest

from motiontwin.fmus import package


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_packed_fmu_has_the_mode_open_would_give(tmp_path: Path, umask: int, mode: int) -> None:
    staging = tmp_path / "staging"
    staging.mkdir()
    (staging / "modelDescription.xml").write_text("<fmiModelDescription/>\n")
    previous = os.umask(umask)
    try:
        fmu = package.pack(staging, tmp_path / "out" / "M.fmu")
        reference = tmp_path / "reference"
        reference.write_text("")   # what open() gives a new file under this umask
    finally:
        os.umask(previous)
    assert stat.S_IMODE(fmu.stat().st_mode) == stat.S_IMODE(reference.stat().st_mode) == mode
    assert zipfile.ZipFile(fmu).namelist() == ["modelDescription.xml"]


def test_built_fmus_are_world_readable_under_umask_022(built_fmus) -> None:
    umask = os.umask(0)
    os.umask(umask)
    for path in built_fmus.values():
        assert stat.S_IMODE(Path(path).stat().st_mode) == 0o666 & ~umask
