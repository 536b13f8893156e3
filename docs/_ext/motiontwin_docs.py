"""Sphinx directives of the motiontwin docs: pages generated at build time from the shipped sources, so that
they cannot drift from the code.

``mt-run``
    Runs the shell commands of its content (as a user types them, ``.venv/bin/motiontwin ...``) in the
    examples folder (``mt_work_dir``, default ``build/docs-work``, with ``.venv`` linked to the interpreter
    that runs Sphinx), shows the commands and their printed output, and optionally a figure they wrote
    (``:figure: PATH`` relative to the examples folder). ``:smoke: COMMAND`` replaces the content when the
    build runs at smoke size (``-D mt_smoke=1``, as ``tests/test_docs.py`` does); ``:smoke: skip`` does not run
    it then and shows the output committed below a line ``----- committed output -----`` in the content
    instead (an example that takes minutes; the test suite runs its own smaller version). ``:hide-output:``
    runs without showing the output. A command that fails or exceeds ``:timeout:`` seconds (default 300) is a
    build error. Pages are read in parallel with ``-j N`` (each page's commands write their own folders under
    the examples folder: ``build/demo``, ``build/fmus``, ``build/lab``, ``build/ma``); the commands of one
    page run in order.
``mt-schema``
    A JSON Schema file (path relative to the repository) as a table of its fields: path, type, required,
    constraints, description.
``mt-constant``
    A module-level string constant (``module.NAME``) as a literal block.

Docstrings write absolute values and norms as ``|x|``; reStructuredText would read ``|x|`` as a substitution, so
:func:`escape_bars` escapes the bars outside literals before autodoc renders a docstring.
"""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = "----- committed output -----"


def _flag(value) -> bool:
    """A config flag given as a bool or as ``-D name=0/1`` text."""
    return str(value).strip().lower() not in ("", "0", "false", "no", "off")


def _literal(text: str, language: str = "none") -> nodes.literal_block:
    block = nodes.literal_block(text, text)
    block["language"] = language
    return block


def work_dir(config) -> Path:
    """The examples folder, with ``.venv`` pointing at the environment that runs the build."""
    folder = Path(config.mt_work_dir)
    folder = folder if folder.is_absolute() else ROOT / folder
    folder.mkdir(parents=True, exist_ok=True)
    venv = folder / ".venv"
    try:
        venv.symlink_to(Path(sys.prefix), target_is_directory=True)
    except FileExistsError:  # made earlier, or by another reader process of a parallel (-j) build
        pass
    return folder


class RunDirective(SphinxDirective):
    has_content = True
    option_spec = {"smoke": directives.unchanged, "figure": directives.unchanged, "hide-output": directives.flag,
                   "timeout": directives.positive_int}

    def run(self) -> list[nodes.Node]:
        config = self.env.config
        text, _, committed = "\n".join(self.content).partition(COMMITTED)
        text = text.strip()
        smoke = self.options.get("smoke", "").strip() if _flag(config.mt_smoke) else ""
        if smoke == "skip":
            return [_literal(text, "console"), _literal(committed.strip()),
                    nodes.paragraph(text="(output committed from an earlier run: `make docs` runs these commands)")]
        if smoke:
            text = smoke
        if not _flag(config.mt_execute):
            return [_literal(text, "console"), nodes.paragraph(text="(not executed: mt_execute is off)")]
        folder = work_dir(config)
        start = time.perf_counter()
        try:
            proc = subprocess.run(["bash", "-euo", "pipefail", "-c", text], cwd=folder, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, timeout=self.options.get("timeout", 300),
                                  env={**os.environ, "MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1"})
        except subprocess.TimeoutExpired:
            raise self.error(f"mt-run: timed out after {self.options.get('timeout', 300)} s: {text}")
        seconds = time.perf_counter() - start
        output = proc.stdout.rstrip()
        if proc.returncode != 0:
            raise self.error(f"mt-run: exit code {proc.returncode} from {text!r} in {folder}:\n{output}")
        self.env.note_dependency(__file__)
        result: list[nodes.Node] = [_literal(text, "console")]
        if "hide-output" not in self.options and output:
            result.append(_literal(output))
        result.append(nodes.paragraph(text=f"(run when these docs were built, {seconds:.0f} s)",
                                      classes=["mt-run-note"]))
        if "figure" in self.options:
            path = folder / self.options["figure"]
            if not path.is_file():
                raise self.error(f"mt-run: the commands wrote no {path}")
            docdir = Path(self.env.doc2path(self.env.docname)).parent
            result.append(nodes.image(uri=os.path.relpath(path, docdir), alt=self.options["figure"]))
        return result


