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
#: the slowest test files, longest first (per-file sums of ``pytest --durations=0`` on 2 cores, session 37, 20-70 s
#: each): collected first, so that pytest-xdist's per-file scheduling (``--dist loadfile`` hands out files in
#: collection order) does not end with one worker running a long file while the other idles. Order only.
SLOWEST_FIRST = ("test_benchmarks_smoke.py", "test_real_recordings.py", "test_diagnosis_decisions.py",
                 "test_diagnosis_new_effects.py", "test_diagnosis_start_state.py", "test_diagnosis_multiaxis.py",
                 "test_diagnosis_polish.py", "test_diagnosis_combination.py", "test_docs.py", "test_tuning_refine.py",
                 "test_wheel.py", "test_diagnosis_fleet.py", "test_diagnosis.py", "test_diagnosis_api.py", "test_cli.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    missing = set(SLOWEST_FIRST) - {path.name for path in Path(__file__).parent.glob("test_*.py")}
    if missing:
        raise pytest.UsageError(f"tests/conftest.py: SLOWEST_FIRST names files that do not exist: {sorted(missing)}")
    rank = {name: k for k, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: files and tests keep their order


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
