"""Lab files -> the project's one recording format (``motiontwin import``).

Reads a MATLAB .mat file (v4-v7 through scipy.io.loadmat; v7.3 through h5py), a generic HDF5 file (.h5, .hdf5)
or a delimited text file with any column names (comma, semicolon, tab or blanks; ``#``/``%`` comment lines
before the header are skipped), and writes ``NAME.csv`` + ``NAME.json`` through :mod:`harness.recording`:

* **columns**: ``mapping`` recording name -> source name (``{"q": "pos_enc"}``); struct fields of a .mat and
  datasets in HDF5 groups are named by their path (``run1.pos``, ``/group/pos``), matrix columns by a 1-based
  MATLAB index (``data(:,2)``; a wide matrix's rows, e.g. six axes in a 6 x N matrix: ``pos(2,:)``). Without a
  mapping every vector of the time's length is imported, under its name
  made CSV-safe (``data(:,2)`` -> ``data_2``, ``/group/pos`` -> ``group_pos``).
* **units and gains**: ``units`` gives the recorded unit of a source column (``{"u": "V"}``), ``gains`` a
  factor with its unit (``{"u": "40 N/V"}``): the column is multiplied by the gain and gets the gain's
  numerator unit; then time, positions and forces in other scales (ms, mm, deg, kN, ...) are converted to SI
  (:func:`harness.units.si_scale`). Every conversion and assumption is reported in ``notes``.
* **sample time**: ``sample_time`` when given (e.g. the controller's period), else the median step, snapped
  to its clock when within the jitter (0.000999984 -> 0.001, :func:`clock_step`); the jitter (deviation of
  each step from the median) is measured and reported. The time stamps are kept as recorded unless
  ``resample`` is set (linear interpolation onto the ticks k Ts of a given ``sample_time``, else onto
  t0 + k Ts; stated in the notes and the sidecar). Jitter beyond the recording format's
  tolerance (``recording.SAMPLE_TIME_TOLERANCE`` of Ts) without ``resample`` leaves ``sample_time`` null.
* **trimming**: to a time window ``[start, stop]``, then to whole periods of the excitation (``period`` [s]),
  counted from the window's first sample; what was dropped is reported.

Errors (:class:`harness.recording.RecordingError`) name the file, the variable or column and, for text
files, the line.

Units: SI after import (s, m, rad, N, N.m); the sidecar records the source, mapping, raw units, gains,
jitter and trimming under ``metadata.import``.
"""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from motiontwin.fmus.limits import check_rows, check_size, read_text
from motiontwin.harness import recording
from motiontwin.harness.recording import DEFAULT_UNITS, Recording, RecordingError
from motiontwin.harness.units import si_scale, units_compatible

__all__ = ["LabSource", "JitterReport", "LabImport", "read_lab_file", "parse_gain", "jitter_report", "clock_step",
           "import_lab_file", "TIME_NAMES", "PERIOD_TOLERANCE"]

TIME_NAMES = ("time", "t", "Time", "T")   # source names taken as the time vector when none is given
PERIOD_TOLERANCE = 1e-6                    # relative deviation of period/Ts from an integer that is accepted
_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


@dataclass
class LabSource:
    """The numeric vectors of a lab file: source name -> 1-D float array, and the file's own units if it
    declares any (a recording written by this project)."""

    path: Path
    kind: str                                   # "mat", "mat-v7.3", "hdf5" or "text"
    vectors: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    lines: dict[str, int] = field(default_factory=dict)   # text files: 1-based line of the first data row

    def where(self, name: str) -> str:
        """'FILE, variable NAME' (or column for text files), for messages."""
        what = "column" if self.kind == "text" else ("dataset" if self.kind == "hdf5" else "variable")
        return f"{self.path}, {what} {name!r}"

    def get(self, name: str) -> np.ndarray:
        """The vector ``name``; a RecordingError listing the available names otherwise."""
        if name not in self.vectors:
            what = "columns" if self.kind == "text" else "numeric vectors"
            raise RecordingError(f"{self.path}: no {what[:-1]} {name!r}; {what} are {list(self.vectors)}")
        return self.vectors[name]


