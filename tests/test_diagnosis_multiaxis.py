"""Multi-axis diagnosis (issue 16, part C) on a coupled two-carriage plant (inertial and elastic coupling, so
an effect on one axis moves both): the MIMO output-error loop against an exact discrete-time reference, the
bundle errors, and the decisions on CasADi-truth bundles (the augmented model with the true effect on one axis,
white encoder noise fed back through the loop): Coulomb friction on q2 -> exactly that effect on q2; a
parameters-only bundle -> no effect."""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from motiontwin.fmus import build, frontend, symbolic
from motiontwin.harness.recording import make_recording
from motiontwin.ident import oeloop, outputerror
from motiontwin.ident.controller import Controller, block_diagonal
from motiontwin.ident.diagnosis import diagnose_bundle, read_bundle, structure
from motiontwin.ident.benchmarks import multi_axis_truth as truth
from motiontwin.ident.diagnosis.bundle import BundleError

TS = 5e-4
PLANT = truth.COUPLED2_TEXT
AXES = truth.COUPLED2_AXES
CONTROLLER = {"kind": "per_axis", "axes": [truth.pid_document(TS, 2.0, 60.0), truth.pid_document(TS, 3.0, 60.0)]}
START = {"m1": 2.3, "d": 8.0}          # the nominal model is off: the refit must move these, not name an effect
FC_TRUE = 0.3


def _bundle(folder: Path, effects: list[truth.TrueEffect], seed: int) -> Path:
    plant = {"class": "Coupled2", "axes": AXES, "parameters": START}
    truth.write_bundle(folder, plant, CONTROLLER, effects, 2.0, 1.0, seed=seed, plant_text=PLANT)
    return folder


@pytest.fixture(scope="module")
def coulomb_q2(tmp_path_factory) -> tuple[dict, Path]:
    folder = _bundle(tmp_path_factory.mktemp("coulomb") / "bundle",
                     [truth.TrueEffect("coulomb_friction", "q2", {"coulomb_Fc": FC_TRUE, "coulomb_v_eps": 1e-4})], 3)
    out = folder.parent / "out"
    lines: list[str] = []
    doc = diagnose_bundle(folder, out, progress=lines.append)
    (folder.parent / "progress.txt").write_text("\n".join(lines))
    return doc, out


def test_mimo_loop_matches_exact_discrete_closed_loop(tmp_path):
    """The two-axis closed loop of build_loop (RK4) against the exact ZOH discretisation of the linear coupled
    plant (scipy matrix exponential) closed by the block-diagonal PID, stepped in numpy."""
    (tmp_path / "plant.mo").write_text(PLANT)
    model = symbolic.build(frontend.load(tmp_path / "plant.mo", "Coupled2"))
    ctrl = block_diagonal([_pid(2.0), _pid(3.0)])
    n = 800
    rng = np.random.default_rng(0)
    r = np.vstack([0.01 + 1e-3 * np.sin(np.arange(n) * TS * 2 * np.pi * 3), 0.02 + 5e-4 * np.sign(
        np.sin(np.arange(n) * TS * 2 * np.pi * 5))])
    u_ext = rng.normal(0, 0.5, (2, n))
    signals = [outputerror.axis_signals("u1", "q1"), outputerror.axis_signals("u2", "q2")]
    cols = {}
    for k, s in enumerate(signals):
        cols.update({s.reference: r[k], s.input: np.zeros(n), s.output: np.full(n, r[k, 0]), s.disturbance: u_ext[k]})
    rec = make_recording(np.arange(n) * TS, cols)
    values = {v.name: float(v.start) for v in model.parameters}
    loop = outputerror.build_loop(model, ctrl, "q1", [], values, n, substeps=8, with_jacobian=False, axes=signals)
    q, u = outputerror.simulate(loop, rec)
    # reference: x = [x1, x2, v1, v2], M dv = u - d v - K x
    m = np.array([[2.0, 0.6], [0.6, 3.0]])
    k_mat = 2000 * np.array([[1, -1], [-1, 1]])
    a_c = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(m, k_mat), -10 * np.linalg.inv(m)]])
    b_c = np.vstack([np.zeros((2, 2)), np.linalg.inv(m)])
    big = scipy.linalg.expm(np.block([[a_c, b_c], [np.zeros((2, 6))]]) * TS)
    ad, bd = big[:4, :4], big[:4, 4:]
    x = np.array([0.01, 0.02, 0.0, 0.0])
    y0 = np.concatenate([r[:, 0], x[:2]])
    z = np.linalg.pinv(ctrl.C) @ (np.zeros(2) - u_ext[:, 0] - ctrl.D @ y0)   # recorded u_0 (= 0) reproduced
    q_ref, u_ref = np.zeros((2, n)), np.zeros((2, n))
    for i in range(n):
        y = np.concatenate([r[:, i], x[:2]])
        force = ctrl.C @ z + ctrl.D @ y + u_ext[:, i]
        q_ref[:, i], u_ref[:, i] = x[:2], force
        z = ctrl.A @ z + ctrl.B @ y
        x = ad @ x + bd @ force
    assert q.shape == (2, n)
    assert np.max(np.abs(q - q_ref)) < 1e-6 * np.ptp(q_ref)
    assert np.max(np.abs(u - u_ref)) < 1e-6 * np.ptp(u_ref)
    assert np.ptp(q_ref[1]) > 1e-4              # the loop really moves both axes


