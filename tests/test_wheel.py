"""The installed product: a wheel of the project, installed into a fresh venv, works outside the checkout.

``pip wheel`` builds the wheel, a fresh venv (no pip of its own) gets it with ``pip --python``, and from a
folder outside the checkout ``motiontwin build`` of a library class, ``motiontwin demo`` and
``import motiontwin`` run there. Only what the wheel carries can be used: the checkout is never on the path.

The dependencies: by default the fresh venv sees the ones already installed for the test run (one ``.pth``
line, so the third-party packages are not unpacked again: ~10 s instead of ~100-120 s on 2 shared cores),
and ``pip check`` proves that they satisfy what the wheel declares. ``MOTIONTWIN_WHEEL_DEPS=install``
installs them from the local pip cache into the fresh venv instead (fully isolated, ~2 min more).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Checkout folder -> where it lands in the wheel (pyproject.toml [tool.setuptools.package-dir]).
INSTALLED_AS = {"motiontwin": "motiontwin", "fmus": "motiontwin/fmus", "harness": "motiontwin/harness",
                "ident": "motiontwin/ident", "modelica": "motiontwin/modelica"}
# Tracked files of the package folders that are documentation, not product: the README's figures.
NOT_SHIPPED = re.compile(r"^harness/examples/figures/.*\.png$")
# The demo's step response against the closed form, and its diagnosis against the concealed truth.
STEP_RESPONSE_TOLERANCE = 1e-9  # m
FRICTION_RELATIVE_TOLERANCE = 0.05


def _run(command: list[str], cwd: Path, env: dict[str, str], timeout: float) -> str:
    """Run a command, fail the test with its output when it fails; return its stdout."""
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(command)} exited {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done.stdout


def _tracked_package_files() -> list[str]:
    """The files git tracks in the folders that make up the installed package (checkout-relative)."""
    listing = subprocess.run(["git", "ls-files", *INSTALLED_AS], cwd=ROOT, capture_output=True, text=True,
                             check=True, timeout=300).stdout
    return [name for name in listing.splitlines() if not NOT_SHIPPED.match(name)]


def _wheel_name(checkout_name: str) -> str:
    top, _, rest = checkout_name.partition("/")
    return f"{INSTALLED_AS[top]}/{rest}"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project's wheel, built by ``pip wheel`` from a copy of the checkout's files (tracked or new, not
    ignored): setuptools builds in the source tree, and a stale ``build/lib`` there would end up in it."""
    source = tmp_path_factory.mktemp("source")
    listing = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, text=True, check=True, timeout=300).stdout
    for name in filter(None, listing.split("\0")):
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    out = tmp_path_factory.mktemp("wheel")
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(out), str(source)],
         cwd=out, env=env, timeout=300)
    (path,) = out.glob("motiontwin-*.whl")
    return path


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str], Path]:
    """(venv bin folder, environment, working folder outside the checkout) with the wheel installed."""
    venv = tmp_path_factory.mktemp("venv")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", "--clear", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    pip = [sys.executable, "-m", "pip", "--python", str(python)]
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", MPLBACKEND="Agg")
    if os.environ.get("MOTIONTWIN_WHEEL_DEPS") == "install":
        _run([*pip, "install", "--quiet", str(wheel)], cwd=venv, env=env, timeout=1200)
    else:
        _run([*pip, "install", "--quiet", "--no-deps", str(wheel)], cwd=venv, env=env, timeout=300)
        site_packages = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                  cwd=venv, env=env, timeout=60).strip())
        (site_packages / "motiontwin_test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([*pip, "check"], cwd=venv, env=env, timeout=120)
    print(f"fresh venv with the wheel: {time.perf_counter() - start:.1f} s")
    work = tmp_path_factory.mktemp("outside")
    assert ROOT not in work.parents
    return venv / "bin", env, work


def test_wheel_installs_only_under_the_motiontwin_name_and_carries_every_package_file(wheel: Path) -> None:
    """Nothing generic at the top of site-packages; every tracked source and data file (Modelica library,
    C runtime, native loop, chain driver, experiments) is in the wheel at its mapped place."""
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    tops = {name.split("/", 1)[0] for name in names}
    assert {top for top in tops if not top.endswith(".dist-info")} == {"motiontwin"}, tops
    missing = sorted(name for name in _tracked_package_files() if _wheel_name(name) not in names)
    assert not missing, "tracked files missing from the wheel (pyproject.toml packages/package-data):\n" + \
        "\n".join(missing)
    assert any(name.endswith(".mo") for name in names) and "motiontwin/fmus/runtime/mt_runtime.c" in names


def test_installed_wheel_imports_from_its_own_site_packages(installed: tuple[Path, dict[str, str], Path]) -> None:
    bin_dir, env, work = installed
    where = _run([str(bin_dir / "python"), "-c", "import motiontwin; print(motiontwin.__file__)"],
                 cwd=work, env=env, timeout=60).strip()
    assert Path(where).is_relative_to(bin_dir.parent), where
    for generic in ("fmus", "harness", "ident"):
        found = _run([str(bin_dir / "python"), "-c",
                      f"import importlib.util; print(importlib.util.find_spec('{generic}') is None)"],
                     cwd=work, env=env, timeout=60).strip()
        assert found == "True", f"a top-level '{generic}' package is importable in the fresh venv"


def test_installed_wheel_builds_a_library_class(installed: tuple[Path, dict[str, str], Path]) -> None:
    """``motiontwin build`` finds the Modelica library and the C runtime in the installed package; the FMU
    it makes has the class's variables and simulates the closed-form free response."""
    bin_dir, env, work = installed
    out = _run([str(bin_dir / "motiontwin"), "build", "MotionTwin.Plants.LinearMotorJoint", "--fmi", "3.0"],
               cwd=work, env=env, timeout=600)
    fmu = work / out.strip().splitlines()[-1]
    assert fmu.is_file() and fmu.suffix == ".fmu", out
    with zipfile.ZipFile(fmu) as archive:
        description = archive.read("modelDescription.xml").decode()
    assert 'fmiVersion="3.0"' in description and 'name="q"' in description


def test_installed_wheel_runs_the_demo(installed: tuple[Path, dict[str, str], Path]) -> None:
    """``motiontwin demo`` end to end outside the checkout: the FMUs' step responses match the closed form
    and the diagnosis finds the concealed Coulomb friction at the value the bundle's truth file holds."""
    bin_dir, env, work = installed
    out = _run([str(bin_dir / "motiontwin"), "demo", "--out", "demo"], cwd=work, env=env, timeout=900)
    errors = [float(value) for value in re.findall(r"max \|q_fmu - q_analytic\| = (\S+) m", out)]
    assert len(errors) == 2 and max(errors) < STEP_RESPONSE_TOLERANCE, out
    truth = json.loads((work / "demo" / "bundle" / "coulomb_friction.truth.json").read_text())
    found = re.search(r"found coulomb_friction \{'Fc': ([0-9.eE+-]+)\}", out)
    assert found, out
    true_fc = truth["truth_model"]["parameters"]["Fc"]
    assert abs(float(found.group(1)) - true_fc) <= FRICTION_RELATIVE_TOLERANCE * true_fc, (found.group(1), truth)
    assert (work / "demo" / "diagnosis" / "report.md").is_file()