def _flatten(value: Any, name: str, out: dict[str, np.ndarray], matlab_order: bool) -> None:
    """Numeric vectors of a loaded value into ``out``: structs/groups by dotted path, a matrix's signals along its
    longer dimension, named by MATLAB's index: ``data(:,2)`` the 2nd column of a tall matrix, ``data(2,:)`` the 2nd
    row of a wide one (a 6 x N matrix of six axes)."""
    if isinstance(value, dict):
        for key, item in value.items():
            _flatten(item, f"{name}.{key}" if name else key, out, matlab_order)
        return
    array = np.asarray(value)
    if array.dtype == object or not np.issubdtype(array.dtype, np.number) or array.size < 2:
        return
    array = np.squeeze(array)
    if array.ndim == 1:
        out[name] = array.astype(float)
    elif array.ndim == 2:
        if matlab_order:           # HDF5 of MATLAB v7.3 stores the transpose
            array = array.T
        wide = array.shape[0] < array.shape[1]
        for j in range(array.shape[0] if wide else array.shape[1]):
            signal = array[j] if wide else array[:, j]
            out[f"{name}({j + 1},:)" if wide else f"{name}(:,{j + 1})"] = signal.astype(float)


def _read_hdf5(path: Path, matlab: bool) -> dict[str, np.ndarray]:
    try:
        import h5py
    except ImportError:
        raise RecordingError(f"{path}: reading HDF5 (and MATLAB v7.3) files needs h5py (pip install h5py)") from None
    out: dict[str, np.ndarray] = {}

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind in "iuf":
            key = name.replace("/", ".") if matlab else "/" + name
            _flatten(obj[()], key, out, matlab)
    try:
        with h5py.File(path, "r") as handle:
            handle.visititems(visit)
    except OSError as exc:   # h5py's errors name neither the file nor, often, the problem in plain words
        raise RecordingError(f"{path}: not a readable HDF5 file ({exc})") from None
    return out


def _read_text(path: Path) -> LabSource:
    lines = read_text(path, RecordingError, "recording").splitlines()
    check_rows(path, len(lines) - 1, RecordingError)
    first = 0
    while first < len(lines) and (not lines[first].strip() or lines[first].lstrip()[:1] in ("#", "%")):
        first += 1
    if first == len(lines):
        raise RecordingError(f"{path}: no header line")
    header_line = lines[first]
    delimiter = next((d for d in (",", ";", "\t") if d in header_line), None)
    split = (lambda s: next(csv.reader([s], delimiter=delimiter))) if delimiter else str.split
    header = [cell.strip().strip('"') for cell in split(header_line)]
    for j, name in enumerate(header):
        if not name:
            raise RecordingError(f"{path}, line {first + 1}, column {j + 1}: empty column name in the header")
        if name in header[:j]:
            raise RecordingError(f"{path}, line {first + 1}, column {name!r}: duplicate column name")
    rows: list[list[float]] = []
    for number, line in enumerate(lines[first + 1:], start=first + 2):
        if not line.strip():
            continue
        cells = split(line)
        if len(cells) != len(header):
            raise RecordingError(f"{path}, line {number}: {len(cells)} fields, the header has {len(header)}")
        row = []
        for name, cell in zip(header, cells):
            try:
                row.append(float(cell))
            except ValueError:
                raise RecordingError(f"{path}, line {number}, column {name!r}: {cell.strip()!r} is not a number") \
                    from None
        rows.append(row)
    if not rows:
        raise RecordingError(f"{path}, line {first + 2}: no data rows after the header")
    data = np.array(rows)
    return LabSource(path, "text", {name: data[:, j] for j, name in enumerate(header)},
                     lines={name: first + 2 for name in header})


