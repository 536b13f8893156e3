"""The front end's cache of flattened models (fmus.modelcache) and its lazy start-up.

Every test runs on its own empty cache (``XDG_CACHE_HOME`` in a tmp folder), so none depends on a warm
one. The reference is a fresh parse: the cached model's CasADi functions must give the same numbers at
random points, and a changed, corrupt or broken source must behave as without a cache.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import build, frontend, modelcache, symbolic

CALC = """model Calc "a model with what the cache must carry"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "moving mass";
  parameter Real d(min = 0, max = 50) = 3;
  parameter Real w = sqrt(d / m) "a calculated parameter";
  parameter Real c[2] = {1.5, -0.5};
  input Real u(unit = "N") "force";
  output Real y(unit = "m");
  Real x(unit = "m", start = c[1]) "position";
  Real v(start = w);
  Real a;
equation
  der(x) = v;
  a = (u - d * v - w * x + c[2] * sin(x)) / m;
  der(v) = a;
  y = x + c[1] * v;
  annotation(__motiontwin(export = true));
end Calc;
"""


@pytest.fixture(autouse=True)
def empty_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache" / "motiontwin" / modelcache.FOLDER


def _entries(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.json")) if folder.is_dir() else []


def _no_parse(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(texts: object) -> None:
        raise AssertionError("parsed although the cache holds the model")

    monkeypatch.setattr(frontend, "_parse_files", refuse)


def _same_functions(a: symbolic.SymbolicModel, b: symbolic.SymbolicModel, seed: int = 0) -> None:
    """Every runtime function of ``a`` and ``b`` at random arguments, to 1e-12."""
    rng = np.random.default_rng(seed)
    fa, fb = a.functions(), b.functions()
    assert sorted(fa) == sorted(fb)
    for name in fa:
        for _ in range(5):
            args = [rng.uniform(0.5, 1.5, fa[name].size_in(i)) for i in range(fa[name].n_in())]
            for got, want in zip(fb[name].call(args), fa[name].call(args)):
                np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("class_name, source", [
    ("Calc", None),
    ("MotionTwin.Plants.CheungManipulator", build.MODELICA_DIR),
    ("MotionTwin.Controllers.DiscreteStateSpaceController", build.MODELICA_DIR),
])
def test_cached_model_equals_a_fresh_parse(class_name, source, tmp_path, empty_cache, monkeypatch):
    if source is None:
        source = tmp_path / "Calc.mo"
        source.write_text(CALC)
    fresh = frontend.load(source, class_name)
    assert len(_entries(empty_cache)) == 1
    _no_parse(monkeypatch)
    cached = frontend.load(source, class_name)
    for group in ("states", "algebraics", "inputs", "parameters"):
        want, got = getattr(fresh, group), getattr(cached, group)
        assert [(v.name, v.description, v.unit, v.min, v.max, v.nominal) for v in got] == \
               [(v.name, v.description, v.unit, v.min, v.max, v.nominal) for v in want]
    assert [v.name for v, _ in cached.calculated] == [v.name for v, _ in fresh.calculated]
    assert (cached.name, cached.description, cached.outputs, cached.annotation, cached.source) == \
           (fresh.name, fresh.description, fresh.outputs, fresh.annotation, fresh.source)
    _same_functions(symbolic.build(fresh), symbolic.build(cached))
    if class_name == "Calc":   # the calculated parameter and the start expressions, by value
        p = ca.vertcat(*[v.symbol for v in cached.parameters])
        w = ca.Function("w", [p], [cached.calculated[0][1]])(ca.DM([2.0, 3.0, 1.5, -0.5]))
        assert float(w) == pytest.approx(np.sqrt(3.0 / 2.0), rel=1e-15)
        x0 = ca.Function("x0", [p], [symbolic.build(cached).x0()])(ca.DM([2.0, 8.0, 1.5, -0.5]))
        np.testing.assert_allclose(np.array(x0).ravel(), [1.5, 2.0], rtol=1e-15)


def test_editing_a_source_file_invalidates_the_entry(tmp_path, empty_cache):
    source = tmp_path / "Calc.mo"
    source.write_text(CALC)
    assert frontend.load(source, "Calc").parameters[0].start == 2.0
    source.write_text(CALC.replace("min = 1e-9) = 2", "min = 1e-9) = 7"))
    assert frontend.load(source, "Calc").parameters[0].start == 7.0
    assert len(_entries(empty_cache)) == 2


@pytest.mark.parametrize("damage", ["truncated", "garbage", "other format", "wrong symbols", "fewer variables",
                                    "more variables", "bad function"])
def test_a_corrupt_entry_is_ignored_and_rebuilt(damage, tmp_path, empty_cache):
    source = tmp_path / "Calc.mo"
    source.write_text(CALC)
    frontend.load(source, "Calc")
    (entry,) = _entries(empty_cache)
    text = entry.read_text()
    doc = json.loads(text)
    entry.write_text({"truncated": text[: len(text) // 2], "garbage": "\x00\x01 not json",
                      "other format": json.dumps({**doc, "format": -1}),
                      "wrong symbols": json.dumps({**doc, "symbols": doc["symbols"][:-1]}),
                      "fewer variables": json.dumps({**doc, "states": doc["states"][:1]}),
                      "more variables": json.dumps({**doc, "states": doc["states"] * 3}),
                      "bad function": json.dumps({**doc, "function": doc["function"][:40]})}[damage])
    model = frontend.load(source, "Calc")
    assert [v.name for v in model.parameters] == ["m", "d", "c[1]", "c[2]"]
    assert json.loads(entry.read_text()) == doc      # rewritten whole


def test_syntax_error_names_file_line_and_column_with_a_warm_cache(tmp_path, empty_cache):
    source = tmp_path / "Calc.mo"
    source.write_text(CALC)
    frontend.load(source, "Calc")
    source.write_text(CALC.replace("  Real a;\n", "  Real a\n"))
    for _ in range(2):
        with pytest.raises(frontend.ModelicaError, match=r"Calc\.mo:11:\d+: syntax error"):
            frontend.load(source, "Calc")


def test_only_the_files_a_class_needs_are_parsed(monkeypatch):
    parsed: list[set[str]] = []
    real = frontend._parse_files

    def spy(texts: dict[Path, str]) -> object:
        parsed.append({p.relative_to(build.MODELICA_DIR).as_posix() for p in texts})
        return real(texts)

    monkeypatch.setattr(frontend, "_parse_files", spy)
    frontend.load(build.MODELICA_DIR, "MotionTwin.Effects.CoulombJoint")
    assert parsed == [{"MotionTwin/package.mo", "MotionTwin/Effects/package.mo", "MotionTwin/Effects/CoulombJoint.mo",
                       "MotionTwin/Effects/JointBase.mo", "MotionTwin/Effects/CoulombFriction.mo"}]


def test_a_subset_that_does_not_flatten_falls_back_to_every_file(monkeypatch):
    """Should the word scan miss a class, the whole library is parsed: same model, no error."""
    monkeypatch.setattr(frontend, "_needed", lambda texts, name: {p: t for p, t in texts.items()
                                                                  if p.name == "CoulombJoint.mo"})
    model = frontend.load(build.MODELICA_DIR, "MotionTwin.Effects.CoulombJoint")
    assert {"m", "d", "Fc"} <= {v.name for v in model.parameters}


def test_a_warm_identify_oe_imports_neither_pymoca_nor_fmpy_nor_scipy_io(tmp_path, empty_cache):
    """identify oe on a warm cache loads no parser, no FMU library, no MATLAB reader, no plotting, and no
    scipy.signal (0.3-0.7 s of import: only a closed loop's controller relation and the unknown controller's
    observer use it, and import it there)."""
    from motiontwin.harness.recording import make_recording, write_recording

    ts, m, d = 1e-3, 2.0, 10.0
    u = np.sin(np.arange(1000) * ts * 2 * np.pi * 3) * 5.0
    x, v, q = 0.0, 0.0, []
    for uk in u:                        # explicit Euler of m*der(v) = u - d*v, fine for a start-up check
        q.append(x)
        x, v = x + ts * v, v + ts * (uk - d * v) / m
    write_recording(tmp_path / "rec.csv", make_recording(np.arange(1000) * ts, {"u": u, "q": np.array(q)}))
    code = ("import sys\nfrom motiontwin.cli import main\n"
            f"rc = main(['identify', 'oe', {str(tmp_path / 'rec.csv')!r}, '--class', "
            "'MotionTwin.Plants.LinearMotorJoint', '--free', 'm,d'])\n"
            "print(rc, sorted(m for m in ('pymoca', 'fmpy', 'scipy.io', 'scipy.signal', 'matplotlib.pyplot')\n"
            "                 if m in sys.modules))\n")
    env = {"XDG_CACHE_HOME": str(empty_cache.parents[1]), "PATH": "/usr/bin:/bin"}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
            for _ in range(2)]
    assert runs[0].stdout.splitlines()[-1] == "0 ['pymoca']", runs[0].stderr
    assert runs[1].stdout.splitlines()[-1] == "0 []", runs[1].stderr
