"""The layers point down only: fmus <- harness <- ident <- the application (motiontwin/: CLI, demo, comparison)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# What each library layer may import of the project (itself and the layers below it).
ALLOWED = {
    "fmus": {"motiontwin.fmus"},
    "harness": {"motiontwin.fmus", "motiontwin.harness"},
    "ident": {"motiontwin.fmus", "motiontwin.harness", "motiontwin.ident"},
}


def _project_imports(path: Path) -> set[str]:
    """The motiontwin modules a source file imports (at any depth: lazy imports count too)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.update(f"{node.module}.{alias.name}" if node.module == "motiontwin" else node.module
                         for alias in node.names)
    return {name for name in names if name == "motiontwin" or name.startswith("motiontwin.")}


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_library_layers_import_only_layers_below(layer: str) -> None:
    offending = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        for name in sorted(_project_imports(path)):
            if not any(name == allowed or name.startswith(allowed + ".") for allowed in ALLOWED[layer]):
                offending.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not offending, "\n".join(offending)


def test_the_layer_check_sees_a_forbidden_import(tmp_path: Path) -> None:
    """The checker itself: an upward import, lazy inside a function, is found."""
    source = tmp_path / "m.py"
    source.write_text("def f():\n    from motiontwin.ident import tuning\n    from motiontwin import cli\n")
    assert _project_imports(source) == {"motiontwin.ident", "motiontwin.cli"}
