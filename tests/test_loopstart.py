"""The state a closed loop starts from on a recording (ident/loopstart.py), whose model- and recording-only
parts are derived once and kept: what is kept must follow the model and the recording it came from.

References: the controller's own recursion (a recording whose forces the controller produced from a known state
must give that state back, also after another recording with the same controller was started), and the model's
declared start values (a model copied with other start values starts there, not at the first model's).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording
from motiontwin.ident import loopstart
from motiontwin.ident import outputerror as oe
from motiontwin.ident.controller import Controller

TS = 5e-4
N = 400
VALUES = {"m": 2.0, "d": 10.0}


def pd_controller() -> Controller:
    """PD with a filtered derivative on e = r - q (one controller state), Tustin at TS."""
    kp, kd, tau = 2e4, 300.0, 1e-3
    a, b, c, d, _ = sps.cont2discrete(tuple(np.array([[v]]) for v in (-1 / tau, 1.0, -kd / tau ** 2, kp + kd / tau)),
                                     TS, "bilinear")
    return Controller(TS, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([d, -d]))


def recording(ctrl: Controller, z_true: float, q0: float = 1e-3):
    """A loop held at q0 = r whose recorded force is the controller's own output from the state ``z_true``."""
    t = np.arange(N) * TS
    y = np.array([q0, q0])
    z, u = np.array([z_true]), np.empty(N)
    for k in range(N):
        u[k] = float((ctrl.C @ z + ctrl.D @ y)[0])
        z = ctrl.A @ z + ctrl.B @ y
    return make_recording(t, {"r": np.full(N, q0), "q": np.full(N, q0), "u": u})


@pytest.fixture(scope="module")
def model():
    return build.load_model("MotionTwin.Plants.LinearMotorJoint")


def test_controller_start_is_each_recordings_own(model):
    """A loop moving at t = 0 (velocity from the first samples) takes the controller state from the first
    recorded forces: the state they were recorded from, for each recording in turn (nothing stale is kept)."""
    ctrl = pd_controller()
    loop = oe.build_loop(model, ctrl, "q", [], VALUES, N, with_jacobian=False, tracking={"v": "dq"})
    for z_true in (3.0, -7.5, 3.0):
        s0 = loopstart.initial_state(loop, recording(ctrl, z_true))
        assert s0[-1] == pytest.approx(z_true, rel=1e-9)
        assert s0[[v.name for v in model.states].index("x")] == 1e-3


def test_start_state_follows_the_models_own_start_values(model):
    names = [v.name for v in model.states]
    rec = recording(pd_controller(), 0.0)
    loop = oe.build_loop(model, pd_controller(), "q", [], VALUES, N, with_jacobian=False)
    assert loopstart.initial_state(loop, rec)[names.index("v")] == 0.0
    moving = model.with_start_values({"v": 0.25})
    other = oe.build_loop(moving, pd_controller(), "q", [], VALUES, N, with_jacobian=False)
    assert loopstart.initial_state(other, rec)[names.index("v")] == 0.25
    assert loopstart.initial_state(loop, rec)[names.index("v")] == 0.0