def read_lab_file(path: str | Path) -> LabSource:
    """All numeric vectors of a .mat (any version), HDF5 or delimited text file.

    A .mat in the layout :func:`harness.recording.write_mat` writes is read with its names and units.
    """
    path = Path(path)
    check_size(path, "recording", RecordingError)
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5", ".hdf"):
        return LabSource(path, "hdf5", _read_hdf5(path, matlab=False))
    if suffix != ".mat":
        return _read_text(path)
    import scipy.io  # here: only .mat files need it, and it costs its import

    try:
        contents = scipy.io.loadmat(path, simplify_cells=True)
    except NotImplementedError:       # MATLAB v7.3 is HDF5
        return LabSource(path, "mat-v7.3", _read_hdf5(path, matlab=True))
    except (ValueError, TypeError, OSError) as exc:
        raise RecordingError(f"{path}: not a readable MATLAB file ({exc})") from None
    contents = {k: v for k, v in contents.items() if not k.startswith("__")}
    if {"time", "data", "names"} <= contents.keys():
        rec = recording.read_mat(path)
        return LabSource(path, "mat", {name: rec[name] for name in rec.names}, dict(rec.units))
    vectors: dict[str, np.ndarray] = {}
    _flatten(contents, "", vectors, matlab_order=False)
    return LabSource(path, "mat", vectors)


def parse_gain(text: str, where: str = "gain") -> tuple[float, str]:
    """``"40 N/V"`` or ``"40N/V"`` or ``"40"`` -> (40.0, "N/V" or ""); ValueError naming ``where`` otherwise."""
    match = _NUMBER.match(text)
    if not match:
        raise ValueError(f"{where}: {text!r} is not a number with an optional unit, e.g. '40 N/V'")
    value = float(match.group(1))
    if not np.isfinite(value) or value == 0:
        raise ValueError(f"{where}: the gain must be finite and non-zero, got {text!r}")
    return value, match.group(2)


@dataclass(frozen=True)
class JitterReport:
    """Time-stamp statistics: sample_time = median step [s]; max_deviation / rms_deviation: largest and RMS
    deviation of a step from it [s]; relative: max_deviation / sample_time; steps: number of steps."""

    sample_time: float
    max_deviation: float
    rms_deviation: float
    relative: float
    steps: int

    def text(self) -> str:
        return (f"sample time {self.sample_time:.9g} s (median of {self.steps} steps); jitter: largest step "
                f"deviation {self.max_deviation:.3g} s ({self.relative:.3g} of Ts), RMS {self.rms_deviation:.3g} s")

    def as_dict(self) -> dict[str, float]:
        return {"sample_time": self.sample_time, "max_deviation": self.max_deviation,
                "rms_deviation": self.rms_deviation, "relative": self.relative, "steps": self.steps}


#: relative rounding of a step stored in single precision (0.004 s -> 0.0039999999): a clock this close to
#: the median step is the same clock, even when the steps do not scatter at all
SINGLE_PRECISION = 2.0 ** -24


def _within(jitter: JitterReport, step: float) -> float:
    """How far a clock may be from the median step and still be its clock: the jitter or single-precision
    rounding of the step, whichever is larger."""
    return max(jitter.max_deviation, SINGLE_PRECISION * step)


def clock_step(jitter: JitterReport) -> float:
    """The clock period the median step stands for: the shortest decimal (1 to 6 significant digits) within the
    jitter (the largest step deviation) or the single-precision rounding of the median step, e.g. 0.000999984 ->
    0.001 when the steps scatter by more than 1.6e-8 s, 0.0039999999 -> 0.004 (a float32 time column); the median
    step itself when none is, or when the steps are not uniform (relative jitter beyond
    ``recording.SAMPLE_TIME_TOLERANCE``: no clock can be told from them)."""
    ts = jitter.sample_time
    if jitter.relative > recording.SAMPLE_TIME_TOLERANCE:
        return ts
    for digits in range(6):
        clock = float(f"{ts:.{digits}e}")
        if abs(clock - ts) <= _within(jitter, ts):
            return clock
    return ts


