"""motiontwin: Modelica models of precision motion systems as FMUs, co-simulation, identification, tuning
and mismatch diagnosis.

The library layers point down only: ``motiontwin.fmus`` (Modelica -> FMU) <- ``motiontwin.harness``
(co-simulation, recordings) <- ``motiontwin.ident`` (identification, tuning, diagnosis) <- the application
in this package (the ``motiontwin`` command, the demo, the paper comparison, the Python API).

Python API (loaded on first use, so ``import motiontwin`` stays fast): :func:`build_fmu`, :func:`simulate`,
:class:`Recording` / :func:`read_recording`, :func:`identify_joint`, :func:`identify_oe`, :func:`identify_frf`
and :class:`IdentificationResult`; ``diagnose`` is reserved for the in-memory mismatch diagnosis.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it
_API = {
    "build_fmu": "motiontwin.api",
    "simulate": "motiontwin.api",
    "identify_joint": "motiontwin.api",
    "identify_oe": "motiontwin.api",
    "identify_frf": "motiontwin.api",
    "IdentificationResult": "motiontwin.api",
    "Recording": "motiontwin.harness.recording",
    "read_recording": "motiontwin.harness.recording",
    "make_recording": "motiontwin.harness.recording",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> object:
    """Import the module behind a public name on first use (PEP 562)."""
    if name not in _API:
        raise AttributeError(f"module 'motiontwin' has no attribute {name!r}")
    value = getattr(importlib.import_module(_API[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
