"""The layers point down only: fmus <- harness <- ident <- the application (motiontwin/: CLI, demo, comparison)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Library modules that may parse a command line: scripts run with ``python -m``, not library API.
ARGPARSE_ALLOWED = {
    "harness/examples/joint_bode.py": "example script (python -m motiontwin.harness.examples.joint_bode)",
    "ident/benchmarks/single_axis.py": "benchmark script (python -m motiontwin.ident.benchmarks.single_axis)",
    "ident/benchmarks/multi_axis.py": "benchmark script (python -m motiontwin.ident.benchmarks.multi_axis)",
    "ident/benchmarks/independent.py": "benchmark script (python -m motiontwin.ident.benchmarks.independent)",
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


LAYER_PACKAGES = {"fmus": "motiontwin.fmus", "harness": "motiontwin.harness", "ident": "motiontwin.ident",
                  "motiontwin": "motiontwin"}


def _module_name(root: Path, path: Path) -> str:
    """The import name of a source file of the checkout (``ident/diagnosis/bundle.py`` ->
    ``motiontwin.ident.diagnosis.bundle``, a package's ``__init__.py`` -> the package)."""
    rel = path.relative_to(root)
    parts = [LAYER_PACKAGES[rel.parts[0]], *rel.parts[1:-1]] + ([] if rel.stem == "__init__" else [rel.stem])
    return ".".join(parts)


def import_graph(root: Path, layers: dict[str, str] = LAYER_PACKAGES) -> dict[str, set[str]]:
    """Module -> the project modules it imports (lazy imports too; ``from package import module`` is an edge to
    the module, ``from module import name`` to the module)."""
    files = {_module_name(root, path): path for layer in layers if (root / layer).is_dir()
             for path in (root / layer).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets.update(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in files else node.module
                               for alias in node.names)
        graph[name] = {t for t in targets if t in files and t != name}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every import cycle, as the modules of one strongly connected component (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while not component or component[-1] != node:
                component.append(stack.pop())
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(cycles)


def test_no_import_cycles_between_modules() -> None:
    """The project's modules import each other without circles (lazy imports included)."""
    assert import_cycles(import_graph(ROOT)) == []


def test_the_cycle_check_sees_a_planted_cycle(tmp_path: Path) -> None:
    """The checker itself: a -> b lazily, b -> c, c -> a is one cycle; d -> a is not part of it."""
    package = tmp_path / "ident"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("def f():\n    from motiontwin.ident import b\n")
    (package / "b.py").write_text("from motiontwin.ident.c import g\n")
    (package / "c.py").write_text("import motiontwin.ident.a\ndef g():\n    pass\n")
    (package / "d.py").write_text("from motiontwin.ident import a\n")
    graph = import_graph(tmp_path)
    assert graph["motiontwin.ident.d"] == {"motiontwin.ident.a"}
    assert import_cycles(graph) == [["motiontwin.ident.a", "motiontwin.ident.b", "motiontwin.ident.c"]]


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


MAX_LINES = 600


def test_no_source_file_holds_more_than_one_idea_by_size() -> None:
    """No Python file of the library or the application is over 600 lines (issue 24: split it by idea)."""
    files = [p for folder in ("fmus", "harness", "ident", "motiontwin") for p in (ROOT / folder).rglob("*.py")]
    long = {str(p.relative_to(ROOT)): n for p in files
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert files and long == {}
