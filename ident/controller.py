"""A sampled linear controller (discrete state space) and its JSON description.

JSON object (the ``controller`` field of a diagnosis bundle's experiment.json, or a file of its own)::

    {"kind": "discrete_state_space", "Ts": 0.0005, "inputs": ["r", "q"], "outputs": ["u"],
     "A": [[...]], "B": [[...], ...], "C": [[...]], "D": [[dr, dq]]}

meaning z[k+1] = A z[k] + B y[k], u[k] = C z[k] + D y[k] with y = the listed inputs. Or one of the project's
sampled library controllers by its Modelica name with parameter values, e.g.
``{"kind": "MotionTwin.Controllers.RobustJointController", "parameters": {"Kp": 2e5, "Kv": 0, "Ka": 0}}``: its
sampled matrices (Tustin, or ``method="discrete"``) at those values (the others at their Modelica defaults),
exactly as its FMU executes them. Inputs other than ``r`` and ``q`` (reference derivatives of a feedforward)
are not recorded, so their gains must be 0. Units: Ts [s]; the
matrices map the reference and the measured position [m] to the force [N].
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.limits import load_json
from motiontwin.harness.numbers import is_finite_number

CONTROLLER_KINDS = ("discrete_state_space",)
LIBRARY_PACKAGE = "MotionTwin.Controllers."   # named controllers: sampled classes of the project's library


class ControllerError(ValueError):
    """A controller description is unusable; the message names the file or object and the field at fault."""


@dataclass
class Controller:
    """Sampled linear controller z+ = A z + B y, u = C z + D y with y = [r; q] (inputs reordered to r, q);
    a multi-axis one has y = [r_1..r_n, q_1..q_n] and u = [u_1..u_n]. ``Ts``: the controller's own period [s];
    ``ticks``: its updates per recorded sample (a controller faster than the recording, set by
    :func:`at_recording_step`), so that ``sample_time`` = ``ticks`` x ``Ts`` is the recording's step."""

    Ts: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    ticks: int = 1

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    @property
    def sample_time(self) -> float:
        """The step of the recordings and of the simulated loop [s]."""
        return self.Ts * self.ticks

    def entries(self) -> np.ndarray:
        """The nonzero entries of A, B, C, D, each column-major: the last inputs of a loop's compiled step
        (``ident.oeloop``), so that its C code is the same for every controller with the same nonzero pattern
        and a compiled chain is reused by the next bundle of the same plant (the values are not folded into the
        code; the arithmetic is the same)."""
        return np.concatenate([_nonzeros(m) for m in (self.A, self.B, self.C, self.D)])

    def symbolic(self, entries: ca.SX | ca.MX) -> list:
        """A, B, C, D with their nonzeros from the symbols ``entries`` (laid out as :meth:`entries`) and
        structural zeros elsewhere."""
        matrices, start = [], 0
        for m in (self.A, self.B, self.C, self.D):
            pattern = ca.sparsify(ca.DM((np.asarray(m, dtype=float) != 0).astype(float))).sparsity()
            count = pattern.nnz()
            matrices.append(type(entries)(pattern, entries[start:start + count]))
            start += count
        return matrices

    def describe_rate(self) -> str:
        """How the controller's period relates to the recording's, in words."""
        if self.ticks == 1:
            return f"the controller runs at the recording's step, {self.Ts:.6g} s"
        return (f"the controller runs at {self.Ts:.6g} s, {self.ticks} updates per recorded sample of "
                f"{self.sample_time:.6g} s: simulated at its own period (the reference held over each recorded "
                f"sample, the position taken from the model at each update), the force recorded at the update on "
                f"the sample instant")


def _nonzeros(matrix: np.ndarray) -> np.ndarray:
    """The nonzero entries of ``matrix`` in column-major order (CasADi's order of the nonzeros)."""
    flat = np.asarray(matrix, dtype=float).ravel(order="F")
    return flat[flat != 0]


#: a recording step is a whole number of controller periods when within this relative tolerance (the one the
#: recording checks allow each step)
TICKS_TOLERANCE = 1e-3


def at_recording_step(controller: Controller, time: np.ndarray, where: str,
                      error: type[ValueError] = ControllerError) -> Controller:
    """``controller`` for a recording at the times ``time`` [s]: its own period when that is the median step,
    else ``ticks`` = step / ``Ts`` updates per recorded sample when that is a whole number (a drive's fast
    controller under a slower recording). Raises ``error`` naming ``where`` otherwise."""
    steps = np.diff(np.asarray(time, float))
    step = float(np.median(steps)) if steps.size else controller.Ts * controller.ticks
    ticks = round(step / controller.Ts)
    if ticks < 1 or abs(ticks * controller.Ts - step) > TICKS_TOLERANCE * step:
        raise error(
            f"{where}: the recording's step {step:.9g} s is not a whole number of the controller's period Ts = "
            f"{controller.Ts:.9g} s (ratio {step / controller.Ts:.6g}); resample the recording onto a multiple of "
            f"it (motiontwin import --resample --sample-time TS)")
    return dataclasses.replace(controller, ticks=int(ticks))


