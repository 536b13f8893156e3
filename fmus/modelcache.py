"""The front end's flattened models cached across calls, keyed by the contents of the Modelica sources.

Parsing and flattening a class with pymoca takes about a second, once per command; the result depends
only on the source files, the class, the front end's own code and the pymoca and CasADi versions, so it is
stored under ``$XDG_CACHE_HOME/motiontwin/flat`` as JSON: one serialised CasADi function from every symbol
of the model to its expressions (residual, start values, calculated parameters) beside the variables'
names and attributes. Loading rebuilds fresh SX symbols and evaluates that function on them. An entry is
written atomically; one that cannot be read (truncated, another format) is ignored and rebuilt.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Any

import casadi as ca

from motiontwin.fmus.clib import cache_dir
from motiontwin.fmus.flatmodel import FlatModel, Variable

FORMAT = 1
FOLDER = "flat"
_GROUPS = ("states", "algebraics", "inputs", "parameters")


def key(files: list[tuple[str, bytes]], class_name: str, code: list[Path]) -> str:
    """sha256 of the sources (relative name and bytes), the class, the front end's code and the versions."""
    digest = hashlib.sha256(f"{FORMAT}\0{class_name}\0{ca.__version__}\0{metadata.version('pymoca')}".encode())
    for path in code:
        digest.update(b"\0" + path.read_bytes())
    for name, data in files:
        digest.update(b"\0" + name.encode() + b"\0" + hashlib.sha256(data).digest())
    return digest.hexdigest()


def _entry(digest: str) -> Path:
    return cache_dir(FOLDER) / f"{digest[:32]}.json"


def _symbols(model: FlatModel) -> list[ca.SX]:
    return [model.time, *model.der_states, *(v.symbol for v in _variables(model))]


def _variables(model: FlatModel) -> list[Variable]:
    return [*(v for g in _GROUPS for v in getattr(model, g)), *(v for v, _ in model.calculated)]


def _expressions(model: FlatModel) -> list[ca.SX]:
    starts = [v.start for v in _variables(model) if isinstance(v.start, ca.SX)]
    return [model.residual, *starts, *(expr for _, expr in model.calculated)]


def _variable_doc(v: Variable) -> dict[str, Any]:
    doc = {k: val for k, val in asdict(v).items() if k != "symbol"}
    doc["start"] = "expr" if isinstance(v.start, ca.SX) else v.start
    return doc


def store(digest: str, model: FlatModel) -> None:
    """Write ``model`` under ``digest`` atomically; a model the format cannot hold is not cached."""
    try:
        symbols = _symbols(model)
        fn = ca.Function("flat", [ca.vertcat(*symbols)], _expressions(model))
        doc = {"format": FORMAT, "function": fn.serialize(), "symbols": [s.name() for s in symbols],
               "name": model.name, "description": model.description, "outputs": model.outputs,
               "annotation": model.annotation, "der_states": len(model.der_states),
               "calculated": [_variable_doc(v) for v, _ in model.calculated],
               **{g: [_variable_doc(v) for v in getattr(model, g)] for g in _GROUPS}}
        text = json.dumps(doc)
    except (RuntimeError, TypeError, ValueError):  # free symbols outside the model, a non-JSON annotation
        return
    try:
        folder = cache_dir(FOLDER)
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            (Path(tmp) / "entry").write_text(text, encoding="utf-8")
            os.replace(Path(tmp) / "entry", _entry(digest))
    except OSError:  # a read-only or full cache only costs the next call a parse
        return


def fetch(digest: str, source: Path) -> FlatModel | None:
    """The model cached under ``digest`` (its ``source`` set to the caller's), or None if absent or unreadable."""
    try:
        doc = json.loads(_entry(digest).read_text(encoding="utf-8"))
        if doc.get("format") != FORMAT:
            return None
        return _rebuild(doc, source)
    except (OSError, ValueError, KeyError, TypeError, IndexError, RuntimeError, StopIteration):
        return None


def _rebuild(doc: dict[str, Any], source: Path) -> FlatModel:
    symbols = [ca.SX.sym(name) for name in doc["symbols"]]
    fn = ca.Function.deserialize(doc["function"])
    outputs = fn(ca.vertcat(*symbols)) if fn.n_out() > 1 else [fn(ca.vertcat(*symbols))]
    residual, exprs = outputs[0], iter(outputs[1:])
    syms = iter(symbols)
    time = next(syms)
    der_states = [next(syms) for _ in range(doc["der_states"])]

    def variable(item: dict[str, Any]) -> Variable:
        start = next(exprs) if item["start"] == "expr" else item["start"]
        return Variable(**{**item, "symbol": next(syms), "start": start})

    groups = {g: [variable(item) for item in doc[g]] for g in _GROUPS}
    bound = [variable(item) for item in doc["calculated"]]
    calculated = [(v, next(exprs)) for v in bound]
    if next(syms, None) is not None or next(exprs, None) is not None:
        raise ValueError("cache entry does not match its symbols")
    return FlatModel(name=doc["name"], description=doc["description"], source=source,
                     der_states=der_states, calculated=calculated, outputs=doc["outputs"], residual=residual,
                     time=time, annotation=doc["annotation"], **groups)
