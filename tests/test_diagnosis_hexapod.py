"""Decision test: the Hexapod (issue 24 item 2) diagnosed end to end in leg coordinates, six axes whose
outputs are the leg lengths L_j(pose), against the truth of ``multi_axis_truth.example`` (the library Hexapod
simulated by CasADi with leg 3's Coulomb friction 15 N above the nominal model's Table II value, through the
plant's own friction law, not the diagnosis's effect code; 1.5 s + 1 s at 1 kHz, 10 nm encoder noise).

The vocabulary is cut to three effects (Coulomb friction, its richer nested Stribeck friction, a gravity
offset) so that the two bundles are diagnosed in minutes, not the quarter of an hour the full vocabulary
takes on this plant (docs/diagnose-multiaxis.md has the full runs and their times): each screened Hexapod
structure compiles its own loop (about 20 s of gcc). Every other stage runs as in ``motiontwin diagnose``."""
from __future__ import annotations

import pytest

from motiontwin.ident.benchmarks import multi_axis_truth as truth
from motiontwin.ident.diagnosis import diagnose_bundle
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence

pytestmark = pytest.mark.timeout(1800)

KEPT = ("coulomb_friction", "stribeck_friction", "gravity_offset")
FC_TRUE = 15.0          # N, leg 3's friction beyond the nominal model's rc3 (multi_axis_truth.example)


@pytest.fixture(scope="module")
def cut_vocabulary():
    """The vocabulary cut to ``KEPT`` for the module's diagnoses."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(effect_models, "VOCABULARY", {k: v for k, v in effect_models.VOCABULARY.items() if k in KEPT})
        patch.setattr(effect_models, "NESTED", {k: v for k, v in effect_models.NESTED.items() if k in KEPT})
        yield


def _diagnosed(tmp_path_factory, case: str) -> dict:
    folder = tmp_path_factory.mktemp(case) / "bundle"
    truth.example(folder, case, 1.5, 1.0, ts=1e-3)
    return diagnose_bundle(folder, folder.parent / "out")


@pytest.fixture(scope="module")
def coulomb_l3(tmp_path_factory, cut_vocabulary) -> dict:
    return _diagnosed(tmp_path_factory, "hexapod_coulomb_L3")


@pytest.fixture(scope="module")
def params_only(tmp_path_factory, cut_vocabulary) -> dict:
    return _diagnosed(tmp_path_factory, "hexapod_params_only")


def test_leg_friction_found_on_its_leg(coulomb_l3) -> None:
    """15 N of extra Coulomb friction on leg 3: located on L3 in round 1, exactly coulomb_friction on L3 (not its
    richer Stribeck form), Fc within 5 % of 15 N, L3's validation RMS within 1.5x its noise floor, nothing
    unexplained."""
    doc = coulomb_l3
    scores = doc["location"][0]["scores"]
    assert max(scores, key=scores.get) == "L3"
    assert [(e["name"], e["axis"]) for e in doc["effects"]] == [("coulomb_friction", "L3")]
    fc = doc["effects"][0]["parameters"]["Fc"]
    assert fc == pytest.approx(FC_TRUE, rel=0.05)
    l3 = doc["validation"]["per_axis"]["L3"]
    assert l3["augmented_rms"] <= 1.5 * l3["noise_floor_rms"]
    assert doc["unexplained"] is None


def test_parameters_only_hexapod_names_nothing(params_only) -> None:
    """The same Hexapod without the extra friction (only mE off): no effect, and no "unexplained" either."""
    doc = params_only
    assert doc["effects"] == []
    assert doc["unexplained"] is None
    assert all(c["cost_reduction"] <= c["null_threshold"] or c.get("validation_rms_after", 0.0) >=
               evidence.VALIDATION_GAIN * c.get("validation_rms_before", 1.0) for c in doc["candidates"])
