"""Multi-axis diagnosis benchmark generator and runner (issue 16, part D): the truth is the CheungEffects FMU
co-simulated by the harness with one controller and one encoder FMU per axis.

References: a CasADi RK4 closed loop of the library's CheungManipulator (the project's front end, no FMU) with
the same per-axis PIDs; the library plant's rigid-body inverse dynamics evaluated on the truth trajectory
against the closed-form Coulomb law; the bundle format fixed for parts C and D; hand-made diagnosis.json files."""
from __future__ import annotations

import json
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import build
from motiontwin.harness import measurement
from motiontwin.harness.recording import read_recording
from motiontwin.ident.benchmarks import single_axis as single
from motiontwin.ident.benchmarks.truth import V_EPS
from motiontwin.ident.benchmarks import multi_axis as mb

PLANT = mb.CHEUNG


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("benchmark-ma-fmus")


@pytest.fixture(scope="module")
def library_model():
    """The library CheungManipulator through the project's front end (CasADi form, no FMU)."""
    return build.load_model(PLANT.library_class)


@pytest.fixture(scope="module")
def rest() -> tuple[np.ndarray, np.ndarray]:
    return mb.rest_state()


@pytest.fixture(scope="module")
def two_axes(tmp_path_factory, fmu_dir) -> tuple[Path, dict]:
    """A short two-axes bundle: Coulomb friction on q1, position ripple on q5."""
    folder = tmp_path_factory.mktemp("bundles") / "tuning" / "two_axes"       # the runner's layout
    truth = mb.write_bundle(folder, "two_axes", seed=11, scale=1.0, axes=["q1", "q5"], durations=(1.0, 0.5),
                            fmu_dir=fmu_dir)
    return folder, truth


def _casadi_loop(model, r: np.ndarray, u_ext: np.ndarray, noise: np.ndarray, ctrls: list, substeps: int = 16) -> dict:
    """The library CheungManipulator (CasADi form) in closed loop with the per-axis PIDs: at every sample the
    controllers read q + noise, the force C z + D [r; y] + u_ext is held over Ts, RK4 with ``substeps``."""
    fns = model.functions()
    p = model.parameter_values()
    x0 = np.array(fns["x0"](p)).ravel()
    states = [v.name for v in model.states]
    q_idx = [states.index(a[2]) for a in PLANT.axes]
    nx, na = x0.size, len(ctrls)
    x, z = ca.SX.sym("x", nx), ca.SX.sym("z", 2 * na)
    step_in = ca.SX.sym("w", 3 * na)                     # r, noise, u_ext per axis
    r_k, n_k, e_k = step_in[:na], step_in[na:2 * na], step_in[2 * na:]
    u, z_next = [], []
    for j, c in enumerate(ctrls):
        y = ca.vertcat(r_k[j], x[q_idx[j]] + n_k[j])
        zj = z[2 * j:2 * j + 2]
        u.append(ca.mtimes(ca.DM(c.C), zj) + ca.mtimes(ca.DM(c.D), y) + e_k[j])
        z_next.append(ca.mtimes(ca.DM(c.A), zj) + ca.mtimes(ca.DM(c.B), y))
    u = ca.vertcat(*u)
    h = single.TS / substeps
    xs = x
    for _ in range(substeps):
        k1 = fns["ode"](0, xs, u, p)
        k2 = fns["ode"](0, xs + h / 2 * k1, u, p)
        k3 = fns["ode"](0, xs + h / 2 * k2, u, p)
        k4 = fns["ode"](0, xs + h * k3, u, p)
        xs = xs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("loop_step", [ca.vertcat(x, z), step_in],
                       [ca.vertcat(xs, ca.vertcat(*z_next)), ca.vertcat(x[q_idx], u)])
    n = r.shape[0]
    _, out = step.mapaccum("loop", n)(np.concatenate([x0, np.zeros(2 * na)]), np.hstack([r, noise, u_ext]).T)
    out = np.array(out)
    return {"q_true": out[:na].T, "u": out[na:].T}


