"""Modelica front end: parse a Modelica class with pymoca and return it as a flat CasADi DAE.

pymoca does the parsing, flattening and translation to CasADi; this module adds what the
pipeline needs around it: errors that name file, line and column, the description strings and
vendor annotations that pymoca's CasADi model drops, array variables expanded to scalars
(``x[1]``, ``x[2]``, 1-based as in Modelica), and two compatibility fixes for casadi >= 3.7.
"""
from __future__ import annotations

import math
import os
import re
import types
from pathlib import Path
from typing import Any

import casadi as ca

from motiontwin.fmus import limits
from motiontwin.fmus.flatmodel import FlatModel, ModelicaError, Variable

for _cls in (ca.MX, ca.SX, ca.DM):  # pymoca 0.12 looks operators and Modelica built-ins up by these names
    _cls.__div__ = _cls.__truediv__
    _cls.atan, _cls.asin, _cls.acos = _cls.arctan, _cls.arcsin, _cls.arccos
    _cls.atan2 = _cls.__arctan2__


def _casadi_proxy() -> types.ModuleType:
    """casadi, but with Function names made valid (pymoca names functions ``Pkg.f``)."""

    class Proxy(types.ModuleType):
        def __getattr__(self, name: str) -> Any:
            return getattr(ca, name)

        @staticmethod
        def Function(name: Any, *args: Any, **kwargs: Any) -> ca.Function:  # noqa: N802 (casadi's name)
            if isinstance(name, str):
                name = re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_") or "f"
            return ca.Function(name, *args, **kwargs)

    return Proxy("casadi_for_pymoca")


def _import_pymoca() -> tuple[Any, Any, Any]:
    import pymoca.backends.casadi.generator as generator
    import pymoca.parser as parser
    from pymoca.backends.casadi import api

    if not isinstance(generator.ca, types.ModuleType) or generator.ca.__name__ != "casadi_for_pymoca":
        generator.ca = _casadi_proxy()
    return parser, api, generator


def _mo_text(path: Path, data: bytes | None = None) -> str:
    """The text of a Modelica file (``data``: its bytes, already read after :func:`_mo_bytes`); ModelicaError
    naming it when it is not UTF-8 or beyond the size limit."""
    if data is None:
        return limits.read_text(path, ModelicaError)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ModelicaError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None


def _mo_bytes(path: Path) -> bytes:
    """The bytes of a Modelica file within the text size limit (ModelicaError naming it otherwise)."""
    limits.check_size(path, "text", ModelicaError)
    return path.read_bytes()


def _mo_files(source: Path) -> list[Path]:
    if source.is_file():
        return [source]
    if not source.is_dir():
        raise ModelicaError(f"{source}: no such Modelica file or folder")
    return sorted(p for p in source.rglob("*.mo") if p.is_file())


def _source_files(source: Path, libraries: tuple[Path, ...]) -> list[Path]:
    """The ``.mo`` files of ``source`` (a file or a library folder), then those of ``libraries`` not among them."""
    files = _mo_files(source)
    if not files:
        raise ModelicaError(f"{source}: no .mo files found")
    return files + [f for lib in libraries for f in _mo_files(Path(lib)) if f not in files]


def parse_tree(source: Path, libraries: tuple[Path, ...] = ()) -> Any:
    """Parse every ``.mo`` file under ``source`` (a file or a library folder) and ``libraries`` into one tree."""
    return _parse_files({path: _mo_text(path) for path in _source_files(source, libraries)})


def _parse_files(texts: dict[Path, str]) -> Any:
    """One pymoca tree of the given files (path -> text); a syntax error names file, line and column."""
    parser, _, _ = _import_pymoca()
    tree = None
    for path, text in texts.items():
        try:
            parsed = parser.parse(text)
        except parser.ModelicaSyntaxError as exc:
            msg, info = exc.args[0], exc.args[1] if len(exc.args) > 1 else None
            line, col = (info[1], info[2] + 1) if info else ("?", "?")
            raise ModelicaError(f"{path}:{line}:{col}: syntax error: {msg}") from None
        except NotImplementedError as exc:
            raise ModelicaError(f"{path}: unsupported construct: {exc}") from None
        if parsed is None:
            raise ModelicaError(f"{path}: could not be parsed")
        if tree is None:
            tree = parsed
        else:
            tree.extend(parsed)
    return tree


