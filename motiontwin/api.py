"""The Python API: one function per job of the ``motiontwin`` command, typed arguments, result objects.

Conventions (as python-control states its own): SI units throughout (s, m, N, rad, Hz for frequencies);
recordings are :class:`~motiontwin.harness.recording.Recording` objects (or the path of a CSV recording);
every function returns an object, never prints, and writes files only where its arguments name them.
``import motiontwin`` stays fast: this module and the layers below load on first use of a name.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

from motiontwin.harness.recording import Recording, atomic_write_texts, read_recording

__all__ = ["IdentificationResult", "build_fmu", "simulate", "identify_joint", "identify_oe", "identify_frf"]


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameters with their statistics, the method, the unit notes and the full result.

    Attributes
    ----------
    parameters : dict of str to float
        Estimates by name (SI); for ``identify_frf`` and ``identify_oe`` the FMU's parameter names, so
        ``motiontwin writeback --values`` takes :meth:`write`'s file.
    std : dict of str to float
        Standard deviations of the estimates (same names; nan where the method gives none).
    method : str
        What was fitted and how.
    notes : list of str
        Unit conversions and choices made on the way (e.g. a column in mm converted to m).
    detail : object
        The identification's own result (``ident.joint.JointIdentification``, ``ident.frf.JointModelFit`` or
        ``ident.outputerror.OutputErrorResult``) with the processed data, fit residuals and covariance.
    """

    parameters: dict[str, float]
    std: dict[str, float]
    method: str
    notes: list[str] = field(default_factory=list)
    detail: Any = None

    def write(self, path: str | os.PathLike) -> Path:
        """Write ``{"method", "parameters", "std", "notes"}`` as JSON (atomically); returns the path."""
        path = Path(path)
        document = {"method": self.method, "parameters": self.parameters, "std": self.std, "notes": self.notes}
        atomic_write_texts({path: json.dumps(document, indent=2) + "\n"})
        return path


def _recording(recording: Recording | str | os.PathLike, required: Iterable[str]) -> tuple[Recording, str]:
    """A Recording and the name to report it by (its path, or "recording")."""
    if isinstance(recording, Recording):
        return recording, "recording"
    return read_recording(recording, required), str(recording)


def build_fmu(class_name: str, out_dir: str | os.PathLike = "build/fmus", fmi_version: str = "3.0",
              modelica: str | os.PathLike | None = None, start_values: Mapping[str, float] | None = None) -> Path:
    """Build an FMU (Model Exchange and Co-Simulation, with sources) of a Modelica class.

    Parameters
    ----------
    class_name : str
        Full class name, e.g. ``"MotionTwin.Plants.LinearMotorJoint"``.
    out_dir : path
        The FMU goes to ``out_dir/fmi2`` or ``out_dir/fmi3``.
    fmi_version : {"2.0", "3.0"}
        FMI version.
    modelica : path, optional
        A Modelica library folder or ``.mo`` file; default: the MotionTwin library shipped with the package.
    start_values : mapping of str to float, optional
        Parameter/state start values compiled into the binary and written to the model description.

    Returns
    -------
    Path
        The FMU file.
    """
    from motiontwin.fmus import build

    model = build.load_model(class_name, build.MODELICA_DIR if modelica is None else modelica)
    return build.build_fmu(model, out_dir, fmi_version, start_values=dict(start_values or {})).path


def simulate(system: Any, stop_time: float | None = None, inputs: Mapping[str, Any] | None = None,
             parameters: Mapping[str, float] | None = None, log: str | None = None) -> Recording:
    """Co-simulate a system file or a system built in Python; returns a recording with units.

    Parameters
    ----------
    system : str, Path, dict or System
        A system file (TOML; format in ``motiontwin.harness.system``), the same description as a dict
        (relative FMU paths from the working directory) or a ``System``.
    stop_time : float, optional
        End of the run [s]; default: the system's ``stop_time``.
    inputs : mapping, optional
        External input -> scalar, array on the base grid, or ``(time, values)`` pair.
    parameters : mapping of str to float, optional
        ``"instance.variable"`` -> value for this run.
    log : str, optional
        Log group to return (default: the first).

    Returns
    -------
    Recording
        ``rec["time"]``, ``rec["plant.q"]`` ..., ``rec.units``; ``rec.to_csv(path)``, ``rec.to_mat(path)``,
        ``rec.to_pandas()``.
    """
    from motiontwin.harness.simulation import simulate as run_system

    return run_system(system, stop_time, inputs, parameters, log)