def test_parameters_only_truth_equals_casadi_closed_loop_of_the_library_plant(library_model, rest, fmu_dir):
    start, masses = rest
    ctrls = mb.controllers(masses)
    rng = np.random.default_rng(2)
    t, r, u_ext = mb.references(1.0, rng, start, 0.1)
    seeds = [1, 2, 3, 4]
    fmu = mb.simulate({}, r, u_ext, seeds, ctrls, start, fmu_dir, resolution=1e-15)
    # the same drive and noise with the pre-roll, as simulate applies it
    cols = [single.with_preroll(r[:, j], u_ext[:, j], float(start[j])) for j in range(4)]
    rr, ue = np.column_stack([c[0] for c in cols]), np.column_stack([c[1] for c in cols])
    noise = np.column_stack([measurement.add_noise(np.zeros(rr.shape[0]), single.NOISE, np.random.default_rng(s))
                             for s in seeds])
    ref = _casadi_loop(library_model, rr, ue, noise, ctrls, substeps=4)
    pre = cols[0][2]
    dq = fmu["q_true"] - ref["q_true"][pre:]
    assert np.max(np.abs(dq)) < 1e-10                                  # 1 % of the encoder noise std
    assert np.max(np.abs(fmu["u"] - ref["u"][pre:])) < 1e-5             # N
    assert np.max(np.abs(fmu["q_true"] - start)) > 2e-3                 # the loop actually moved every axis
    assert np.all(np.ptp(fmu["q_true"], axis=0) > 1e-4) and np.max(np.ptp(fmu["q_true"], axis=0)) > 5e-3


def test_concealed_effect_is_present_as_a_force_on_its_axis_only(library_model, rest, fmu_dir):
    """Coulomb friction on q5: the library plant's rigid-body inverse dynamics on the truth trajectory leaves
    u - F_rigid = Fc*tanh(v5/v_eps) on q5 and nothing on the other actuators."""
    start, masses = rest
    values, effects = mb.truth_parameters("coulomb_friction", ["q5"], 1.0)
    fc = effects[0]["contract"]["Fc"]
    rng = np.random.default_rng(5)
    t, r, u_ext = mb.references(1.5, rng, start, 0.1)
    out = mb.simulate(values, r, u_ext, [1, 2, 3, 4], mb.controllers(masses), start, fmu_dir, noise_std=0.0,
                      resolution=1e-15)
    q, u, h = out["q_true"], out["u"], single.TS
    v = (q[2:] - q[:-2]) / (2 * h)
    acc = (q[2:] - 2 * q[1:-1] + q[:-2]) / h ** 2
    force = (u[1:-1] + u[:-2]) / 2                     # the held forces of the two intervals around sample k
    model = library_model
    accel = ca.Function("accel", [model.x, model.u, model.p],
                        [model.dx[4:], ca.jacobian(model.dx[4:], model.u)])   # M^-1 (u - c - g - c_v v), M^-1
    x = np.hstack([q[1:-1], v])
    p = model.parameter_values()
    n = x.shape[0]
    free, per_force = (np.array(a) for a in accel.map(n)(x.T, np.zeros((4, n)), np.tile(p, (n, 1)).T))
    per_force = per_force.reshape(4, n, 4).transpose(1, 0, 2)
    rigid = np.linalg.solve(per_force, (acc - free.T)[..., None])[..., 0]
    residual = force - rigid
    expected = fc * np.tanh(v[:, 2] / V_EPS)
    assert np.sqrt(np.mean((residual[:, 2] - expected) ** 2)) < 0.02 * fc        # measured 0.3 %
    assert np.max(expected) > 0.9 * fc and np.min(expected) < -0.9 * fc   # it slid both ways
    for j in (0, 1, 3):
        assert np.sqrt(np.mean(residual[:, j] ** 2)) < 0.01 * fc                 # measured 0.07 %