_DEFINES = re.compile(r"\b(?:model|block|class|package|record|connector|type|function)\s+(\w+)")
_WORD = re.compile(r"[A-Za-z_]\w*")
_PROSE = re.compile(r'"(?:[^"\\]|\\.)*"|//[^\n]*|/\*.*?\*/', re.S)  # strings and comments


def _needed(texts: dict[Path, str], class_name: str) -> dict[Path, str]:
    """The files that may define ``class_name`` and, transitively, any name their text mentions.

    A superset by words outside strings and comments, so the tree holds every class the flattening looks up; the
    caller parses everything when it does not."""
    code = {path: _PROSE.sub(" ", text) for path, text in texts.items()}
    defines: dict[str, list[Path]] = {}
    for path, text in code.items():
        for name in set(_DEFINES.findall(text)):
            defines.setdefault(name, []).append(path)
    wanted: set[Path] = set()
    todo, seen = class_name.split("."), set()
    while todo:
        word = todo.pop()
        if word in seen:
            continue
        seen.add(word)
        for path in defines.get(word, ()):
            if path not in wanted:
                wanted.add(path)
                todo.extend(set(_WORD.findall(code[path])))
    return {path: text for path, text in texts.items() if path in wanted}


def _find_class(tree: Any, name: str) -> Any:
    node = tree
    for part in name.split("."):
        classes = getattr(node, "classes", {})
        if part not in classes:
            return None
        node = classes[part]
    return node


_UNSUPPORTED = ("when", "sample", "pre", "noEvent", "smooth", "delay", "algorithm", "initial equation")


def _explain_unsupported(text: str) -> str:
    found = [w for w in _UNSUPPORTED if re.search(rf"\b{w}\b", text)]
    return f" (the front end does not support: {', '.join(found)})" if found else ""


def _annotation(cls: Any) -> dict[str, Any]:
    """Vendor annotation ``__motiontwin(...)`` of a class, as nested dicts of strings."""

    def walk(mod: Any) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for arg in getattr(mod, "arguments", []) or []:
            value = getattr(arg, "value", None)
            comp = getattr(value, "component", None)
            if comp is None:
                continue
            key = comp.name
            mods = getattr(value, "modifications", []) or []
            if mods and hasattr(mods[0], "arguments"):
                out[key] = walk(mods[0])
            elif mods:
                item = mods[0]
                out[key] = getattr(item, "value", None) if hasattr(item, "value") else getattr(item, "name", None)
            else:
                out[key] = True
        return out

    ann = walk(getattr(cls, "annotation", None))
    return ann.get("__motiontwin", {}) if isinstance(ann.get("__motiontwin"), dict) else {}


def _descriptions(tree: Any, class_name: str) -> tuple[str, dict[str, str]]:
    """Class description and per-variable description strings from the flattened pymoca AST."""
    import pymoca.ast
    import pymoca.tree

    flat = pymoca.tree.flatten(tree, pymoca.ast.ComponentRef.from_string(class_name))
    cls = flat.classes.get(class_name) or next(iter(flat.classes.values()))
    comments = {name: (sym.comment or "").strip().strip('"') for name, sym in cls.symbols.items()}
    return (cls.comment or "").strip().strip('"'), comments


def _scalar_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """Modelica names of the scalars of an array, in CasADi's column-major order: x[1], A[1,1], A[2,1], ..."""
    rows, cols = (int(shape[0]), int(shape[1])) if len(shape) == 2 else (int(shape[0]), 1)
    if rows * cols == 1:
        return [name]
    if cols == 1:
        return [f"{name}[{i + 1}]" for i in range(rows)]
    return [f"{name}[{i + 1},{j + 1}]" for j in range(cols) for i in range(rows)]


def _as_list(value: Any, n: int) -> list[Any]:
    """Attribute values of an array's scalars (column-major), broadcasting a scalar attribute."""
    if isinstance(value, (list, tuple)):
        if value and isinstance(value[0], (list, tuple)):  # a matrix given row by row
            return [value[i][j] for j in range(len(value[0])) for i in range(len(value))]
        return list(value)
    if isinstance(value, (ca.MX, ca.SX, ca.DM)) and value.numel() == n and n > 1:
        return [value[i] for i in range(n)]
    return [value] * n


def _number(value: Any, default: float) -> float:
    if isinstance(value, (int, float)) and not (isinstance(value, float) and math.isnan(value)):
        return float(value)
    if isinstance(value, ca.DM) or (isinstance(value, (ca.MX, ca.SX)) and value.is_constant()):
        return float(ca.DM(value))
    return default


