"""Values given on the command line as text, parsed once for every subcommand."""
from __future__ import annotations

import math


def name_values(text: str, where: str) -> dict[str, float]:
    """``"K=1.2, omega=2300"`` -> ``{"K": 1.2, "omega": 2300.0}`` (commas separate, blanks are ignored).

    ``where`` (e.g. ``"--plant #1"``) starts every error message, which also names the field at fault.
    """
    values: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = (part.strip() for part in item.partition("="))
        if not sep or not name:
            raise ValueError(f"{where} {text!r}: field {item!r} must be NAME=VALUE")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{where} {text!r}: field {name!r} = {value!r} is not a number") from None
        if not math.isfinite(number):
            raise ValueError(f"{where} {text!r}: field {name!r} = {value!r} is not a finite number")
        values[name] = number
    return values


def loop_controller(value: str | None, rec: object, output: str, input_name: str, reference: str = "r",
                    fitted: dict | None = None) -> tuple:
    """``--controller`` of ``identify oe`` and ``validate``: None (open loop), ``unknown`` or a JSON whose kind is
    ``unknown`` (the prediction-error predictor of :mod:`ident.observer`: the observer, reference = the output
    column, disturbance = the input column), else a controller JSON. Returns (controller or None, signals,
    observer or None); ``rec`` needs the columns the choice uses (a known controller: ``reference`` too).
    ``fitted``: the controller object of the fit being validated; with ``unknown`` its observer is used (the
    one the fit's RMS was scored with), not one sized on ``rec``."""
    from pathlib import Path

    from motiontwin.ident.oeloop import Signals

    if value is None:
        return None, Signals(output=output, input=input_name, reference=reference), None
    from motiontwin.fmus.limits import load_json
    from motiontwin.ident import observer
    from motiontwin.ident.controller import ControllerError, load_controller

    doc = None if value == observer.UNKNOWN_KIND else load_json(Path(value), ControllerError)
    source = str(value)
    if doc is None and isinstance(fitted, dict) and fitted.get("kind") == observer.UNKNOWN_KIND:
        doc, source = fitted, "the fit (sized on its training recording)"
    inner = doc.get("controller", doc) if isinstance(doc, dict) and "kind" not in doc else doc
    if doc is None or (isinstance(inner, dict) and inner.get("kind") == observer.UNKNOWN_KIND):
        found = observer.observer_from_document(inner or {}, rec, f"--controller {value}", source)
        return found.controller(), observer.predictor_signals(output, input_name), found
    return load_controller(Path(value)), Signals(output=output, input=input_name, reference=reference), None
