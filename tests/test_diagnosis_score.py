"""The score test that decides whether the time delay is screened at all (``screen.score_test``): one free run
with sensitivities at the delay's vanishing point predicts the cost reduction its fit would reach.

References: the full output-error fit of the same structure (``screen.fit_structure``: the vanishing point and
every data-driven start, 15 free runs each), and the bootstrap null of the same extension, the level a
candidate's fitted reduction must beat in the selection. Bundles: the short benchmark bundles of a concealed
0.4 ms input delay, and of a concealed Coulomb friction and a gravity offset (no delay).
"""
from __future__ import annotations

import dataclasses

import pytest

from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence, noise
from motiontwin.ident.diagnosis.screen import fit_structure, score_test
from motiontwin.ident.diagnosis.select import bootstrap_null
from tests.test_diagnosis_search import short_bundle_nominal


def _scored(tmp_path, case: str, seed: int) -> tuple[float, float, float]:
    """(predicted reduction, fitted reduction, null threshold) of the time delay on a short ``case`` bundle."""
    bundle, current, weights, ctx = short_bundle_nominal(tmp_path / case, case, seed)
    bundle.process_noise = noise.of_bundle(bundle, current.fit.values, weights.sigma_q)
    null, base_gain = bootstrap_null(bundle, current, weights, seed=1)
    predicted, jac, dof = score_test(bundle, current, "time_delay", None, ctx, weights, tmp_path / "score")
    threshold = evidence.null_threshold(evidence.extension_null(jac, current.fit.jacobian, null, base_gain), dof)
    fitted = fit_structure(bundle, current, effect_models.VOCABULARY["time_delay"](ctx), ctx, weights,
                           tmp_path / "fit")
    print(f"{case}: predicted {predicted:.6g}, fitted {current.fit.cost - fitted.fit.cost:.6g}, null {threshold:.6g}")
    return predicted, current.fit.cost - fitted.fit.cost, threshold


def test_score_test_predicts_the_fitted_reduction_of_a_true_delay(tmp_path):
    predicted, fitted, threshold = _scored(tmp_path, "time_delay", 508)
    assert fitted > 10 * threshold                       # the delay is there, far above its null
    assert predicted == pytest.approx(fitted, rel=0.05)  # one Gauss-Newton step from the vanishing point
    assert predicted > threshold                         # so it is screened


@pytest.mark.parametrize("case, seed", [("coulomb_friction", 3), ("gravity_offset", 5)])
def test_score_test_predicts_nothing_where_the_fit_finds_nothing(tmp_path, case, seed):
    """Bundles without a delay, whose nominal model misses another effect. On the Coulomb bundle the free step
    takes the delay below zero (5.0e6 predicted without holding it at its bound); on the offset bundle the step
    of the controller's start, which the fit prices by the controller's relation and the bare projection does
    not, would be credited to the delay (5.7e7 predicted against 5e-5 fitted)."""
    predicted, fitted, threshold = _scored(tmp_path, case, seed)
    assert fitted < threshold
    assert predicted <= fitted + threshold
    assert predicted < threshold                         # not screened


def test_the_prediction_under_doubled_noise_levels_is_a_quarter(tmp_path):
    """The test reuses the current fit's residual and Jacobian beside the delay's own column only when that fit was
    weighted as the test is (else it takes them again under the test's weights): every weighted cost scales as
    1 / sigma^2, so doubling both noise levels divides the prediction by four (a single column's projected gain
    does not depend on its scale, so mixing the fit's old weights with the delay's new ones would leave it as
    it was)."""
    bundle, current, weights, ctx = short_bundle_nominal(tmp_path / "delay", "time_delay", 508)
    predicted, _, _ = score_test(bundle, current, "time_delay", None, ctx, weights, tmp_path / "white")
    doubled = dataclasses.replace(weights, sigma_q=2 * weights.sigma_q, sigma_u=2 * weights.sigma_u)
    quarter, _, _ = score_test(bundle, current, "time_delay", None, ctx, doubled, tmp_path / "doubled")
    assert predicted > 1e5
    assert quarter == pytest.approx(predicted / 4, rel=1e-3)


def test_the_selection_screens_the_delay_only_when_its_score_test_passes(tmp_path, monkeypatch):
    """The selection runs the score test in the screening (in a worker when there are several; its line is
    logged by the main process) and does not screen the delay when it fails: on the Coulomb bundle the log says
    'not screened', has no screening line of the delay, and the selection finds the friction."""
    from motiontwin.ident.diagnosis import select

    vocabulary = {n: effect_models.VOCABULARY[n] for n in ("coulomb_friction", "time_delay")}
    monkeypatch.setattr(effect_models, "VOCABULARY", vocabulary)
    bundle, current, weights, ctx = short_bundle_nominal(tmp_path / "coulomb", "coulomb_friction", 3)
    bundle.process_noise = noise.of_bundle(bundle, current.fit.values, weights.sigma_q)
    lines: list[str] = []
    final, _, _ = select.select(bundle, current, weights, ctx, tmp_path / "work", lines.append)
    print("\n".join(lines))
    assert any(line.startswith("  score test time_delay: predicted cost +0,") and "(not screened" in line
               for line in lines)
    assert not any(line.startswith("  screen time_delay") for line in lines)
    assert any(line.startswith("  screen coulomb_friction") for line in lines)
    assert [e.name for e in final.effects] == ["coulomb_friction"]
