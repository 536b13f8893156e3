"""motiontwin.comparison: the paper's robust vs computed-torque comparison on the coupled 4-DOF plant.

Independent references: the target pose of the paper (a constant) and the Python inverse kinematics for
where the run must end; the plant FMU's own Modelica forward kinematics against harness.kinematics; fmpy's
simulate_fmu (Co-Simulation) for the holding force computed through Model Exchange; the integral-action
property (zero steady-state error for a constant load) for the steady-state error.
"""
from __future__ import annotations

import json
from pathlib import Path

import fmpy
import numpy as np
import pytest

from motiontwin import cli, comparison
from motiontwin.harness import kinematics, metrics
from motiontwin.harness.recording import read_recording

STOP = 0.2


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return comparison.build_fmus(tmp_path_factory.mktemp("cmp_fmus"))


@pytest.fixture(scope="module")
def outputs(fmus: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("comparison")
    fmu_dir = fmus["plant"].parents[1]
    assert cli.main(["compare", "--out", str(out), "--fmu-dir", str(fmu_dir), "--stop-time", str(STOP)]) == 0
    return out


def test_holding_force_from_model_exchange_keeps_the_cosimulated_plant_at_rest(fmus):
    start = kinematics.cheung_inverse(kinematics.CHEUNG_START_POSE)
    with comparison.PlantDynamics(fmus["plant"]) as dyn:
        np.testing.assert_allclose(dyn.start_state[:4], start, atol=1e-9)
        holding = dyn.inverse(start, np.zeros(4), np.zeros(4))
        mass = dyn.mass_matrix(start)
    assert np.all(np.linalg.eigvalsh(mass) > 0) and np.allclose(mass, mass.T, atol=1e-12)
    assert np.max(np.abs(holding)) > 1e-3  # gravity loads the actuators: the check below is not trivial
    values = {f"u{p}": float(f) for p, f in zip(comparison.PORTS, holding)}
    held = fmpy.simulate_fmu(str(fmus["plant"]), fmi_type="CoSimulation", stop_time=0.1, output_interval=1e-3,
                             start_values=values, output=[f"q{p}" for p in comparison.PORTS])
    free = fmpy.simulate_fmu(str(fmus["plant"]), fmi_type="CoSimulation", stop_time=0.1, output_interval=1e-3,
                             output=[f"q{p}" for p in comparison.PORTS])
    drift = max(abs(held[f"q{p}"][-1] - x) for p, x in zip(comparison.PORTS, start))
    sag = max(abs(free[f"q{p}"][-1] - x) for p, x in zip(comparison.PORTS, start))
    assert drift < 1e-9 < 1e-6 < sag


def test_run_ends_at_the_target_pose_within_the_reported_accuracy(outputs):
    table = json.loads((outputs / "table.json").read_text())
    target = kinematics.CHEUNG_END_POSE
    for controller in comparison.CONTROLLERS:
        rec = read_recording(outputs / f"{controller}.csv")
        d_end = np.array([rec[f"q_{j}"][-1] for j in comparison.JOINTS])
        # the reference ends at the inverse kinematics of the paper's target pose
        np.testing.assert_allclose([rec[f"r_{j}"][-1] for j in comparison.JOINTS], kinematics.cheung_inverse(target),
                                   atol=1e-12)
        # the plant's Modelica forward kinematics agree with harness.kinematics on the whole run
        q = np.column_stack([rec[f"q_{j}"] for j in comparison.JOINTS])
        pose_fk = np.array([kinematics.cheung_forward(row) for row in q])
        np.testing.assert_allclose(pose_fk, np.column_stack([rec[a] for a in comparison.POSE_AXES]), atol=1e-10)
        error = target - kinematics.cheung_forward(d_end)
        accuracy = np.array(table["ours"][controller]["end_effector"]["steady_state_error"])
        assert np.all(np.abs(error[:3]) < metrics.DEFAULT_BAND) and abs(error[3]) < metrics.DEFAULT_THETA_BAND
        assert np.all(np.abs(error - accuracy) <= np.abs(accuracy) + np.array([2e-7, 2e-7, 2e-7, 1e-5]))


def test_integral_action_drives_the_steady_state_error_to_zero(outputs):
    table = json.loads((outputs / "table.json").read_text())["ours"]
    # exact model feedforward + integrator: nothing left to correct at rest, the error decays towards 0
    ct = np.abs(table["computed_torque"]["joints"]["steady_state_error"])
    assert np.max(ct) < 0.1 * metrics.DEFAULT_BAND
    rec = read_recording(outputs / "computed_torque.csv")
    assert all(abs(rec[f"e_{j}"][-1]) < s for j, s in zip(comparison.JOINTS, ct))
    # decoupled feedforward: the integrator still removes the gravity change of the move
    assert np.max(np.abs(table["robust"]["joints"]["steady_state_error"])) < 2e-6
    for controller in comparison.CONTROLLERS:
        settling = table[controller]["joints"]["settling_time"]
        assert all(0 <= s < STOP - comparison.PRE_MOVE - comparison.MOVE_TIME for s in settling)
        assert all(1e-6 < m < 1e-3 for m in table[controller]["joints"]["max_dynamic_error"])


def test_recordings_and_table_are_consistent(outputs):
    table = json.loads((outputs / "table.json").read_text())
    text = (outputs / "table.txt").read_text()
    assert "Table 3" in text and "Table 4" in text and "140.2" in text
    for controller in comparison.CONTROLLERS:
        rec = read_recording(outputs / f"{controller}.csv", required=["time", "q_d1", "r_d1", "u_d1", "x"])
        assert rec.sample_time == comparison.TS and rec.units["u_d1"] == "N"
        e = np.column_stack([rec[f"r_{j}"] - rec[f"q_{j}"] for j in comparison.JOINTS])
        np.testing.assert_allclose(e, np.column_stack([rec[f"e_{j}"] for j in comparison.JOINTS]), atol=1e-15)
        start, end = comparison.PRE_MOVE, comparison.PRE_MOVE + comparison.MOVE_TIME
        np.testing.assert_allclose(metrics.max_dynamic_error(rec.time, e, start, end),
                                   table["ours"][controller]["joints"]["max_dynamic_error"], rtol=1e-12)
    for name in ("comparison_joint_errors.png", "comparison_end_effector.png"):
        assert (outputs / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_design_files_one_for_all_joints_and_clear_errors(tmp_path):
    design = {"Kp": 1000.0, "Ki": 5000.0, "Kd": 8.0, "KL": 10.0, "fp": 300.0, "fc": 600.0, "sigma": 15.0,
              "wl": 380.0, "wh": 400.0, "tau": 1e-3, "Ts": 5e-4}
    path = tmp_path / "tuned.json"
    path.write_text(json.dumps({"parameters": design}))
    designs = comparison.load_designs([path], [0.8, 0.9, 1.0, 1.1], 5.0)
    assert len(designs) == 4
    for d, mass in zip(designs, [0.8, 0.9, 1.0, 1.1]):
        assert d["Ka"] * d["KL"] * d["fc"] / d["fp"] == pytest.approx(mass)  # rigid inverse through F_L's DC gain
        assert d["Kv"] * 20 == pytest.approx(5.0)
    bad = tmp_path / "bad.json"
    bad.write_text('{"parameters": {\n  "Kp": ,}}')
    with pytest.raises(ValueError, match=r"bad.json, line 2, column \d+: invalid JSON"):
        comparison.load_designs([bad], [1.0] * 4, 5.0)
    path.write_text(json.dumps({"parameters": {"Kp": 1.0}}))
    with pytest.raises(ValueError, match="lacks"):
        comparison.load_designs([path], [1.0] * 4, 5.0)
    with pytest.raises(ValueError, match="one design JSON for all joints or four"):
        comparison.load_designs([path, path], [1.0] * 4, 5.0)


def test_computed_torque_default_places_a_triple_pole_and_meets_the_margin_spec():
    import control

    mass, damping = 0.82, 5.0
    gains = comparison.computed_torque_gains([mass], damping, [0.08])[0]
    w = 2 * np.pi * comparison.CT_POLE_HZ
    # continuous loop with exact model and velocity: u = m (Kp e + Ki/s e + Kd s e) + c s q on m s^2 + c s
    s = control.tf("s")
    loop = mass * (gains["Kp"] + gains["Ki"] / s + gains["Kd"] * s) / (mass * s**2)
    poles = np.sort_complex(control.poles(control.feedback(loop, 1)))
    np.testing.assert_allclose(poles, [-w, -w, -w], rtol=1e-3)
    margins = comparison.ct_loop_margins(mass, damping, gains)  # sampled, filtered: the paper's eq. (14)-(15) spec
    assert margins["gm_db"] >= 7.0 and margins["pm_deg"] >= 45.0
