"""A sampled linear controller (discrete state space) and its JSON description.

JSON object (the ``controller`` field of a diagnosis bundle's experiment.json, or a file of its own)::

    {"kind": "discrete_state_space", "Ts": 0.0005, "inputs": ["r", "q"], "outputs": ["u"],
     "A": [[...]], "B": [[...], ...], "C": [[...]], "D": [[dr, dq]]}

meaning z[k+1] = A z[k] + B y[k], u[k] = C z[k] + D y[k] with y = the listed inputs. Units: Ts [s]; the
matrices map the reference and the measured position [m] to the force [N].
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

CONTROLLER_KINDS = ("discrete_state_space",)


class ControllerError(ValueError):
    """A controller description is unusable; the message names the file or object and the field at fault."""


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


def _field(doc: dict, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    if not isinstance(doc, dict) or key not in doc:
        raise ControllerError(f"{where}: required field {key!r} missing")
    value = doc[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        name = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise ControllerError(f"{where}: field {key!r} must be a {name}, got {value!r}")
    return value


def _matrix(doc: dict, key: str, where: str, shape: tuple[int, int]) -> np.ndarray:
    raw = _field(doc, key, where, list)
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
    """Parse a controller object (kind discrete_state_space); ``where`` names it in error messages."""
    kind = _field(doc, "kind", where, str)
    if kind not in CONTROLLER_KINDS:
        raise ControllerError(f"{where}: field 'kind' is {kind!r}; supported controller kinds: "
                              f"{', '.join(CONTROLLER_KINDS)}")
    ts = _field(doc, "Ts", where, (int, float))
    if not (math.isfinite(ts) and ts > 0):
        raise ControllerError(f"{where}: field 'Ts' must be a positive number of seconds, got {ts!r}")
    inputs = _field(doc, "inputs", where, list)
    if sorted(map(str, inputs)) != ["q", "r"]:
        raise ControllerError(f"{where}: field 'inputs' must be ['r', 'q'] (in any order), got {inputs!r}")
    outputs = _field(doc, "outputs", where, list)
    if list(outputs) != ["u"]:
        raise ControllerError(f"{where}: field 'outputs' must be ['u'], got {outputs!r}")
    n = len(_field(doc, "A", where, list))
    A = _matrix(doc, "A", where, (n, n))
    B = _matrix(doc, "B", where, (n, 2))
    C = _matrix(doc, "C", where, (1, n))
    D = _matrix(doc, "D", where, (1, 2))
    order = [inputs.index("r"), inputs.index("q")]
    return Controller(float(ts), A, B[:, order], C, D[:, order])


def load_controller(path: str | Path) -> Controller:
    """Read a controller JSON file: the controller object itself or an experiment.json holding one."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ControllerError(f"{path}: file not found") from None
    except json.JSONDecodeError as exc:
        raise ControllerError(f"{path}, line {exc.lineno}, column {exc.colno}: invalid JSON ({exc.msg})") from None
    if isinstance(doc, dict) and "kind" not in doc and isinstance(doc.get("controller"), dict):
        return read_controller(doc["controller"], f"{path}: controller")
    return read_controller(doc, str(path))


def controller_document(controller: Controller) -> dict[str, Any]:
    """The JSON object of ``controller`` (inputs ordered r, q), as :func:`read_controller` reads it."""
    return {"kind": "discrete_state_space", "Ts": controller.Ts, "inputs": ["r", "q"], "outputs": ["u"],
            "A": controller.A.tolist(), "B": controller.B.tolist(), "C": controller.C.tolist(),
            "D": controller.D.tolist()}