def _clock(jitter: JitterReport, sample_time: float | None, resample: bool, notes: list[str]) -> tuple[float, str]:
    """The sample time of the import and where it comes from: ``sample_time`` (checked against the median step
    unless resampling onto it), else the median step snapped to its clock (:func:`clock_step`)."""
    median = jitter.sample_time
    if sample_time is not None:
        if not sample_time > 0:
            raise ValueError(f"sample time must be > 0 s, got {sample_time}")
        off = abs(sample_time - median)
        if not resample and off > _within(jitter, sample_time):
            raise ValueError(f"sample time {sample_time:.9g} s differs from the median step {median:.9g} s by "
                             f"{off:.3g} s, more than the jitter ({jitter.max_deviation:.3g} s) and single-precision "
                             "rounding; add --resample to interpolate onto it")
        return sample_time, "given"
    clock = clock_step(jitter)
    if abs(clock - median) > 1e-9 * clock:
        notes.append(f"sample time snapped to the clock {clock:.9g} s: the median step {median:.9g} s is within the "
                     f"jitter ({jitter.max_deviation:.3g} s) or single-precision rounding of it")
        return clock, "median step snapped to the clock"
    return clock, "median step"


def jitter_report(time: np.ndarray) -> JitterReport:
    """Median step of ``time`` [s] and the deviations of the steps from it."""
    steps = np.diff(np.asarray(time, dtype=float))
    if steps.size == 0:
        raise ValueError("a time vector needs at least two samples for a sample time")
    ts = float(np.median(steps))
    deviation = steps - ts
    largest = float(np.max(np.abs(deviation)))
    return JitterReport(ts, largest, float(np.sqrt(np.mean(deviation ** 2))), largest / ts, int(steps.size))


@dataclass
class LabImport:
    """The imported recording and what was done to get it (one line each in ``notes``)."""

    recording: Recording
    jitter: JitterReport
    notes: list[str]


def _converted(source: LabSource, name: str, target: str, values: np.ndarray, raw_unit: str | None,
               gain: str | None, notes: list[str]) -> tuple[np.ndarray, str, dict[str, Any]]:
    """Apply the gain and the SI conversion of one column; returns values, unit and the sidecar record."""
    where = source.where(name)
    raw = raw_unit if raw_unit is not None else source.units.get(name)
    info: dict[str, Any] = {"source": name, "raw_unit": raw}
    unit = raw
    if gain is not None:
        value, gain_unit = parse_gain(gain, f"gain of {target!r}")
        numerator, slash, denominator = gain_unit.rpartition("/") if "/" in gain_unit else (gain_unit, "", "")
        if not gain_unit:
            numerator = DEFAULT_UNITS.get(target, "")
            if not numerator:
                raise ValueError(f"gain of {target!r}: give its unit, e.g. '{gain} N/V' (the unit the column gets)")
            notes.append(f"{where}: gain {value:g} has no unit; the result is taken in {numerator} "
                         f"(the default unit of {target!r})")
        elif not slash:
            raise ValueError(f"gain of {target!r}: unit {gain_unit!r} must be RESULT/RECORDED, e.g. N/V")
        elif raw is None:
            raw = denominator
            info["raw_unit"] = raw
            notes.append(f"{where}: recorded unit taken from the gain: {raw}")
        elif not units_compatible(raw, denominator):
            raise ValueError(f"gain of {target!r}: {gain!r} converts from {denominator}, but the column is "
                             f"recorded in {raw} (--unit {target}={raw})")
        values = values * value
        unit = numerator
        info["gain"] = value
        info["gain_unit"] = gain_unit or f"{numerator}/{raw or '1'}"
        notes.append(f"{where} -> {target}: x {value:g} {info['gain_unit']} ({raw or 'unitless'} -> {numerator})")
    if unit is None:
        unit = DEFAULT_UNITS.get(target, "")
        if unit:
            notes.append(f"{where} -> {target}: no unit given; assumed {unit}")
    scale = si_scale(unit) if unit else None
    if scale is not None and (scale[0] != unit or scale[1] != 1.0):
        values = values * scale[1]
        notes.append(f"{where} -> {target}: converted from {unit} to {scale[0]} (x {scale[1]:.10g})")
        unit = scale[0]
    elif unit and scale is None:
        notes.append(f"{where} -> {target}: unit {unit!r} kept (no SI conversion known; give a gain to convert it)")
    return values, unit, info