def load(source: str | os.PathLike[str], class_name: str, libraries: tuple[Path, ...] = ()) -> FlatModel:
    """Translate Modelica class ``class_name`` found under ``source`` (using ``libraries``) into a FlatModel.

    The result is cached by the contents of the source files (:mod:`fmus.modelcache`); on a miss only the
    files the class needs are parsed (all of them when that subset does not flatten, for the same errors)."""
    from motiontwin.fmus import flatmodel, modelcache

    source = Path(source)
    libraries = tuple(Path(lib) for lib in libraries)
    files = _source_files(source, libraries)
    data = {path: _mo_bytes(path) for path in files}
    roots = [source.parent if source.is_file() else source, *libraries]
    named = [(_relative_name(path, roots), raw) for path, raw in data.items()]
    digest = modelcache.key(named, class_name, [Path(__file__), Path(flatmodel.__file__), Path(modelcache.__file__)])
    model = modelcache.fetch(digest, source)
    if model is None:
        texts = {path: _mo_text(path, raw) for path, raw in data.items()}
        subset = _needed(texts, class_name) or texts
        try:
            model = _flatten(source, class_name, _parse_files(subset))
        except ModelicaError:
            if len(subset) == len(texts):
                raise
            model = _flatten(source, class_name, _parse_files(texts))
        modelcache.store(digest, model)
    return model


def _relative_name(path: Path, roots: list[Path]) -> str:
    """``path`` relative to the first of ``roots`` holding it, prefixed by that root's index (the cache key's name)."""
    index, root = next((i, r) for i, r in enumerate(roots) if r in path.parents)
    return f"{index}/{path.relative_to(root).as_posix()}"


def _flatten(source: Path, class_name: str, tree: Any) -> FlatModel:
    """The FlatModel of ``class_name`` in a parsed ``tree``."""
    _, api, _ = _import_pymoca()
    cls = _find_class(tree, class_name)
    if cls is None:
        raise ModelicaError(f"{source}: class {class_name!r} not found")
    try:
        model = api.generate_model(tree, class_name, {"replace_constants": True, "check_balanced": False})
        description, comments = _descriptions(tree, class_name)
    except Exception as exc:  # pymoca raises bare Exceptions and NotImplementedErrors
        text = _class_text(source, class_name)
        raise ModelicaError(
            f"{source}: class {class_name}: the front end failed: {exc}{_explain_unsupported(text)}"
        ) from None
    if model.initial_equations:
        raise ModelicaError(f"{source}: class {class_name}: initial equations are not supported; use start values")
    return _to_sx(model, class_name, description, comments, source, _annotation(cls))


def _class_text(source: Path, class_name: str) -> str:
    short = class_name.split(".")[-1]
    for path in _mo_files(source):
        text = _mo_text(path)
        if re.search(rf"\b(model|block|class)\s+{re.escape(short)}\b", text):
            return text
    return ""


def _to_sx(model: Any, name: str, description: str, comments: dict[str, str], source: Path,
           annotation: dict[str, Any]) -> FlatModel:
    """Expand pymoca's MX model into scalar SX symbols (the form code generation and AD prefer)."""
    groups = {g: list(getattr(model, g)) for g in ("states", "der_states", "alg_states", "inputs", "parameters")}
    mx_syms: list[ca.MX] = []
    sx_syms: list[ca.SX] = []
    scalars: dict[str, list[Variable]] = {g: [] for g in groups}
    first: dict[int, int] = {}  # id(pymoca variable) -> index of its first scalar in its group
    for group, variables in groups.items():
        for var in variables:
            sym = var.symbol
            names = _scalar_names(sym.name(), sym.shape)
            shaped = ca.SX.sym(sym.name(), *sym.shape)
            mx_syms.append(sym)
            sx_syms.append(shaped)
            first[id(var)] = len(scalars[group])
            for i, (scalar, symbol) in enumerate(zip(names, ca.vertsplit(ca.vec(shaped)))):
                scalars[group].append(Variable(
                    name=scalar,
                    symbol=symbol,
                    description=comments.get(sym.name(), ""),
                    unit=getattr(var, "unit", "") or "",
                    min=_number(_as_list(var.min, len(names))[i], -math.inf),
                    max=_number(_as_list(var.max, len(names))[i], math.inf),
                    nominal=(_number(_as_list(var.nominal, len(names))[i], 0.0) or None),
                ))
    for der, state in zip(scalars["der_states"], scalars["states"]):
        der.name = f"der({state.name})"
    time_sx = ca.SX.sym("time")
    residual_mx = ca.vertcat(*[ca.vec(e) for e in model.equations]) if model.equations else ca.MX(0, 1)
    to_sx = ca.Function("to_sx", [model.time, *mx_syms], [residual_mx] + _start_exprs(groups), {"allow_free": True})
    if to_sx.has_free():
        raise ModelicaError(f"{source}: class {name}: equations use undeclared symbols {to_sx.get_free()}")
    out = to_sx.expand()(time_sx, *sx_syms)
    residual = ca.simplify(out[0])
    starts = iter(out[1:])  # start values (values for parameters), in the order of _start_exprs
    for group in ("states", "alg_states", "inputs", "parameters"):
        for var in groups[group]:
            expr = next(starts)
            for i in range(expr.numel()):
                e = expr[i]
                scalars[group][first[id(var)] + i].start = float(ca.DM(e)) if e.is_constant() else e
    return _split_parameters(FlatModel(
        name=name,
        description=description,
        source=source,
        states=scalars["states"],
        der_states=[v.symbol for v in scalars["der_states"]],
        algebraics=scalars["alg_states"],
        inputs=scalars["inputs"],
        parameters=scalars["parameters"],
        calculated=[],
        outputs=_expand_outputs(model, scalars),
        residual=residual,
        time=time_sx,
        annotation=annotation,
    ))