def _pid(mass: float) -> Controller:
    from motiontwin.ident.controller import read_controller

    return read_controller(truth.pid_document(TS, mass, 60.0), "pid")


def _coupled_case(tmp_path: Path, n: int, disturbance: float) -> tuple:
    """The coupled plant, its block-diagonal PID, the axes' columns and a recording of sine references."""
    (tmp_path / "plant.mo").write_text(PLANT)
    model = symbolic.build(frontend.load(tmp_path / "plant.mo", "Coupled2"))
    signals = [outputerror.axis_signals("u1", "q1"), outputerror.axis_signals("u2", "q2")]
    t = np.arange(n) * TS
    cols = {}
    for k, s in enumerate(signals):
        cols.update({s.reference: 0.01 * (k + 1) + 1e-3 * np.sin(2 * np.pi * (k + 2) * t), s.input: np.zeros(n),
                     s.output: np.full(n, 0.01 * (k + 1)), s.disturbance: disturbance * np.sin(2 * np.pi * 40 * t)})
    values = {v.name: float(v.start) for v in model.parameters}
    return model, block_diagonal([_pid(2.0), _pid(3.0)]), signals, make_recording(t, cols), values


def test_mimo_jacobian_matches_finite_differences(tmp_path):
    """The chained AD sensitivities of a two-axis loop (channel-major rows) against central differences."""
    n = 300
    model, ctrl, signals, rec, values = _coupled_case(tmp_path, n, 0.0)
    free = ["m1", "kc"]
    loop = outputerror.build_loop(model, ctrl, "q1", free, values, n, substeps=4, axes=signals)
    weights = outputerror.Weights(np.array([1e-6, 2e-6]), np.array([0.1, 0.3]))
    s0 = outputerror.initial_state(loop, rec)
    W = outputerror.drive(rec, signals=loop.channels)
    pf = loop.pfix()
    jac = outputerror.weighted_jacobian(loop, s0, W, loop.theta(), pf, [], weights)
    for j, name in enumerate(free):
        h = 1e-6 * values[name]
        res = [outputerror.residuals(loop, rec, {**values, name: values[name] + sign * h}, weights)[0]
               for sign in (1, -1)]
        numeric = (res[0] - res[1]) / (2 * h)
        assert np.max(np.abs(jac[:, j] - numeric)) < 1e-4 * np.max(np.abs(numeric))


