"""Read and validate a diagnosis bundle (issue 7 contract): experiment.json, the nominal plant, the
sampled controller and the train/validation recordings.

Every problem raises :class:`BundleError` whose message names the file and the field or column at fault.
Units: time [s], positions [m], forces [N].
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from fmus import frontend, symbolic
from harness.recording import Recording, RecordingError, read_recording

REQUIRED_COLUMNS = ("time", "r", "u", "q")
CONTROLLER_KINDS = ("discrete_state_space",)


class BundleError(ValueError):
    """A bundle is unusable; the message names the file and the field, column or row at fault."""


@dataclass
class Controller:
    """Sampled linear controller z+ = A z + B y, u = C z + D y with y = [r; q] (inputs reordered to r, q)."""

    Ts: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n_states(self) -> int:
        return self.A.shape[0]


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


@dataclass
class Bundle:
    directory: Path
    experiment: dict[str, Any]
    plant: PlantInfo
    controller: Controller
    train: Recording
    validation: Recording


def _field(doc: dict, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    if not isinstance(doc, dict) or key not in doc:
        raise BundleError(f"{where}: required field {key!r} missing")
    value = doc[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        name = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise BundleError(f"{where}: field {key!r} must be a {name}, got {value!r}")
    return value


def _matrix(doc: dict, key: str, where: str, shape: tuple[int, int]) -> np.ndarray:
    raw = _field(doc, key, where, list)
    try:
        mat = np.array(raw, dtype=float)
    except (TypeError, ValueError):
        raise BundleError(f"{where}: field {key!r} must be a list of rows of numbers") from None
    if mat.size == 0 and shape[0] * shape[1] == 0:
        return np.zeros(shape)
    if mat.ndim != 2 or mat.shape != shape:
        raise BundleError(f"{where}: field {key!r} has shape {mat.shape}, expected {shape}")
    if not np.all(np.isfinite(mat)):
        raise BundleError(f"{where}: field {key!r} contains a non-finite value")
    return mat


def read_controller(doc: dict, where: str) -> Controller:
    """Parse the ``controller`` object of experiment.json (kind discrete_state_space)."""
    kind = _field(doc, "kind", where, str)
    if kind not in CONTROLLER_KINDS:
        raise BundleError(f"{where}: field 'kind' is {kind!r}; supported controller kinds: "
                          f"{', '.join(CONTROLLER_KINDS)}")
    ts = _field(doc, "Ts", where, (int, float))
    if not (math.isfinite(ts) and ts > 0):
        raise BundleError(f"{where}: field 'Ts' must be a positive number of seconds, got {ts!r}")
    inputs = _field(doc, "inputs", where, list)
    if sorted(map(str, inputs)) != ["q", "r"]:
        raise BundleError(f"{where}: field 'inputs' must be ['r', 'q'] (in any order), got {inputs!r}")
    outputs = _field(doc, "outputs", where, list)
    if list(outputs) != ["u"]:
        raise BundleError(f"{where}: field 'outputs' must be ['u'], got {outputs!r}")
    a_raw = _field(doc, "A", where, list)
    n = len(a_raw)
    A = _matrix(doc, "A", where, (n, n))
    B = _matrix(doc, "B", where, (n, 2))
    C = _matrix(doc, "C", where, (1, n))
    D = _matrix(doc, "D", where, (1, 2))
    order = [inputs.index("r"), inputs.index("q")]
    return Controller(float(ts), A, B[:, order], C, D[:, order])


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
    return PlantInfo(path, class_name, path.read_text(encoding="utf-8"), model, input_name, output_name, pos, vel)


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
