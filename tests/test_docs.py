"""The documentation site (docs/, Sphinx + MyST): it builds offline with warnings as errors, its generated pages
hold what the code ships (every field of the bundle JSON Schema, the TOML formats of the harness docstrings, the
API of the public modules), and its worked examples ran during the build and printed their results: the demo's
FMU step response against the closed form, and the lab example's output-error refit against the truth the
recordings were co-simulated from (labexample.TRUTH). The README stays short and its links into docs/ resolve.
"""
from __future__ import annotations

import html
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from motiontwin import labexample

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The docs built at smoke size (the demo's step response only), the examples in a private folder. Read on
    two processes (-j 2): the API pages' imports overlap the examples' commands; the pages come out the same as
    from a serial build except for the printed run times."""
    out = tmp_path_factory.mktemp("docs")
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q", "-j", "2",
                           "-D", "mt_smoke=1", "-D", f"mt_work_dir={out / 'work'}", str(ROOT / "docs"),
                           str(out / "html")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    print(f"docs built in {time.perf_counter() - start:.1f} s")
    return out / "html"


def page_text(site: Path, name: str) -> str:
    """The page's text without tags and entities."""
    return html.unescape(re.sub(r"<[^>]+>", "", (site / f"{name}.html").read_text(encoding="utf-8")))


def test_bundle_format_page_lists_every_schema_field(site: Path) -> None:
    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    from motiontwin_docs import schema_rows  # the docs' own extension renders the table from these rows

    schema = json.loads((ROOT / "ident" / "diagnosis" / "bundle.schema.json").read_text())
    text = page_text(site, "formats")
    rows = schema_rows(schema)
    assert {"plant.class", "plant.axes[].input", "controller.kind", "recordings.train"} <= {r[0] for r in rows}
    for path, _, _, _, description in rows:
        assert path in text, path
        assert " ".join(description.split()) in " ".join(text.split()), path
    from motiontwin.ident.bundleformat import BUNDLE_FORMAT

    assert " ".join(BUNDLE_FORMAT.split()) in " ".join(text.split())


def test_toml_formats_come_from_the_harness_docstrings(site: Path) -> None:
    from motiontwin.harness import experiment, regress, sweep, system

    text = " ".join(page_text(site, "formats").split())
    for module in (system, sweep, experiment, regress):
        block = re.search(r"::\n\n(.*?)(\n\S|\Z)", module.__doc__, flags=re.S).group(1)
        first_line = " ".join(block.strip().splitlines()[0].split())
        assert first_line in text, (module.__name__, first_line)


def test_api_reference_documents_the_public_functions(site: Path) -> None:
    page = (site / "api.html").read_text(encoding="utf-8")
    for name in ("motiontwin.api.identify_oe", "motiontwin.api.simulate", "motiontwin.fmus.build.build",
                 "motiontwin.harness.recording.Recording", "motiontwin.ident.outputerror.build_loop",
                 "motiontwin.ident.diagnosis.diagnose", "motiontwin.ident.oeloop.build_loop",
                 "motiontwin.ident.oefit.fit", "motiontwin.ident.diagnosis.engine.diagnose_bundle",
                 "motiontwin.ident.tuning.optimisation.tune", "motiontwin.fmus.flatmodel.FlatModel",
                 "motiontwin.fmus.files.atomic_path", "motiontwin.fmus.limits.limit",
                 "motiontwin.fmus.modelcache.fetch", "motiontwin.ident.benchmarks.single_axis.write_bundle"):
        assert f'id="{name}"' in page, name


def test_api_reference_lists_every_module() -> None:
    """docs/api.md names each module of fmus/, harness/ and ident/ (packages included) as the installed
    motiontwin.* module, and no module that is gone."""
    listed = set(re.findall(r"^\.\. automodule:: (\S+)$", (ROOT / "docs" / "api.md").read_text(), flags=re.M))
    shipped = {"motiontwin.api"}
    for layer in ("fmus", "harness", "ident"):
        for path in (ROOT / layer).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if "examples" in parts or parts[-1] == "__main__":
                continue
            shipped.add(".".join(("motiontwin",) + (parts[:-1] if parts[-1] == "__init__" else parts)))
    shipped -= {"motiontwin.fmus", "motiontwin.harness", "motiontwin.ident"}
    assert listed == shipped, (sorted(shipped - listed), sorted(listed - shipped))


def test_demo_ran_and_matches_the_closed_form(site: Path) -> None:
    text = page_text(site, "getting-started")
    errors = [float(e) for e in re.findall(r"FMI [23]\.0: max \|q_fmu - q_analytic\| = (\S+) m", text)]
    assert len(errors) == 2 and max(errors) < 1e-12
    assert any(p.name.startswith("step_response") for p in (site / "_images").iterdir())


def test_lab_example_ran_and_refits_the_truth(site: Path) -> None:
    text = page_text(site, "lab-example")
    assert "27300 samples, 0..27.299 s, columns q [m], r [m], u [N]" in text
    assert "dropped the last 3300 samples (3.3 s" in text
    refit = dict(re.findall(r"^\s+(m|d|Fc|F0)\s+(\S+)\s", text.split("identify oe", 1)[1], flags=re.M)[:4])
    truth = labexample.TRUTH
    for name in ("m", "d", "Fc", "F0"):
        assert float(refit[name]) == pytest.approx(truth[name], rel=0.02), name
    fit = float(re.search(r"on build/lab/axis_b.csv, closed loop, 27300 samples\s+fit (\S+) %", text).group(1))
    assert fit > 99.9
    assert any(p.name.startswith("validate") for p in (site / "_images").iterdir())


def test_readme_is_short_and_links_into_the_docs() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 200
    links = re.findall(r"\]\((docs/[^)#]+)(?:#[^)]*)?\)", text)
    assert len(links) >= 10
    for link in links:
        assert (ROOT / link).is_file(), link
    pages = {p.stem for p in (ROOT / "docs").glob("*.md")}
    assert {Path(link).stem for link in links if link.endswith(".md")} >= pages - {"index"}