@pytest.mark.parametrize("ticks", [1, 2])
def test_called_rhs_loop_equals_inlined_loop(tmp_path, monkeypatch, ticks):
    """The large-plant forms of the loop (right-hand side and its full Jacobians, or its forward directional
    derivatives, called in an MX graph, variational RK4 written out) against the inlined SX loop with CasADi's
    own AD: same free run and same Jacobian, the initial-state sensitivities included; also with a controller
    updating twice per recorded sample (``ticks`` = 2, the same matrices at half the period)."""
    n = 400
    model, ctrl, signals, rec, values = _coupled_case(tmp_path, n, 0.2)
    ctrl = dataclasses.replace(ctrl, Ts=ctrl.Ts / ticks, ticks=ticks)
    tracking = {"v2": "dq:q2"}
    loops = []
    for limit, directional in ((10 ** 9, 10 ** 9), (0, 10 ** 9), (0, 0)):   # inlined SX, called, directional
        monkeypatch.setattr(oeloop, "CALL_INSTRUCTIONS", limit)
        monkeypatch.setattr(oeloop, "DIRECTIONAL_INSTRUCTIONS", directional)
        loops.append(outputerror.build_loop(model, ctrl, "q1", ["m1", "kc", "d"], values, n, substeps=2,
                                            axes=signals, tracking=tracking))
    s0 = outputerror.initial_state(loops[0], rec)
    W = outputerror.drive(rec, signals=loops[0].channels)
    args = (s0, W, loops[0].theta(), loops[0].pfix())
    for called in loops[1:]:
        for inlined, other in zip(loops[0].sim(*args), called.sim(*args)):
            assert np.max(np.abs(np.array(inlined) - np.array(other))) <= 1e-12 * np.max(np.abs(inlined))
        blocks = list(zip(loops[0].jac(*args), called.jac(*args)))
        assert len(blocks) == 4 and all(np.size(b[0]) for b in blocks)
        for inlined, other in blocks:
            assert np.max(np.abs(np.array(inlined) - np.array(other))) <= 1e-9 * np.max(np.abs(inlined))


def test_large_plants_take_directional_derivatives():
    """Where the threshold sits (both forms give the same values, above): the CheungManipulator's full Jacobian
    (13 901 instructions) stays whole, the Hexapod's (69 463) gives way to forward directions, as measured
    (Hexapod Jacobian pass over 1500 samples 2.5 -> 0.8 s of CPU, generated C 5.5 -> 1.2 MB; the
    CheungManipulator 1.6x slower with directions): a threshold moved past either plant turns this red."""
    assert not oeloop.directional_derivatives(build.load_model("MotionTwin.Plants.CheungManipulator"))
    assert oeloop.directional_derivatives(build.load_model("MotionTwin.Plants.Hexapod"))


def test_coulomb_on_one_axis_found_on_that_axis(coulomb_q2):
    """Coulomb friction concealed on q2 of the coupled plant: located on q2 (its force residual), exactly
    coulomb_friction on q2, Fc within 3 %, q2's validation RMS at the noise floor (within 20 %)."""
    doc, out = coulomb_q2
    assert [(e["name"], e["axis"]) for e in doc["effects"]] == [("coulomb_friction", "q2")]
    assert doc["effects"][0]["parameters"]["Fc"] == pytest.approx(FC_TRUE, rel=0.03)
    first = doc["location"][0]["scores"]
    assert max(first, key=first.get) == "q2"
    q2 = doc["validation"]["per_axis"]["q2"]
    assert q2["augmented_rms"] < 0.2 * q2["nominal_rms"]
    assert q2["augmented_rms"] < 1.2 * q2["noise_floor_rms"]
    assert doc["augmented_parameters"]["m1"] == pytest.approx(2.0, rel=0.01)   # the start was 2.3
    model = (out / "augmented_model" / "Augmented.mo").read_text()
    assert "plant.u2 = u2 - (MotionTwin.Effects.CoulombFriction(plant.v2, q2_coulomb_Fc" in model
    assert "plant.u1 = u1;" in model
    assert "coulomb_friction on axis q2" in (out / "report.md").read_text()
    assert {entry["round"] for entry in doc["candidates"]} == {1}     # no axis left above 1.5x its noise level
    assert max(doc["location"][1]["scores"].values()) < 1.5


def test_time_delay_score_tested_on_the_located_axis(coulomb_q2):
    """The multi-axis selection runs the time delay's score test on the located axis inside the screening (its
    line logged by the main process) and screens the delay only when it passes: no delay here, so no
    screening line of it."""
    _, out = coulomb_q2
    lines = (out.parent / "progress.txt").read_text().splitlines()
    assert any(line.startswith("  score test time_delay on q2: predicted cost") and "(not screened" in line
               for line in lines)
    assert not any(line.startswith("  screen time_delay") for line in lines)


