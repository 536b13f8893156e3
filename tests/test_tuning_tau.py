"""The slowest closed-loop time constant tau_cl of ident.tuning against independent references: the hand-derived
characteristic polynomial of a sampled PI loop, its continuous-time limit, and python-control ``feedback``."""
from __future__ import annotations

import math

import control
import numpy as np
import pytest

from motiontwin.ident import tuning
from motiontwin.ident.tuning import margins as tuning_margins
from motiontwin.ident.tuning import spec as tuning_spec
from motiontwin.ident.frf import JointModel

TS = 5e-4
MASS, DAMPING = 2.0, 40.0  # kg, N s/m: plant 1/(m s + b) (force -> velocity of a damped mass)
KP, KI = 60.0, 1500.0  # N s/m, N/m: PI gains of that velocity loop
NOMINAL = JointModel(1.0, 10.0, ((2450.0, 0.05),), ((1885.0, 0.05),))  # CheungJoint defaults (1 kg)


def pi_parameters(kp: float, ki: float, tau: float = 2 * TS) -> dict[str, float]:
    """RobustJointController parameters that make its law exactly kp + ki/s: Kd/tau = kp cancels the filter
    state's input (Kp - Ki tau - Kd/tau = 0), sigma = 1 removes the notch, fc = fp with KL = 1 the lag."""
    return {"Kp": kp + ki * tau, "Ki": ki, "Kd": kp * tau, "tau": tau, "KL": 1.0, "fp": 300.0, "fc": 300.0,
            "sigma": 1.0, "wl": 380.0, "wh": 400.0, "Ts": TS}


def analytic_pi_poles(delay_samples: int) -> np.ndarray:
    """Roots of z^d (z - 1)(z - p) + k (q0 z - q1): ZOH plant k/(z - p), Tustin PI (q0 z - q1)/(z - 1)."""
    p = math.exp(-DAMPING / MASS * TS)
    k = (1 - p) / DAMPING
    q0, q1 = KP + KI * TS / 2, KP - KI * TS / 2
    open_loop = np.polymul([1.0] + [0.0] * delay_samples, np.polymul([1.0, -1.0], [1.0, -p]))
    return np.roots(np.polyadd(open_loop, k * np.array([q0, -q1])))


@pytest.mark.parametrize("delay_samples", [0, 1])
def test_pi_loop_poles_match_the_characteristic_polynomial(delay_samples):
    plant = control.tf([1.0], [MASS, DAMPING])
    params = pi_parameters(KP, KI)
    sampled = tuning.discrete_plant(plant, TS, delay_samples)
    modes = tuning.closed_loop_modes(tuning.controller_matrices(params), (sampled.A, sampled.B, sampled.C))
    expected = analytic_pi_poles(delay_samples)
    assert modes.size == expected.size  # the 4 cancelled controller states (filter, notch, lag) are dropped
    np.testing.assert_allclose(np.sort_complex(modes), np.sort_complex(expected), rtol=0, atol=1e-9)
    # python-control's closed loop has those poles plus the cancelled ones, which it cannot tell apart
    every = control.poles(control.feedback(tuning.loop_system(params, plant, delay_samples), 1))
    assert every.size == expected.size + 4
    assert all(np.min(np.abs(every - z)) < 1e-7 for z in expected)
    tau = tuning.loop_margins(params, plant, delay_samples, points=500).tau_cl
    assert tau == pytest.approx(-TS / math.log(np.max(np.abs(expected))), rel=1e-9)
    # continuous limit: m s^2 + (b + kp) s + ki, slowest root; Ts = 0.5 ms is far below the loop's time scale
    slow = np.max(np.roots([MASS, DAMPING + KP, KI]).real)
    assert tau == pytest.approx(-1 / slow, rel=0.02)


def test_tau_of_a_full_design_equals_python_control_feedback_poles():
    """Table 2 d1 rescaled on the joint model: no cancellation, so every pole of python-control's closed loop
    counts, and the search's numpy evaluator agrees with loop_margins."""
    column = tuning.TABLE2["d1"]
    params = {k: float(column[k]) for k in tuning.DESIGN_NAMES} | {"tau": 2 * TS, "Ts": TS}
    params, _ = tuning.rescale_to_bandwidth(params, NOMINAL, column["CLBW"])
    poles = control.poles(control.feedback(tuning.loop_system(params, NOMINAL, 1), 1))
    reference = -TS / math.log(float(np.max(np.abs(poles))))
    margins = tuning.loop_margins(params, NOMINAL, 1, points=500)
    assert margins.tau_cl == pytest.approx(reference, rel=1e-6)
    fast = tuning_margins._LoopEvaluator([NOMINAL], TS, 1, 300).evaluate(params)[0]
    assert fast.tau_cl == pytest.approx(reference, rel=1e-6)


def test_slow_integral_design_is_reported_with_its_shortfall():
    """A D-dominated PID whose integral zero sits at 0.01 rad/s: GM/PM/Ms pass, tau_cl is about 1/0.01 s and
    the violation names the bound and the value reached."""
    params = {"Kp": 200.0, "Ki": 2.0, "Kd": 400.0, "tau": 2 * TS, "KL": 1.0, "fp": 300.0, "fc": 300.0,
              "sigma": 1.0, "wl": 380.0, "wh": 400.0, "Ts": TS}
    plant = control.tf([1.0], [1.0, 10.0, 0.0])  # 1 kg, alpha = 10 rad/s
    margins = tuning.loop_margins(params, plant, 1, points=500)
    assert margins.stable
    # closed loop s^3 + (10 + Kd) s^2 + Kp s + Ki: its slowest root is the integral zero Ki/Kp, near-cancelled
    slow = np.max(np.roots([1.0, 10.0 + 400.0, 200.0, 2.0]).real)
    assert margins.tau_cl == pytest.approx(-1 / slow, rel=0.01)
    assert margins.tau_cl > 50
    spec = tuning.TuningSpec(gm_min_db=0.0, pm_min_deg=0.0, pm_max_deg=180.0, ms_max=10.0, tau_max_s=0.02)
    found = tuning.violations([margins], spec)
    assert [v[0] for v in found] == ["slowest closed-loop time constant tau_cl <= 0.02 s"]
    assert found[0][1] == margins.tau_cl and found[0][3] == "s"
    assert "tau_cl <= 0.02 s infeasible: best design reaches" in tuning_spec._format_violations(found)


def test_tune_meets_tau_max_on_every_plant_set():
    """A short search on two plant sets: the bound holds on each (checked against python-control poles)."""
    plants = tuning.position_sets(NOMINAL, 0.3, 0.1)[::2]
    spec = tuning.TuningSpec(pm_min_deg=40.0, tau_max_s=0.05)
    result = tuning.tune(plants, TS, spec, 1, seed=2, popsize=6, maxiter=15, refine=1, refine_evaluations=300,
                         progress=False, feedforward=False)
    for plant, m in zip(plants, result.margins):
        poles = control.poles(control.feedback(tuning.loop_system(result.parameters, plant, 1), 1))
        assert m.tau_cl == pytest.approx(-TS / math.log(float(np.max(np.abs(poles)))), rel=1e-6)
        assert m.tau_cl <= 0.05
    assert result.as_dict()["spec"]["tau_max_s"] == 0.05
    assert "tau_cl" in result.as_dict()["margins"][0]


def test_tau_max_must_be_positive():
    with pytest.raises(tuning.TuningError, match="tau_max_s"):
        tuning.TuningSpec(tau_max_s=0.0)
