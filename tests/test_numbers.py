"""harness.numbers: the one test of what a number is in the project's files, as every reader applies it."""
from __future__ import annotations

import math

import pytest

from motiontwin.harness.experiment import ExperimentError, parse_experiment
from motiontwin.harness.numbers import is_finite_number, is_integer, is_number
from motiontwin.harness.regress import SuiteError, Tolerance, _tolerance


@pytest.mark.parametrize("value, number, integer, finite", [
    (1, True, True, True), (1.5, True, False, True), (True, False, False, False), (math.nan, True, False, False),
    (math.inf, True, False, False), ("1", False, False, False), (None, False, False, False),
])
def test_number_classes(value: object, number: bool, integer: bool, finite: bool) -> None:
    assert (is_number(value), is_integer(value), is_finite_number(value)) == (number, integer, finite)


def test_readers_refuse_booleans_and_infinities_naming_the_field() -> None:
    """A TOML ``true`` is no sample time and ``inf`` no tolerance: each reader names where."""
    with pytest.raises(ExperimentError, match="e.toml: field 'sample_time' must be a finite number, got True"):
        parse_experiment({"sample_time": True, "duration": 1.0, "excitation": {"kind": "step", "t_step": 0.1,
                                                                               "amplitude": 1.0}}, "e.toml")
    with pytest.raises(SuiteError, match="tolerance abs must be a number >= 0, got inf"):
        _tolerance({"abs": math.inf}, Tolerance(0.0, 0.0, 0.0), "suite.toml [case]")
