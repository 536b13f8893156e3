"""Issue 12: the diagnosis and ``identify oe`` on every plant form the front end accepts.

Ten forms of the same rigid axis (tests/models/plant_forms/): the output as the position state itself
(``der(q) = v``), an alias, a gear ratio, a sensor offset, other names for everything, parameter
attributes, extra inputs/outputs, ``extends``, a class inside a package, SI types. Each form is checked
cheaply against independent references: its roles and output map against the equations written in the file,
every catalogue effect's augmented model (all of them at once, closed loop) against the same physics on the
library-form plant, and ``identify oe`` against the exact ZOH discretisation (scipy) of the true axis. The
full diagnosis (about 30-90 s each on a shared machine) runs on a representative subset: the issue's form
(``der(q) = v``) and the gear ratio (position and velocity in other units than the measured output).
"""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.fmus import frontend, symbolic
from motiontwin.harness.recording import make_recording, write_recording
from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import BundleError, main, read_bundle
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import plant_roles as pr

FORMS_DIR = Path(__file__).parent / "models" / "plant_forms"
LEAD = 0.002          # m/rad, the gear ratio written in GearRatio.mo
OFFSET = 0.0025       # m, the sensor offset written in SensorOffset.mo
TRUE_M, TRUE_D = 2.0, 15.0


@dataclass(frozen=True)
class Form:
    file: str
    class_name: str
    position: str
    velocity: str
    free: tuple[str, str] = ("m", "d")       # (mass-like, damping-like) parameter names
    input: str = "u"
    output: str = "q"
    gain: float = 1.0                        # q = gain*position + offset
    offset: float = 0.0

    @property
    def path(self) -> Path:
        return FORMS_DIR / self.file

    def truth(self) -> dict[str, float]:
        """The true axis (m = 2 kg, d = 15 N.s/m) in this form's parameters."""
        scale = self.gain ** 2      # J = m*lead^2, b = d*lead^2 for the gear ratio
        return {self.free[0]: TRUE_M * scale, self.free[1]: TRUE_D * scale}


FORMS = [
    Form("StateOutput.mo", "RigidJoint", "q", "v"),
    Form("AliasOutput.mo", "AliasAxis", "x", "v"),
    Form("GearRatio.mo", "BallScrewAxis", "phi", "w", ("J", "b"), gain=LEAD),
    Form("SensorOffset.mo", "OffsetSensorAxis", "s", "sd", offset=OFFSET),
    Form("ArbitraryNames.mo", "Carriage", "pos_m", "vel_mps", ("mass", "damping"), input="F", output="y"),
    Form("ParameterAttributes.mo", "AttributedAxis", "q", "v"),
    Form("ExtraInputsOutputs.mo", "InstrumentedAxis", "x", "v"),
    Form("Extends.mo", "DampedMass", "x", "v"),
    Form("InPackage.mo", "Machines.LinearStage", "q", "v"),
    Form("SIUnits.mo", "SITypedAxis", "x", "v"),
]
IDS = [f.file[:-3] for f in FORMS]
LIBRARY_FORM = Form("AliasOutput.mo", "AliasAxis", "x", "v")   # the benchmark's LinearAxis, verified vs FMUs


def _load(form: Form) -> symbolic.SymbolicModel:
    return symbolic.build(frontend.load(form.path, form.class_name))


def _roles(form: Form) -> pr.PlantRoles:
    return pr.find_roles(_load(form), form.path.read_text(), form.path, form.input, form.output)


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_roles_from_the_derivative_chain(form):
    """Position and velocity are the states the file's equations make them; the output map is the one
    written in the file (gear ratio 2 mm/rad, offset 2.5 mm)."""
    model = _load(form)
    roles = _roles(form)
    assert (roles.input, roles.output, roles.position, roles.velocity) == \
        (form.input, form.output, form.position, form.velocity)
    assert roles.source == pr.CHAIN
    gain, offset = pr.output_map(model, roles, {v.name: float(v.start) for v in model.parameters})
    assert gain == pytest.approx(form.gain, rel=1e-12)
    assert offset == pytest.approx(form.offset, abs=1e-15)


