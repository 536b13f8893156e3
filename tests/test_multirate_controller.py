"""A controller faster than the recording (issue 23, item 4): a drive's 8 kHz controller under a 1 kHz
recording is simulated at its own period, ``ticks`` = 8 updates per recorded sample.

Reference: an independent simulation, the project's FMU run by fmpy (the C runtime's own integrator) in a hand-run
8 kHz sampled loop, recorded every 8th sample. Units: s, m, N.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording, write_recording
from motiontwin.ident import outputerror as oe
from motiontwin.ident.channels import channel_problem
from motiontwin.ident.controller import Controller, ControllerError, at_recording_step, controller_document
from motiontwin.ident.diagnosis.bundle import BundleError, read_bundle
from tests.fmi_util import fmpy_closed_loop

CLASS = "MotionTwin.Plants.LinearMotorJoint"
TICKS = 8
TS_CTRL = 1 / 8000                 # the drive's controller
TS_REC = TICKS * TS_CTRL           # the recording, 1 kHz
TRUTH = {"m": 2.6, "d": 14.0}
NOISE = 1e-6


def pid(ts: float) -> Controller:
    """PID on e = r - q with a filtered derivative (Tustin at ``ts``): 4e4 N/m, 4e5 N/(m.s), 250 N.s/m, 0.5 ms."""
    kp, ki, kd, tau = 4e4, 4e5, 250.0, 5e-4
    num = np.polyadd(np.polymul([kp, ki], [tau, 1]), [kd, 0, 0])
    a, b, c, d, _ = sps.cont2discrete(sps.tf2ss(num, [tau, 1, 0]), ts, "bilinear")
    return Controller(ts, a, np.hstack([b, -b]), c, np.hstack([d, -d]))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> dict:
    """The 8 kHz loop run by fmpy, the reference and u_ext held over each 1 ms recorded sample; every 8th sample."""
    model = build.load_model(CLASS)
    fmu = build.build_fmu(model, tmp_path_factory.mktemp("multirate"), "2.0").path
    n_rec = 2000
    t = np.arange(n_rec) * TS_REC
    r = 0.01 * np.sin(2 * np.pi * 1.5 * t) ** 2 + 0.004 * np.sin(2 * np.pi * 7.0 * t) ** 2     # from rest
    u_ext = 3.0 * np.sin(2 * np.pi * 23.0 * t)
    noise = NOISE * np.random.default_rng(4).standard_normal(n_rec * TICKS)
    fast = {name: np.repeat(x, TICKS) for name, x in (("r", r), ("u_ext", u_ext))}
    out = {"model": model}
    for key, encoder in (("exact", np.zeros_like(noise)), ("rec", noise)):
        q, u = fmpy_closed_loop(fmu, pid(TS_CTRL), fast["r"], fast["u_ext"], encoder, TRUTH, TS_CTRL)
        out[key] = make_recording(t, {"r": r, "u": u[::TICKS], "q": q[::TICKS], "u_ext": u_ext})
    return out


def test_ticks_from_the_recording_step_and_a_clear_error_otherwise():
    ctrl = at_recording_step(pid(TS_CTRL), np.arange(5) * 0.001000000001, "train.csv")
    assert ctrl.ticks == TICKS and ctrl.sample_time == pytest.approx(TS_REC) and ctrl.Ts == TS_CTRL
    assert at_recording_step(pid(TS_CTRL), np.arange(5) * TS_CTRL, "x").ticks == 1
    with pytest.raises(ControllerError, match=r"train.csv: the recording's step 0.0001875 s is not a whole number.*"
                                              r"ratio 1.5"):
        at_recording_step(pid(TS_CTRL), np.arange(5) * 1.5 * TS_CTRL, "train.csv")


def test_loop_at_the_controllers_own_period_reproduces_the_fast_loop(recorded):
    """Noise-free, the model's free run with the 8 kHz controller (8 updates per 1 ms sample) reproduces the
    fmpy loop's recorded samples to round-off; the same matrices taken as a 1 kHz controller miss by far more
    than the encoder noise of the refit below."""
    rec, model = recorded["exact"], recorded["model"]
    fast = at_recording_step(pid(TS_CTRL), rec.time, "recording")
    q, u = oe.simulate(oe.build_loop(model, fast, "q", ["m"], TRUTH, rec.time.size), rec, TRUTH)
    assert np.max(np.abs(q - rec["q"])) < 1e-12 * np.max(np.abs(rec["q"]))
    assert np.max(np.abs(u - rec["u"])) < 1e-9 * np.max(np.abs(rec["u"]))
    slow = Controller(TS_REC, *(getattr(pid(TS_CTRL), k) for k in "ABCD"))
    q_slow, _ = oe.simulate(oe.build_loop(model, slow, "q", ["m"], TRUTH, rec.time.size), rec, TRUTH)
    assert not np.sqrt(np.mean((q_slow - rec["q"]) ** 2)) < 100 * NOISE


def test_loop_moving_at_t0_starts_its_fast_controller_from_the_recorded_outputs(recorded):
    """A recording that starts mid-move (the fmpy loop's samples from 0.3 s on): the controller state is
    estimated from the first recorded forces with the controller's 8 updates per sample, and the free run
    from that start follows the fmpy loop within 30 um (a 15 mm move; one update per sample: 6.6 mm off)."""
    from motiontwin.ident import plant_states
    from motiontwin.ident.oeloop import output_state

    rec, model = recorded["exact"], recorded["model"]
    k0 = 300
    moving = make_recording(rec.time[k0:] - rec.time[k0], {c: rec[c][k0:] for c in ("r", "u", "q", "u_ext")})
    fast = at_recording_step(pid(TS_CTRL), moving.time, "recording")
    velocity = model.states[plant_states.velocity_state(model, output_state(model, "q"))].name
    loop = oe.build_loop(model, fast, "q", ["m"], TRUTH, moving.time.size, tracking={velocity: "dq"})
    q, _ = oe.simulate(loop, moving, TRUTH)
    assert np.max(np.abs(q - moving["q"])) < 3e-5


def test_refit_from_the_slow_recording_recovers_the_plant(recorded):
    """Output-error refit from the 1 kHz recording with the controller described at its own 8 kHz period: the
    plant's mass and damping within 0.5 %."""
    rec, model = recorded["rec"], recorded["model"]
    result = oe.identify(model, rec, ["m", "d"], controller=pid(TS_CTRL))
    est = result.statistics.as_dict()
    for name, true in TRUTH.items():
        assert est[name] == pytest.approx(true, rel=5e-3), (name, est[name])


def test_channel_check_and_bundle_accept_the_fast_controller(recorded, tmp_path: Path):
    """The channel check (the controller lifted over the recorded sample, the position interpolated) passes the
    consistent recording and still catches a force in the wrong unit; a bundle whose controller runs 8 times
    per recorded sample is read with 8 ticks, one at 1.5 times is refused naming the file."""
    rec = recorded["rec"]
    assert channel_problem(rec, pid(TS_CTRL)) is None
    wrong = make_recording(rec.time, {**rec.columns, "u": 10 * rec["u"]})
    assert "does not match" in channel_problem(wrong, pid(TS_CTRL))
    folder = tmp_path / "bundle"
    folder.mkdir()
    (folder / "plant.mo").write_text((build.MODELICA_DIR / "MotionTwin" / "Plants" / "LinearMotorJoint.mo")
                                     .read_text().replace("within MotionTwin.Plants;\n", ""))
    half = rec.time.size // 2
    for name, part in (("train", slice(0, half)), ("validation", slice(half, None))):
        write_recording(folder / f"{name}.csv", make_recording(rec.time[part] - rec.time[part][0],
                                                               {k: v[part] for k, v in rec.columns.items()}))
    experiment = {"plant": {"modelica": "plant.mo", "class": "LinearMotorJoint", "input": "u", "output": "q"},
                  "controller": controller_document(pid(TS_CTRL)),
                  "recordings": {"train": "train.csv", "validation": "validation.csv"}}
    (folder / "experiment.json").write_text(json.dumps(experiment))
    bundle = read_bundle(folder)
    assert bundle.controller.ticks == TICKS and bundle.controller.Ts == TS_CTRL
    experiment["controller"]["Ts"] = TS_REC / 1.5
    (folder / "experiment.json").write_text(json.dumps(experiment))
    with pytest.raises(BundleError, match=r"train.csv: the recording's step .* not a whole number"):
        read_bundle(folder)


