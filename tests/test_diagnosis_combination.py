"""Several effects (issue 22 item 4): a constant force and a Stribeck friction on one axis, simulated by the
independent truth simulator (its own integrator and force laws, process noise), are both named with their
parameters. Two decisions make this: every round screens the whole vocabulary (the offset ranks sixth behind
five frictions in the first round), and the kept Coulomb friction is refitted in its richer forms once the
offset is in (the offset had hidden the Stribeck hump in the first round)."""
from __future__ import annotations

import json

import pytest

from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import diagnose_bundle


@pytest.fixture(scope="module")
def combination(tmp_path_factory) -> tuple[dict, dict]:
    root = tmp_path_factory.mktemp("combination")
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