def identify_joint(recording: Recording | str | os.PathLike, fundamental_frequency: float, cutoff_frequency: float,
                   position: str = "q", force: str = "u", friction: str = "asymmetric", gravity: bool = True,
                   min_speed: float = 0.0, nominal_inertia: float | None = None) -> IdentificationResult:
    """Inverse-dynamics identification of a joint from a periodic recording (Gauss-Markov least squares).

    Parameters
    ----------
    recording : Recording or path
        A whole number of periods of a periodic excitation.
    fundamental_frequency : float
        Fundamental frequency of the excitation [Hz].
    cutoff_frequency : float
        Low-pass cut-off of the differentiating filter [Hz].
    position, force : str
        Columns of the position [m or rad] and the force [N or N.m].
    friction : str
        Friction parametrisation (``ident.joint``; default ``"asymmetric"``).
    gravity : bool
        Fit the gravity terms.
    min_speed : float
        Samples slower than this are left out [m/s or rad/s].
    nominal_inertia : float, optional
        A-priori inertia: a fit more than 10x away is refused (mis-declared units).

    Returns
    -------
    IdentificationResult
        Regressor parameters (``J``, friction, gravity terms) with standard deviations; ``detail`` is the
        ``JointIdentification`` (filtered period, mask, covariance).
    """
    from motiontwin.ident.joint import identify_joint_recording

    rec, source = _recording(recording, ("time", position, force))
    result, notes = identify_joint_recording(rec, fundamental_frequency, cutoff_frequency, position=position,
                                             force=force, min_speed=min_speed, friction=friction, gravity=gravity,
                                             nominal_inertia=nominal_inertia, source=source)
    fit = result.fit
    return IdentificationResult(fit.as_dict(), dict(zip(fit.names, fit.std.tolist())),
                                "inverse-dynamics Gauss-Markov least squares (Abdellatif, Bona eq. 2)", notes, result)


def identify_oe(recording: Recording | str | os.PathLike, class_name: str, free: Iterable[str],
                modelica: str | os.PathLike | None = None, input: str = "u", output: str = "q",
                controller: Any = None, max_nfev: int = 50, shooting: str = "single",
                segments: int = 4) -> IdentificationResult:
    """Output-error refit of a Modelica plant's parameters to a recording (open or closed loop).

    Parameters
    ----------
    recording : Recording or path
        Uniformly sampled data (at the controller period in closed loop; then with the reference ``r``).
    class_name : str
        The plant class, e.g. ``"MotionTwin.Plants.LinearMotorJoint"``.
    free : iterable of str
        Parameters to fit; the others keep their Modelica values.
    modelica : path, optional
        Library folder or ``.mo`` file; default: the shipped MotionTwin library.
    input, output : str
        Recording columns of the plant input and output (the output a state or output of the plant).
    controller : Controller or path, optional
        A sampled controller (``ident.controller``) or its JSON file: closed-loop refit.
    max_nfev : int
        Residual evaluations per single-shooting fit.
    shooting : {"single", "multiple"}
        Single shooting (Gauss-Newton) or multiple shooting (IPOPT over ``segments`` segments).
    segments : int
        Segments for multiple shooting.

    Returns
    -------
    IdentificationResult
        The fitted parameters in the plant's names with standard deviations; ``detail`` is the
        ``OutputErrorResult`` (loop, fit with the simulated output, weights, statistics).
    """
    from motiontwin.fmus import build
    from motiontwin.ident.controller import Controller, load_controller
    from motiontwin.ident.outputerror import Signals, identify

    if controller is not None and not isinstance(controller, Controller):
        controller = load_controller(controller)
    signals = Signals(output=output, input=input)
    required = ["time", output, input] + ([signals.reference] if controller is not None else [])
    rec, _ = _recording(recording, required)
    model = build.load_model(class_name, build.MODELICA_DIR if modelica is None else modelica)
    result = identify(model, rec, list(free), controller, signals, max_nfev=max_nfev, shooting=shooting,
                      segments=segments)
    stats = result.statistics
    loop = "closed loop" if controller is not None else "open loop"
    return IdentificationResult(stats.as_dict(), dict(zip(stats.names, stats.std.tolist())),
                                f"output-error refit ({shooting} shooting, CasADi RK4), {loop}", [], result)


def identify_frf(recording: Recording | str | os.PathLike, input: str = "u", position: str = "q",
                 segment_length: int | None = None, min_coherence: float = 0.9, alpha: float | None = None,
                 low_frequency: Recording | str | os.PathLike | None = None) -> IdentificationResult:
    """Cheung's joint model K/(s(s+alpha)) x resonance/antiresonance pairs from a swept-sine recording.

    Parameters
    ----------
    recording : Recording or path
        Force and encoder position of a swept-sine experiment.
    input, position : str
        Columns of the force [N] and the position [m].
    segment_length : int, optional
        Welch segment [samples]; default: the largest power of two <= min(4096, n/4).
    min_coherence : float
        FRF points below this coherence are left out.
    alpha : float, optional
        Hold alpha [1/s] at this value (default: fitted if the sweep band determines it, else 10).
    low_frequency : Recording or path, optional
        A point-to-point move (same columns): alpha from its fit, as Cheung does.

    Returns
    -------
    IdentificationResult
        ``K``, ``alpha``, ``omega``, ``zeta``, ``omega_bar``, ``zeta_bar`` (the CheungJoint FMU's names; std
        nan: the fit gives none); ``detail`` is the ``JointModelFit`` (model, FRF data, rms log error).
    """
    from motiontwin.ident.frf import FRF_METHOD, identify_frf_recording, joint_model_parameters

    columns = ("time", input, position)
    rec, source = _recording(recording, columns)
    options: dict[str, Any] = {}
    if low_frequency is not None:
        low, low_source = _recording(low_frequency, columns)
        options = {"low_frequency": low, "low_frequency_source": low_source}
    fit, notes = identify_frf_recording(rec, input=input, position=position, segment_length=segment_length,
                                        min_coherence=min_coherence, alpha=alpha, source=source, **options)
    parameters = joint_model_parameters(fit.model)
    return IdentificationResult(parameters, {name: float("nan") for name in parameters}, FRF_METHOD, notes, fit)
