"""The layers point down only: fmus <- harness <- ident <- the application (motiontwin/: CLI, demo, comparison)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Library modules that may parse a command line: scripts run with ``python -m``, not library API.
ARGPARSE_ALLOWED = {
    "harness/examples/joint_bode.py": "example script (python -m motiontwin.harness.examples.joint_bode)",
    "ident/diagnosis/benchmark.py": "benchmark script (python -m motiontwin.ident.diagnosis.benchmark)",
    "ident/diagnosis/benchmark_multiaxis.py": "benchmark script (python -m motiontwin.ident.diagnosis.benchmark_multiaxis)",
    "ident/diagnosis/__init__.py": "python -m motiontwin.ident.diagnosis; the diagnosis work moves it to the app",
}
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


def _argparse_uses(path: Path) -> list[str]:
    """Where a source file imports argparse or has a function taking parsed arguments: a parameter annotated
    ``Namespace`` or a parameter ``args`` whose attributes it reads (``args.out``)."""
    found = []
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(alias.name == "argparse" for alias in node.names) or \
                isinstance(node, ast.ImportFrom) and node.module == "argparse":
            found.append(f"line {node.lineno}: imports argparse")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            parameters = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
            for parameter in parameters:
                annotated = parameter.annotation is not None and "Namespace" in ast.unparse(parameter.annotation)
                reads_args = parameter.arg == "args" and any(
                    isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id == "args"
                    for sub in ast.walk(node))
                if annotated or reads_args:
                    found.append(f"line {node.lineno}: {node.name}({parameter.arg}) takes parsed arguments")
    return found


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_library_functions_take_typed_arguments_not_argparse(layer: str) -> None:
    """argparse lives in motiontwin/cli/: library functions take typed values (exceptions: ARGPARSE_ALLOWED)."""
    offending = [f"{path.relative_to(ROOT)} {use}" for path in sorted((ROOT / layer).rglob("*.py"))
                 if str(path.relative_to(ROOT)) not in ARGPARSE_ALLOWED for use in _argparse_uses(path)]
    assert not offending, "\n".join(offending)


def test_every_argparse_exception_still_parses_a_command_line() -> None:
    """The exception list does not outlive the scripts it names."""
    stale = [name for name in ARGPARSE_ALLOWED if not (ROOT / name).is_file() or not _argparse_uses(ROOT / name)]
    assert not stale, stale


def test_the_argparse_check_sees_parsed_arguments(tmp_path: Path) -> None:
    """The checker itself: a lazy argparse import, an annotated Namespace and an untyped ``args.x`` are found."""
    source = tmp_path / "m.py"
    source.write_text("def f(args):\n    return args.out\n\n"
                      "def g(ns: 'argparse.Namespace') -> None:\n    import argparse\n\n"
                      "def h(*args):\n    return len(args)\n")
    assert _argparse_uses(source) == ["line 1: f(args) takes parsed arguments",
                                      "line 4: g(ns) takes parsed arguments", "line 5: imports argparse"]
