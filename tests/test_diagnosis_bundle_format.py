"""The bundle format (issue 13): the JSON Schema shipped in the package, errors naming the field, the plant
by library class name or by a path outside the bundle (only when allowed), and the format in
``motiontwin diagnose --help``.

References: jsonschema's own meta-schema check (Draft 2020-12), the generator's experiment.json, and the
library class's equations (the same states and parameters as the flat plant file)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import jsonschema
import pytest

from motiontwin.cli import main as cli_main
from motiontwin.ident.diagnosis import augmented
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.benchmarks import single_axis as bench
from motiontwin.ident.diagnosis.bundle import SCHEMA_PATH, BundleError, read_bundle


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("format") / "b"
    bench.write_bundle(folder, "params_only_a", seed=2, durations=(0.5, 0.5), engine="casadi")
    return folder


def _edited(bundle: Path, tmp_path: Path, edit) -> Path:
    target = tmp_path / "bundle"
    shutil.copytree(bundle, target)
    doc = json.loads((target / "experiment.json").read_text())
    edit(doc)
    (target / "experiment.json").write_text(json.dumps(doc))
    return target


def test_schema_is_shipped_valid_and_accepts_the_generated_bundle(bundle):
    schema = json.loads(SCHEMA_PATH.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(json.loads((bundle / "experiment.json").read_text()), schema)
    assert SCHEMA_PATH.parent.name == "diagnosis"             # inside the package (package-data *.json)


@pytest.mark.parametrize("edit, needles", [
    (lambda d: d["plant"].update(modelika="x.mo"), ("field 'plant'", "'modelika' was unexpected")),
    (lambda d: d["recordings"].update(train=3), ("field 'recordings.train'", "must be a string", "3")),
    (lambda d: d["plant"].update(parameters={"m": "heavy"}), ("field 'plant.parameters.m'", "finite number")),
    (lambda d: d.pop("recordings"), ("'recordings' is a required property",)),
    (lambda d: d["controller"].update(Ts=-1), ("field 'controller.Ts'", "-1")),
])
def test_schema_errors_name_the_field(bundle, tmp_path, edit, needles):
    folder = _edited(bundle, tmp_path, edit)
    with pytest.raises(BundleError) as info:
        read_bundle(folder)
    message = str(info.value)
    assert "experiment.json" in message
    for needle in needles:
        assert needle in message, message


def test_plant_by_path_outside_the_bundle(bundle, tmp_path):
    elsewhere = tmp_path / "models" / "axis.mo"
    elsewhere.parent.mkdir()
    shutil.copy(bundle / "plant.mo", elsewhere)
    folder = _edited(bundle, tmp_path, lambda d: d["plant"].update(modelica=str(elsewhere)))
    (folder / "plant.mo").unlink()
    with pytest.raises(BundleError, match="field 'plant.modelica' names .* outside the bundle folder .* pass "
                                          "--allow-outside-paths"):
        read_bundle(folder)
    b = read_bundle(folder, allow_outside_paths=True)
    assert b.plant.source == elsewhere and b.plant.position_state == "x" and b.plant.velocity_state == "v"


def test_plant_by_library_class_name(bundle, tmp_path):
    folder = _edited(bundle, tmp_path, lambda d: d.update(plant={"class": "MotionTwin.Plants.LinearMotorJoint",
                                                                 "parameters": {"m": 2.5}}))
    b = read_bundle(folder)
    assert [p.name for p in b.plant.model.parameters] == ["m", "d"]
    assert (b.plant.position_state, b.plant.velocity_state, b.plant.parameters) == ("x", "v", {"m": 2.5})
    # the augmented model the diagnosis writes around it loads through the front end
    ctx = effect_models.Context(bench.TS, 0.0, 0.1, 0.2, 2.0)
    augmented.write_model(tmp_path / "aug", b.plant.text, b.plant.class_name, [effect_models.gravity_offset(ctx)],
                              {"gravity_F0": 1.0}, {"m": 2.5}, "Augmented", b.plant.roles)
    model = augmented.load_augmented(tmp_path / "aug", "Augmented")
    assert {"plant.m", "plant.d", "gravity_F0"} <= {p.name for p in model.parameters}
    for name, needle in (("MotionTwin.Plants.NoSuchJoint", "not a class of the MotionTwin library"),
                         ("MotionTwin.Effects.CoulombJoint", "uses other library classes")):
        bad = _edited(bundle, tmp_path / name, lambda d, n=name: d.update(plant={"class": n}))
        with pytest.raises(BundleError, match=needle):
            read_bundle(bad)


def test_format_in_diagnose_help(capsys):
    with pytest.raises(SystemExit):
        cli_main(["diagnose", "--help"])
    text = capsys.readouterr().out
    for needle in ("experiment.json", "\"parameters\"", "u_ext", "discrete_state_space", "--allow-outside-paths",
                   "moving"):
        assert needle in text, needle
