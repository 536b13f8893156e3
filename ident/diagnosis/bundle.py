"""Read and validate a diagnosis bundle (issue 7 contract): experiment.json, the nominal plant, the
sampled controller and the train/validation recordings.

The controller is either ``{"kind": "discrete_state_space", "Ts": ..., "inputs": ["r", "q"], "outputs": ["u"],
"A": ..., "B": ..., "C": ..., "D": ...}`` or one of the project's sampled library controllers by its
Modelica name with parameter values, e.g. ``{"kind": "MotionTwin.Controllers.RobustJointController",
"parameters": {"Kp": 2e5, "Ki": 4e6, "Kd": 900, "Kv": 0, "Ka": 0, "Ts": 0.0005}}``: the class is loaded
with ``fmus.build.load_model`` and its sampled matrices (Tustin, or ``method="discrete"``) are evaluated at
the parameters (the others at their Modelica defaults), exactly as its FMU executes them. Inputs other
than ``r`` and ``q`` (reference derivatives of a feedforward) are not recorded, so their gains must be 0.

The plant is ``{"modelica": FILE, "class": NAME, "input": "u", "output": "q"}`` with the optional state
names ``"position"`` and ``"velocity"``; without them both are found from the derivative chain of the output
(:mod:`ident.diagnosis.plant_roles`).

A multi-axis bundle's plant has ``"axes": [{"input": "u1", "output": "q1"}, ...]`` instead of ``input``/``output``
(each axis may name its ``position``/``velocity`` states), its controller is ``{"kind": "per_axis", "axes":
[one single-axis controller per axis, same Ts]}`` or one multivariable ``discrete_state_space`` with inputs
``r_<output>`` and ``<output>`` of every axis and outputs the axes' inputs, and its recordings have the
columns ``time`` and, per axis, ``r_<output>``, ``<input>``, ``<output>`` and optionally ``u_ext_<input>``.
A motor's magnet pole pitch is given per axis (``plant.axes[k].pole_pitch``; a plant-wide one is refused).

An unknown controller (``controller`` absent or ``{"kind": "unknown"}``, optional ``"Ts"`` and
``"bandwidth_hz"``; single axis only): the recordings need only time, u and q; the bundle's controller is then the
observer of :mod:`ident.observer` (fitted with the plant after the nominal refit unless given), its recordings get
r = q and u_ext = u (the predictor's roles; a recorded r or u_ext is unused), ``Bundle.observer`` says so.

Every problem raises :class:`BundleError` whose message names the file and the field or column at fault.
Units: time [s], positions [m], forces [N].
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from pathlib import Path
from typing import Any

import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.harness.recording import Recording, RecordingError, read_recording
from motiontwin.ident import controller, startvalues, units
from motiontwin.ident.controller import Controller, at_recording_step, field
from motiontwin.ident.observer import UNKNOWN_KIND, Observer, ObserverError, observer_from_document
from motiontwin.ident.diagnosis import axis_kinematics
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, PlantRoles, find_roles

REQUIRED_COLUMNS = ("time", "r", "u", "q")
PREDICTOR_COLUMNS = ("time", "u", "q")      # an unknown controller's recordings
#: JSON Schema of experiment.json, shipped with the package (``motiontwin diagnose --help`` shows the format)
SCHEMA_PATH = Path(__file__).with_name("bundle.schema.json")
_TYPE_WORDS = {"number": "a finite number", "string": "a string", "object": "an object {...}", "array": "a list [...]"}


def validate_experiment(doc: Any, exp_path: Path) -> None:
    """Check experiment.json against the shipped JSON Schema; the first error raises :class:`BundleError`
    naming the file and the field (dotted path), e.g. ``field 'plant.parameters.m' must be a finite number``."""
    import jsonschema

    schema = json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))
    error = jsonschema.exceptions.best_match(jsonschema.Draft202012Validator(schema).iter_errors(doc))
    if error is None:
        return
    path = ".".join(str(p) for p in error.absolute_path)
    where = f"field '{path}'" if path else "top level"
    if error.validator == "type":
        expected = error.validator_value if isinstance(error.validator_value, str) else error.validator_value[0]
        message = f"must be {_TYPE_WORDS.get(expected, expected)}, got {error.instance!r}"
    else:
        message = error.message
    raise BundleError(f"{exp_path}: {where}: {message} (schema: {SCHEMA_PATH.name}; see motiontwin diagnose --help)")



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
    position_state: str          # state the measured output is affine in (the position)
    velocity_state: str          # state equal to the position state's derivative
    roles: PlantRoles            # the above, the held inputs and how they were found
    parameters: dict[str, float] = dataclass_field(default_factory=dict)   # plant.parameters: user start values
    pole_pitch: float | None = None   # plant.pole_pitch [m]: magnet pole pitch, fixes the cogging period
    free: list[str] | None = None     # plant.free: the parameters the nominal refit moves (None: every non-zero one)
    axes: list[PlantRoles] = dataclass_field(default_factory=list)   # multi-axis plant: the roles of each axis
    pole_pitches: dict[str, float] = dataclass_field(default_factory=dict)   # multi-axis: plant.axes[k].pole_pitch

    def pitch_of(self, axis: str) -> float | None:
        """The magnet pole pitch [m] of the axis with output ``axis`` (``plant.axes[k].pole_pitch``; one axis:
        ``plant.pole_pitch``), or None."""
        return self.pole_pitches.get(axis) if self.axes else self.pole_pitch


@dataclass
class Bundle:
    directory: Path
    experiment: dict[str, Any]
    plant: PlantInfo
    controller: Controller
    train: Recording
    validation: Recording
    start: dict[str, float] = dataclass_field(default_factory=dict)   # nominal start values (set by the pipeline)
    cache: Any = None            # the compiled loops of the diagnosis running on this bundle (set by the pipeline)
    nominal_free: tuple = ()     # multi-axis: (free nominal parameters, their bounds) (set by the diagnosis)
    process_noise: Any = None    # noise.Process of the training recording (several axes: one per axis; None: none)
    observer: Observer | None = None   # unknown controller: the observer standing in for it (ident.observer)

    def recording_path(self, part: str) -> Path:
        """Path of the ``train`` or ``validation`` recording."""
        return self.directory / self.experiment["recordings"][part]

    @property
    def multi_axis(self) -> bool:
        """True for a bundle with ``plant.axes`` (several inputs and outputs)."""
        return bool(self.plant.axes)


def _field(doc: dict, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    return field(doc, key, where, kind, BundleError)


def read_controller(doc: dict, where: str) -> Controller:
    """The ``controller`` object of experiment.json (see :mod:`ident.controller` for both forms)."""
    try:
        return controller.read_controller(doc, where)
    except controller.ControllerError as exc:
        raise BundleError(str(exc)) from None


def read_plant(doc: dict, bundle_dir: Path, where: str) -> PlantInfo:
    """Load the nominal plant with the project's front end and check it has input u and output q."""
    class_name = _field(doc, "class", where, str)
    input_name = doc.get("input", "u")
    output_name = doc.get("output", "q")
    pole_pitch = check_pole_pitch(doc.get("pole_pitch"), where)
    if "modelica" not in doc:
        info = library_plant(class_name, input_name, output_name, doc.get("parameters", {}), where,
                             doc.get("position"), doc.get("velocity"))
    else:
        path = _modelica_path(doc, bundle_dir, where)
        info = load_plant(path, class_name, input_name, output_name, doc.get("parameters", {}), where,
                          doc.get("position"), doc.get("velocity"))
    info.pole_pitch = pole_pitch
    return info