def _start_exprs(groups: dict[str, list[Any]]) -> list[ca.MX]:
    """Start values (states, algebraics, inputs) and values (parameters) as MX, one vector per variable."""
    exprs = []
    for group in ("states", "alg_states", "inputs", "parameters"):
        for var in groups[group]:
            n = var.symbol.numel()
            raw = var.value if group == "parameters" else var.start
            items = _as_list(raw, n)
            exprs.append(ca.vertcat(*[_mx_value(x) for x in items]))
    return exprs


def _mx_value(x: Any) -> ca.MX:
    if isinstance(x, ca.MX):
        return x
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ca.MX(math.nan)
    return ca.MX(float(x))


def _expand_outputs(model: Any, scalars: dict[str, list[Variable]]) -> list[str]:
    names = {v.name for g in ("states", "alg_states") for v in scalars[g]}
    out: list[str] = []
    for base in model.outputs:
        matching = [n for n in sorted(names, key=_natural) if n == base or n.startswith(base + "[")]
        out.extend(matching)
    return out


def _natural(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _split_parameters(model: FlatModel) -> FlatModel:
    """Separate numeric parameters from parameters bound to expressions of others; substitute the latter."""
    free = [p for p in model.parameters if isinstance(p.start, float) and not math.isnan(p.start)]
    bound = [p for p in model.parameters if not (isinstance(p.start, float))]
    missing = [p.name for p in model.parameters if isinstance(p.start, float) and math.isnan(p.start)]
    if missing:
        raise ModelicaError(f"{model.source}: class {model.name}: parameters without a value: {', '.join(missing)}")
    if bound:
        syms = ca.vertcat(*[p.symbol for p in bound])
        exprs = ca.vertcat(*[p.start for p in bound])
        for _ in range(len(bound)):  # resolve chains of bound parameters
            if not ca.depends_on(exprs, syms):
                break
            exprs = ca.substitute(exprs, syms, exprs)
        if ca.depends_on(exprs, syms):
            raise ModelicaError(f"{model.source}: class {model.name}: cyclic parameter bindings among "
                                + ", ".join(p.name for p in bound))
        model.residual = ca.substitute(model.residual, syms, exprs)
        for v in model.states + model.algebraics + model.inputs:
            if isinstance(v.start, ca.SX):
                v.start = ca.substitute(v.start, syms, exprs)
        model.calculated = [(p, exprs[i]) for i, p in enumerate(bound)]
    model.parameters = _used(free, model)
    return model


def _used(parameters: list[Variable], model: FlatModel) -> list[Variable]:
    """Parameters some equation, start value or calculated parameter uses; the others only sized arrays."""
    exprs = [model.residual] + [v.start for v in model.states + model.algebraics if isinstance(v.start, ca.SX)]
    exprs += [expr for _, expr in model.calculated]
    names = {str(s) for e in exprs for s in ca.symvar(e)}
    sampled = model.annotation.get("sampled")
    period = str(sampled.get("period", "Ts")) if isinstance(sampled, dict) else None
    return [p for p in parameters if str(p.symbol) in names or p.name == period]
