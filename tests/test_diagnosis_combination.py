"""Several effects (issue 22 item 4): a constant force and a Stribeck friction on one axis, simulated by the
independent truth simulator (its own integrator and force laws, process noise), are both named with their
parameters. Two decisions make this: every round screens the whole vocabulary (the offset ranks sixth behind
five frictions in the first round), and the kept Coulomb friction is refitted in its richer forms once the
offset is in (the offset had hidden the Stribeck hump in the first round)."""
from __future__ import annotations

import json

import pytest

from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import diagnose_bundle, noise
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis.nested import simplify_nested
from motiontwin.ident.diagnosis.prune import prune
from motiontwin.ident.diagnosis.screen import fit_structure
from tests.test_diagnosis_search import short_bundle_nominal


@pytest.fixture(scope="module")
def combination(tmp_path_factory) -> tuple[dict, dict]:
    root = tmp_path_factory.mktemp("combination")
    with pytest.MonkeyPatch.context() as patch:     # half the set's length: the same rounds, decisions and values
        patch.setattr(independent, "DURATIONS", (4.0, 2.0))
        independent.generate(root, "heldout", only=["offset+stribeck"])
    truth = json.loads((root / "heldout" / "offset+stribeck.truth.json").read_text())
    return diagnose_bundle(root / "heldout" / "offset+stribeck", root / "out"), truth


def test_offset_and_stribeck_are_both_named_with_their_parameters(combination) -> None:
    doc, truth = combination
    found = {e["name"]: e["parameters"] for e in doc["effects"]}
    assert sorted(found) == ["gravity_offset", "stribeck_friction"], doc["candidates"]
    laws = {law["law"]: law for law in truth["laws"]}
    assert abs(found["gravity_offset"]["F0"]) == pytest.approx(laws["offset"]["main"]["value"], rel=0.1)
    assert found["stribeck_friction"]["Fs"] == pytest.approx(laws["stribeck"]["main"]["value"], rel=0.1)
    assert doc["unexplained"] is None


@pytest.mark.parametrize("case, seed", [("coulomb_friction", 3), ("stribeck_friction", 6)])
def test_a_richer_friction_kept_beside_another_effect_is_simplified_only_when_it_earns_nothing(tmp_path, case,
                                                                                             seed) -> None:
    """A Stribeck friction kept beside a second effect (a round judged it before the second was in) is refitted
    as Coulomb friction with the second one in: on a short Coulomb truth its extra parameters do not beat their
    null and Coulomb takes its place; on a short Stribeck truth it stays. Reference: the truth's law."""
    bundle, nominal, weights, ctx = short_bundle_nominal(tmp_path / case, case, seed)
    bundle.process_noise = noise.of_bundle(bundle, nominal.fit.values, weights.sigma_q)
    current = nominal
    for name in ("stribeck_friction", "gravity_offset"):
        current = fit_structure(bundle, current, effect_models.VOCABULARY[name](ctx), ctx, weights, tmp_path / name)
    lines: list[str] = []
    final = simplify_nested(bundle, current, weights, ctx, tmp_path / "simplify", lines.append)
    assert [e.name for e in final.effects] == [case, "gravity_offset"], lines


def test_an_effect_the_later_one_makes_redundant_is_dropped(tmp_path) -> None:
    """Backward elimination after the rounds, one axis: on a short Coulomb-friction truth, a constant force kept
    first (it takes up part of the friction's force) saves nothing once the friction is in, and is dropped; the
    friction is kept. Reference: the truth's law."""
    bundle, current, weights, ctx = short_bundle_nominal(tmp_path / "coulomb", "coulomb_friction", 3)
    bundle.process_noise = noise.of_bundle(bundle, current.fit.values, weights.sigma_q)
    for name in ("gravity_offset", "coulomb_friction"):
        current = fit_structure(bundle, current, effect_models.VOCABULARY[name](ctx), ctx, weights, tmp_path / name)
    lines: list[str] = []
    final = prune(bundle, current, weights, tmp_path / "prune", lines.append)
    assert [e.name for e in final.effects] == ["coulomb_friction"], lines