def _modelica_path(doc: dict, bundle_dir: Path, where: str) -> Path:
    """The plant's Modelica file (field ``modelica``, relative to the bundle or absolute); it must exist."""
    file_name = _field(doc, "modelica", where, str)
    path = bundle_dir / Path(file_name).expanduser()
    if not path.is_file():
        raise BundleError(f"{where}: field 'modelica' names {file_name!r}, but {path} does not exist")
    return path


def check_free(value: Any, model: symbolic.SymbolicModel, where: str) -> list[str] | None:
    """``plant.free``: absent (None: the nominal refit moves every non-zero parameter) or a list of the plant's
    parameter names, the ones the user does not know (as ``identify oe --free``); the others keep their values.
    A coupled mechanism has parameters the recordings cannot separate (link masses against gravity): fixing
    the known ones keeps the refit from trading them against the missing physics."""
    if value is None:
        return None
    known = [v.name for v in model.parameters]
    if not isinstance(value, list) or not value or not all(isinstance(n, str) for n in value):
        raise BundleError(f"{where}: field 'free' must be a non-empty list of parameter names, got {value!r}")
    unknown = [n for n in value if n not in known]
    if unknown:
        raise BundleError(f"{where}: field 'free' names {', '.join(map(repr, unknown))}, which "
                          f"{'is not a parameter' if len(unknown) == 1 else 'are not parameters'} of the plant; "
                          f"parameters: {', '.join(known)}")
    return list(value)