def field(doc: dict, key: str, where: str, kind: type | tuple[type, ...],
          error: type[ValueError] = ControllerError) -> Any:
    """``doc[key]`` checked for presence and type; ``error`` (naming ``where`` and the field) otherwise."""
    if not isinstance(doc, dict) or key not in doc:
        raise error(f"{where}: required field {key!r} missing")
    value = doc[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        name = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise error(f"{where}: field {key!r} must be a {name}, got {value!r}")
    return value


def _matrix(doc: dict, key: str, where: str, shape: tuple[int, int]) -> np.ndarray:
    raw = field(doc, key, where, list)
    try:
        mat = np.array(raw, dtype=float)
    except (TypeError, ValueError):
        raise ControllerError(f"{where}: field {key!r} must be a list of rows of numbers") from None
    if mat.size == 0 and shape[0] * shape[1] == 0:
        return np.zeros(shape)
    if mat.ndim != 2 or mat.shape != shape:
        raise ControllerError(f"{where}: field {key!r} has shape {mat.shape}, expected {shape}")
    if not np.all(np.isfinite(mat)):
        raise ControllerError(f"{where}: field {key!r} contains a non-finite value")
    return mat


def read_controller(doc: dict, where: str) -> Controller:
    """Parse a controller object: kind ``discrete_state_space`` (matrices given) or the name of one of the
    library's sampled controllers with its ``parameters``; ``where`` names it in error messages."""
    kind = field(doc, "kind", where, str)
    if kind.startswith(LIBRARY_PACKAGE):
        return read_named_controller(doc, where)
    if kind not in CONTROLLER_KINDS:
        raise ControllerError(f"{where}: field 'kind' is {kind!r}; supported controller kinds: "
                              f"{', '.join(CONTROLLER_KINDS)}, the name of a sampled controller of the "
                              f"project's library, e.g. {LIBRARY_PACKAGE}RobustJointController, or 'unknown' "
                              f"(no controller: a prediction-error predictor stands in for it, ident.observer)")
    ts = field(doc, "Ts", where, (int, float))
    if not (math.isfinite(ts) and ts > 0):
        raise ControllerError(f"{where}: field 'Ts' must be a positive number of seconds, got {ts!r}")
    inputs = field(doc, "inputs", where, list)
    if sorted(map(str, inputs)) != ["q", "r"]:
        raise ControllerError(f"{where}: field 'inputs' must be ['r', 'q'] (in any order), got {inputs!r}")
    outputs = field(doc, "outputs", where, list)
    if list(outputs) != ["u"]:
        raise ControllerError(f"{where}: field 'outputs' must be ['u'], got {outputs!r}")
    n = len(field(doc, "A", where, list))
    A = _matrix(doc, "A", where, (n, n))
    B = _matrix(doc, "B", where, (n, 2))
    C = _matrix(doc, "C", where, (1, n))
    D = _matrix(doc, "D", where, (1, 2))
    order = [inputs.index("r"), inputs.index("q")]
    return Controller(float(ts), A, B[:, order], C, D[:, order])


@functools.lru_cache(maxsize=8)
def _library_controller(class_name: str) -> symbolic.SymbolicModel:
    from motiontwin.fmus import build

    return build.load_model(class_name)


def read_named_controller(doc: dict, where: str) -> Controller:
    """The sampled (Tustin or discrete) matrices of a library controller at the given parameter values,
    exactly as its FMU executes them (fmus.symbolic's discretisation). Its inputs ``r`` and ``q`` are the
    recorded reference and position; any other input (e.g. the reference derivatives of the feedforward)
    is not recorded, so its path must be switched off by the parameters (its matrix columns zero)."""
    kind = doc["kind"]
    try:
        model = _library_controller(kind)
    except frontend.ModelicaError as exc:
        raise ControllerError(f"{where}: field 'kind' names {kind!r}, which the project's Modelica library cannot "
                          f"provide ({exc})") from None
    if not model.sampled:
        raise ControllerError(f"{where}: field 'kind' names {kind!r}, which is not a sampled controller (no "
                          "__motiontwin(sampled(...)) annotation)")
    inputs = [v.name for v in model.inputs]
    outputs = [c.var.name for c in model.computed if c.causality == "output"]
    if not {"r", "q"} <= set(inputs) or "u" not in outputs:
        raise ControllerError(f"{where}: controller {kind} must have inputs 'r', 'q' and output 'u'; it has inputs "
                          f"{inputs} and outputs {outputs}")
    raw = doc.get("parameters", {})
    if not isinstance(raw, dict):
        raise ControllerError(f"{where}: field 'parameters' must be an object of parameter values, got {raw!r}")
    names = [v.name for v in model.parameters]
    values = dict(zip(names, model.parameter_values()))
    for key, value in raw.items():
        if key not in values:
            raise ControllerError(f"{where}: field 'parameters.{key}': {kind} has no parameter {key!r} "
                              f"(parameters: {', '.join(names)})")
        if not is_finite_number(value):
            raise ControllerError(f"{where}: field 'parameters.{key}' must be a finite number, got {value!r}")
        values[key] = float(value)
    ts = values[names[model.ts_index]]
    if not ts > 0:
        raise ControllerError(f"{where}: field 'parameters.{names[model.ts_index]}' (the sample period) must be "
                          f"positive, got {ts!r}")
    p = [values[n] for n in names]
    ad, bd, cd, dd = (np.array(m, dtype=float)
                      for m in ca.Function("law", [model.p], [model.Ad, model.Bd, model.Cd, model.Dd])(p))
    row = outputs.index("u")
    u_row = [c.var.name for c in model.computed].index(outputs[row])
    cd, dd = cd[u_row:u_row + 1], dd[u_row:u_row + 1]
    for i, name in enumerate(inputs):
        if name not in ("r", "q") and (np.any(bd[:, i] != 0) or dd[0, i] != 0):
            raise ControllerError(f"{where}: field 'parameters': input {name!r} of {kind} is not recorded, so the "
                              f"gains acting on it must be zero (e.g. a feedforward gain)")
    order = [inputs.index("r"), inputs.index("q")]
    mats = (ad, bd[:, order], cd, dd[:, order])
    if not all(np.all(np.isfinite(m)) for m in mats):
        raise ControllerError(f"{where}: field 'parameters' gives a non-finite sampled law for {kind}")
    return Controller(float(ts), *mats)


def block_diagonal(controllers: list[Controller]) -> Controller:
    """One multivariable controller from one single-axis controller per axis: inputs
    y = [r_1..r_n, q_1..q_n], outputs u_1..u_n, states stacked (all must share ``Ts``)."""
    n = len(controllers)
    sizes = [c.n_states for c in controllers]
    nz = sum(sizes)
    A, B, C, D = np.zeros((nz, nz)), np.zeros((nz, 2 * n)), np.zeros((n, nz)), np.zeros((n, 2 * n))
    offset = 0
    for k, c in enumerate(controllers):
        block = slice(offset, offset + c.n_states)
        A[block, block] = c.A
        B[block, k], B[block, n + k] = c.B[:, 0], c.B[:, 1]
        C[k, block] = c.C[0]
        D[k, k], D[k, n + k] = c.D[0, 0], c.D[0, 1]
        offset += c.n_states
    return Controller(controllers[0].Ts, A, B, C, D)


def read_multivariable(doc: dict, where: str, inputs: list[str], outputs: list[str]) -> Controller:
    """A multivariable ``discrete_state_space`` controller of a multi-axis loop whose inputs are
    ``r_<output>`` and ``<output>`` of every axis and whose outputs are the axes' plant inputs (in any
    order); the matrices are reordered to y = [r_1..r_n, q_1..q_n], u = [u_1..u_n] in the axes' order."""
    ts = field(doc, "Ts", where, (int, float))
    if not (math.isfinite(ts) and ts > 0):
        raise ControllerError(f"{where}: field 'Ts' must be a positive number of seconds, got {ts!r}")
    expected_in = [f"r_{o}" for o in outputs] + list(outputs)
    got_in = [str(v) for v in field(doc, "inputs", where, list)]
    if sorted(got_in) != sorted(expected_in):
        raise ControllerError(f"{where}: field 'inputs' must list {expected_in} (in any order), got {got_in!r}")
    got_out = [str(v) for v in field(doc, "outputs", where, list)]
    if sorted(got_out) != sorted(inputs):
        raise ControllerError(f"{where}: field 'outputs' must list the axes' inputs {inputs} (in any order), "
                              f"got {got_out!r}")
    n = len(field(doc, "A", where, list))
    A = _matrix(doc, "A", where, (n, n))
    B = _matrix(doc, "B", where, (n, len(got_in)))
    C = _matrix(doc, "C", where, (len(got_out), n))
    D = _matrix(doc, "D", where, (len(got_out), len(got_in)))
    cols = [got_in.index(name) for name in expected_in]
    rows = [got_out.index(name) for name in inputs]
    return Controller(float(ts), A, B[:, cols], C[rows], D[rows][:, cols])


def load_controller(path: str | Path) -> Controller:
    """Read a controller JSON file: the controller object itself or an experiment.json holding one."""
    path = Path(path)
    doc = load_json(path, ControllerError)
    if isinstance(doc, dict) and "kind" not in doc and isinstance(doc.get("controller"), dict):
        return read_controller(doc["controller"], f"{path}: controller")
    return read_controller(doc, str(path))


def controller_document(controller: Controller) -> dict[str, Any]:
    """The JSON object of ``controller`` (inputs ordered r, q), as :func:`read_controller` reads it."""
    return {"kind": "discrete_state_space", "Ts": controller.Ts, "inputs": ["r", "q"], "outputs": ["u"],
            "A": controller.A.tolist(), "B": controller.B.tolist(), "C": controller.C.tolist(),
            "D": controller.D.tolist()}
