"""Input size and memory limits in one place, and the checked readers of text inputs that apply them.

A hostile or mistaken input must be refused before it is parsed, not after minutes and gigabytes: every file
is measured before it is read, a recording's rows are counted before they are parsed, and a generator
estimates its bytes before it allocates. Each limit is overridable with its environment variable (the
``motiontwin --help`` text lists them, :func:`limits_help`). The module lives in ``fmus``, the lowest layer,
so that every reader (Modelica, TOML, JSON, recordings) can use it.
"""
from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["LIMITS", "check_memory", "check_rows", "check_size", "limit", "limits_help", "load_json",
           "load_toml", "read_text"]


@dataclass(frozen=True)
class Limit:
    """One limit: its environment variable, default value, unit and what it bounds."""
    variable: str
    default: float
    unit: str
    bounds: str


LIMITS = {
    "text": Limit("MOTIONTWIN_MAX_TEXT_MB", 16, "MB", "a JSON, TOML or Modelica input file"),
    "recording": Limit("MOTIONTWIN_MAX_RECORDING_MB", 256, "MB", "a recording or lab data file (CSV, MAT, HDF5)"),
    "rows": Limit("MOTIONTWIN_MAX_ROWS", 500_000, "rows", "the samples of one recording read"),
    "steps": Limit("MOTIONTWIN_MAX_STEPS", 1e8, "steps", "the base steps (or samples) of one run or "
                                                          "experiment (800 MB per logged signal)"),
    "memory": Limit("MOTIONTWIN_MAX_MEMORY_MB", 0, "MB", "a generated signal table (0: half the memory "
                                                         "available)"),
}


def limit(name: str) -> float:
    """The value of limit ``name`` (its environment variable, else the default); ValueError if malformed."""
    spec = LIMITS[name]
    text = os.environ.get(spec.variable)
    if text is None:
        return spec.default
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 0 or value == float("inf"):
        raise ValueError(f"environment variable {spec.variable}={text!r}: expected a number >= 0 ({spec.unit})")
    return value


def _how_to_raise(name: str, needed: float | None = None) -> str:
    spec = LIMITS[name]
    example = f"{spec.variable}={needed:.0f}" if needed is not None else f"{spec.variable}=<{spec.unit}>"
    return f"the limit for {spec.bounds} is {limit(name):g} {spec.unit}; raise it with {example} if intended"


def limits_help() -> str:
    """The limits and their environment variables, for ``--help``."""
    return "limits (environment variables): " + "; ".join(
        f"{s.variable} ({s.bounds}, default {s.default:g} {s.unit})"
        for s in LIMITS.values())


def check_size(path: str | os.PathLike, kind: str, error: type[Exception] = ValueError) -> int:
    """The size of the file ``path`` in bytes; ``error`` naming it when it is missing, a folder or larger than
    the ``kind`` limit (``"text"`` or ``"recording"``)."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise error(f"{path}: not found; check the path") from None
    if path.is_dir():
        raise error(f"{path}: is a folder, expected a file")
    if size > limit(kind) * 1e6:
        raise error(f"{path}: {size / 1e6:.1f} MB, too large ({_how_to_raise(kind, size / 1e6 + 1)})")
    return size


def read_text(path: str | os.PathLike, error: type[Exception] = ValueError, kind: str = "text") -> str:
    """The UTF-8 text of ``path`` after :func:`check_size`; ``error`` naming the file if it is not text."""
    check_size(path, kind, error)
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None


def load_json(path: str | os.PathLike, error: type[Exception] = ValueError) -> Any:
    """The JSON document in ``path``; ``error`` naming the file and line for anything that is not one."""
    text = read_text(path, error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}, line {exc.lineno}, column {exc.colno}: invalid JSON ({exc.msg})") from None
    except RecursionError:
        raise error(f"{path}: invalid JSON (nested too deeply to read)") from None


def load_toml(path: str | os.PathLike, error: type[Exception] = ValueError) -> tuple[dict[str, Any], str]:
    """The TOML document in ``path`` and its text; ``error`` naming the file for anything that is not one."""
    text = read_text(path, error)
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: invalid TOML ({exc})") from None
    except RecursionError:
        raise error(f"{path}: invalid TOML (nested too deeply to read)") from None


def check_rows(path: str | os.PathLike, rows: int, error: type[Exception] = ValueError) -> None:
    """``error`` naming ``path`` when a recording has more rows than the ``rows`` limit."""
    if rows > limit("rows"):
        raise error(f"{path}: {rows} rows, too many ({_how_to_raise('rows', rows)})")


def _available_bytes() -> float:
    """Memory available to new allocations (MemAvailable of /proc/meminfo, else the free physical pages)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def check_memory(what: str, n_bytes: float, error: type[Exception] = ValueError) -> None:
    """``error`` when ``what`` would take ``n_bytes``, more than the ``memory`` limit (default: half the memory
    available now), so a table that cannot fit is refused before it is allocated."""
    configured = limit("memory")
    allowed = configured * 1e6 if configured > 0 else _available_bytes() / 2
    if n_bytes > allowed:
        source = "" if configured > 0 else ", half the memory available now"
        raise error(f"{what} needs about {n_bytes / 1e9:.3g} GB of memory, more than the limit of "
                    f"{allowed / 1e9:.3g} GB{source}; raise it with {LIMITS['memory'].variable}="
                    f"{n_bytes / 1e6 + 1:.0f} if intended")