def test_roles_named_in_the_bundle_and_bad_names():
    form = FORMS[1]
    model = _load(form)
    named = pr.find_roles(model, form.path.read_text(), form.path, "u", "q", position="x", velocity="v")
    assert (named.position, named.velocity, named.source) == ("x", "v", pr.NAMED)
    with pytest.raises(pr.PlantFormError, match="plant.velocity names 'speed'.*states are x, v"):
        pr.find_roles(model, form.path.read_text(), form.path, "u", "q", velocity="speed")


# -- every catalogue effect on every form -----------------------------------------------------------------

# every effect's parameters in the measured (library) coordinates: metres, m/s, kg
LIBRARY_VALUES = {
    "gravity_F0": 0.3, "coulomb_Fc": 0.2, "coulomb_v_eps": 0.005,
    "asym_Fc_pos": 0.15, "asym_Fc_neg": 0.05, "asym_zero": 0.0, "asym_v_eps": 0.004,
    "stribeck_Fc": 0.1, "stribeck_Fs": 0.25, "stribeck_vs": 0.004, "stribeck_v_eps": 0.003,
    "ripple_a": 0.3, "ripple_b": -0.1, "ripple_period": 0.02, "ripple_zero": 0.0, "ripple_quarter": math.pi / 2,
    "inertia_slope": 3.0, "inertia_centre": 0.03,
    "delay_T": 3e-4,
    "resonance_m2": 0.2, "resonance_fa": 150.0, "resonance_zeta": 0.05,
    "backlash_m2": 0.2, "backlash_fa": 150.0, "backlash_zeta": 0.05, "backlash_b": 5e-6, "backlash_eps": 1e-7,
    "lugre_Fc": 0.2, "lugre_dFs": 0.1, "lugre_vs": 0.01, "lugre_z0": 1e-4, "lugre_sigma1": 20.0,
    "saturation_Fmax": 1e3, "saturation_eps": 1e-3,   # neutral: the PID winds up when it saturates
    "cogging_a1": 0.3, "cogging_b1": -0.1, "cogging_a2": 0.05, "cogging_b2": 0.02, "cogging_pitch": 0.032,
    "cogging_n": 3.0, "cogging_zero": 0.0, "cogging_quarter": math.pi / 2,
    "load_Fc0": 0.1, "load_mu": 0.05, "load_v_eps": 0.004,
    "drift_Fc0": 0.2, "drift_dFc": -0.1, "drift_tau": 0.2, "drift_v_eps": 0.003,
}


def _state_values(form: Form) -> dict[str, float]:
    """LIBRARY_VALUES in the form's state coordinates x_s = (q - offset)/gain (velocities /gain, masses
    *gain, the ripple phase shifted by the offset), i.e. the same physics seen from the plant's states."""
    g, b = form.gain, form.offset
    v = dict(LIBRARY_VALUES)
    for name in ("coulomb_v_eps", "asym_v_eps", "stribeck_vs", "stribeck_v_eps", "ripple_period", "backlash_b",
                 "backlash_eps", "lugre_z0", "lugre_vs", "cogging_pitch", "load_v_eps", "drift_v_eps"):
        v[name] /= g
    v["inertia_slope"] *= g ** 2
    v["inertia_centre"] = (v["inertia_centre"] - b) / g
    v["resonance_m2"] *= g
    v["lugre_sigma1"] *= g     # a damping, as the masses: F = sigma1 * g * d(x_s)/dt
    v["backlash_m2"] *= g
    harmonics = [("ripple_a", "ripple_b", 2 * math.pi * b / LIBRARY_VALUES["ripple_period"])]
    cogging = 2 * math.pi * LIBRARY_VALUES["cogging_n"] * b / LIBRARY_VALUES["cogging_pitch"]
    harmonics += [("cogging_a1", "cogging_b1", cogging), ("cogging_a2", "cogging_b2", 2 * cogging)]
    for sine, cosine, shift in harmonics:   # a sin(k q) + b cos(k q), q = g x_s + offset
        a, c = LIBRARY_VALUES[sine], LIBRARY_VALUES[cosine]
        v[sine] = a * math.cos(shift) - c * math.sin(shift)
        v[cosine] = a * math.sin(shift) + c * math.cos(shift)
    return v


