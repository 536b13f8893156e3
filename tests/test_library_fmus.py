"""Every class of the MotionTwin library that is marked for export builds into FMI 2.0 and 3.0 FMUs that
pass fmpy's and fmu-manipulation-toolbox's checks and run in Co-Simulation and Model Exchange."""
from __future__ import annotations

import logging
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


class _Errors(logging.Handler):
    """The ERROR records fmu-manipulation-toolbox's checkers log (what makes ``fmutool -check`` fail)."""

    def __init__(self) -> None:
        super().__init__(level=logging.ERROR)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _checker_errors(path: Path) -> list[str]:
    """What the checkers of ``fmutool -check`` report on the FMU at ``path``, run in this process (one interpreter
    instead of one per FMU)."""
    from fmu_manipulation_toolbox.checker import get_checkers
    from fmu_manipulation_toolbox.operations import FMU

    errors = _Errors()
    logger = logging.getLogger("fmu_manipulation_toolbox")
    logger.addHandler(errors)
    try:
        with FMU(str(path)) as archive:
            for checker in get_checkers():
                archive.apply_operation(checker(), None)
    finally:
        logger.removeHandler(errors)
    return errors.messages


def test_library_fmus_validate(library_fmus):
    """fmpy's validation and the checkers of ``fmutool -check`` find nothing in any library FMU."""
    for fmu in library_fmus:
        assert validate_fmu(str(fmu.path)) == [], fmu.path
        assert _checker_errors(fmu.path) == [], fmu.path


def test_the_in_process_check_sees_a_broken_fmu(library_fmus, tmp_path):
    """The checkers do report through that logger: an FMU whose modelDescription.xml declares a parameter with
    continuous variability (not allowed by FMI) is caught."""
    import zipfile

    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(library_fmus[0].path) as zin, zipfile.ZipFile(broken, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'causality="parameter" variability="fixed"',
                                    b'causality="parameter" variability="continuous"', 1)
                assert b'variability="continuous" initial="exact"' in data
            zout.writestr(item, data)
    assert _checker_errors(broken)


@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_library_fmus_simulate_from_their_defaults(library_fmus, fmi_type):
    for fmu in library_fmus:
        result = fmpy.simulate_fmu(str(fmu.path), fmi_type=fmi_type, stop_time=0.02, output_interval=5e-4)
        for name in result.dtype.names:
            assert np.all(np.isfinite(result[name])), f"{fmu.path} {name}"
