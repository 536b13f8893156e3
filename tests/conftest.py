"""Shared fixtures: FMUs built once per test session by the project's own pipeline."""
from __future__ import annotations

from pathlib import Path

import pytest

from fmus import build

MODELS = Path(__file__).parent / "models"
TEST_MODELS = {
    "LinearMotorJoint": ("MotionTwin.Plants.LinearMotorJoint", build.MODELICA_DIR),
    "FrictionJoint": ("FrictionJoint", MODELS / "FrictionJoint.mo"),
    "SampledPI": ("SampledPI", MODELS / "SampledPI.mo"),
}


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fmus")


@pytest.fixture(scope="session")
def built_fmus(fmu_dir: Path) -> dict[tuple[str, str], Path]:
    """{(model, fmi_version): path} for the test models, FMI 2.0 and 3.0."""
    out = {}
    for name, (class_name, source) in TEST_MODELS.items():
        model = build.load_model(class_name, source)
        for version in build.FMI_VERSIONS:
            out[name, version] = build.build_fmu(model, fmu_dir, version).path
    return out