def _closed_loop_q(form: Form, folder: Path) -> np.ndarray:
    """Closed-loop free run (benchmark PID, 0.4 s of moves from q0 = 12 mm) of the form's plant with every
    catalogue effect, at the true mass and damping: the model is the one the diagnosis' first pass builds."""
    roles = _roles(form)
    ctx = effect_models.Context(bench.TS, 0.0, 0.1 / form.gain, 0.2 / form.gain, TRUE_M * form.gain)
    model = augmented.check_buildable(folder, form.path.read_text(), form.path, form.class_name, roles, ctx,
                                      "Augmented")
    text = (folder / "all" / "Augmented.mo").read_text()
    assert "$" not in text and f"plant.{roles.position}" in text and f"plant.{roles.velocity}" in text
    assert {f"plant.{form.position}", f"plant.{form.velocity}", "resonance_x2", "delay_s", "backlash_x2",
            "lugre_Fz", "drift_s"} <= {s.name for s in model.states}
    values = {**_state_values(form), **{f"plant.{k}": v for k, v in form.truth().items()}}
    n = 800
    t = np.arange(n) * bench.TS
    r = 0.012 + 0.03 * (1 - np.cos(np.pi * np.clip(t / 0.3, 0, 1))) / 2
    u_ext = 0.5 * np.sin(2 * np.pi * 40 * t)
    rec = make_recording(t, {"r": r, "u": np.zeros(n), "q": np.full(n, 0.012), "u_ext": u_ext})
    loop = outputerror.build_loop(model, bench.pid_controller(), "q", [], values, n, substeps=8,
                                  tracking={"resonance_x2": "q", "backlash_x2": "q", "delay_p1": "u",
                                            "lugre_Fz": "u"}, with_jacobian=False)
    q, _ = outputerror.simulate(loop, rec)
    return q


@pytest.fixture(scope="module")
def library_q(tmp_path_factory) -> np.ndarray:
    """The reference run on the library form, whose augmented text is the one written before issue 12."""
    folder = tmp_path_factory.mktemp("library")
    q = _closed_loop_q(LIBRARY_FORM, folder)
    text = (folder / "all" / "Augmented.mo").read_text()
    for written in ("plant.u = u - delay_a - (gravity_F0)", "CoulombFriction(plant.v, coulomb_Fc",
                    "RippleForce(plant.x, ripple_a", "inertia_slope*(plant.x - inertia_centre)*der(plant.v)",
                    "*(plant.x - resonance_x2)", "q = plant.q + (encoder_a1*sin(6.283185307179586*plant.x/"):
        assert written in text, written
    return q


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_every_effect_builds_and_matches_the_library_form(form, library_q, tmp_path):
    """The first pass of the diagnosis builds every catalogue effect's augmented model on the form, and the
    model with every catalogue effect reproduces the same physics on the library's LinearAxis (the form the
    benchmark verifies against FMU co-simulations) to round-off."""
    q = _closed_loop_q(form, tmp_path)
    assert np.all(np.isfinite(q)) and np.ptp(q) > 0.02
    assert np.max(np.abs(q - library_q)) < 1e-9, np.max(np.abs(q - library_q))


def test_unsupported_form_named_before_fitting(tmp_path):
    """A plant class whose name clashes with the augmented class fails in the first pass, with the line."""
    form = FORMS[0]
    text = form.path.read_text().replace("RigidJoint", "Augmented")
    with pytest.raises(pr.PlantFormError, match=r"line 1: the plant's top-level class name 'Augmented'"):
        augmented.check_buildable(tmp_path, text, form.path, "Augmented", _roles(form),
                           effect_models.Context(bench.TS, 0.0, 0.1, 0.2, 2.0), "Augmented")


