"""Shared fixtures: FMUs built once per test session by the project's own pipeline."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import threadpoolctl

import motiontwin.cli  # noqa: F401  first: one BLAS thread per process, as the command (and its subprocesses) run
from motiontwin.fmus import build
from tests.fmi_util import gemseo_fmu_folder

os.environ.setdefault("MOTIONTWIN_DIAGNOSIS_WORKERS", "1")  # pytest-xdist already runs a test process per core
threadpoolctl.threadpool_limits(1)   # numpy loaded before motiontwin.cli set the variables: limit it here too
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


@pytest.fixture(scope="session")
def gemseo_fmus(request: pytest.FixtureRequest) -> Path:
    """Folder with the Linux FMUs of the gemseo-fmu wheel (``MOTIONTWIN_TEST_FMUS`` if set, else
    downloaded once into the pytest cache)."""
    given = os.environ.get("MOTIONTWIN_TEST_FMUS")
    return Path(given) if given else gemseo_fmu_folder(Path(request.config.cache.mkdir("gemseo_fmus")))
