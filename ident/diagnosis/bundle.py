"""Read and validate a diagnosis bundle (issue 7 contract): experiment.json, the nominal plant, the
sampled controller and the train/validation recordings.

The controller is either ``{"kind": "discrete_state_space", "Ts": ..., "inputs": ["r", "q"], "outputs": ["u"],
"A": ..., "B": ..., "C": ..., "D": ...}`` or one of the project's sampled library controllers by its
Modelica name with parameter values, e.g. ``{"kind": "MotionTwin.Controllers.RobustJointController",
"parameters": {"Kp": 2e5, "Ki": 4e6, "Kd": 900, "Kv": 0, "Ka": 0, "Ts": 0.0005}}``: the class is loaded
with ``fmus.build.load_model`` and its sampled matrices (Tustin, or ``method="discrete"``) are evaluated at
the parameters (the others at their Modelica defaults), exactly as its FMU executes them. Inputs other
than ``r`` and ``q`` (reference derivatives of a feedforward) are not recorded, so their gains must be 0.

Every problem raises :class:`BundleError` whose message names the file and the field or column at fault.
Units: time [s], positions [m], forces [N].
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.harness.recording import Recording, RecordingError, read_recording
from motiontwin.ident import controller, startvalues
from motiontwin.ident.bundleformat import BUNDLE_FORMAT  # noqa: F401  (re-exported: the documented format)
from motiontwin.ident.controller import Controller, field

REQUIRED_COLUMNS = ("time", "r", "u", "q")



class BundleError(ValueError):
    """A bundle is unusable; the message names the file and the field, column or row at fault."""


@dataclass
class PlantInfo:
    """The nominal plant and where its position and velocity live in the state vector."""

    source: Path
    class_name: str
    text: str                    # Modelica source of the plant file (copied into the augmented model)
    model: symbolic.SymbolicModel
    input_name: str
    output_name: str
    position_state: str          # state whose value is the measured output
    velocity_state: str          # state whose derivative is the position state's derivative
    parameters: dict[str, float] = dataclass_field(default_factory=dict)   # plant.parameters: user start values


@dataclass
class Bundle:
    directory: Path
    experiment: dict[str, Any]
    plant: PlantInfo
    controller: Controller
    train: Recording
    validation: Recording
    start: dict[str, float] = dataclass_field(default_factory=dict)   # nominal start values (set by the pipeline)

    def recording_path(self, part: str) -> Path:
        """Path of the ``train`` or ``validation`` recording."""
        return self.directory / self.experiment["recordings"][part]


def _field(doc: dict, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    return field(doc, key, where, kind, BundleError)


def read_controller(doc: dict, where: str) -> Controller:
    """The ``controller`` object of experiment.json (see :mod:`ident.controller` for both forms)."""
    try:
        return controller.read_controller(doc, where)
    except controller.ControllerError as exc:
        raise BundleError(str(exc)) from None


def _state_roles(model: symbolic.SymbolicModel, output: str, where: str) -> tuple[str, str]:
    """Names of the position state (equal to the output) and the velocity state (its derivative)."""
    names = [v.name for v in model.states]
    if output in model.state_outputs:
        q_expr = model.x[names.index(output)]
    else:
        found = [c.expr for c in model.computed if c.var.name == output]
        if not found:
            raise BundleError(f"{where}: the plant has no output {output!r}")
        q_expr = found[0]
    jac = ca.jacobian(q_expr, model.x)
    hits = [i for i in range(len(names)) if not ca.is_equal(jac[0, i], 0)]
    if len(hits) != 1 or not ca.is_equal(ca.simplify(q_expr - model.x[hits[0]]), 0, 2) \
            or ca.depends_on(q_expr, model.u):
        raise BundleError(f"{where}: output {output!r} must equal one state of the plant (a position), "
                          f"got {q_expr}")
    pos = hits[0]
    dpos = model.dx[pos]
    vel = [i for i in range(len(names)) if ca.is_equal(dpos, model.x[i], 2)]
    if not vel:
        raise BundleError(f"{where}: der({names[pos]}) must equal a velocity state of the plant, got {dpos}")
    return names[pos], names[vel[0]]


def read_plant(doc: dict, bundle_dir: Path, where: str) -> PlantInfo:
    """Load the nominal plant with the project's front end and check it has input u and output q."""
    file_name = _field(doc, "modelica", where, str)
    class_name = _field(doc, "class", where, str)
    input_name = doc.get("input", "u")
    output_name = doc.get("output", "q")
    path = bundle_dir / file_name
    if not path.is_file():
        raise BundleError(f"{where}: field 'modelica' names {file_name!r}, but {path} does not exist")
    try:
        model = symbolic.build(frontend.load(path, class_name))
    except frontend.ModelicaError as exc:
        raise BundleError(str(exc)) from None
    inputs = [v.name for v in model.inputs]
    if inputs != [input_name]:
        raise BundleError(f"{path}: class {class_name} must have exactly one input {input_name!r} "
                          f"(field 'plant.input' of {where}); it has inputs {inputs}")
    if model.sampled:
        raise BundleError(f"{path}: class {class_name} is a sampled model; the plant must be continuous")
    if not model.parameters:
        raise BundleError(f"{path}: class {class_name} has no parameters to refit")
    pos, vel = _state_roles(model, output_name, f"{path}: class {class_name}")
    parameters = doc.get("parameters", {})
    if not isinstance(parameters, dict):
        raise BundleError(f"{where}: field 'parameters' must be an object {{NAME: VALUE}}, got {parameters!r}")
    try:
        parameters = startvalues.check_numbers(parameters, where)
        startvalues.check_parameters(model, parameters, f"{where}.parameters")
    except startvalues.StartValueError as exc:
        raise BundleError(str(exc).replace("field 'parameters.", "field 'plant.parameters.")) from None
    return PlantInfo(path, class_name, path.read_text(encoding="utf-8"), model, input_name, output_name, pos, vel,
                     parameters)