def _column_name(source_name: str) -> str:
    """A CSV-safe recording column name for a source path (``data(:,2)`` -> ``data_2``, ``/axis/pos`` -> ``axis_pos``)."""
    return re.sub(r"[^A-Za-z0-9_.]+", "_", source_name).strip("_") or "column"


def _check_finite(source: LabSource, name: str, values: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        at = f"line {source.lines[name] + i}" if name in source.lines else f"sample {i + 1}"
        raise RecordingError(f"{source.where(name)}, {at}: value {values[i]} is not finite")


def import_lab_file(path: str | Path, *, mapping: dict[str, str] | None = None, time: str | None = None,
                    units: dict[str, str] | None = None, gains: dict[str, str] | None = None,
                    window: tuple[float, float] | None = None, period: float | None = None,
                    resample: bool = False, sample_time: float | None = None, excited: Any = None) -> LabImport:
    """Read a lab file and return it as a validated recording with the notes of every step.

    Parameters
    ----------
    path : the .mat, .h5/.hdf5 or text file.
    mapping : recording column -> source vector name (default: every vector of the time's length, own names).
    time : source name of the time vector (default: the first of ``TIME_NAMES`` present, also as the last
        part of a struct field or HDF5 path such as ``run1.time``).
    units : recorded unit per recording column or ``"time"`` (e.g. ``{"u": "V", "q": "mm", "time": "ms"}``);
        default: the file's own units, else the project's default unit of that name.
    gains : per recording column, a factor with its unit (``{"u": "40 N/V"}``).
    window : (start, stop) [s, after conversion]: keep samples with start <= t <= stop.
    period : excitation period [s]: keep the largest whole number of periods from the window's start.
    resample : interpolate linearly onto a uniform grid: the ticks k Ts of a given ``sample_time`` (recordings of
        one experiment share them), else t0 + k Ts from the first sample.
    sample_time : Ts [s], e.g. the controller's period: the grid of ``resample``; without it, the median step
        must lie within the jitter of it. Default: the median step, snapped to its clock (:func:`clock_step`).
    excited : what was excited, stored in the sidecar.

    Returns
    -------
    LabImport with the recording (SI units, ``sample_time`` set when the steps are uniform within the format's
    tolerance or after resampling), the jitter statistics of the imported time stamps, and the notes.
    """
    source = read_lab_file(path)
    units, gains = dict(units or {}), dict(gains or {})
    leaf = {n: re.split(r"[./]", n)[-1] for n in source.vectors}
    time_name = time or next((n for n in TIME_NAMES if n in source.vectors), None) or next(
        (n for n, last in leaf.items() if last in TIME_NAMES), None)
    if time_name is None:
        raise RecordingError(f"{source.path}: no time vector {TIME_NAMES[0]!r} or {TIME_NAMES[1]!r}; name it "
                             f"(--time NAME); vectors are {list(source.vectors)}")
    t_raw = source.get(time_name)
    mapping = dict(mapping) if mapping else {_column_name(n): n for n, v in source.vectors.items()
                                             if n != time_name and v.size == t_raw.size}
    unknown = [k for k in [*units, *gains] if k not in mapping and k != "time"]
    if unknown:
        raise ValueError(f"unit or gain given for {unknown[0]!r}, which is not an imported column "
                         f"(columns: {list(mapping)})")
    if "time" in mapping:
        raise ValueError("'time' is the time vector: name its source with --time, not --column")
    notes: list[str] = []
    _check_finite(source, time_name, t_raw)
    t, time_unit, _ = _converted(source, time_name, "time", t_raw, units.get("time"), gains.get("time"), notes)
    if time_unit != "s":
        raise RecordingError(f"{source.where(time_name)}: time in {time_unit!r}; give its unit (--unit time=ms)")
    columns: dict[str, np.ndarray] = {}
    column_units: dict[str, str] = {"time": "s"}
    provenance: dict[str, Any] = {}
    for target, name in mapping.items():
        values = source.get(name)
        if values.size != t_raw.size:
            raise RecordingError(f"{source.where(name)}: {values.size} samples, time {time_name!r} has {t_raw.size}")
        _check_finite(source, name, values)
        columns[target], column_units[target], provenance[target] = _converted(
            source, name, target, values, units.get(target), gains.get(target), notes)
    steps = np.diff(t)
    back = np.flatnonzero(~(steps > 0))
    if back.size:
        i = int(back[0]) + 1
        at = f"line {source.lines[time_name] + i}" if time_name in source.lines else f"sample {i + 1}"
        raise RecordingError(f"{source.where(time_name)}, {at}: time {float(t_raw[i])!r} is not greater than the "
                             f"previous {float(t_raw[i - 1])!r} (time must be strictly increasing)")
    keep = np.ones(t.size, dtype=bool)
    trimmed: dict[str, Any] = {}
    if window is not None:
        start, stop = window
        if not start < stop:
            raise ValueError(f"window: start {start} s must be before stop {stop} s")
        keep = (t >= start) & (t <= stop)
        if keep.sum() < 2:
            raise ValueError(f"window {start}..{stop} s holds {int(keep.sum())} samples; the record spans "
                             f"{t[0]:.6g}..{t[-1]:.6g} s")
        trimmed["window"] = [start, stop]
        notes.append(f"window {start:g}..{stop:g} s: kept {int(keep.sum())} of {t.size} samples")
    t = t[keep]
    columns = {k: v[keep] for k, v in columns.items()}
    jitter = jitter_report(t)
    notes.append(jitter.text())
    ts, origin = _clock(jitter, sample_time, resample, notes)
    if resample:
        if sample_time is None:   # the recording's own clock, from its first sample
            grid, where = t[0] + ts * np.arange(int(np.floor((t[-1] - t[0]) / ts * (1 + 1e-12))) + 1), "t0 + k*"
        else:                     # the given clock's ticks k*Ts: recordings of one experiment share them
            first, last = np.ceil(t[0] / ts - 1e-9), np.floor(t[-1] / ts + 1e-9)
            grid, where = np.arange(first, last + 1) * ts, "k*"
        if grid.size < 2:
            raise ValueError(f"sample time {ts:.9g} s: the record ({t[-1] - t[0]:.6g} s) holds less than one step")
        columns = {k: np.interp(grid, t, v) for k, v in columns.items()}
        t = grid
        notes.append(f"resampled onto the uniform grid {where}{ts:.9g} s ({origin}) by linear interpolation "
                     f"({t.size} samples from {t[0]:.9g} s)")
    if period is not None:
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        ratio = period / ts
        per = int(round(ratio))
        if per < 2 or abs(ratio - per) > PERIOD_TOLERANCE * ratio:
            raise ValueError(f"period {period!r} s is {ratio:.9g} sample times of {ts:.9g} s, not a whole number "
                             f"(within {PERIOD_TOLERANCE:g}); check --period/--f0 against the sample time")
        periods = t.size // per
        if periods < 1:
            raise ValueError(f"the record ({t.size} samples) is shorter than one period ({per} samples)")
        dropped = t.size - periods * per
        notes.append(f"trimmed to {periods} whole periods of {per} samples ({period:g} s): dropped the last "
                     f"{dropped} samples ({dropped * ts:.6g} s)")
        trimmed.update({"period": period, "samples_per_period": per, "periods": periods,
                        "dropped_samples_at_end": dropped})
        t = t[:periods * per]
        columns = {k: v[:periods * per] for k, v in columns.items()}
    largest = float(np.max(np.abs(np.diff(t) - ts))) / ts
    uniform = largest <= recording.SAMPLE_TIME_TOLERANCE
    if not uniform:
        notes.append(f"steps deviate by up to {largest:.3g} of Ts (more than "
                     f"{recording.SAMPLE_TIME_TOLERANCE:g}): sample_time left null; import with --resample for a "
                     "uniform grid")
    metadata = {"import": {"source": str(source.path), "format": source.kind, "time": time_name,
                           "columns": provenance, "jitter": jitter.as_dict(), "resampled": bool(resample),
                           "clock": {"sample_time": ts, "origin": origin},
                           "trimmed": trimmed}}
    rec = recording.make_recording(t, columns, column_units, sample_time=ts if uniform else None,
                                   excited=excited, metadata=metadata)
    return LabImport(rec, jitter, notes)
