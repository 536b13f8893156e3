"""External input signals of a run, as suite and sweep files and ``motiontwin run --input`` give them.

One value of a system's external input is one of

* a number: held constant over the run;
* ``{recording = "FILE.csv", column = "NAME"}``: a recording column (held from sample to sample);
* ``{experiment = "FILE.toml", field = "NAME"}``: a signal of an excitation experiment file
  (:mod:`harness.experiment`; ``field`` defaults to ``value``, else ``position``);

paths relative to the file that names them. :func:`add_input_noise` adds seeded white noise on the
master's base grid (:func:`harness.measurement.add_noise`). Values are in the input's unit.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["InputError", "resolve_input", "input_from_spec", "sample_held", "add_input_noise"]


class InputError(ValueError):
    """An input value is malformed (the message names the file, the case and the input)."""


def _experiment_signal(path: Path, field: str | None, where: str) -> tuple[np.ndarray, np.ndarray]:
    from motiontwin.harness import experiment

    signals = experiment.load_experiment(path).generate()
    field = field or ("value" if "value" in signals else "position")
    if field not in signals:
        raise InputError(f"{where}: the experiment {path} has no field {field!r}; it has {sorted(signals)}")
    values = signals[field]
    if values.ndim != 1:
        raise InputError(f"{where}: field {field!r} of {path} has {values.shape[1]} axes; an input takes one")
    return signals["time"], values


def resolve_input(value: Any, root: Path, where: str) -> Any:
    """A number, or (time, values) for a recording column or an experiment signal (see module docstring)."""
    from motiontwin.harness.recording import read_recording

    if isinstance(value, bool) or not isinstance(value, (int, float, dict)):
        raise InputError(f"{where}: expected a number, {{recording, column}} or {{experiment, field}}, "
                         f"got {value!r}")
    if not isinstance(value, dict):
        return float(value)
    if set(value) == {"recording", "column"}:
        rec = read_recording(root / value["recording"], required=("time", value["column"]))
        return rec.time, rec[value["column"]]
    if "experiment" in value and set(value) <= {"experiment", "field"}:
        return _experiment_signal(root / value["experiment"], value.get("field"), where)
    raise InputError(f"{where}: expected {{recording = \"FILE.csv\", column = \"NAME\"}} or "
                     f"{{experiment = \"FILE.toml\", field = \"NAME\"}}, got keys {sorted(value)}")


def input_from_spec(spec: str) -> tuple[str, float | tuple[np.ndarray, np.ndarray]]:
    """``NAME=VALUE`` or ``NAME=EXPERIMENT.toml[:FIELD]`` (the ``--input`` option) -> (NAME, constant) or
    (NAME, (time, values)), as a suite file's ``[case.inputs]`` takes them."""
    name, sep, rest = spec.partition("=")
    if not sep or not name:
        raise InputError(f"--input {spec!r}: expected NAME=VALUE or NAME=EXPERIMENT.toml[:FIELD]")
    try:
        value = float(rest)
    except ValueError:
        value = None
    if value is not None:
        if not math.isfinite(value):
            raise InputError(f"--input {spec!r}: the constant must be a finite number")
        return name, value
    path, field = rest, None
    if ":" in rest and rest.rsplit(":", 1)[0].endswith(".toml"):
        path, field = rest.rsplit(":", 1)
    return name, _experiment_signal(Path(path), field, f"--input {spec!r}")


def sample_held(t: np.ndarray, v: np.ndarray, grid: np.ndarray, base_step: float) -> np.ndarray:
    """``v`` held from each ``t[i]`` to the next, read at ``grid`` (before the first sample: ``v[0]``)."""
    index = np.searchsorted(t, grid + 1e-9 * base_step, side="right") - 1
    return np.asarray(v, dtype=float)[np.clip(index, 0, len(v) - 1)]


def add_input_noise(value: Any, grid: np.ndarray, base_step: float, std: float, seed: int) -> np.ndarray:
    """``value`` (number, (time, values) held, or None = 0) on the base ``grid`` plus seeded white noise."""
    from motiontwin.harness.measurement import add_noise

    if value is None:
        base = np.zeros(grid.size)
    elif isinstance(value, tuple):
        base = sample_held(np.asarray(value[0], float), value[1], grid, base_step)
    else:
        base = np.full(grid.size, float(value))
    return add_noise(base, std, seed)
