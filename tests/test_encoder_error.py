"""The sensor effect ``encoder_error`` (issue 22 item 5): the measured output the augmented model writes against
its closed form, the initial state solved from the first measured sample through the nonlinear output, and the
screening decision on a bundle of the independent truth simulator (``ident.benchmarks.independent``: its own
integrator and encoder law ``EncoderCyclicError``, no code shared with the candidates), where an encoder cyclic
error must be told from a force periodic in position.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from motiontwin.ident.benchmarks import independent
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import sensor_effects, structure
from motiontwin.ident.diagnosis.plant_roles import PlantRoles
from motiontwin.ident.diagnosis.screen import SCREEN_NFEV, fit_structure
from motiontwin.ident.oeloop import _state_for_output
from motiontwin.ident.plant_states import output_expression
from tests.diagnosis_util import refitted_nominal

GEARED = '''model Geared "Axis read through a gear ratio and an offset: q = 2 x + 0.01"
  parameter Real m(unit = "kg") = 2.0;
  parameter Real d(unit = "N.s/m") = 15.0;
  input Real u(unit = "N");
  output Real q(unit = "m");
  Real x(unit = "m", start = 0, fixed = true);
  Real v(unit = "m/s", start = 0, fixed = true);
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = 2*x + 0.01;
end Geared;
'''
VALUES = {"encoder_a1": 3e-6, "encoder_b1": -1e-6, "encoder_a2": 5e-7, "encoder_b2": 2e-7, "encoder_period": 1e-3}


def test_measured_output_is_the_position_plus_the_periodic_error(tmp_path):
    """q = plant.q + a1 sin(2 pi x/lam) + b1 cos(..) + a2 sin(4 pi x/lam) + b2 cos(..): the amplitudes in the
    measured unit, the period in the plant's state coordinates (x, not q = 2 x + 0.01); the contract gives the
    period in the measured unit (2 lam). The initial state solved from a measured q0 reproduces q0 through the
    nonlinear output (one affine step would be off by the error)."""
    ctx = effect_models.Context(5e-4, 0.0, 0.1, 0.2, 2.0, position_gain=2.0)
    effect = effect_models.VOCABULARY["encoder_error"](ctx)
    assert effect.sensor and not effect.force and effect.family == "encoder_error"
    augmented.write_model(tmp_path, GEARED, "Geared", [effect], VALUES, {}, "Augmented",
                              PlantRoles("u", "q", "x", "v"))
    model = augmented.load_augmented(tmp_path, "Augmented")
    states = [s.name for s in model.states]
    p = np.array([VALUES.get(v.name, v.start) for v in model.parameters], float)
    h = ca.Function("h", [model.x, model.u, model.p], [output_expression(model, "q")])
    x = np.random.default_rng(5).uniform(-0.05, 0.1, 50)
    xs = np.zeros((len(states), x.size))
    xs[states.index("plant.x")] = x
    q = np.array(h.map(x.size)(xs, np.zeros((1, x.size)), p)).ravel()
    theta = 2 * np.pi * x / 1e-3
    error = 3e-6 * np.sin(theta) - 1e-6 * np.cos(theta) + 5e-7 * np.sin(2 * theta) + 2e-7 * np.cos(2 * theta)
    np.testing.assert_allclose(q, 2 * x + 0.01 + error, rtol=1e-13, atol=1e-17)
    assert effect.contract(VALUES, ctx) == pytest.approx(
        {"error_amplitude": math.hypot(3e-6, 1e-6), "error_amplitude_2": math.hypot(5e-7, 2e-7), "period": 2e-3})

    target = 0.0912345
    x0 = _state_for_output(model, "q", np.zeros(len(states)), p, target)
    assert float(h(x0, 0.0, p)) == pytest.approx(target, abs=1e-15)
    assert abs(x0[states.index("plant.x")] - (target - 0.01) / 2) > 1e-7      # the error is really there


def test_effect_on_an_axis_reads_that_axis_position():
    """Placed on axis q3 the error reads q3's position state and the prefixed parameters."""
    ctx = effect_models.Context(5e-4, 0.0, 0.1, 0.2, 2.0)
    placed = structure.on_axis(effect_models.VOCABULARY["encoder_error"](ctx), PlantRoles("u3", "q3", "d3", "v3"))
    assert "q3_encoder_a1*sin(6.283185307179586*plant.d3/q3_encoder_period)" in placed.sensor
    assert "$x" not in placed.sensor and "encoder_b2" in placed.sensor


