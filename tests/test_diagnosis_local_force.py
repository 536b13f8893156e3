"""A force acting on one stretch of the stroke is not a global law (issue 22 item 5): a friction bump on one
place of the rail, simulated by the independent truth simulator (its own integrator and force law, process
noise), lowers the cost of every friction candidate, and a Coulomb friction fitted to it even lowers the
validation RMS by 26 %; but it raises the recorded force's residual 6x in the quarter of the recording where
the axis rests at the end of the stroke, away from the bump. The diagnosis does not report it as friction and
answers "unexplained" (before: Coulomb friction + "unexplained"), located at the bump.

References: the truth's own law list (no Coulomb friction in it) and, for :func:`evidence.stroke_ratios`, a
residual built by hand whose bin ratios are known exactly."""
from __future__ import annotations

import json

import numpy as np
import pytest

from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import diagnose_bundle, evidence


def test_stroke_ratios_are_the_mean_square_ratios_of_equal_count_position_bins() -> None:
    position = np.linspace(0.0, 1.0, 400)[::-1]          # any order: binned by position
    before = np.where(position < 0.5, 2.0, 1.0)
    after = np.where(position >= 0.75, 3.0, 1.0)
    ratios = evidence.stroke_ratios(position, before, after)
    assert [r for _, _, r in ratios] == pytest.approx([0.25, 0.25, 1.0, 9.0])
    assert ratios[-1][:2] == pytest.approx((position[99], 1.0))
    assert evidence.stroke_ratios(position, np.zeros(400), np.zeros(400))[0][2] == 1.0


@pytest.fixture(scope="module")
def bump(tmp_path_factory) -> tuple[dict, dict]:
    root = tmp_path_factory.mktemp("bump")
    independent.generate(root, "heldout", only=["friction_bump"])
    truth = json.loads((root / "heldout" / "friction_bump.truth.json").read_text())
    doc = diagnose_bundle(root / "heldout" / "friction_bump", root / "out")
    return {**doc, "report.md": (root / "out" / "report.md").read_text()}, truth


def test_friction_bump_is_unexplained_not_a_coulomb_friction(bump) -> None:
    doc, truth = bump
    assert [law["law"] for law in truth["laws"]] == ["friction_bump"]
    assert doc["effects"] == [], doc["effects"]
    assert doc["unexplained"] is not None and doc["unexplained"]["status"].startswith("unexplained")
    low, high = doc["unexplained"]["position_range"]      # where the force residual is largest: at the bump
    assert low <= truth["laws"][0]["parameters"]["x0"] <= high, (low, high)
    coulomb = [c for c in doc["candidates"] if c["effect"] == "coulomb_friction" and "stroke_force_ratio" in c]
    assert coulomb and coulomb[0]["validation_rms_after"] < coulomb[0]["validation_rms_before"]
    worst = coulomb[0]["stroke_force_ratio"]["ratio"]
    assert worst > evidence.STROKE_RATIO
    row = next(line for line in doc["report.md"].splitlines() if line.startswith("| 1 | coulomb_friction |"))
    assert row.split("|")[8].strip() == f"{worst:.3g}", row