def test_written_fmu_is_self_contained_and_carries_the_fit(coulomb_q2):
    """The augmented model is written with the MotionTwin library beside it (it loads without the project's
    library path) and built into an FMI 2.0 FMU whose start values are the fitted parameters; fmpy validates
    the FMU and simulates it from those defaults."""
    import fmpy
    from fmpy.validation import validate_fmu

    doc, out = coulomb_q2
    fmu = Path(doc["augmented_fmu"])
    assert fmu.is_file() and fmu.parent.parent == out / "fmu"
    assert (out / "augmented_model" / "MotionTwin" / "Effects" / "CoulombFriction.mo").is_file()
    symbolic.build(frontend.load(out / "augmented_model", "Augmented"))     # no library path given
    assert validate_fmu(str(fmu)) == []
    starts = {v.name: v.start for v in fmpy.read_model_description(str(fmu)).modelVariables}
    assert float(starts["q2_coulomb_Fc"]) == pytest.approx(doc["effects"][0]["parameters"]["Fc"], rel=1e-12)
    assert float(starts["plant.m1"]) == pytest.approx(doc["augmented_parameters"]["m1"], rel=1e-12)
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.05, output=["q1", "q2"], fmi_type="ModelExchange")
    assert np.all(np.isfinite(res["q1"])) and np.all(np.isfinite(res["q2"]))


def test_parameters_only_bundle_gives_no_effect(tmp_path):
    """Only the nominal parameters are off (m1 2.3 vs 2.0, d 8 vs 10): no effect on any axis, the refit
    reaches the true mass, and the validation RMS of every axis is at its noise floor."""
    doc = diagnose_bundle(_bundle(tmp_path / "bundle", [], 5), tmp_path / "out")
    assert doc["effects"] == []
    assert doc["nominal_parameters"]["m1"] == pytest.approx(2.0, rel=0.01)
    for v in doc["validation"]["per_axis"].values():
        assert v["nominal_rms"] < 1.2 * v["noise_floor_rms"]
    assert all(entry["cost_reduction"] < entry["null_threshold"] for entry in doc["candidates"])
    assert not any("validation_rms_after" in entry for entry in doc["candidates"])   # never validated


@pytest.fixture(scope="module")
def small_bundle(tmp_path_factory) -> Path:
    return _bundle(tmp_path_factory.mktemp("errors") / "bundle", [], 7)


def _edited(small_bundle: Path, tmp_path: Path, edit) -> Path:
    folder = tmp_path / "bad"
    shutil.copytree(small_bundle, folder)
    doc = json.loads((folder / "experiment.json").read_text())
    edit(doc, folder)
    (folder / "experiment.json").write_text(json.dumps(doc))
    return folder


def _drop_column(folder: Path, name: str) -> None:
    lines = (folder / "train.csv").read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h != name]
    (folder / "train.csv").write_text("\n".join(",".join(row.split(",")[i] for i in keep) for row in lines) + "\n")
    (folder / "train.json").unlink(missing_ok=True)


@pytest.mark.parametrize("edit, message", [
    (lambda d, f: _drop_column(f, "u2"), "train.csv, row 1: required column 'u2' missing"),
    (lambda d, f: d["plant"]["axes"][1].update(input="u9"),
     "field 'plant.axes[1].input' names 'u9', which is not an input of class Coupled2"),
    (lambda d, f: d["controller"]["axes"][1].update(Ts=1e-3),
     "field 'axes[1].Ts' is 0.001 s, but axes[0] has Ts = 0.0005 s"),
    (lambda d, f: d["controller"]["axes"].pop(), "field 'axes' has 1 controllers, but plant.axes has 2 axes"),
    (lambda d, f: d["plant"].update(input="u1"), "field 'plant.input' cannot be combined with 'plant.axes'"),
    (lambda d, f: d["controller"].update(kind="MotionTwin.Controllers.RobustJointController"),
     "a multi-axis bundle needs 'per_axis'"),
    (lambda d, f: d["plant"].update(free=["m1", "mass2"]),
     "field 'free' names 'mass2', which is not a parameter of the plant"),
])
def test_bundle_errors_name_file_and_field(small_bundle, tmp_path, edit, message):
    with pytest.raises(BundleError) as info:
        read_bundle(_edited(small_bundle, tmp_path, edit))
    assert message in str(info.value)