@pytest.fixture(scope="module")
def independent_encoder_case(tmp_path_factory):
    """The held-out encoder case of the independent benchmark (linear 9 kg, 8 s + 4 s): a cyclic error of
    1.74 um at a 1 mm signal period (plus 0.35 um at 0.5 mm) concealed to 4.8 um; the nominal refit and its
    context."""
    folder = tmp_path_factory.mktemp("encoder") / "encoder_error"
    name, seed = next(c for c in independent.case_list("heldout") if c[0] == "encoder_error")
    truth = independent.write_bundle(folder, independent.draw_case(name, seed))
    return (*refitted_nominal(folder), truth, folder.parent / "work")


def test_encoder_error_beats_a_force_ripple_on_an_independent_truth(independent_encoder_case):
    """Screened against the force periodic in position, the sensor effect takes almost all of the nominal
    model's cost (the ripple hardly any), with the first-harmonic amplitude and the period of the truth."""
    bundle, nominal, weights, ctx, truth, work = independent_encoder_case
    law = truth["laws"][0]
    assert law["expected"] == "encoder_error" and law["main"]["contract"] == "error_amplitude"
    fits = {name: fit_structure(bundle, nominal, effect_models.VOCABULARY[name](ctx), ctx, weights, work / name,
                                SCREEN_NFEV) for name in ("encoder_error", "position_ripple")}
    cost = nominal.fit.cost
    assert fits["encoder_error"].fit.cost < 0.05 * cost
    assert fits["position_ripple"].fit.cost > 0.9 * cost
    found = fits["encoder_error"].effects[-1].contract(fits["encoder_error"].fit.values, ctx)
    assert found["error_amplitude"] == pytest.approx(law["main"]["value"], rel=0.05)
    assert found["period"] == pytest.approx(law["parameters"]["lam"], rel=0.01)


@pytest.mark.parametrize("second", [0.3, 3.0])
def test_slow_axis_error_period_is_found_in_the_output_residual(second: float):
    """Where the axis moves too slowly for the error's force (m e'' v^2) to stand above the process noise, the
    starts come from the output residual: a 1 mm error whose second harmonic the loop's sensitivity raised
    above the fundamental (second = 3) or not (0.3), on a slow back-and-forth sweep with white noise; the true
    period is among the starting periods within one scan step (0.25 periods over the span)."""
    rng = np.random.default_rng(2)
    t = np.arange(40000) * 5e-4
    x = 0.017 * (1 - np.cos(2 * np.pi * t / 7.0))
    period = 1e-3
    residual = (np.sin(2 * np.pi * x / period + 0.4) + second * np.sin(4 * np.pi * x / period + 1.1)) * 1e-7
    ctx = effect_models.Context(5e-4, float(x.min()), float(x.max()), 0.01, 30.0, x=x,
                                q_residual=residual + 2e-8 * rng.standard_normal(x.size))
    span = ctx.x_max - ctx.x_min
    found = [p for p, amplitudes in sensor_effects.residual_periods(ctx, span, span / 500)]
    step = 0.25 * period ** 2 / span
    assert min(abs(p - period) for p in found) < step, found
    assert sensor_effects.residual_periods(effect_models.Context(5e-4, 0.0, 1.0, 0.01, 30.0), 1.0, 0.002) == []
