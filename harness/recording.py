"""The one recording format of motiontwin: a CSV file plus a JSON sidecar, and MATLAB .mat export/import.

Units: SI throughout (time in s, positions in m, forces in N); the unit of every column is stated in the sidecar.

CSV file ``NAME.csv``
    A header line with the column names, then one line per sample, comma separated, numbers only
    (written with 17 significant digits so that a round trip is exact). The column ``time`` is required,
    strictly increasing, and written first. No NaN or infinite values.

JSON sidecar ``NAME.json`` (optional when reading a CSV from elsewhere; always written)::

    {
      "format": "motiontwin-recording", "version": 1,
      "columns": ["time", "r", "u", "q"],          # must equal the CSV header
      "units": {"time": "s", "r": "m", "u": "N", "q": "m"},
      "sample_time": 0.0005,                        # [s] or null for non-uniform sampling
      "excited": "swept sine 80-500 Hz on u_ext",   # what was excited (free text or an object)
      "fmus": ["plant", "controller"],              # FMU names, or {name: {"path": ..., ...}}
      "parameters": {"plant": {"m": 1.2}},          # parameter values per FMU
      "seed": 42,                                   # random seed or null
      "metadata": {}                                # free-form
    }

MATLAB file ``NAME.mat`` (written by :func:`write_mat`, read by :func:`read_mat`), top-level variables:
    ``time`` (N x 1 double), ``data`` (N x M double, one column per signal, in ``names`` order),
    ``names`` (1 x M cell of char), ``units`` (1 x M cell of char) and ``meta_json`` (char: the sidecar
    fields ``sample_time``, ``excited``, ``fmus``, ``parameters``, ``seed``, ``metadata`` as JSON).
    In MATLAB: ``s = load('NAME.mat'); q = s.data(:, strcmp(s.names, 'q'));``.
    :func:`read_mat` also imports lab files in other layouts: flat variables or one struct of equal-length
    vectors, one of which is the time (``time`` or ``t`` unless named).
"""

from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from motiontwin.fmus import limits
from motiontwin.fmus.files import atomic_path, atomic_write_texts

FORMAT_NAME = "motiontwin-recording"
FORMAT_VERSION = 1
META_KEYS = ("sample_time", "excited", "fmus", "parameters", "seed", "metadata")
DEFAULT_UNITS = {"time": "s", "r": "m", "q": "m", "u": "N", "u_ext": "N", "v": "m/s", "a": "m/s2"}
SAMPLE_TIME_TOLERANCE = 1e-3  # relative deviation of a time step from sample_time that is accepted


class RecordingError(ValueError):
    """A recording file or object is invalid; the message names file, line and column of the first problem."""


@dataclass
class Recording:
    """A recorded (or simulated) experiment.

    time: sample instants [s], strictly increasing, shape (N,).
    columns: signal name -> values, each shape (N,); ``time`` is not among them.
    units: column name (including ``time``) -> unit string, e.g. ``{"time": "s", "q": "m"}``.
    meta: the sidecar fields ``sample_time`` [s] or None, ``excited``, ``fmus`` (names, or name -> details),
    ``parameters`` ({fmu: {name: value}}), ``seed`` (int or None) and ``metadata`` (free-form dict).
    """

    time: np.ndarray
    columns: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        """Return a column by name; ``"time"`` gives the time vector."""
        if name == "time":
            return self.time
        if name not in self.columns:
            raise KeyError(f"recording has no column {name!r}; columns are {['time', *self.columns]}")
        return self.columns[name]

    @property
    def names(self) -> list[str]:
        """All column names in file order, ``time`` first."""
        return ["time", *self.columns]

    @property
    def sample_time(self) -> float | None:
        """Sample time [s] from the metadata, or None for non-uniform sampling."""
        return self.meta.get("sample_time")

    def renamed(self, names: dict[str, str]) -> "Recording":
        """A copy with columns renamed (old -> new, units follow), e.g. ``{"plant.q": "q"}`` so that a logged
        FMU port matches the model variable an identification fits."""
        unknown = sorted(set(names) - set(self.columns))
        if unknown:
            raise KeyError(f"recording has no column {unknown[0]!r}; columns are {['time', *self.columns]}")
        columns = {names.get(name, name): values.copy() for name, values in self.columns.items()}
        units = {names.get(name, name): unit for name, unit in self.units.items()}
        renamed = Recording(self.time.copy(), columns, units, json.loads(json.dumps(self.meta)))
        validate_recording(renamed)
        return renamed

    def to_csv(self, path: str | os.PathLike) -> tuple[Path, Path]:
        """Write ``NAME.csv`` and its ``NAME.json`` sidecar atomically (:func:`write_recording`)."""
        return write_recording(path, self)

    @classmethod
    def from_csv(cls, path: str | os.PathLike, required: Iterable[str] = ("time",)) -> "Recording":
        """Read a CSV recording and its sidecar (:func:`read_recording`)."""
        return read_recording(path, required)

    def to_mat(self, path: str | os.PathLike) -> Path:
        """Write a MATLAB .mat file atomically (:func:`write_mat`)."""
        return write_mat(path, self)

    @classmethod
    def from_mat(cls, path: str | os.PathLike, required: Iterable[str] = ("time",)) -> "Recording":
        """Read a .mat recording (:func:`read_mat`)."""
        return read_mat(path, required)

    def to_pandas(self) -> Any:
        """A ``pandas.DataFrame`` indexed by time [s], one column per signal; units in ``frame.attrs["units"]``.

        Raises ImportError when pandas is not installed (it is not a dependency of motiontwin).
        """
        try:
            import pandas
        except ImportError:
            raise ImportError("Recording.to_pandas needs pandas: pip install pandas") from None
        frame = pandas.DataFrame(self.columns, index=pandas.Index(self.time, name="time"))
        frame.attrs["units"] = dict(self.units)
        return frame