def test_multivariable_controller_reads_as_block_diagonal(small_bundle, tmp_path):
    """One multivariable discrete_state_space (inputs r_q1, r_q2, q1, q2 in any order) equals the per-axis
    controllers combined block-diagonally."""
    per_axis = read_bundle(small_bundle).controller

    def edit(doc, folder):
        order_in = ["q2", "r_q1", "q1", "r_q2"]
        canonical = ["r_q1", "r_q2", "q1", "q2"]
        cols = [canonical.index(n) for n in order_in]
        doc["controller"] = {"kind": "discrete_state_space", "Ts": TS, "inputs": order_in, "outputs": ["u2", "u1"],
                             "A": per_axis.A.tolist(), "B": per_axis.B[:, cols].tolist(),
                             "C": per_axis.C[[1, 0]].tolist(), "D": per_axis.D[[1, 0]][:, cols].tolist()}
    multi = read_bundle(_edited(small_bundle, tmp_path, edit)).controller
    for name in "ABCD":
        np.testing.assert_array_equal(getattr(multi, name), getattr(per_axis, name))


def test_effect_on_axis_renames_parameters_and_states():
    """An effect placed on an axis uses that axis's states and prefixed parameters; the contract reads them."""
    from motiontwin.ident.diagnosis import effects as effect_models
    from motiontwin.ident.diagnosis.plant_roles import PlantRoles

    ctx = effect_models.Context(TS, 0.0, 0.1, 0.1, 1.0)
    roles = PlantRoles("u3", "q3", "d3", "v3")
    placed = structure.on_axis(effect_models.VOCABULARY["coulomb_friction"](ctx), roles)
    assert placed.force == "MotionTwin.Effects.CoulombFriction(plant.v3, q3_coulomb_Fc, q3_coulomb_v_eps)"
    assert [p.name for p in placed.params] == ["q3_coulomb_Fc", "q3_coulomb_v_eps"]
    assert placed.contract({"q3_coulomb_Fc": 0.7}, ctx) == {"Fc": 0.7}
    delay = structure.on_axis(effect_models.VOCABULARY["resonance"](ctx), roles)
    assert "der(q3_resonance_x2) = q3_resonance_v2" in delay.equations


def test_in_memory_multi_axis_bundle_equals_folder(small_bundle):
    """make_bundle(axes=...) (the Python diagnose) reads the same plant axes, controller and recordings."""
    from motiontwin.harness.recording import read_recording
    from motiontwin.ident.diagnosis import make_bundle

    folder = read_bundle(small_bundle)
    doc = json.loads((small_bundle / "experiment.json").read_text())
    memory = make_bundle(PLANT, doc["controller"], read_recording(small_bundle / "train.csv"),
                         read_recording(small_bundle / "validation.csv"), "Coupled2", START, axes=AXES)
    assert memory.multi_axis and [a.as_dict() for a in memory.plant.axes] == [a.as_dict() for a in folder.plant.axes]
    for name in "ABCD":
        np.testing.assert_array_equal(getattr(memory.controller, name), getattr(folder.controller, name))
    np.testing.assert_array_equal(memory.train["u_ext_u2"], np.zeros(memory.train.time.size))
    with pytest.raises(BundleError, match="required column 'q2' missing"):
        rec = read_recording(small_bundle / "train.csv")
        del rec.columns["q2"]
        make_bundle(PLANT, doc["controller"], rec, read_recording(small_bundle / "validation.csv"), "Coupled2",
                    axes=AXES)


def test_free_restricts_the_nominal_refit(small_bundle, tmp_path):
    """plant.free names the parameters the nominal refit moves; without it every non-zero one moves."""
    from motiontwin.ident.diagnosis import pipeline

    everything, _ = pipeline._nominal_bounds(read_bundle(small_bundle), "plant.")
    assert len(everything) > 1 and "plant.m1" in everything
    bundle = read_bundle(_edited(small_bundle, tmp_path, lambda d, f: d["plant"].update(free=["m1"])))
    free, bounds = pipeline._nominal_bounds(bundle, "plant.")
    assert free == ["plant.m1"] and list(bounds) == ["plant.m1"]


