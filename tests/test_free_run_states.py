"""The free run's state trajectory (:func:`outputerror.simulate_states`) and the inverse dynamics of models with
more than the two motion states (issue 22 item 5), whose other states come from that free run.

References: the same free run's output (:func:`outputerror.simulate`, compiled chain), the closed-form step
response of a mass-damper v(t) = F/d (1 - exp(-d t/m)), and known forces left out of a two-mass resonance and
a Pade-delayed joint (the library's MotionTwin.Effects models) simulated with their states. Units: s, m, N.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording
from motiontwin.ident import outputerror as oe
from motiontwin.ident.controller import Controller
from motiontwin.ident.diagnosis import evidence

TS = 5e-4                       # 2 kHz
MASS_DAMPER = {"m": 2.0, "d": 10.0}
TWO_MASS = {"m1": 1.2, "m2": 0.8, "k": 2e4, "c": 5.0, "d": 10.0}    # resonance at 32 Hz, inside the 150 Hz filter
DELAYED = {"m": 2.0, "d": 10.0, "T": 4e-3}
RESIDUAL_TOLERANCE = 0.02       # residual error within 2 % of the RMS of the force left out
EDGE = 0.05                     # share of samples at each end left out (the derivative filter's end effects)


def pd_controller() -> Controller:
    """PD with a first-order derivative filter on e = r - q, Tustin-discretised: 2e4 N/m, 300 N.s/m, 1 ms."""
    kp, kd, tau = 2e4, 300.0, 1e-3
    a, b, c, d, _ = sps.cont2discrete(tuple(np.array([[v]]) for v in (-1 / tau, 1.0, -kd / tau ** 2, kp + kd / tau)),
                                     TS, "bilinear")
    return Controller(TS, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([d, -d]))


def open_loop(class_name: str, values: dict[str, float], force: np.ndarray) -> tuple[oe.Loop, object]:
    """The plant's open-loop free run driven by ``force`` (held over each sample) and its recording."""
    model = build.load_model(class_name)
    loop = oe.build_loop(model, None, "q", [], values, force.size, ts=TS, with_jacobian=False)
    t = np.arange(force.size) * TS
    return loop, make_recording(t, {"q": np.zeros(t.size), "u": force})


def test_position_row_is_the_free_run_output_in_closed_loop():
    """Closed loop (PD tracking a smooth move): the position row of the state trajectory is the free run's q
    sample for sample, and the trajectory has the plant's two states (not the controller's)."""
    model = build.load_model("MotionTwin.Plants.LinearMotorJoint")
    n = 2000
    t = np.arange(n) * TS
    rec = make_recording(t, {"r": 0.01 * (1 - np.cos(2 * np.pi * 2 * t)), "q": np.zeros(n), "u": np.zeros(n)})
    loop = oe.build_loop(model, pd_controller(), "q", ["m"], MASS_DAMPER, n, with_jacobian=False)
    q, _ = oe.simulate(loop, rec, {"m": 2.4})
    states = oe.simulate_states(loop, rec, {"m": 2.4})
    assert states.shape == (2, n)
    assert np.max(np.abs(q)) > 5e-3
    np.testing.assert_allclose(states[[s.name for s in model.states].index("x")], q, rtol=0, atol=1e-15)


def test_velocity_row_is_the_step_response_of_a_mass_damper():
    """Open loop, a 4 N step from rest: the velocity row equals F/d (1 - exp(-d t/m)) at the sample instants
    (the row at t = 0 is the initial state) and the position row its integral."""
    force = np.full(3000, 4.0)
    loop, rec = open_loop("MotionTwin.Plants.LinearMotorJoint", MASS_DAMPER, force)
    states = oe.simulate_states(loop, rec)
    names = [s.name for s in loop.model.states]
    m, d = MASS_DAMPER["m"], MASS_DAMPER["d"]
    t = rec.time
    v = 4.0 / d * (1 - np.exp(-d * t / m))
    x = 4.0 / d * (t - m / d * (1 - np.exp(-d * t / m)))
    np.testing.assert_allclose(states[names.index("v")], v, rtol=0, atol=1e-9 * v.max())
    np.testing.assert_allclose(states[names.index("x")], x, rtol=0, atol=1e-9 * x.max())


def _force_left_out(t: np.ndarray) -> np.ndarray:
    """A force the fitted model does not have [N]: an offset and a slow oscillation."""
    return 3.0 + 2.0 * np.sin(2 * np.pi * 3 * t)


@pytest.mark.parametrize("class_name, values, motion", [
    ("MotionTwin.Effects.TwoMassJoint", TWO_MASS, ("x1", "v1")),
    ("MotionTwin.Effects.DelayedInputJoint", DELAYED, ("x", "v")),
])
def test_inverse_dynamics_with_free_run_states(class_name, values, motion):
    """A plant with more than the motion states (load states; Pade states driven by the input) in a PD loop
    moving from rest to rest, while a force F acts against the recorded force u: with its other states from
    the free run the recorded (q, u) leave the residual F within 2 % of F's RMS (the input gain d(acc)/du is
    the plant's force gain, 1/m1 or 1/m, through the delay's direct feedthrough); with those states at rest
    instead, over 5 times the tolerance is left."""
    n = 4400                                        # 2 s of moves, then 0.2 s at rest
    t = np.arange(n) * TS
    moving = t < 2.0
    r = moving * sum(a * (1 - np.cos(2 * np.pi * f * t)) for a, f in ((5e-3, 1), (2e-3, 4), (5e-4, 9)))
    force = _force_left_out(t)
    rec = make_recording(t, {"r": r, "u_ext": -force, "q": np.zeros(n), "u": np.zeros(n)})
    model = build.load_model(class_name)
    loop = oe.build_loop(model, pd_controller(), "q", [], values, n, with_jacobian=False)
    q, u = oe.simulate(loop, rec)
    states = oe.simulate_states(loop, rec)
    recorded = make_recording(t, {"q": q, "u": u + force})    # the plant felt u, the recording says u + F
    assert model.x.numel() == 4
    assert evidence.inverse_dynamics(recorded, model, values, *motion, TS, held_input=True) is None
    inner = slice(int(EDGE * n), int((1 - EDGE) * n))
    tolerance = RESIDUAL_TOLERANCE * np.sqrt(np.mean(force[inner] ** 2))
    inv = evidence.inverse_dynamics(recorded, model, values, *motion, TS, held_input=True, states=states)
    assert np.sqrt(np.mean((inv.force[inner] - force[inner]) ** 2)) < tolerance
    at_rest = np.zeros_like(states)
    inv_rest = evidence.inverse_dynamics(recorded, model, values, *motion, TS, held_input=True, states=at_rest)
    assert np.sqrt(np.mean((inv_rest.force[inner] - force[inner]) ** 2)) > 5 * tolerance
