"""One co-simulation run of a system -> a :class:`~motiontwin.harness.recording.Recording`.

Why a module of its own: the master (``harness.master``) returns its log groups as structured arrays; turning
one group into a recording with units, FMUs and provenance is what ``motiontwin run``, ``motiontwin sweep`` and
the Python API (``motiontwin.simulate``) share. Units: SI; the unit of every column comes from the system file's
inputs and the FMUs' model descriptions.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from motiontwin.harness.master import Master
from motiontwin.harness.recording import Recording, make_recording
from motiontwin.harness.system import System, system_from_dict

__all__ = ["recording_from_log", "simulate"]


def recording_from_log(logs: Mapping[str, np.ndarray], group: str | None, run_info: Mapping[str, Any],
                       **provenance: Any) -> Recording:
    """The recording of one log group of a master run.

    Parameters
    ----------
    logs : mapping of str to structured array
        What :meth:`Master.run` returns (group name -> array with a ``time`` field).
    group : str or None
        The log group to record; None: the first one.
    run_info : mapping
        :meth:`Master.metadata` (units per signal, FMUs).
    **provenance
        Sidecar fields of :func:`~motiontwin.harness.recording.make_recording` (``excited``, ``metadata``, ...).

    Returns
    -------
    Recording
        The group's signals with their units; ``sample_time`` is the log step.
    """
    group = group or next(iter(logs))
    if group not in logs:
        raise ValueError(f"log group {group!r}: the system logs {sorted(logs)}")
    log = logs[group]
    columns = {name: log[name] for name in log.dtype.names if name != "time"}
    units = {name: run_info["units"].get(name) or "" for name in columns}
    return make_recording(log["time"], columns, units, sample_time=float(log["time"][1] - log["time"][0]),
                          fmus=run_info["fmus"], **provenance)


def simulate(system: System | dict[str, Any] | str | Path, stop_time: float | None = None,
             inputs: Mapping[str, Any] | None = None, parameters: Mapping[str, float] | None = None,
             log: str | None = None) -> Recording:
    """Co-simulate a system and return one log group as a recording.

    Parameters
    ----------
    system : System, dict, str or Path
        A system file (TOML, format in ``harness.system``), the same description as a dict (relative FMU paths
        from the working directory), or a validated :class:`~motiontwin.harness.system.System`.
    stop_time : float, optional
        End of the run [s]; default: the system's ``stop_time``.
    inputs : mapping, optional
        External input name -> a scalar, an array on the base grid (N + 1 samples) or a ``(time, values)``
        pair (held between samples), as :meth:`Master.run` takes them.
    parameters : mapping of str to float, optional
        ``"instance.variable"`` -> value, applied on top of the system's parameter overrides for this run.
    log : str, optional
        Log group to return (default: the first).

    Returns
    -------
    Recording
        Time [s], the logged signals with their units, the FMUs and the run's parameters in ``meta``.
    """
    if isinstance(system, dict):
        system = system_from_dict(system)
    with Master(system) as master:
        logs = master.run(inputs=inputs, parameters=parameters, stop_time=stop_time, progress=False)
        run_info = master.metadata()
    source = str(system) if isinstance(system, (str, Path)) else str(master.system.source or "<python>")
    return recording_from_log(logs, log, run_info, excited={"inputs": sorted(inputs or {})},
                              metadata={"system": source, "order": run_info["order"],
                                        "parameters": dict(parameters or {})})