def test_location_sentence_names_the_axis(coulomb_q2):
    """The location of an effect on q2 is a sentence about q2 (not the single-axis 'x')."""
    doc, _ = coulomb_q2
    text = doc["effects"][0]["location_text"]
    assert text.startswith("Strongest on axis q2 ")
    assert "moving in +q2" in text or "moving in -q2" in text or "around standstill" in text
    assert " x " not in text and "-x " not in text and "+x " not in text


def test_pole_pitch_is_given_per_axis(small_bundle, tmp_path):
    """plant.axes[k].pole_pitch is that axis's pitch (the others have none); a plant-wide pole_pitch on a
    multi-axis bundle, a bad per-axis value and pole_pitch with axes in memory are refused naming the field."""
    from motiontwin.harness.recording import read_recording
    from motiontwin.ident.diagnosis import make_bundle

    plant = read_bundle(_edited(small_bundle, tmp_path, lambda d, f: d["plant"]["axes"][1].update(
        pole_pitch=0.002))).plant
    assert plant.pitch_of("q2") == 0.002 and plant.pitch_of("q1") is None
    assert read_bundle(small_bundle).plant.pitch_of("q2") is None
    with pytest.raises(BundleError, match="field 'plant.pole_pitch' cannot be combined with 'plant.axes'"):
        read_bundle(_edited(small_bundle, tmp_path / "a", lambda d, f: d["plant"].update(pole_pitch=0.002)))
    with pytest.raises(BundleError, match=r"experiment\.json: field 'plant\.axes\.1\.pole_pitch'"):
        read_bundle(_edited(small_bundle, tmp_path / "b", lambda d, f: d["plant"]["axes"][1].update(
            pole_pitch=-1.0)))
    doc = json.loads((small_bundle / "experiment.json").read_text())
    train, validation = (read_recording(small_bundle / f"{part}.csv") for part in ("train", "validation"))
    with pytest.raises(BundleError, match="plant: pole_pitch cannot be combined with axes"):
        make_bundle(PLANT, doc["controller"], train, validation, "Coupled2", START, pole_pitch=0.002, axes=AXES)
    axes = [AXES[0], {**AXES[1], "pole_pitch": 0.002}]
    memory = make_bundle(PLANT, doc["controller"], train, validation, "Coupled2", START, axes=axes)
    assert memory.plant.pitch_of("q2") == 0.002


def test_cogging_on_one_axis_with_its_pole_pitch(tmp_path):
    """Cogging (pole pitch 2 mm, 0.5 N fundamental, 0.2 N second harmonic) concealed on q2 of the coupled
    plant whose bundle gives q2's pole pitch: answered cogging on q2 (not a one-harmonic position_ripple),
    with the true fundamental amplitude within 10 %, the period of the pitch, and q2 at its noise floor."""
    pitch, a1, a2 = 0.002, 0.5, 0.2
    true = truth.TrueEffect("cogging", "q2", {"cogging_a1": a1, "cogging_b1": 0.0, "cogging_a2": 0.0,
                                              "cogging_b2": a2, "cogging_pitch": pitch, "cogging_n": 1.0})
    plant = {"class": "Coupled2", "axes": [AXES[0], {**AXES[1], "pole_pitch": pitch}], "parameters": START}
    folder = tmp_path / "bundle"
    truth.write_bundle(folder, plant, CONTROLLER, [true], 2.0, 1.0, seed=11, plant_text=PLANT)
    doc = diagnose_bundle(folder, tmp_path / "out")
    assert [(e["name"], e["axis"]) for e in doc["effects"]] == [("cogging", "q2")], doc["candidates"]
    found = doc["effects"][0]["parameters"]
    assert found["A1"] == pytest.approx(a1, rel=0.1) and found["period"] == pytest.approx(pitch, rel=1e-9)
    q2 = doc["validation"]["per_axis"]["q2"]
    assert q2["augmented_rms"] < 1.2 * q2["noise_floor_rms"]