def check_pole_pitch(value: Any, where: str) -> float | None:
    """``plant.pole_pitch`` [m]: absent (None) or a finite positive number (the magnet pole pitch)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise BundleError(f"{where}: field 'pole_pitch' must be a positive length in m (the motor's magnet "
                          f"pole pitch), got {value!r}")
    return float(value)


def library_source(class_name: str, where: str, example: str) -> tuple[Path, str]:
    """The file of a MotionTwin library class and its source without the ``within`` clause."""
    from motiontwin.fmus.build import MODELICA_DIR

    path = MODELICA_DIR.joinpath(*class_name.split(".")).with_suffix(".mo")
    if not class_name.startswith("MotionTwin.") or not path.is_file():
        raise BundleError(f"{where}: field 'class' names {class_name!r}, which is not a class of the MotionTwin "
                          f"library (without field 'modelica', 'class' must be one, e.g. {example})")
    lines = path.read_text(encoding="utf-8").splitlines()
    return path, "\n".join(line for line in lines if not line.lstrip().startswith("within ")) + "\n"


def library_plant(class_name: str, input_name: str = "u", output_name: str = "q", parameters: Any = None,
                  where: str = "plant", position: str | None = None, velocity: str | None = None) -> PlantInfo:
    """A plant class of the MotionTwin library by its full name (e.g. ``MotionTwin.Plants.LinearMotorJoint``).
    Its source (without the ``within`` clause) becomes the plant text of the augmented model, so it must be
    self-contained: a class that uses other library classes is refused with a message saying so."""
    import tempfile

    path, text = library_source(class_name, where, "MotionTwin.Plants.LinearMotorJoint")
    if "MotionTwin." in text:
        raise BundleError(f"{where}: library class {class_name} uses other library classes; give it as a flat "
                          f"Modelica file (field 'modelica')")
    short = class_name.rsplit(".", 1)[-1]
    with tempfile.TemporaryDirectory(prefix="motiontwin-plant-") as tmp:
        flat = Path(tmp) / "plant.mo"
        flat.write_text(text, encoding="utf-8")
        info = load_plant(flat, short, input_name, output_name, parameters, where, position, velocity)
    info.source = path
    return info


def load_plant(path: Path, class_name: str, input_name: str = "u", output_name: str = "q",
               parameters: Any = None, where: str = "plant", position: str | None = None,
               velocity: str | None = None) -> PlantInfo:
    """The plant class ``class_name`` of the Modelica file ``path`` with its input, output and start values
    ``parameters`` checked, and its roles (position and velocity states: ``position``/``velocity`` when given,
    else found from the output's derivative chain); errors name ``where`` and the field."""
    try:
        model = symbolic.build(frontend.load(path, class_name))
    except frontend.ModelicaError as exc:
        raise BundleError(str(exc)) from None
    inputs = [v.name for v in model.inputs]
    if input_name not in inputs:
        raise BundleError(f"{path}: class {class_name} must have an input {input_name!r} "
                          f"(field 'plant.input' of {where}); it has inputs {inputs}")
    if model.sampled:
        raise BundleError(f"{path}: class {class_name} is a sampled model; the plant must be continuous")
    parameters = _start_parameters(model, path, class_name, parameters, where)
    text = path.read_text(encoding="utf-8")
    try:
        roles = find_roles(model, text, path, input_name, output_name, position, velocity)
    except PlantFormError as exc:
        raise BundleError(str(exc)) from None
    return PlantInfo(path, class_name, text, model, input_name, output_name, roles.position, roles.velocity, roles,
                     parameters)


def _start_parameters(model: symbolic.SymbolicModel, path: Path, class_name: str, parameters: Any,
                      where: str) -> dict[str, float]:
    """``plant.parameters`` checked: numbers, known parameters, inside the Modelica min/max."""
    if not model.parameters:
        raise BundleError(f"{path}: class {class_name} has no parameters to refit")
    parameters = {} if parameters is None else parameters
    if not isinstance(parameters, dict):
        raise BundleError(f"{where}: field 'parameters' must be an object {{NAME: VALUE}}, got {parameters!r}")
    try:
        parameters = startvalues.check_numbers(parameters, where)
        startvalues.check_parameters(model, parameters, f"{where}.parameters")
    except startvalues.StartValueError as exc:
        raise BundleError(str(exc).replace("field 'parameters.", "field 'plant.parameters.")) from None
    return parameters


def read_axes_plant(doc: dict, bundle_dir: Path, where: str) -> PlantInfo:
    """A multi-axis plant (``plant.axes``): a Modelica file or a library class (the MotionTwin library on the path),
    each axis's input and output of the class, position/velocity states as for one axis or an output expression."""
    from motiontwin.fmus.build import MODELICA_DIR

    for key in ("input", "output", "position", "velocity", "pole_pitch"):
        if key in doc:
            raise BundleError(f"{where}: field 'plant.{key}' cannot be combined with 'plant.axes' (give it per "
                              f"axis, e.g. 'plant.axes[0].{key}')")
    class_name = _field(doc, "class", where, str)
    if "modelica" in doc:
        path = _modelica_path(doc, bundle_dir, where)
        text = path.read_text(encoding="utf-8")
    else:
        path, text = library_source(class_name, where, "MotionTwin.Plants.CheungManipulator")
        class_name = class_name.rsplit(".", 1)[-1]
    try:
        if "modelica" in doc:
            model = symbolic.build(frontend.load(path, class_name, (MODELICA_DIR,)))
        else:
            model = symbolic.build(frontend.load(MODELICA_DIR, _field(doc, "class", where, str)))
    except frontend.ModelicaError as exc:
        raise BundleError(str(exc)) from None
    if model.sampled:
        raise BundleError(f"{path}: class {class_name} is a sampled model; the plant must be continuous")
    inputs = [v.name for v in model.inputs]
    outputs = model.state_outputs + [c.var.name for c in model.computed if c.causality == "output"]
    axes = _field(doc, "axes", where, list)
    if not axes:
        raise BundleError(f"{where}: field 'plant.axes' is empty; list one {{\"input\", \"output\"}} per axis")
    roles: list[PlantRoles] = []
    pitches: dict[str, float] = {}
    for k, axis in enumerate(axes):
        at = f"field 'plant.axes[{k}]"
        for key, names, what in (("input", inputs, "inputs"), ("output", outputs, "outputs")):
            name = axis.get(key) if isinstance(axis, dict) else None
            if not isinstance(name, str):
                raise BundleError(f"{where}: {at}.{key}' is required (a string)")
            if name not in names:
                raise BundleError(f"{where}: {at}.{key}' names {name!r}, which is not an {key} of class "
                                  f"{class_name} ({what}: {', '.join(names)})")
        try:
            found = find_roles(model, text, path, axis["input"], axis["output"], axis.get("position"),
                               axis.get("velocity"), expression=True)
            axis_kinematics.function_files(model, [found])
        except PlantFormError as exc:
            raise BundleError(f"{where}: {at}': {exc}") from None
        roles.append(found)
        pitch = check_pole_pitch(axis.get("pole_pitch"), f"{where}: {at}'")
        pitches.update({} if pitch is None else {found.output: pitch})
    for key in ("input", "output", "position"):
        names = [getattr(r, key) for r in roles]
        twice = sorted({n for n in names if names.count(n) > 1 and n})
        if twice:
            raise BundleError(f"{where}: field 'plant.axes': {key} {twice[0]!r} belongs to two axes")
    driven = {r.input for r in roles}
    held = {v.name: float(v.start) if isinstance(v.start, (int, float)) else 0.0
            for v in model.inputs if v.name not in driven}
    roles = [PlantRoles(r.input, r.output, r.position, r.velocity, r.source, held) for r in roles]
    parameters = _start_parameters(model, path, class_name, doc.get("parameters", {}), where)
    first = roles[0]
    return PlantInfo(path, class_name, text, model, first.input, first.output, first.position, first.velocity,
                     first, parameters, axes=roles, pole_pitches=pitches)


def read_axes_controller(doc: dict, where: str, axes: list[PlantRoles]) -> Controller:
    """The controller of a multi-axis bundle: ``per_axis`` (one single-axis controller per axis, same Ts,
    combined block-diagonally) or one multivariable ``discrete_state_space``."""
    kind = _field(doc, "kind", where, str)
    try:
        if kind == "per_axis":
            entries = _field(doc, "axes", where, list)
            if len(entries) != len(axes):
                raise BundleError(f"{where}: field 'axes' has {len(entries)} controllers, but plant.axes has "
                                  f"{len(axes)} axes ({', '.join(a.output for a in axes)}); give one per axis")
            parts = [controller.read_controller(entry, f"{where}: field 'axes[{k}]'")
                     for k, entry in enumerate(entries)]
            for k, part in enumerate(parts[1:], 1):
                if abs(part.Ts - parts[0].Ts) > 1e-12 * parts[0].Ts:
                    raise BundleError(f"{where}: field 'axes[{k}].Ts' is {part.Ts} s, but axes[0] has Ts = "
                                      f"{parts[0].Ts} s; every axis's controller must share one sample period")
            return controller.block_diagonal(parts)
        if kind == "discrete_state_space":
            return controller.read_multivariable(doc, where, [a.input for a in axes], [a.output for a in axes])
    except controller.ControllerError as exc:
        raise BundleError(str(exc)) from None
    raise BundleError(f"{where}: field 'kind' is {kind!r}; a multi-axis bundle needs 'per_axis' (one controller "
                      f"per axis) or a multivariable 'discrete_state_space'")


def axis_columns(axes: list[PlantRoles]) -> list[str]:
    """Required recording columns of a multi-axis bundle: per axis r_<output>, <input>, <output>."""
    return [c for a in axes for c in (f"r_{a.output}", a.input, a.output)]


def _to_si(rec: Recording, source: str, axes: list[PlantRoles] | None = None) -> None:
    """Read the declared units as ``identify joint`` does (ident.units): positions r, q and forces u, u_ext
    (multi-axis: per axis) converted to SI (mm, deg, kN ... with a note in the recording's metadata
    'unit_notes'), a unit of the wrong kind refused, and q's motion checked for plausibility (mm declared as m);
    UnitError names the column."""
    pairs = [(a.input, a.output) for a in axes] if axes else [("u", "q")]
    quantities: dict[str, str] = {}
    for force, position in pairs:
        reference, disturbance = ("r", "u_ext") if not axes else (f"r_{position}", f"u_ext_{force}")
        quantities.update({position: "position", force: "force"})
        if reference in rec.columns:
            quantities[reference] = "position"
        if disturbance in rec.columns:
            quantities[disturbance] = "force"
    columns = units.checked_columns(rec, quantities, source=source)
    for _, position in pairs:
        units.check_motion(columns, position, source=source)
    rec.time = columns.time
    rec.columns.update(columns.values)
    rec.units.update({"time": "s", **columns.units})
    if columns.notes:
        rec.meta.setdefault("metadata", {})["unit_notes"] = columns.notes


def _recording(doc: dict, key: str, bundle_dir: Path, where: str, ts: float | None,
               axes: list[PlantRoles] | None = None, predictor: bool = False) -> Recording:
    """The recording ``recordings.<key>`` in SI and checked at steps ``ts``; ``ts`` None: in SI but not checked
    yet; ``predictor``: an unknown controller's recording (columns time, u, q; :func:`predictor_recording`
    checks it)."""
    name = _field(doc, key, where, str)
    path = bundle_dir / name
    if not path.is_file():
        raise BundleError(f"{where}: field 'recordings.{key}' names {name!r}, but {path} does not exist")
    try:
        rec = read_recording(path, ("time", *axis_columns(axes)) if axes else
                             PREDICTOR_COLUMNS if predictor else REQUIRED_COLUMNS)
        _to_si(rec, str(path), axes)
    except RecordingError as exc:
        raise BundleError(str(exc)) from None
    return rec if ts is None else check_recording(rec, path, ts, axes)


def predictor_recording(rec: Recording, path: Path | str, ts: float) -> Recording:
    """An unknown controller's recording checked (time, u, q at steps ``ts``) with the predictor's signal
    roles: r = q (the observer's reference is the measured position), u_ext = u (the measured force drives
    the model)."""
    missing = [c for c in PREDICTOR_COLUMNS[1:] if c not in rec.columns]
    if missing:
        raise BundleError(f"{path}: required column {missing[0]!r} missing (columns: {', '.join(rec.columns)})")
    rec.columns["r"] = np.array(rec["q"], float)
    checked = check_recording(rec, path, ts)
    checked.columns["u_ext"] = np.array(checked["u"], float)
    return checked


def check_recording(rec: Recording, path: Path | str, ts: float, axes: list[PlantRoles] | None = None) -> Recording:
    """A recording fit for the diagnosis: columns time, r, u, q (multi-axis: per axis r_<output>, <input>,
    <output>; u_ext or u_ext_<input> added as zeros when absent), at least 20 samples, finite values, time
    steps of the controller's ``ts``; errors name ``path``, row and column."""
    required = tuple(axis_columns(axes)) if axes else REQUIRED_COLUMNS[1:]
    missing = [c for c in required if c not in rec.columns]
    if missing:
        raise BundleError(f"{path}: required column {missing[0]!r} missing (columns: {', '.join(rec.columns)})")
    for name in ("time",) + required:
        values = rec.time if name == "time" else rec[name]
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise BundleError(f"{path}, row {int(bad[0]) + 2}, column {name!r}: NaN or infinite value")
    if rec.time.size < 20:
        raise BundleError(f"{path}: only {rec.time.size} samples; a diagnosis needs at least 20")
    steps = np.diff(rec.time)
    bad = np.flatnonzero(np.abs(steps - ts) > 1e-3 * ts)
    if bad.size:
        i = int(bad[0])
        raise BundleError(f"{path}, row {i + 3}, column 'time': step {steps[i]!r} s differs from the controller "
                          f"sample time Ts = {ts} s (samples must be taken at the controller's sample instants; "
                          f"an unknown controller's recording at its median step)")
    for disturbance in ([f"u_ext_{a.input}" for a in axes] if axes else ["u_ext"]):
        if disturbance not in rec.columns:
            rec.columns[disturbance] = np.zeros_like(rec.time)
    return rec


def check_paths_inside(experiment: dict, bundle_dir: Path, exp_path: Path) -> None:
    """Refuse a file field of experiment.json (``plant.modelica``, ``recordings.*``) that resolves, symbolic
    links followed, outside ``bundle_dir``: a bundle from elsewhere must not read arbitrary files."""
    plant = experiment.get("plant") if isinstance(experiment.get("plant"), dict) else {}
    recordings = experiment.get("recordings") if isinstance(experiment.get("recordings"), dict) else {}
    fields = {"plant.modelica": plant.get("modelica"), **{f"recordings.{k}": v for k, v in recordings.items()}}
    inside = bundle_dir.resolve()
    for name, value in fields.items():
        if isinstance(value, str) and not (bundle_dir / Path(value).expanduser()).resolve().is_relative_to(inside):
            raise BundleError(f"{exp_path}: field {name!r} names {value!r}, a file outside the bundle folder "
                              f"{inside}; copy it into the bundle, or pass --allow-outside-paths to read it")


def read_bundle(bundle_dir: str | Path, allow_outside_paths: bool = False) -> Bundle:
    """Read and validate everything in ``bundle_dir``; raises :class:`BundleError` on the first problem.
    Files named in experiment.json must lie inside ``bundle_dir`` unless ``allow_outside_paths``."""
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
    validate_experiment(experiment, exp_path)
    if not allow_outside_paths:
        check_paths_inside(experiment, bundle_dir, exp_path)
    plant_doc = _field(experiment, "plant", str(exp_path), dict)
    controller_doc = experiment.get("controller")
    if controller_doc is None or controller_doc.get("kind") == UNKNOWN_KIND:
        return _unknown_controller_bundle(bundle_dir, experiment, exp_path, controller_doc or {})
    if "axes" in plant_doc:
        plant = read_axes_plant(plant_doc, bundle_dir, f"{exp_path}: plant")
        controller = read_axes_controller(controller_doc, f"{exp_path}: controller", plant.axes)
    else:
        controller = read_controller(controller_doc, f"{exp_path}: controller")
        plant = read_plant(plant_doc, bundle_dir, f"{exp_path}: plant")
    plant.free = check_free(plant_doc.get("free"), plant.model, f"{exp_path}: plant")
    recs = _field(experiment, "recordings", str(exp_path), dict)
    where = f"{exp_path}: recordings"
    train = _recording(recs, "train", bundle_dir, where, None, plant.axes)
    controller = at_recording_step(controller, train.time, str(bundle_dir / recs["train"]), BundleError)
    train = check_recording(train, bundle_dir / recs["train"], controller.sample_time, plant.axes)
    validation = _recording(recs, "validation", bundle_dir, where, controller.sample_time, plant.axes)
    return Bundle(bundle_dir, experiment, plant, controller, train, validation)



def _observer(doc: dict, train: Recording, where: str, source: str) -> Observer:
    """The observer of an unknown controller (:func:`ident.observer.observer_from_document`)."""
    try:
        return observer_from_document(doc, train, where, source)
    except ObserverError as exc:
        raise BundleError(str(exc)) from None


def _unknown_controller_bundle(bundle_dir: Path, experiment: dict, exp_path: Path, controller_doc: dict) -> Bundle:
    """A bundle whose controller is unknown: plant, recordings with the predictor's roles, the observer."""
    plant_doc = experiment["plant"]
    if "axes" in plant_doc:
        raise BundleError(f"{exp_path}: field 'controller' is absent or of kind 'unknown', which a multi-axis "
                          f"plant (field 'plant.axes') does not support yet; give the controller")
    plant = read_plant(plant_doc, bundle_dir, f"{exp_path}: plant")
    plant.free = check_free(plant_doc.get("free"), plant.model, f"{exp_path}: plant")
    recs = _field(experiment, "recordings", str(exp_path), dict)
    where = f"{exp_path}: recordings"
    raw = {key: _recording(recs, key, bundle_dir, where, None, predictor=True) for key in ("train", "validation")}
    ts = controller_doc.get("Ts") or float(np.median(np.diff(raw["train"].time)))
    train, validation = (predictor_recording(raw[key], bundle_dir / recs[key], ts) for key in ("train", "validation"))
    observer = _observer({**controller_doc, "Ts": ts}, train, str(exp_path), str(bundle_dir / recs["train"]))
    return Bundle(bundle_dir, experiment, plant, observer.controller(), train, validation, observer=observer)


IN_MEMORY = Path("(in memory)")


def _is_file(text: str) -> bool:
    """True when ``text`` names an existing file (a Modelica source longer than a file name is not one)."""
    try:
        return Path(text).is_file()
    except OSError:
        return False


def make_bundle(plant: str | Path, controller: Controller | dict, train: Recording, validation: Recording,
                plant_class: str | None = None, parameters: dict[str, float] | None = None,
                input_name: str = "u", output_name: str = "q", pole_pitch: float | None = None,
                axes: list[dict] | None = None) -> Bundle:
    """A bundle from in-memory objects, checked as :func:`read_bundle` checks a folder.

    Parameters
    ----------
    plant : a Modelica file (path) or Modelica source text holding the plant class.
    controller : a :class:`ident.controller.Controller`, or its experiment.json object.
    train, validation : closed-loop recordings (columns time, r, u, q[, u_ext]) at the controller's samples.
    plant_class : the plant class (default: the first ``model`` of the text/file).
    parameters : start values of plant parameters (as ``plant.parameters`` of experiment.json).
    input_name, output_name : the plant's force input and position output.
    pole_pitch : the motor's magnet pole pitch [m] (as ``plant.pole_pitch``), or None.
    axes : a multi-axis plant, ``[{"input": "u1", "output": "q1"}, ...]`` as ``plant.axes`` of experiment.json
        (then the controller is a per_axis or multivariable object, or a :class:`Controller` mapping
        [r_1..r_n, q_1..q_n] to [u_1..u_n], and the recordings have the per-axis columns).

    Returns
    -------
    Bundle
        With ``directory`` = ``IN_MEMORY`` (messages name the recordings "train" and "validation").
    """
    import re
    import tempfile

    text = str(plant)
    is_text = isinstance(plant, str) and ("\n" in text or ";" in text) and not _is_file(text)
    if not is_text and not Path(plant).is_file():
        raise BundleError(f"plant: {plant!r} is neither a Modelica file nor Modelica source text")
    source = text if is_text else Path(plant).read_text(encoding="utf-8")
    if plant_class is None:
        found = re.search(r"^\s*model\s+(\w+)", source, re.MULTILINE)
        if not found:
            raise BundleError("plant: no 'model NAME' in the Modelica source; give plant_class")
        plant_class = found.group(1)
    with tempfile.TemporaryDirectory(prefix="motiontwin-plant-") as tmp:
        path = Path(tmp) / "plant.mo" if is_text else Path(plant)
        if is_text:
            path.write_text(source, encoding="utf-8")
        if axes:
            info = read_axes_plant({"modelica": str(path), "class": plant_class, "axes": list(axes),
                                    "parameters": parameters or {}}, path.parent, "plant")
        else:
            info = load_plant(path, plant_class, input_name, output_name, parameters, "plant")
    info.pole_pitch = check_pole_pitch(pole_pitch, "plant")
    if axes and pole_pitch is not None:
        raise BundleError("plant: pole_pitch cannot be combined with axes (give it per axis, e.g. "
                          "axes=[{'input': 'u1', 'output': 'q1', 'pole_pitch': 0.032}, ...])")
    experiment = {"recordings": {"train": "train", "validation": "validation"}}
    if controller is None or (isinstance(controller, dict) and controller.get("kind") == UNKNOWN_KIND):
        if axes:
            raise BundleError("controller: an unknown controller (None or kind 'unknown') supports one axis only")
        doc = dict(controller or {})
        ts = doc.get("Ts") or float(np.median(np.diff(train.time)))
        checked = [predictor_recording(Recording(rec.time, dict(rec.columns), rec.units, rec.meta), name, ts)
                   for rec, name in ((train, "train"), (validation, "validation"))]
        observer = _observer({**doc, "Ts": ts}, checked[0], "controller", "train")
        return Bundle(IN_MEMORY, experiment, info, observer.controller(), *checked, observer=observer)
    if not isinstance(controller, Controller):
        controller = (read_axes_controller(dict(controller), "controller", info.axes) if axes
                      else read_controller(dict(controller), "controller"))
    controller = at_recording_step(controller, train.time, "train", BundleError)
    checked = [check_recording(rec, name, controller.sample_time, info.axes)
               for rec, name in ((train, "train"), (validation, "validation"))]
    return Bundle(IN_MEMORY, experiment, info, controller, *checked)
