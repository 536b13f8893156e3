"""A diagnosis structure is loaded from its source written with canonical values (one front-end pass per
structure and machine, :func:`augmented.load_written`), and is the model its written source gives: the reference
is the written folder loaded by the front end directly."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import frontend
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.plant_roles import PlantRoles

ROLES = PlantRoles("u", "q", "x", "v")
PLANT = bench.PLANT_TEXT.format(m=2.0, d=15.0)


def _effects() -> list[effect_models.Effect]:
    ctx = effect_models.Context(bench.TS, 0.0, 0.1, 0.2, 2.0, pole_pitch=0.032, duration=3.0)
    return [effect_models.VOCABULARY[n](ctx) for n in ("coulomb_friction", "cogging", "lugre_friction")]


def _writer(effects: list[effect_models.Effect]):
    def write(folder: Path, values: dict[str, float]) -> Path:
        plant = {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")}
        return augmented.write_model(folder, PLANT, bench.PLANT_CLASS, effects, values, plant, "Augmented", ROLES)
    return write


def _load(folder: Path):
    return augmented.load_augmented(folder, "Augmented")


def _values(effects: list[effect_models.Effect], rng: np.random.Generator) -> dict[str, float]:
    """Every effect parameter and the plant's mass and damping at values no other call uses."""
    values = {p.name: float(rng.uniform(*p.bounds)) if np.all(np.isfinite(p.bounds)) else float(rng.uniform(0.1, 1))
              for e in effects for p in e.params}
    return values | {"plant.m": float(rng.uniform(1, 3)), "plant.d": float(rng.uniform(5, 20))}


def test_the_structure_is_the_model_its_written_source_gives_and_is_flattened_once(tmp_path, monkeypatch):
    effects = _effects()
    rng = np.random.default_rng(5)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))    # an empty front-end cache
    parsed = []
    real_parse = frontend._parse_files
    monkeypatch.setattr(frontend, "_parse_files", lambda texts: parsed.append(1) or real_parse(texts))
    for k in range(2):
        values = _values(effects, rng)
        model = augmented.load_written(_writer(effects), _load, values, tmp_path / f"written{k}")
        assert model.flat.source == tmp_path / f"written{k}"
        reference = _load(tmp_path / f"written{k}")     # the written text, read by the front end itself
        assert [v.name for v in model.parameters] == [v.name for v in reference.parameters]
        assert [v.start for v in model.parameters] == [float(v.start) for v in reference.parameters]
        assert {v.name: v.start for v in model.parameters if v.name in values} == values
        f, g = (ca.Function("f", [m.x, m.u, m.p], [m.dx]) for m in (model, reference))
        for _ in range(3):
            x, u, p = rng.normal(size=model.x.numel()), rng.normal(size=1), rng.uniform(0.5, 2, model.p.numel())
            assert np.array_equal(np.array(f(x, u, p)), np.array(g(x, u, p)))
    # the first structure parsed its canonical source once and each reference once; the second its reference only
    assert len(parsed) == 3


def test_a_plant_value_that_sets_no_parameter_reads_the_written_folder(tmp_path):
    """A modifier on a plant variable that is no parameter (``plant.x``, a state: here a binding equation too
    many) is read from the written folder, whose error names it."""
    effects = _effects()[:1]
    values = _values(effects, np.random.default_rng(1)) | {"plant.x": 0.25}
    with pytest.raises(frontend.ModelicaError, match=str(tmp_path / "written")):
        augmented.load_written(_writer(effects), _load, values, tmp_path / "written")