def make_recording(
    time: Sequence[float] | np.ndarray,
    columns: dict[str, Sequence[float] | np.ndarray],
    units: dict[str, str] | None = None,
    *,
    sample_time: float | None = None,
    excited: Any = None,
    fmus: Iterable[str] | dict[str, Any] = (),
    parameters: dict[str, dict[str, Any]] | None = None,
    seed: int | None = None,
    metadata: dict[str, Any] | None = None,
) -> Recording:
    """Build and validate a :class:`Recording`; units default to the project's names (q, r in m; u in N)."""
    unit_map = {name: DEFAULT_UNITS.get(name, "") for name in ["time", *columns]}
    unit_map.update(units or {})
    meta = _normalised_meta(
        {
            "sample_time": None if sample_time is None else float(sample_time),
            "excited": excited,
            "fmus": fmus,
            "parameters": parameters,
            "seed": seed,
            "metadata": metadata,
        }
    )
    rec = Recording(
        time=np.asarray(time, dtype=float).copy(),
        columns={name: np.asarray(values, dtype=float).copy() for name, values in columns.items()},
        units=unit_map,
        meta=meta,
    )
    validate_recording(rec)
    return rec


def validate_recording(rec: Recording, required: Iterable[str] = ("time",), source: str = "recording") -> None:
    """Check shapes, required columns, finite values and strictly increasing time.

    Rows in messages are 1-based line numbers of the CSV file (the header is line 1, sample i is line i + 2).
    """
    missing = [name for name in required if name != "time" and name not in rec.columns]
    if missing:
        raise RecordingError(f"{source}: required column {missing[0]!r} missing; columns are {rec.names}")
    if "time" in rec.columns:
        raise RecordingError(f"{source}: 'time' must be the time vector, not an entry of columns")
    time = np.asarray(rec.time)
    if time.ndim != 1 or time.size == 0:
        raise RecordingError(f"{source}: time must be a non-empty 1-D array, got shape {time.shape}")
    problems: list[tuple[int, int, str]] = []  # (sample index, column index, message) of each first problem
    for j, name in enumerate(rec.names):
        values = np.asarray(rec[name])
        if values.shape != time.shape:
            raise RecordingError(f"{source}: column {name!r} has shape {values.shape}, time has {time.shape}")
        if not np.issubdtype(values.dtype, np.number):
            raise RecordingError(f"{source}: column {name!r} is not numeric (dtype {values.dtype})")
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            i = int(bad[0])
            what = "NaN value" if np.isnan(values[i]) else f"value {float(values[i])} is not finite"
            problems.append((i, j, f"column {name!r}: {what}"))
    steps = np.diff(time)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        i = int(bad[0]) + 1
        problems.append((i, 0, (
            f"column 'time': time {float(time[i])!r} is not greater than the previous {float(time[i - 1])!r} "
            "(time must be strictly increasing)"
        )))
    sample_time = rec.meta.get("sample_time")
    if sample_time is not None:
        if isinstance(sample_time, bool) or not (isinstance(sample_time, (int, float)) and sample_time > 0):
            raise RecordingError(f"{source}: field 'sample_time' must be a positive number, got {sample_time!r}")
        off = np.flatnonzero(np.abs(steps - sample_time) > SAMPLE_TIME_TOLERANCE * sample_time)
        if off.size:
            i = int(off[0]) + 1
            problems.append((i, 0, (
                f"column 'time': step {steps[i - 1]:.9g} s differs from sample_time {sample_time:.9g} s"
            )))
    if problems:
        i, _, message = min(problems)
        raise RecordingError(f"{source}, row {i + 2}, {message}")


