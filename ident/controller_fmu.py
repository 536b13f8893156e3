"""Tuned controller parameters -> a new controller FMU (the FMU output of ``motiontwin tune``).

Why a module of its own: the design (``ident.tuning``) is numerical and FMU-free; writing its result into a
``MotionTwin.Controllers.RobustJointController`` FMU needs the FMU pipeline (build, write-back) and a check
that the FMU samples at the period the design assumed. Units: Ts [s].
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

from motiontwin.fmus import build, writeback
from motiontwin.fmus.archive import read_description
from motiontwin.ident.tuning.spec import CONTROLLER_CLASS, TuningError

__all__ = ["write_controller_fmu", "sample_period_of"]


def sample_period_of(fmu: Path | str) -> float:
    """The start value of the controller FMU's parameter ``Ts`` [s] (fixed by its build)."""
    for variable in read_description(fmu).modelVariables:
        if variable.name == "Ts":
            return float(variable.start)
    raise TuningError(f"{fmu}: the controller FMU has no parameter 'Ts'")


def write_controller_fmu(parameters: dict[str, float], ts: float, out: Path | str, provenance: dict,
                         source_fmu: Path | str | None = None, fmi_version: str = "3.0") -> Path:
    """Write tuned controller parameters as the start values of a new controller FMU.

    Parameters
    ----------
    parameters : dict of str to float
        Controller parameters (``TuningResult.parameters``); ``Ts`` is skipped (fixed by the FMU's build).
    ts : float
        Sample period the design used [s]; the controller FMU must sample at it.
    out : path
        The new FMU; ``source_fmu`` is never modified.
    provenance : dict
        Stored in the FMU's ``documentation/provenance.json`` (method, spec, margins, ...).
    source_fmu : path, optional
        A ``RobustJointController`` FMU to start from; default: one built now from the library.
    fmi_version : {"2.0", "3.0"}
        FMI version of the FMU built when ``source_fmu`` is not given.

    Returns
    -------
    Path
        The written FMU.
    """
    values = {name: value for name, value in parameters.items() if name != "Ts"}
    with tempfile.TemporaryDirectory(prefix="motiontwin-tune-") as tmp:
        source = source_fmu or build.build_fmu(build.load_model(CONTROLLER_CLASS), tmp, fmi_version).path
        fmu_ts = sample_period_of(source)
        if not math.isclose(fmu_ts, ts, rel_tol=1e-12):
            raise TuningError(f"{source}: the controller FMU samples at Ts = {fmu_ts} s but the design used "
                              f"Ts = {ts} s; rebuild the controller with that period")
        return writeback.write_back(source, values, out, provenance)