def test_multi_axis_report_has_plots_and_the_selection_fields(coulomb_q2):
    """The one selection loop gives a multi-axis effect what it gives one axis: the equivalent explanations and
    the rule that picked it, timed candidates; the report draws the per-axis residual and validation plots."""
    doc, out = coulomb_q2
    effect = doc["effects"][0]
    assert isinstance(effect["equivalent_explanations"], list) and "selection_rule" in effect
    assert all(isinstance(entry["seconds"], float) for entry in doc["candidates"])
    text = (out / "report.md").read_text()
    for name in ("residual_time.png", "validation_fit.png"):
        assert (out / name).stat().st_size > 10_000 and f"![{name}]({name})" in text


def test_time_delay_on_one_axis(tmp_path):
    """An input delay of 0.4 ms concealed on q1 (its Pade states on q1's input only) is answered time_delay on
    q1 with the delay within 20 %; q2 gets nothing."""
    folder = _bundle(tmp_path / "bundle", [truth.TrueEffect("time_delay", "q1", {"delay_T": 4e-4})], 13)
    doc = diagnose_bundle(folder, tmp_path / "out")
    assert [(e["name"], e["axis"]) for e in doc["effects"]] == [("time_delay", "q1")], doc["candidates"]
    assert doc["effects"][0]["parameters"]["delay"] == pytest.approx(4e-4, rel=0.2)


def test_unexplained_stage_runs_on_several_axes(coulomb_q2):
    """After the catalogue the unexplained stage asks the located axis too; with the Coulomb friction found
    nothing significant is left: the check says so and there is no unexplained entry."""
    doc, _ = coulomb_q2
    assert doc["residual_check"]["status"] == "none" and doc["residual_check"]["reason"]
    assert doc["unexplained"] is None


def test_outside_law_on_one_axis_is_unexplained_on_that_axis(tmp_path):
    """Quadratic drag (outside the catalogue, 2000 N s^2/m^2) concealed on q2: no catalogue effect is named and
    the unexplained stage says "unexplained" on q2, with v*|v| among the terms of the sparse law of q2's force
    residual (here it does not validate: "unexplained, no term validated")."""
    drag = truth.TrueEffect("quadratic_drag", "q2", {"empirical_c1": 2000.0})
    doc = diagnose_bundle(_bundle(tmp_path / "bundle", [drag], 17), tmp_path / "out")
    assert doc["effects"] == [], doc["candidates"]
    entry = doc["unexplained"]
    assert entry is not None and entry["status"].startswith("unexplained") and entry["axis"] == "q2", \
        doc["residual_check"]
    term = entry.get("empirical_term") or entry["rejected_term"]
    assert "v*|v|" in term["terms"] and term["cost_reduction"] > term["null_threshold"]


def test_diagnose_help_documents_the_multi_axis_format(capsys):
    """motiontwin diagnose --help shows the multi-axis bundle: axes, per-axis controllers and their signal
    names, pole pitch per axis, free, and the recordings' column naming."""
    from motiontwin.cli import main

    with pytest.raises(SystemExit):
        main(["diagnose", "--help"])
    text = capsys.readouterr().out
    for part in ('"axes": [{"input": "u1", "output": "q1"}', '"kind": "per_axis"',
                 '"inputs": ["r_q1", "r_q2", "q1", "q2"]', '"pole_pitch": 0.032}]', '"free":',
                 "r_<output> [m], <input> [N], <output> [m]", "u_ext_<input>"):
        assert part in text, part


def _nominal_of(folder: Path, work: Path) -> tuple:
    """The bundle in ``folder`` read as the multi-axis engine reads it, and its nominal refit and weights."""
    from motiontwin.ident.diagnosis.nominal import fit_nominal_axes, nominal_free

    bundle = read_bundle(folder)
    bundle.cache = structure.LoopCache()
    bundle.start = {v.name: float(v.start) for v in bundle.plant.model.parameters} | bundle.plant.parameters
    bundle.nominal_free = nominal_free(bundle)
    return (bundle, *fit_nominal_axes(bundle, work))


