"""The nested friction laws judged again under the final fit's prediction-error weighting (polish.upgraded).

Reference: the truth of a bundle of the independent truth simulator (its laws and their parameters)."""
from __future__ import annotations

import json

import pytest

from motiontwin.ident import outputerror
from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.polish import polished
from motiontwin.ident.diagnosis.structure import ModelFit, build_structure
from tests.diagnosis_util import refitted_nominal


def test_a_stribeck_hump_the_white_weights_bury_is_named_under_the_whitened_ones(tmp_path) -> None:
    """The independent simulator's audit case offset + Stribeck (a rotary axis under process noise): the structure
    the white-weighted selection ends with, offset + Coulomb friction (fitted white from the truth's mass, where
    the selection's fit ends too), polished with its context. Whitened, the Stribeck law in place of the Coulomb
    one beats the chi-square quantile and the validation run (-24 %), so the answer is offset + Stribeck, with
    the breakaway level within 20 % of the truth; red if the upgrade is not judged."""
    independent.generate(tmp_path, "audit", only=["offset+stribeck"])
    truth = json.loads((tmp_path / "audit" / "offset+stribeck.truth.json").read_text())
    bundle, nominal, weights, ctx = refitted_nominal(tmp_path / "audit" / "offset+stribeck", process_noise=True)
    effects = [effect_models.VOCABULARY[name](ctx) for name in ("gravity_offset", "coulomb_friction")]
    laws = {law["law"]: law for law in truth["laws"]}
    start = {"plant.m": truth["axis"]["mass"], "plant.d": truth["axis"]["damping"],
             "gravity_F0": laws["offset"]["main"]["value"], "coulomb_Fc": laws["stribeck"]["parameters"]["Fc"],
             "coulomb_v_eps": 1e-4}
    loop, bounds = build_structure(bundle, effects, start, tmp_path / "fit", bundle.train.time.size)
    fit = outputerror.fit(loop, bundle.train, weights, bounds, start=start, max_nfev=40, estimate_start=True)
    white = ModelFit(effects, loop.with_values(fit.values), fit, bounds, tmp_path / "fit")
    result, used = polished(bundle, white, weights, ctx, tmp_path / "polish")
    assert result.names == ["gravity_offset", "stribeck_friction"] and used.whiten_q is not None
    assert result.fit.values["stribeck_Fs"] == pytest.approx(laws["stribeck"]["parameters"]["Fs"], rel=0.2)
    assert result.evidence["stribeck_friction"]["upgraded_from"] == "coulomb_friction"
