"""What counts as a number in the project's files (TOML, JSON): the one test every reader applies.

Why: ``bool`` is an ``int`` in Python, and NaN or infinity parse from TOML/JSON, so ``isinstance(v, float)`` alone
lets ``true`` or ``inf`` through as a parameter value; each reader then names the file and field itself.
"""
from __future__ import annotations

import math
from typing import Any

__all__ = ["is_number", "is_integer", "is_finite_number"]


def is_number(value: Any) -> bool:
    """An int or float, not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_integer(value: Any) -> bool:
    """An int, not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_finite_number(value: Any) -> bool:
    """An int or float, not a bool, neither NaN nor infinite."""
    return is_number(value) and math.isfinite(value)