# -- identify oe on every form ------------------------------------------------------------------------

def _exact_open_loop(q0: float, n: int = 2000, ts: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true axis m*a = u - d*v from rest at q0, force held over each sample: exact ZOH (scipy)."""
    t = np.arange(n) * ts
    u = 4.0 * np.sin(2 * np.pi * 1.5 * t) + 2.0 * np.sign(np.sin(2 * np.pi * 7 * t))
    a = np.array([[0.0, 1.0], [0.0, -TRUE_D / TRUE_M]])
    b = np.array([[0.0], [1.0 / TRUE_M]])
    ad, bd, *_ = sps.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), ts, method="zoh")
    x = np.array([q0, 0.0])
    q = np.zeros(n)
    for k in range(n):
        q[k] = x[0]
        x = ad @ x + bd[:, 0] * u[k]
    return t, u, q


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_identify_oe_recovers_the_parameters(form, tmp_path, capsys):
    """``motiontwin identify oe`` (open loop, recording columns named like the plant's input and output)
    recovers the true mass and damping of each form from the exact response, starting 25 % off."""
    from motiontwin.cli import main as cli_main

    t, u, q = _exact_open_loop(q0=0.012)
    rec = make_recording(t, {form.input: u, form.output: q}, sample_time=1e-3)
    write_recording(tmp_path / "rec.csv", rec)
    out = tmp_path / "values.json"
    assert cli_main(["identify", "oe", str(tmp_path / "rec.csv"), "--modelica", str(form.path),
                     "--class", form.class_name, "--free", ",".join(form.free), "--input", form.input,
                     "--output", form.output, "--out", str(out)]) == 0
    found = json.loads(out.read_text())["parameters"]
    for name, true in form.truth().items():
        assert found[name] == pytest.approx(true, rel=1e-4), (name, found)


# -- the full diagnosis on a representative subset --------------------------------------------------------

@pytest.fixture(scope="module")
def gravity_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """A short concealed gravity-offset bundle (truth F0 = 2.25 N) written by the benchmark generator."""
    folder = tmp_path_factory.mktemp("forms") / "base"
    truth = bench.write_bundle(folder, "gravity_offset", seed=7, scale=1.5, durations=(2.0, 1.0))
    return folder, truth


def _bundle_in_form(base: Path, form: Form, target: Path) -> Path:
    shutil.copytree(base, target)
    shutil.copyfile(form.path, target / "plant.mo")
    doc = json.loads((target / "experiment.json").read_text())
    doc["plant"].update({"class": form.class_name, "input": form.input, "output": form.output})
    (target / "experiment.json").write_text(json.dumps(doc))
    return target


@pytest.mark.parametrize("form", [FORMS[0], FORMS[2]], ids=[IDS[0], IDS[2]])
def test_diagnosis_finds_the_concealed_effect(form, gravity_bundle, tmp_path, capsys):
    """``motiontwin diagnose`` on the issue's form (der(q) = v) and on the gear ratio finds the concealed
    gravity offset with its true size, and reports which states it used and how it found them."""
    base, truth = gravity_bundle
    bundle = _bundle_in_form(base, form, tmp_path / "bundle")
    out = tmp_path / "out"
    assert main([str(bundle), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"position plant.{form.position}, velocity plant.{form.velocity} (from the {pr.CHAIN})" in err
    assert err.index("every candidate effect's augmented model builds") < err.index("nominal refit")
    doc = json.loads((out / "diagnosis.json").read_text())
    assert [e["name"] for e in doc["effects"]] == ["gravity_offset"]
    f0 = truth["effects"][0]["contract"]["F0"]
    assert doc["effects"][0]["parameters"]["F0"] == pytest.approx(f0, rel=0.05)
    assert doc["validation"]["augmented_rms"] < 0.1 * doc["validation"]["nominal_rms"]
    assert Path(doc["augmented_fmu"]).is_file()          # built from the augmented model on this form
    assert doc["plant_roles"] == {"input": "u", "output": "q", "position": form.position,
                                  "velocity": form.velocity, "found_from": pr.CHAIN, "held_inputs": {}}


@pytest.mark.parametrize("edit, construct", [
    (("q = x;", "q = x*x;"), "output q = sq(x) is not affine in exactly one state"),
    (("der(x) = v;", "der(x) = 2*v;"), "der(x) = (2.*v) is not a state"),
])
def test_unsupported_output_names_the_line(edit, construct, gravity_bundle, tmp_path):
    """An output that is not a position, or a position whose derivative is not a state: one message with
    the construct and the plant file's line, exit code 2, nothing written."""
    base, _ = gravity_bundle
    bundle = _bundle_in_form(base, FORMS[1], tmp_path / "bundle")
    text = (bundle / "plant.mo").read_text()
    line = text.splitlines().index(f"  {edit[0]}") + 1
    (bundle / "plant.mo").write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(BundleError) as info:
        read_bundle(bundle)
    assert f"plant.mo, line {line}" in str(info.value) and construct in str(info.value), str(info.value)
    assert main([str(bundle), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", sorted(bench.PLANT_FORMS))
def test_benchmark_plant_forms_are_the_same_axis(name, tmp_path):
    """Every form the benchmark generator writes is the rigid axis m = 2 kg, d = 15 N.s/m seen from the
    measured output: d(q'')/du = 1/m and d(q'')/dq' = -d/m, with the roles found from the derivative chain."""
    form = bench.PLANT_FORMS[name]
    path = tmp_path / "plant.mo"
    path.write_text(form.text.format(a=TRUE_M * form.scale, b=TRUE_D * form.scale))
    model = symbolic.build(frontend.load(path, form.class_name))
    roles = pr.find_roles(model, path.read_text(), path, form.input, form.output)
    values = [float(v.start) for v in model.parameters]
    gain, offset = pr.output_map(model, roles, dict(zip([v.name for v in model.parameters], values)))
    i_v = [s.name for s in model.states].index(roles.velocity)
    acc = gain * model.dx[i_v]                 # q'' = gain*der(velocity state), q' = gain*velocity state
    fn = ca.Function("f", [model.x, model.u, model.p], [ca.jacobian(acc, model.u), ca.jacobian(acc, model.x[i_v])])
    du, dv = (float(o) for o in fn(np.zeros(2), np.zeros(model.u.numel()), values))
    assert du == pytest.approx(1 / TRUE_M, rel=1e-12)
    assert dv / gain == pytest.approx(-TRUE_D / TRUE_M, rel=1e-12)
    assert offset == 0.0 and roles.source == pr.CHAIN


def test_roles_named_in_the_bundle_make_the_form_supported(gravity_bundle, tmp_path):
    """The same der(x) = 2*v plant is accepted when experiment.json names plant.position and plant.velocity;
    the first pass then builds every effect's augmented model on it (no fitting)."""
    from motiontwin.ident.diagnosis import pipeline

    base, _ = gravity_bundle
    bundle = _bundle_in_form(base, FORMS[1], tmp_path / "bundle")
    text = (bundle / "plant.mo").read_text()
    (bundle / "plant.mo").write_text(text.replace("der(x) = v;", "der(x) = 2*v;"))
    doc = json.loads((bundle / "experiment.json").read_text())
    doc["plant"].update({"position": "x", "velocity": "v"})
    (bundle / "experiment.json").write_text(json.dumps(doc))
    read = read_bundle(bundle)
    assert (read.plant.roles.position, read.plant.roles.velocity, read.plant.roles.source) == ("x", "v", pr.NAMED)
    pipeline.check_plant_form(read, tmp_path / "check")
    assert "CoulombFriction(plant.v," in (tmp_path / "check" / "all" / "Augmented.mo").read_text()