def test_two_axes_bundle_follows_the_format(two_axes, rest):
    folder, truth = two_axes
    experiment = json.loads((folder / "experiment.json").read_text())
    plant = experiment["plant"]
    assert plant["class"] == "MotionTwin.Plants.CheungManipulator" and "modelica" not in plant
    assert "input" not in plant and "output" not in plant
    assert [(a["input"], a["output"]) for a in plant["axes"]] == [("u1", "q1"), ("u3", "q3"), ("u5", "q5"),
                                                                  ("u7", "q7")]
    for name, value in plant["parameters"].items():                   # nominal 20-40 % off the library value
        assert 0.2 - 1e-3 <= abs(value / truth["nominal"]["true"][name] - 1) <= 0.4 + 1e-3
    ctrl = experiment["controller"]
    assert ctrl["kind"] == "per_axis" and len(ctrl["axes"]) == 4
    _, masses = rest
    for c, m in zip(ctrl["axes"], masses):
        assert c["kind"] == "discrete_state_space" and c["Ts"] == single.TS
        assert c["inputs"] == ["r", "q"] and c["outputs"] == ["u"]
        assert np.allclose(c["A"], single.pid_controller(mass=m, bandwidth=mb.BANDWIDTH).A)
        assert np.allclose(c["D"], single.pid_controller(mass=m, bandwidth=mb.BANDWIDTH).D)
    assert experiment["recordings"] == {"train": "train.csv", "validation": "validation.csv"}
    columns = ["time"] + [c for i, o in PLANT.ports for c in (f"r_{o}", i, o, f"u_ext_{i}")]
    for part, n in (("train", 2000), ("validation", 1000)):
        rec = read_recording(folder / f"{part}.csv", required=columns)
        assert rec.time.size == n and np.allclose(np.diff(rec.time), single.TS) and rec.time[0] == 0
        for _, o in PLANT.ports:
            counts = rec[o] / single.RESOLUTION
            assert np.max(np.abs(counts - np.round(counts))) < 1e-3    # on the encoder grid
        assert (folder / f"{part}.csv").read_text().splitlines()[0].split(",") == columns
    saved = json.loads((folder.parent / "two_axes.truth.json").read_text())
    assert [(e["axis"], e["name"]) for e in saved["effects"]] == [("q1", "coulomb_friction"),
                                                                   ("q5", "position_ripple")]
    assert saved["effects"][0]["contract"]["Fc"] == pytest.approx(0.15 * mb.EFFECT_SCALE)
    params = saved["truth_model"]["parameters"]
    assert params["Fc_1"] == params["Fs_1"] == pytest.approx(0.15 * mb.EFFECT_SCALE)
    assert params["A_5"] == pytest.approx(mb.EFFECT_SCALE * np.hypot(0.5, 0.3))
    assert not any(k.endswith(("_3", "_7")) for k in params)
    hidden = saved["concealment"]
    assert 0.3e-6 < hidden["q1"]["max_abs_m"] < 20e-6 and 0.3e-6 < hidden["q5"]["max_abs_m"] < 20e-6
    assert hidden["q1"]["force_max_abs_N"] > 3 * max(hidden["q3"]["force_max_abs_N"],
                                                    hidden["q7"]["force_max_abs_N"])


def test_effective_masses_are_the_inverse_of_the_force_to_acceleration_map(library_model, rest):
    """At the rest pose, finite force steps on the library plant's ODE give M^-1 column by column."""
    _, masses = rest
    model = library_model
    fns, p = model.functions(), model.parameter_values()
    x0 = np.array(fns["x0"](p)).ravel()
    ode = lambda u: np.array(fns["ode"](0.0, x0, u, p)).ravel()[4:]    # the velocity states' derivatives
    per_force = np.column_stack([ode(np.eye(4)[j]) - ode(np.zeros(4)) for j in range(4)])
    assert np.allclose(masses, np.diag(np.linalg.inv(per_force)), rtol=1e-9)
    assert np.all((masses > 0.7) & (masses < 1.0))                     # slider 0.7 kg plus its share of the links


def test_effects_go_on_named_axes_of_the_plant():
    with pytest.raises(ValueError, match="needs 1 different axes among q1, q3, q5, q7, got \\['q2'\\]"):
        mb.truth_parameters("coulomb_friction", ["q2"], 1.0)
    with pytest.raises(ValueError, match="needs 2 different axes"):
        mb.truth_parameters("two_axes", ["q3", "q3"], 1.0)


def test_workspace_check_refuses_positions_outside_the_actuator_ranges(rest):
    start, _ = rest
    mb.check_workspace(np.tile(start, (3, 1)), "rest")
    outside = np.tile(start, (3, 1))
    outside[1, 0] = 0.05                                              # d1 below its 59.5 mm limit
    with pytest.raises(ValueError, match="sample 1 leaves the 4-DOF workspace"):
        mb.check_workspace(outside, "test")


def _doc(effects: list[dict]) -> dict:
    per_axis = {o: {"nominal_rms": 2e-6, "augmented_rms": 1e-7, "noise_floor_rms": 1e-8} for o in PLANT.outputs}
    return {"effects": effects, "augmented_parameters": {"m_s": 0.77, "c_v": 5.0},
            "validation": {"nominal_rms": 2e-6, "augmented_rms": 1e-7, "per_axis": per_axis}}