def _normalised_meta(source: dict[str, Any]) -> dict[str, Any]:
    """The META_KEYS of ``source`` with empty containers for absent ``fmus``, ``parameters``, ``metadata``."""
    meta = {key: source.get(key) for key in META_KEYS}
    fmus = meta["fmus"] or []
    meta["fmus"] = dict(fmus) if isinstance(fmus, dict) else list(fmus)
    meta["parameters"] = dict(meta["parameters"] or {})
    meta["metadata"] = dict(meta["metadata"] or {})
    return meta


def sidecar_path(csv_path: str | os.PathLike) -> Path:
    """The JSON sidecar belonging to a recording CSV: same name, suffix ``.json``."""
    return Path(csv_path).with_suffix(".json")


def _csv_rows(path: Path, raw: bytes) -> Iterator[list[str]]:
    """The rows of the CSV text ``raw`` one at a time (universal newlines: a lone CR ends a line too)."""
    try:
        yield from csv.reader(io.TextIOWrapper(io.BytesIO(raw), encoding="utf-8", newline=None))
    except csv.Error as exc:
        raise RecordingError(f"{path}: not a CSV file ({exc})") from None


def _blank(row: list[str]) -> bool:
    return not any(cell.strip() for cell in row)


def _parse_csv(path: Path) -> tuple[list[str], np.ndarray, RecordingError | None]:
    """Read header and numbers up to the first malformed line or field.

    Returns the header, the rows before the first malformed one, and the error for that row (or None), so the
    caller can still report an earlier problem in the well-formed rows (e.g. time going backwards) first.
    Size and rows are checked first; the rows are parsed one at a time into the array (never a list of rows
    of text), so the peak memory is about the file's size plus 8 bytes per value.
    """
    limits.check_size(path, "recording", RecordingError)
    raw = path.read_bytes()
    limits.check_rows(path, max(raw.count(b"\n"), raw.count(b"\r")) - 1, RecordingError)
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    rows = _csv_rows(path, raw)
    first = next(rows, None)
    if first is None or (_blank(first) and all(_blank(row) for row in rows)):
        raise RecordingError(f"{path}, row 1: empty file, expected a header line")
    header = [cell.strip() for cell in first]
    if "time" not in header:   # not a recording: nothing of its content is echoed (it may be any file)
        raise RecordingError(f"{path}, row 1: required column 'time' missing; not a recording (a recording "
                             f"starts with a header line of column names, 'time' among them)")
    for j, name in enumerate(header):
        if not name:
            raise RecordingError(f"{path}, row 1, column {j + 1}: empty column name in the header")
        if name in header[:j]:
            raise RecordingError(f"{path}, row 1, column {name!r}: duplicate column name")
    data = np.empty((raw.count(b"\n") + raw.count(b"\r") + 1, len(header)))   # an upper bound, not touched
    i = 0
    pending: list[list[str]] = []   # blank rows are an error only when a data row follows them
    for row in rows:
        if _blank(row):
            pending.append(row)
            continue
        for cells in [*pending, row]:
            line = i + 2
            if len(cells) != len(header):
                error = RecordingError(f"{path}, row {line}: {len(cells)} fields, the header has {len(header)}")
                return header, data[:i], error
            for j, cell in enumerate(cells):
                try:
                    data[i, j] = float(cell)
                except ValueError:
                    error = RecordingError(f"{path}, row {line}, column {header[j]!r}: {cell.strip()!r} is not a "
                                           f"number")
                    return header, data[:i], error
            i += 1
        pending = []
    if i == 0:
        raise RecordingError(f"{path}, row 2: no data rows after the header")
    return header, data[:i], None


_SIDECAR_TYPES = {"version": (int, "an integer"), "columns": (list, "a list of column names"),
                  "fmus": ((list, dict, type(None)), "a list or an object"),
                  "parameters": ((dict, type(None)), "an object"), "metadata": ((dict, type(None)), "an object")}


