"""Shared fixtures: FMUs built once per test session by the project's own pipeline."""
from __future__ import annotations

import os
import subprocess
import sys
import zipfile
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


GEMSEO_FMU_WHEEL = "gemseo-fmu==3.1.1"


@pytest.fixture(scope="session")
def gemseo_fmus(request: pytest.FixtureRequest) -> Path:
    """Folder with the Linux FMUs of the gemseo-fmu wheel (``MOTIONTWIN_TEST_FMUS`` if set, else
    ``pip download gemseo-fmu --no-deps`` once into the pytest cache)."""
    given = os.environ.get("MOTIONTWIN_TEST_FMUS")
    if given:
        return Path(given)
    folder = Path(request.config.cache.mkdir("gemseo_fmus"))
    if not (folder / "add.fmu").is_file():
        subprocess.run([sys.executable, "-m", "pip", "download", GEMSEO_FMU_WHEEL, "--no-deps",
                        "--quiet", "-d", str(folder)], check=True)
        wheel = next(folder.glob("gemseo_fmu-*.whl"))
        prefix = "gemseo_fmu/problems/fmu_files/linux/"
        with zipfile.ZipFile(wheel) as zf:
            for name in zf.namelist():
                if name.startswith(prefix) and name.endswith(".fmu"):
                    (folder / Path(name).name).write_bytes(zf.read(name))
    return folder