def test_runner_scores_a_hand_made_diagnosis(two_axes):
    _, truth = two_axes
    fc = truth["effects"][0]["contract"]["Fc"]
    doc = _doc([{"name": "coulomb_friction", "axis": "q1", "parameters": {"Fc": 1.1 * fc}},
                {"name": "position_ripple", "axis": "q3", "parameters": {"amplitude": 0.2}},
                {"name": "gravity_offset", "axis": "q7", "parameters": {"F0": 0.1}}])
    s = mb.score(doc, truth)
    assert s["outcomes"] == [("coulomb_friction", "coulomb_friction"), ("position_ripple", "wrong axis")]
    assert s["false_positives"] == ["gravity_offset"]
    assert s["parameter_errors"] == {"q1:Fc": pytest.approx(0.1)}
    assert s["nominal_errors"]["m_s"] == pytest.approx(0.77 / 0.7 - 1)
    assert s["validation"]["q5"] == (2e-6, 1e-7)
    # a parameters-only truth: nothing found is the (none, none) cell, an empirical term counts as unexplained
    quiet = {**truth, "effects": []}
    empty, empirical = mb.score(_doc([]), quiet), mb.score(_doc([{"name": "empirical_q3", "axis": "q3",
                                                                   "empirical": True, "parameters": {}}]), quiet)
    # the verdict's "unexplained" (no effect entry) counts as unexplained on its axis too
    verdict = mb.score({**_doc([]), "unexplained": {"status": "unexplained, no term validated", "axis": "q3"}}, quiet)
    assert verdict["false_positives"] == [mb.UNEXPLAINED]
    # the ripple on q5 reported on its axis as something else, and a found name on the right axis
    other = mb.score(_doc([{"name": "stribeck_friction", "axis": "q5", "parameters": {}}]), truth)
    assert other["outcomes"] == [("coulomb_friction", "(none)"), ("position_ripple", "stribeck_friction")]
    novel = mb.score(_doc([{"name": "backlash", "axis": "q7", "parameters": {}}]), quiet)   # a new candidate
    rows, cols, table = mb.confusion_table([s, empty, empirical, other, novel])
    assert table["(none)"]["backlash"] == 1 and cols[-3:] == [mb.UNEXPLAINED, "wrong axis", "(none)"]
    assert table["coulomb_friction"]["coulomb_friction"] == 1 and table["coulomb_friction"]["(none)"] == 1
    assert table["position_ripple"]["wrong axis"] == 1 and table["position_ripple"]["stribeck_friction"] == 1
    assert table["(none)"]["gravity_offset"] == 1 and table["(none)"][mb.UNEXPLAINED] == 1
    assert table["(none)"]["(none)"] == 1
    assert sum(sum(row.values()) for row in table.values()) == 8
    line = mb.format_line("two_axes", truth, s, wall=301.0, cpu=550.0)
    assert "OVER vs 300 s" in line and "q1:Fc +10%" in line and "q5 2e-06->1e-07 (x0.05)" in line
    assert "(ok vs 300 s)" in mb.format_line("two_axes", truth, s, wall=120.0, cpu=200.0)
    diverged = mb.format_line("two_axes", truth, {**s, "validation": {"q1": (3e-6, None)}}, wall=1.0, cpu=None)
    assert "q1 3e-06->None (diverged)" in diverged
    text = mb.print_confusion([s, empty, empirical, other])
    assert text.splitlines()[-1].split()[-1] == "1"                   # (none) row ends with the (none) count


def test_score_command_prints_the_table_of_a_hand_made_diagnosis_json(two_axes, capsys):
    folder, truth = two_axes
    out = folder.parent.parent
    doc = _doc([{"name": "position_ripple", "axis": "q5", "parameters": {
        "amplitude": 0.8 * truth["effects"][1]["contract"]["amplitude"]}}])
    result = out / "results" / "tuning" / "two_axes"
    result.mkdir(parents=True)
    (result / "diagnosis.json").write_text(json.dumps({**doc, "runtime_s": 42.0}))
    assert mb.main(["score", str(out), "--set", "tuning", "--case", "two_axes"]) == 0
    text = capsys.readouterr().out
    assert "outcome=coulomb_friction->(none),position_ripple->position_ripple" in text
    assert "q5:amplitude -20%" in text and "wall 42 s cpu - (ok vs 300 s)" in text
    rows = {line.split()[0]: [int(n) for n in line.split()[1:]] for line in text.splitlines()
            if line.split() and line.split()[0] in list(single.MAIN_PARAMETER) + ["(none)"]}
    ripple = list(single.MAIN_PARAMETER).index("position_ripple")
    assert rows["coulomb_friction"][-1] == 1 and rows["position_ripple"][ripple] == 1
    assert sum(map(sum, rows.values())) == 2
    assert mb.main(["score", str(out), "--set", "tuning", "--case", "gravity_offset"]) == 1   # no results
    assert "gravity_offset     diagnosis failed" in capsys.readouterr().out
