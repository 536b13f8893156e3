"""Every class of the MotionTwin library that is marked for export builds into FMI 2.0 and 3.0 FMUs that
pass fmpy's and fmu-manipulation-toolbox's checks and run in Co-Simulation and Model Exchange."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

from motiontwin.fmus import build


@pytest.fixture(scope="session")
def library_fmus(tmp_path_factory: pytest.TempPathFactory) -> list[build.BuiltFmu]:
    classes = build.exported_classes()
    return build.build(classes, out_dir=tmp_path_factory.mktemp("library"))


def test_every_exported_class_is_built_for_both_versions(library_fmus):
    classes = build.exported_classes()
    assert len(classes) >= 20
    assert {(f.identifier, f.fmi_version) for f in library_fmus} == {
        (build.identifier_of(c), v) for c in classes for v in build.FMI_VERSIONS}


def test_library_fmus_validate(library_fmus):
    fmutool = Path(sys.executable).with_name("fmutool")
    for fmu in library_fmus:
        assert validate_fmu(str(fmu.path)) == [], fmu.path
        proc = subprocess.run([str(fmutool), "-input", str(fmu.path), "-check"], capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, f"{fmu.path}: {proc.stdout}"


@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_library_fmus_simulate_from_their_defaults(library_fmus, fmi_type):
    for fmu in library_fmus:
        result = fmpy.simulate_fmu(str(fmu.path), fmi_type=fmi_type, stop_time=0.02, output_interval=5e-4)
        for name in result.dtype.names:
            assert np.all(np.isfinite(result[name])), f"{fmu.path} {name}"