def test_kept_friction_is_judged_in_its_nested_forms_on_its_axis(tmp_path, monkeypatch):
    """The nested stages on several axes: a Stribeck friction kept on q2 beside a constant force on q2 (the
    truth: Coulomb friction and that force, 2 s + 1 s) is refitted as Coulomb friction with the force in, its
    extra parameters earn nothing, and Coulomb takes its place on q2; tried again in its richer form, Stribeck
    does not come back. The nested table is cut to Stribeck over Coulomb (each multi-axis structure compiles
    its own loop)."""
    from motiontwin.ident.diagnosis import effects as effect_models
    from motiontwin.ident.diagnosis.locate import locate
    from motiontwin.ident.diagnosis.nested import simplify_nested, upgrade_nested
    from motiontwin.ident.diagnosis.screen import MAX_NFEV, fit_candidate

    monkeypatch.setattr(effect_models, "NESTED", {"stribeck_friction": "coulomb_friction"})
    folder = _bundle(tmp_path / "bundle", [
        truth.TrueEffect("coulomb_friction", "q2", {"coulomb_Fc": FC_TRUE, "coulomb_v_eps": 1e-4}),
        truth.TrueEffect("gravity_offset", "q2", {"gravity_F0": 0.8})], 5)
    bundle, current, weights = _nominal_of(folder, tmp_path / "nominal")
    ctx = next(e for e in locate(bundle, current, weights, seed=1) if e.axis == "q2").context
    for name in ("gravity_offset", "stribeck_friction"):
        current = fit_candidate(bundle, current, effect_models.VOCABULARY[name](ctx), "q2", ctx, weights,
                                tmp_path / name, MAX_NFEV)
        current.evidence[structure.evidence_key(name, "q2")] = {"context": ctx}   # as the round records it
    lines: list[str] = []
    simple = simplify_nested(bundle, current, weights, None, tmp_path / "simplify", lines.append)
    assert [(a, e.name) for a, e in simple.placed] == [("q2", "gravity_offset"), ("q2", "coulomb_friction")], lines
    final = upgrade_nested(bundle, simple, weights, None, tmp_path / "upgrade", lines.append)
    assert [e.name for e in final.effects] == ["gravity_offset", "coulomb_friction"], lines
    assert any(line.startswith("  stribeck_friction in place of coulomb_friction on q2: extra") for line in lines)


def test_an_effect_a_later_one_makes_redundant_is_dropped(tmp_path):
    """Coupled axes, Coulomb friction on q2 and a constant force on q1 (2 s + 1 s): the coupling carries the force
    to q2, whose force residual stands highest, so a greedy selection adds a constant force on q2 before the
    one on q1 (measured on this bundle). With all three in, the force on q2 saves nothing (its null is not
    beaten) and is dropped; the two true effects are kept."""
    from motiontwin.ident.diagnosis import effects as effect_models
    from motiontwin.ident.diagnosis.locate import locate
    from motiontwin.ident.diagnosis.prune import prune
    from motiontwin.ident.diagnosis.screen import MAX_NFEV, fit_candidate

    folder = _bundle(tmp_path / "bundle", [
        truth.TrueEffect("coulomb_friction", "q2", {"coulomb_Fc": FC_TRUE, "coulomb_v_eps": 1e-4}),
        truth.TrueEffect("gravity_offset", "q1", {"gravity_F0": 0.8})], 5)
    bundle, current, weights = _nominal_of(folder, tmp_path / "nominal")
    contexts = {e.axis: e.context for e in locate(bundle, current, weights, seed=1)}
    for name, axis in (("coulomb_friction", "q2"), ("gravity_offset", "q2"), ("gravity_offset", "q1")):
        current = fit_candidate(bundle, current, effect_models.VOCABULARY[name](contexts[axis]), axis,
                                contexts[axis], weights, tmp_path / f"{name}@{axis}", MAX_NFEV)
    lines: list[str] = []
    final = prune(bundle, current, weights, tmp_path / "prune", lines.append)
    assert [(a, e.name) for a, e in final.placed] == [("q2", "coulomb_friction"), ("q1", "gravity_offset")], lines
    assert any("gravity_offset on q2 with the other effects in" in line and "(dropped)" in line for line in lines)
