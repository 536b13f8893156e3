"""LuGre friction with its Stribeck curve: a bristle model whose sliding friction falls from a breakaway level
Fs to the Coulomb level Fc (Canudas de Wit et al. 1995) is fitted with that curve, not bent into Dahl's form.

Reference: the independent truth simulator's LuGre law (:mod:`ident.benchmarks.independent_laws`: its own
integrator, Fs = 1.5 Fc, bristle damping sigma1 at 0.2 of the pre-sliding spring's critical damping) and the
truth's own floor."""
from __future__ import annotations

import pytest

from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.screen import fit_structure, refine
from motiontwin.ident.diagnosis.structure import validate
from tests.diagnosis_util import refitted_nominal


def test_a_lugre_breakaway_above_the_sliding_level_is_fitted(tmp_path, monkeypatch) -> None:
    """A 4 s + 2 s bundle of the simulator's LuGre law (seed 13006, outside the benchmark sets): the fit recovers
    the breakaway over the sliding level (Dahl's form, the catalogue's law before, holds it at 1 and left the
    tuning set's recorded force 1.59x its floor), and its validation run of the recorded force comes within
    1.5x the truth's own floor. With the bristle damping fitted, the pre-sliding displacement comes within 10 %
    (-3 %; without sigma1 in the law -13 %) and sigma1 within 30 % (-19 %)."""
    monkeypatch.setattr(independent, "DURATIONS", (4.0, 2.0))
    truth = independent.write_bundle(tmp_path / "bundle", independent.draw_case("lugre", 13006))
    law = truth["laws"][0]["parameters"]
    bundle, nominal, weights, ctx = refitted_nominal(tmp_path / "bundle", process_noise=True)
    fit = refine(bundle, fit_structure(bundle, nominal, effect_models.VOCABULARY["lugre_friction"](ctx), ctx,
                                       weights, tmp_path / "lugre"), weights)
    validate(bundle, fit, tmp_path / "validation")
    values = fit.fit.values
    ratio = (values["lugre_Fc"] + values["lugre_dFs"]) / values["lugre_Fc"]
    assert ratio == pytest.approx(law["Fs"] / law["Fc"], rel=0.2)
    assert fit.val_force < 1.5 * truth["force_floor_rms"]
    assert values["lugre_z0"] == pytest.approx(law["z0"], rel=0.1)
    assert values["lugre_sigma1"] == pytest.approx(law["sigma1"], rel=0.3)