def _read_sidecar(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    doc = limits.load_json(path, RecordingError)
    if not isinstance(doc, dict):
        raise RecordingError(f"{path}: the sidecar must be a JSON object")
    if doc.get("format", FORMAT_NAME) != FORMAT_NAME:
        raise RecordingError(f"{path}: field 'format' is {doc['format']!r}, expected {FORMAT_NAME!r}")
    for key, (kinds, wanted) in _SIDECAR_TYPES.items():
        if key in doc and (isinstance(doc[key], bool) or not isinstance(doc[key], kinds)):
            raise RecordingError(f"{path}: field {key!r} must be {wanted}, got {json.dumps(doc[key])[:40]}")
    if doc.get("version", FORMAT_VERSION) > FORMAT_VERSION:
        raise RecordingError(f"{path}: field 'version' {doc['version']} is newer than supported {FORMAT_VERSION}")
    units = doc.get("units", {})
    if not isinstance(units, dict) or not all(isinstance(v, str) for v in units.values()):
        raise RecordingError(f"{path}: field 'units' must map column names to unit strings")
    return doc


def read_recording(path: str | os.PathLike, required: Iterable[str] = ("time",)) -> Recording:
    """Read and validate ``NAME.csv`` and, when present, its sidecar ``NAME.json``.

    required: column names that must be present (e.g. ``("time", "r", "u", "q")`` for a diagnosis bundle).
    Raises RecordingError naming the file, row (1-based line number) and column of the first problem.
    """
    path = Path(path)
    header, data, parse_error = _parse_csv(path)
    required = list(required)
    if "time" not in required:
        required.insert(0, "time")
    for name in required:
        if name not in header:
            raise RecordingError(f"{path}, row 1: required column {name!r} missing; header is {header}")
    side_path = sidecar_path(path)
    doc = _read_sidecar(side_path) or {}
    if "columns" in doc and list(doc["columns"]) != header:
        raise RecordingError(
            f"{side_path}: field 'columns' {doc['columns']} does not match the CSV header {header} of {path}"
        )
    units = {name: doc.get("units", {}).get(name, DEFAULT_UNITS.get(name, "")) for name in header}
    meta = _normalised_meta(doc)
    order = ["time", *[name for name in header if name != "time"]]
    rec = Recording(
        time=data[:, header.index("time")].copy(),
        columns={name: data[:, header.index(name)].copy() for name in order[1:]},
        units={name: units[name] for name in order},
        meta=meta,
    )
    if parse_error is not None:
        if data.shape[0]:
            validate_recording(rec, required, source=str(path))
        raise parse_error
    validate_recording(rec, required, source=str(path))
    return rec


def _sidecar_document(rec: Recording) -> dict[str, Any]:
    doc: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "columns": rec.names}
    doc["units"] = {name: rec.units.get(name, DEFAULT_UNITS.get(name, "")) for name in rec.names}
    doc.update(_normalised_meta(rec.meta))
    return doc


def _csv_text(rec: Recording) -> str:
    table = np.column_stack([rec[name] for name in rec.names])
    buffer = io.StringIO()
    buffer.write(",".join(rec.names) + "\n")
    np.savetxt(buffer, table, delimiter=",", fmt="%.17g")
    return buffer.getvalue()


def write_figure(path: str | os.PathLike, fig: Any, dpi: int = 110) -> Path:
    """Save a matplotlib figure as a PNG at ``path`` atomically (all or nothing, ordinary file mode)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_texts({path: buffer.getvalue()})
    return path


def recording_texts(path: str | os.PathLike, rec: Recording) -> dict[Path, str]:
    """Validate ``rec`` and return the texts of ``NAME.csv`` and ``NAME.json`` (for atomic_write_texts,
    so that several recordings can be written all or none)."""
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise RecordingError(f"{path}: a recording file name must end in .csv")
    validate_recording(rec, source=str(path))
    side_text = json.dumps(_sidecar_document(rec), indent=2, allow_nan=False) + "\n"
    return {path: _csv_text(rec), sidecar_path(path): side_text}


def write_recording(path: str | os.PathLike, rec: Recording) -> tuple[Path, Path]:
    """Validate ``rec`` and write ``NAME.csv`` and ``NAME.json`` atomically; returns both paths."""
    atomic_write_texts(recording_texts(path, rec))
    return Path(path), sidecar_path(Path(path))


def write_mat(path: str | os.PathLike, rec: Recording) -> Path:
    """Write ``rec`` as a MATLAB .mat file (layout in the module docstring), atomically."""
    path = Path(path)
    validate_recording(rec, source=str(path))
    names = list(rec.columns)
    contents = {
        "time": np.asarray(rec.time, dtype=float).reshape(-1, 1),
        "data": np.column_stack([rec.columns[n] for n in names]) if names else np.zeros((rec.time.size, 0)),
        "names": np.array(names, dtype=object).reshape(1, -1),
        "units": np.array([rec.units.get(n, "") for n in names], dtype=object).reshape(1, -1),
        "time_unit": rec.units.get("time", "s"),
        "meta_json": json.dumps({key: rec.meta.get(key) for key in META_KEYS}, allow_nan=False),
    }
    import scipy.io  # here: scipy.io costs its import (0.7 s), and only .mat files need it

    with atomic_path(path) as tmp:
        scipy.io.savemat(tmp, contents, do_compression=False, oned_as="column")
    return path


def _as_vector(value: Any) -> np.ndarray | None:
    """A numeric vector from a loadmat value, or None if it is not one."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return None
    array = np.asarray(value)
    if not np.issubdtype(array.dtype, np.number) or array.ndim == 0:
        return None
    squeezed = np.squeeze(array)
    return squeezed.astype(float) if squeezed.ndim == 1 else None


