"""The project's FMUs (test models and the library's joint and robust controller) under its own regression
suite (tests/regression/suite.toml, stored references)."""
from __future__ import annotations

from pathlib import Path

from motiontwin.fmus import build
from motiontwin.harness import regress
from tests.conftest import TEST_MODELS

SUITE = Path(__file__).parent / "regression" / "suite.toml"
FMU_DIR = Path(__file__).resolve().parents[1] / "build" / "regression-fmus"


LIBRARY_CLASSES = ["MotionTwin.Plants.CheungJoint", "MotionTwin.Controllers.RobustJointController"]


def build_suite_fmus() -> None:
    for name in ("SampledPI", "FrictionJoint"):
        class_name, source = TEST_MODELS[name]
        build.build([class_name], source, FMU_DIR, workers=1)
    build.build(LIBRARY_CLASSES, out_dir=FMU_DIR, workers=1)


def test_project_fmus_match_their_stored_references(tmp_path):
    build_suite_fmus()
    junit = tmp_path / "junit.xml"
    assert regress.run_suite(SUITE, junit=junit, plots=tmp_path / "plots") == 0, junit.read_text()