def _type(schema: dict) -> str:
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[-1]
    kind = schema.get("type", "any")
    if kind == "array" and isinstance(schema.get("items"), dict):
        return f"array of {_type(schema['items'])}"
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        return f"object of {_type(schema['additionalProperties'])}"
    return kind


def _constraints(schema: dict) -> str:
    words = []
    for key in ("minLength", "minItems", "minimum", "exclusiveMinimum", "maximum", "enum", "const"):
        if key in schema:
            words.append(f"{key} {json.dumps(schema[key])}")
    if schema.get("additionalProperties") is False:
        words.append("no other fields")
    return ", ".join(words)


def schema_rows(schema: dict, prefix: str = "") -> list[tuple[str, str, str, str, str]]:
    """(path, type, required, constraints, description) of every property, depth first."""
    rows = []
    required = set(schema.get("required", ()))
    for name, sub in schema.get("properties", {}).items():
        path = f"{prefix}{name}"
        rows.append((path, _type(sub), "yes" if name in required else "", _constraints(sub),
                     sub.get("description", "")))
        rows += schema_rows(sub, path + ".")
        items = sub.get("items")
        if isinstance(items, dict) and "properties" in items:
            rows += schema_rows(items, path + "[].")
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ") if text else " "


class SchemaDirective(SphinxDirective):
    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        path = ROOT / self.arguments[0]
        self.env.note_dependency(str(path))
        schema = json.loads(path.read_text(encoding="utf-8"))
        lines = [f"**{schema.get('title', path.name)}** (`{self.arguments[0]}`, {schema.get('$schema', '')})", "",
                 schema.get("description", ""), "",
                 "| field | type | required | constraints | description |", "|---|---|---|---|---|"]
        lines += ["| " + " | ".join(_cell(c if i else f"`{c}`") for i, c in enumerate(row)) + " |"
                  for row in schema_rows(schema)]
        for name, sub in schema.get("$defs", {}).items():
            lines += ["", f"`{name}`: {_type(sub)}" + (f" of {_type(sub['items'])}" if "items" in sub and
                                                        sub.get("type") != "array" else "")]
        container = nodes.container()
        self.state.nested_parse(StringList(lines, source=str(path)), self.content_offset, container)
        return container.children


class ConstantDirective(SphinxDirective):
    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        module, _, name = self.arguments[0].rpartition(".")
        value = getattr(importlib.import_module(module), name)
        self.env.note_dependency(importlib.import_module(module).__file__)
        return [_literal(str(value).rstrip())]


def _escape_outside_literals(line: str) -> str:
    parts = line.split("``")
    return "``".join(part if i % 2 else part.replace("|", "\\|") for i, part in enumerate(parts))


def escape_bars(app, what, name, obj, options, lines: list[str]) -> None:
    """autodoc-process-docstring: ``|x|`` as text (not a substitution), except in literal blocks and literals."""
    literal_indent = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        indent = len(line) - len(line.lstrip())
        if literal_indent is not None:
            if not stripped or indent > literal_indent:
                continue
            literal_indent = None
        lines[i] = _escape_outside_literals(line)
        if stripped.endswith("::"):
            literal_indent = indent


def setup(app):
    app.connect("autodoc-process-docstring", escape_bars)
    app.add_config_value("mt_execute", True, "env")
    app.add_config_value("mt_smoke", False, "env")
    app.add_config_value("mt_work_dir", "build/docs-work", "env")
    app.add_directive("mt-run", RunDirective)
    app.add_directive("mt-schema", SchemaDirective)
    app.add_directive("mt-constant", ConstantDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
