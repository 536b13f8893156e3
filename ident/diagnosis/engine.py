"""The diagnosis's entry points: :func:`diagnose` (in memory), :func:`diagnose_bundle` (a bundle folder); the
stages run by :mod:`ident.diagnosis.pipeline`."""
from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from pathlib import Path
from typing import Callable

import threadpoolctl

from motiontwin.harness import BLAS_THREAD_VARIABLES
from motiontwin.harness.interrupt import raise_if_terminated
from motiontwin.harness.recording import Recording
from motiontwin.ident.controller import Controller
from motiontwin.ident import channels
from motiontwin.ident.diagnosis import pipeline
from motiontwin.ident.diagnosis.bundle import Bundle, BundleError, make_bundle, read_bundle
from motiontwin.ident.oeloop import Signals, axis_signals

#: one diagnosis at a time per process: CasADi's symbolic layer is not thread-safe (see :func:`diagnose`)
_CASADI_LOCK = threading.Lock()


def diagnose(plant: str | Path, controller: Controller | dict, train: Recording, validation: Recording, *,
             plant_class: str | None = None, parameters: dict[str, float] | None = None,
             pole_pitch: float | None = None, progress: Callable[[str], None] | None = None,
             axes: list[dict] | None = None) -> pipeline.Diagnosis | pipeline.MultiAxisDiagnosis:
    """Diagnose the mismatch between a nominal plant and two closed-loop recordings (in memory).

    Parameters
    ----------
    plant : Modelica file or Modelica source text of the nominal plant (input u [N], output q [m]).
    controller : the sampled controller (:class:`ident.controller.Controller` or its experiment.json object).
    train, validation : :class:`harness.recording.Recording` with time [s], r [m], u [N], q [m][, u_ext [N]].
    plant_class : the plant class (default: the first ``model`` in the source).
    parameters : start values of plant parameters (default: Modelica values and inverse dynamics).
    pole_pitch : the motor's magnet pole pitch [m] (enables the ``cogging`` candidate), or None.
    progress : called with one line per step.
    axes : a multi-axis plant (``[{"input": "u1", "output": "q1"}, ...]``, see :func:`bundle.make_bundle`);
        the result then names each effect's axis and the validation RMS per axis.

    Returns
    -------
    Diagnosis
        Effects, parameters and validation; ``.write(folder)`` writes the report and the FMU.

    Re-entrant: every call compiles its own loops (no module-level cache), so repeated calls and calls from
    several threads give the same result as one call. Calls from several threads run one at a time: CasADi's
    symbolic layer shares reference-counted constants between expressions and is not thread-safe (parallel
    diagnoses belong in separate processes).
    """
    bundle = make_bundle(plant, controller, train, validation, plant_class, parameters, pole_pitch=pole_pitch,
                         axes=axes)
    return diagnose_bundle_object(bundle, progress)


def diagnose_bundle_object(bundle: Bundle, progress: Callable[[str], None] | None = None
                           ) -> pipeline.Diagnosis | pipeline.MultiAxisDiagnosis:
    """:func:`diagnose` of an already read :class:`Bundle` (working files in a temporary folder); refused
    (:class:`BundleError`) when a recording's u is not controller(r, q) + u_ext (:func:`check_bundle_channels`)."""
    check_bundle_channels(bundle)
    with _CASADI_LOCK, _one_blas_thread(), tempfile.TemporaryDirectory(prefix="motiontwin-diagnosis-") as tmp:
        if bundle.multi_axis:
            return pipeline.MultiAxisDiagnosis.from_result(pipeline.run_axes(bundle, Path(tmp), progress))
        return pipeline.Diagnosis.from_result(pipeline.run(bundle, Path(tmp), progress))


def _one_blas_thread() -> contextlib.AbstractContextManager:
    """One BLAS thread while diagnosing (inherited by the forked screening workers), as the ``motiontwin``
    command runs, unless the user set a thread count (:data:`harness.BLAS_THREAD_VARIABLES`): the work is many small
    least-squares problems, and OpenBLAS's own threads spin. A 12 s + 6 s bundle called from Python took 58 s of
    CPU with two BLAS threads on a loaded 2-core machine and 27.5 s with one, with the same result."""
    if any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES):
        return contextlib.nullcontext()
    return threadpoolctl.threadpool_limits(limits=1, user_api="blas")


def check_bundle_channels(bundle: Bundle) -> None:
    """Raise :class:`BundleError` naming the recording file and the likely cause when its u is not
    controller(r, q) + u_ext beyond noise (:mod:`ident.channels`)."""
    signals = ([axis_signals(a.input, a.output) for a in bundle.plant.axes] if bundle.multi_axis
               else [Signals()])
    for part, rec in (("train", bundle.train), ("validation", bundle.validation)):
        problem = channels.channel_problem(rec, bundle.controller, signals)
        if problem:
            raise BundleError(f"{bundle.recording_path(part)}: {problem}. Fix the column (unit, sign, time shift) "
                              "before diagnosing: a wrong channel would be taken for missing physics")


def diagnose_bundle(bundle_dir: str | os.PathLike, out_dir: str | os.PathLike, progress=None) -> dict:
    """Diagnose a bundle folder and write diagnosis.json, validation_prediction.csv, report.md (+ PNGs), the
    augmented Modelica model and its FMU into ``out_dir``. Nothing is written when the input is bad, nor when a
    SIGTERM arrived during the analysis and its exception was swallowed (:func:`interrupt.raise_if_terminated`)."""
    diagnosis = diagnose_bundle_object(read_bundle(bundle_dir), progress)
    raise_if_terminated()
    return diagnosis.write(out_dir)
