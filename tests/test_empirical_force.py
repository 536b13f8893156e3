"""The empirical force term (sparse regression of a force residual): it finds the terms of a known law that no
catalogue effect has (friction rising with position, quadratic drag), finds nothing in pure noise, and its
Modelica text evaluated by the project's front end equals its numpy evaluation."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import build
from motiontwin.ident.diagnosis import empirical
from motiontwin.ident.diagnosis.empirical import fit_empirical_force


def _signals(seconds: float = 6.0, rate: float = 1000.0) -> dict[str, np.ndarray]:
    t = np.arange(0, seconds, 1 / rate)
    w1, w2 = 2 * np.pi * 0.5, 2 * np.pi * 1.7
    x = 0.02 * np.sin(w1 * t) + 0.005 * np.sin(w2 * t + 0.4)
    v = 0.02 * w1 * np.cos(w1 * t) + 0.005 * w2 * np.cos(w2 * t + 0.4)
    a = -0.02 * w1**2 * np.sin(w1 * t) - 0.005 * w2**2 * np.sin(w2 * t + 0.4)
    u = 2.0 * a + 10 * v + 0.7 * np.sin(2 * np.pi * 3.1 * t)
    return {"x": x, "v": v, "a": a, "u": u}


def test_finds_the_terms_of_a_law_outside_the_catalogue():
    signals = _signals()
    v_eps = 1e-3
    truth = (0.3 + 25 * signals["x"]) * np.tanh(signals["v"] / v_eps) + 30.0 * signals["v"] * np.abs(signals["v"])
    noise = np.random.default_rng(1).normal(0, 0.02, truth.size)
    law = fit_empirical_force(signals, truth + noise, v_eps=v_eps)
    assert sorted(law.names) == ["sign(v)", "v*|v|", "x*sign(v)"]
    found = dict(zip(law.names, law.coefficients))
    assert found["sign(v)"] == pytest.approx(0.3, rel=0.03)
    assert found["x*sign(v)"] == pytest.approx(25, rel=0.03)
    assert found["v*|v|"] == pytest.approx(30.0, rel=0.05)
    assert law.cv_rms == pytest.approx(0.02, rel=0.15)   # down to the noise
    assert law.gain < 0.2


def test_finds_nothing_in_noise():
    signals = _signals()
    noise = np.random.default_rng(2).normal(0, 0.05, signals["v"].size)
    law = fit_empirical_force(signals, noise)
    assert law.terms == []
    assert law.modelica("x", "v", "der(v)", "u") == "0"


def test_modelica_text_equals_the_numpy_law(tmp_path: Path):
    signals = _signals(seconds=3.0)
    truth = 0.5 * np.tanh(signals["v"] / 2e-3) - 40 * signals["x"] ** 2 + 0.05 * np.abs(signals["u"]) * np.tanh(
        signals["v"] / 2e-3)
    law = fit_empirical_force(signals, truth, v_eps=2e-3)
    assert len(law.terms) >= 3
    source = tmp_path / "EmpiricalCheck.mo"
    source.write_text(
        "model EmpiricalCheck\n  input Real pos;\n  input Real vel;\n  input Real acc;\n  input Real force;\n"
        f"  output Real F;\nequation\n  F = {law.modelica('pos', 'vel', 'acc', 'force')};\nend EmpiricalCheck;\n")
    model = build.load_model("EmpiricalCheck", source)
    expr = next(c.expr for c in model.computed if c.var.name == "F")
    order = [v.name for v in model.inputs]
    fn = ca.Function("F", [model.u], [expr])
    columns = {"pos": signals["x"], "vel": signals["v"], "acc": signals["a"], "force": signals["u"]}
    u = np.vstack([columns[name] for name in order])
    np.testing.assert_allclose(np.array(fn(u)).ravel(), law.evaluate(signals), rtol=1e-12, atol=1e-12)


def test_bad_signals_name_the_field():
    signals = _signals(seconds=1.0)
    with pytest.raises(ValueError, match=r"signals\['a'\]"):
        fit_empirical_force({k: v for k, v in signals.items() if k != "a"}, np.zeros(signals["v"].size))
    with pytest.raises(ValueError, match="NaN"):
        fit_empirical_force(signals, np.full(signals["v"].size, np.nan))


@pytest.mark.parametrize("strength", [0.0, 0.001, 0.0016, 0.002, 0.01, 0.05])
def test_lower_bound_shortcut_gives_the_answer_of_the_full_threshold_path(strength, monkeypatch):
    """The reference is the full cross-validated threshold path (the bound switched off): from pure noise to a
    drag just past the MIN_GAIN cut (0.001: shortcut; 0.0016: path, nothing; 0.002: v|v|), the answer with the
    shortcut is the same; where the shortcut decides (no path), the full path also finds nothing."""
    signals = _signals(seconds=3.0)
    noise = np.random.default_rng(7).normal(0, 0.02, signals["v"].size)
    residual = noise + strength * 1e3 * signals["v"] * np.abs(signals["v"])
    fast = fit_empirical_force(signals, residual)
    monkeypatch.setattr(empirical, "cross_validation_bound", lambda *args: -np.inf)
    full = fit_empirical_force(signals, residual)
    assert fast.names == full.names and fast.cv_rms == full.cv_rms
    np.testing.assert_array_equal(fast.coefficients, full.coefficients)
    if not fast.path:
        assert full.terms == []
    else:
        assert fast.path == full.path


def test_lower_bound_is_below_every_cross_validated_rms():
    signals = _signals(seconds=3.0)
    rng = np.random.default_rng(3)
    theta = np.column_stack([t.evaluate(signals, 1e-3) for t in empirical.default_library()])[::3]
    theta = theta / np.sqrt(np.mean(theta ** 2, axis=0))
    y = rng.normal(0, 1, theta.shape[0]) + 0.3 * theta[:, 4]
    blocks = np.array_split(np.arange(y.size), empirical.FOLDS)
    bound = empirical.cross_validation_bound(theta, y, blocks)
    for threshold in empirical.THRESHOLDS:
        errors = []
        for test in blocks:
            train = np.setdiff1d(np.arange(y.size), test)
            xi = empirical._stlsq(theta[train], y[train], threshold)
            errors.append(np.sqrt(np.mean((y[test] - theta[test] @ xi) ** 2)))
        assert bound <= np.mean(errors)
    assert bound > 0.9     # tight: only the noise the 13 columns absorb per block is below it