def _recording(doc: dict, key: str, bundle_dir: Path, where: str, ts: float) -> Recording:
    name = _field(doc, key, where, str)
    path = bundle_dir / name
    if not path.is_file():
        raise BundleError(f"{where}: field 'recordings.{key}' names {name!r}, but {path} does not exist")
    try:
        rec = read_recording(path, REQUIRED_COLUMNS)
    except RecordingError as exc:
        raise BundleError(str(exc)) from None
    if rec.time.size < 20:
        raise BundleError(f"{path}: only {rec.time.size} samples; a diagnosis needs at least 20")
    steps = np.diff(rec.time)
    bad = np.flatnonzero(np.abs(steps - ts) > 1e-3 * ts)
    if bad.size:
        i = int(bad[0])
        raise BundleError(f"{path}, row {i + 3}, column 'time': step {steps[i]!r} s differs from the controller "
                          f"sample time Ts = {ts} s (samples must be taken at the controller's sample instants)")
    if "u_ext" not in rec.columns:
        rec.columns["u_ext"] = np.zeros_like(rec.time)
    return rec


def read_bundle(bundle_dir: str | Path) -> Bundle:
    """Read and validate everything in ``bundle_dir``; raises :class:`BundleError` on the first problem."""
    bundle_dir = Path(bundle_dir)
    exp_path = bundle_dir / "experiment.json"
    if not exp_path.is_file():
        raise BundleError(f"{exp_path}: file not found (a bundle needs experiment.json)")
    try:
        experiment = json.loads(exp_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise BundleError(f"{exp_path}, line {exc.lineno}, column {exc.colno}: invalid JSON ({exc.msg})") from None
    if not isinstance(experiment, dict):
        raise BundleError(f"{exp_path}: must hold a JSON object")
    controller = read_controller(_field(experiment, "controller", str(exp_path), dict), f"{exp_path}: controller")
    plant = read_plant(_field(experiment, "plant", str(exp_path), dict), bundle_dir, f"{exp_path}: plant")
    recs = _field(experiment, "recordings", str(exp_path), dict)
    where = f"{exp_path}: recordings"
    train = _recording(recs, "train", bundle_dir, where, controller.Ts)
    validation = _recording(recs, "validation", bundle_dir, where, controller.Ts)
    return Bundle(bundle_dir, experiment, plant, controller, train, validation)