def _char(value: Any) -> str:
    """A MATLAB char array as loaded by scipy.io.loadmat (possibly empty) as a Python string."""
    if value is None:
        return ""
    array = np.asarray(value)
    return "".join(str(v) for v in array.ravel()) if array.size else ""


def _cell_strings(value: Any) -> list[str]:
    """A MATLAB cell array of char (as loaded by scipy.io.loadmat) as a list of strings."""
    return [_char(item) for item in np.asarray(value, dtype=object).ravel()]


def read_mat(
    path: str | os.PathLike,
    required: Iterable[str] = ("time",),
    time_name: str | None = None,
    rename: dict[str, str] | None = None,
) -> Recording:
    """Read a .mat recording: the layout :func:`write_mat` writes, or lab files of equal-length vectors.

    time_name: variable holding time in a foreign layout (default: ``time`` or ``t``).
    rename: foreign variable name -> recording column name (e.g. ``{"pos": "q", "force": "u"}``).
    """
    import scipy.io

    path = Path(path)
    limits.check_size(path, "recording", RecordingError)
    try:
        raw = scipy.io.loadmat(path)
    except NotImplementedError:
        raise RecordingError(f"{path}: MATLAB v7.3 (HDF5) file; save it with save(..., '-v7') to import") from None
    except (ValueError, TypeError, OSError) as exc:
        raise RecordingError(f"{path}: not a readable MATLAB file ({exc})") from None
    if {"time", "data", "names"} <= raw.keys():
        names = _cell_strings(raw["names"])
        units = _cell_strings(raw["units"]) if "units" in raw else [""] * len(names)
        time = np.asarray(raw["time"], dtype=float).ravel()
        data = np.asarray(raw["data"], dtype=float).reshape(time.size, len(names))
        meta = json.loads(_char(raw.get("meta_json")) or "{}")
        rec = Recording(
            time=time,
            columns={name: data[:, j].copy() for j, name in enumerate(names)},
            units={"time": _char(raw.get("time_unit")) or "s", **dict(zip(names, units))},
            meta={key: meta.get(key) for key in META_KEYS},
        )
    else:
        contents = scipy.io.loadmat(path, simplify_cells=True)
        contents = {k: v for k, v in contents.items() if not k.startswith("__")}
        if len(contents) == 1 and isinstance(next(iter(contents.values())), dict):
            contents = next(iter(contents.values()))
        vectors = {name: vec for name, value in contents.items() if (vec := _as_vector(value)) is not None}
        rename = rename or {}
        vectors = {rename.get(name, name): vec for name, vec in vectors.items()}
        candidates = [time_name] if time_name else ["time", "t"]
        time_key = next((c for c in candidates if c in vectors), None)
        if time_key is None:
            raise RecordingError(f"{path}: no time variable {candidates[0]!r}; numeric vectors are {list(vectors)}")
        time = vectors.pop(time_key)
        for name, vec in vectors.items():
            if vec.size != time.size:
                raise RecordingError(f"{path}: variable {name!r} has {vec.size} samples, time has {time.size}")
        rec = Recording(
            time=time,
            columns=vectors,
            units={name: DEFAULT_UNITS.get(name, "") for name in ["time", *vectors]},
            meta={key: None for key in META_KEYS},
        )
    rec.meta = _normalised_meta(rec.meta)
    validate_recording(rec, required, source=str(path))
    return rec
