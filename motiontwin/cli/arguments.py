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
