"""Model validation on a new recording (``motiontwin validate``), like System Identification Toolbox's
``compare`` and ``resid``.

A fitted model (a Modelica class with parameter values: the JSON ``identify oe --out`` writes, an FMU written by
``writeback``/``diagnose``, whose modelName and start values give the class and values, or a class with
``--set`` values) is re-simulated along the recording with the output-error free run of :mod:`ident.outputerror`
(same equations, same RK4 chain): open loop from the measured input, or closed loop with the sampled controller.
Only the initial position and velocity of the plant are estimated (as SITB's ``compare`` estimates initial
conditions; :func:`ident.outputerror.initial_motion_states`); no parameter is changed.

The RMS output error is defined once, by :func:`free_run`, and ``identify oe`` reports the same number for the
model it returns: the free run of the model at its parameter values along the whole recording (closed loop
with the controller fed r and u_ext, or open loop from the measured input), its initial position and
velocity estimated by least squares on the output alone (start: the first sample, at rest or at the slope of
the first samples, ``initial``; closed loop: the controller state from its first outputs, or from u_0 at
rest), RMS = sqrt(mean((y - y_sim)^2)) over all N samples.

Measures (e = measured - simulated output, N samples):

* fit % = 100 (1 - ||e|| / ||y - mean(y)||) (SITB's NRMSE fit), RMS of e (:func:`free_run`);
* residual autocorrelation r_e(tau), tau = 1..M, with the 99 % band +-2.576/sqrt(N); the whiteness decision is
  the portmanteau statistic Q = N sum r_e(tau)^2 against the chi-square 99 % quantile with M degrees of freedom;
* input-residual cross-correlation r_ue(tau), tau = -M..M, with the per-lag 99 % band 2.576 sqrt(P/N),
  P = sum_{|k|<=M} rho_u(k) rho_e(k) (the variance of a cross-correlation of two independent series, as SITB's
  ``resid``; P = 1 for a white residual); r_ue at different lags are correlated when the input is coloured, so
  the decision is simultaneous: max |r_ue| / sqrt(P/N) against the normal quantile of 1 - 0.01/(2M+1)
  (Bonferroni). Positive tau: the residual lags the input (input at t-tau vs residual at t).

Unknown controller (``controller`` = the observer of :mod:`ident.observer`, ``signals`` =
:func:`ident.observer.predictor_signals`): the free run is the prediction-error predictor's (the model driven by
the measured force plus the observer's correction), so its RMS is a prediction error, not a simulation error;
``horizon`` adds the k-step-ahead scores (:func:`ident.observer.k_step_ahead`: the model alone restarted every
k samples from the predictor's state, RMS over the segments and at the k-th sample).

Units: those of the recording and model (SI).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.fmus.limits import load_json
from motiontwin.harness.recording import Recording, write_figure
from motiontwin.ident import outputerror as oe
from motiontwin.ident import plant_states
from motiontwin.ident.controller import Controller, at_recording_step

__all__ = ["ModelSpec", "CorrelationTest", "Validation", "load_model_spec", "load_model", "fit_percent",
           "free_run", "autocorrelation_test", "cross_correlation_test", "validate", "validation_document",
           "plot_validation", "CONFIDENCE", "RMS_DEFINITION"]

CONFIDENCE = 0.99
#: the one definition of the RMS output error that identify oe and validate print (see :func:`free_run`)
RMS_DEFINITION = "free run over the whole recording, initial position and velocity estimated from the output alone"
#: the same free run started at the first samples (their position and slope), as ``motiontwin diagnose`` scores
RMS_FROM_DATA = "free run over the whole recording, initial position and velocity from the first samples"


@dataclass
class ModelSpec:
    """A model to validate: Modelica class (and the file or library it lives in) and parameter values."""

    class_name: str
    modelica: Path
    values: dict[str, float]
    source: str          # where the values came from, for the report
    initial: str = "samples"   # start of the initial-state estimate (identify oe --initial): "samples" or "rest"
    controller: dict | None = None   # the fit's controller object (identify oe, diagnose): its observer, if unknown


def load_model_spec(path: Path | None, *, class_name: str | None = None, modelica: Path | None = None,
                    values: dict[str, float] | None = None) -> ModelSpec:
    """The model described by ``path``: a values JSON (``class``, ``modelica``, ``parameters`` and
    ``fixed_parameters``, ``initial``, as ``identify oe --out`` writes), an FMU (modelName = class, parameter start
    values; its Modelica source found next to it by :func:`_source_next_to`), the output folder of ``motiontwin
    diagnose`` (its FMU and ``augmented_model``), or None (then ``class_name`` is required).

    ``class_name``/``modelica`` override the file's; ``values`` (``--set``) override its parameters.
    """
    from motiontwin.fmus.build import MODELICA_DIR

    found: dict[str, float] = {}
    name, library, source, initial = class_name, modelica, "Modelica start values", "samples"
    controller = None
    if path is not None:
        path = Path(path)
        if path.is_dir():
            fmu = _diagnosis_fmu(path)
            diagnosis = load_json(path / "diagnosis.json")
            axes = (diagnosis.get("validation") or {}).get("per_axis")
            if axes:
                raise ValueError(f"{path}: a multi-axis diagnosis (axes {', '.join(axes)}); validate re-simulates "
                                 f"one axis. The diagnosis' validation free runs of every axis are in "
                                 f"{path / 'validation_prediction.csv'}")
            controller = diagnosis.get("controller")
            path, library = fmu, library or path / "augmented_model"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: model file not found")
        if path.suffix.lower() == ".fmu":
            import fmpy

            md = fmpy.read_model_description(str(path))
            name = class_name or md.modelName
            for var in md.modelVariables:
                if var.causality == "parameter" and var.variability in ("fixed", "tunable") and var.start is not None:
                    try:
                        found[var.name] = float(var.start)
                    except ValueError:
                        continue
            source = f"start values of {path}"
            library = library or _source_next_to(path, md.modelName)
        elif path.suffix.lower() == ".json":
            doc = load_json(path)
            if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), dict):
                raise ValueError(f"{path}: field 'parameters' (an object of name: value) missing")
            for field in ("fixed_parameters", "parameters"):
                for key, value in (doc.get(field) or {}).items():
                    if isinstance(value, bool) or not isinstance(value, (int, float)):
                        raise ValueError(f"{path}: field '{field}.{key}' must be a number, got {value!r}")
                    found[key] = float(value)
            if doc.get("initial", initial) not in ("samples", "rest"):
                raise ValueError(f"{path}: field 'initial' must be 'samples' or 'rest', got {doc['initial']!r}")
            initial = doc.get("initial", initial)
            controller = doc.get("controller")
            name = class_name or doc.get("class")
            if library is None and doc.get("modelica"):
                library = Path(doc["modelica"])
            source = str(path)
            if not name:
                raise ValueError(f"{path}: field 'class' missing; give --class")
        else:
            raise ValueError(f"{path}: a model is a values JSON (identify oe --out), an FMU (.fmu) or the output "
                             "folder of motiontwin diagnose")
    if not name:
        raise ValueError("name the model: a values JSON, an FMU or a diagnose output folder, or --class")
    found.update(values or {})
    return ModelSpec(name, Path(library) if library is not None else MODELICA_DIR, found, source, initial,
                     controller if isinstance(controller, dict) else None)


def _diagnosis_fmu(folder: Path) -> Path:
    """The augmented FMU in a ``motiontwin diagnose`` output folder (fmu/fmi*/NAME.fmu)."""
    if not (folder / "diagnosis.json").is_file():
        raise FileNotFoundError(f"{folder}: a folder is read as the output of motiontwin diagnose, but it has no "
                                "diagnosis.json")
    fmus = sorted((folder / "fmu").glob("*/*.fmu"))
    if not fmus:
        raise FileNotFoundError(f"{folder}: no FMU under {folder / 'fmu'} (diagnose writes fmu/fmi2/Augmented.fmu)")
    return fmus[0]


def _source_next_to(fmu: Path, class_name: str) -> Path | None:
    """The Modelica folder of ``class_name`` next to an FMU: ``NAME.mo`` or ``augmented_model/NAME.mo`` in the
    FMU's folder or up to two folders above it (diagnose writes OUT/fmu/fmi2/Augmented.fmu beside
    OUT/augmented_model/Augmented.mo); None: the project's library."""
    short = class_name.rpartition(".")[2]
    for folder in (fmu.parent, *list(fmu.parents)[1:3]):
        for candidate in (folder / f"{short}.mo", folder / "augmented_model" / f"{short}.mo"):
            if candidate.is_file():
                return candidate.parent
    return None


def load_model(spec: ModelSpec) -> symbolic.SymbolicModel:
    """The symbolic model of ``spec``; a ``.mo`` file is read with the files beside it (the classes it uses,
    e.g. the plant that diagnose's Augmented.mo instantiates), and the project's library."""
    from motiontwin.fmus import build
    from motiontwin.fmus.flatmodel import ModelicaError

    source = spec.modelica.parent if spec.modelica.is_file() else spec.modelica
    try:
        return build.load_model(spec.class_name, source)
    except ModelicaError as exc:
        if "not found" in str(exc) and spec.source.startswith("start values of "):
            raise ModelicaError(f"{exc} (the Modelica source of an FMU is looked up next to it, as NAME.mo or "
                            "augmented_model/NAME.mo, then in the library; else give --modelica)") from None
        raise


def fit_percent(measured: np.ndarray, simulated: np.ndarray) -> float:
    """SITB's NRMSE fit: 100 (1 - ||y - y_sim|| / ||y - mean(y)||) [%]."""
    y = np.asarray(measured, dtype=float)
    spread = float(np.linalg.norm(y - y.mean()))
    if spread == 0:
        raise ValueError("the measured output is constant: fit % is undefined")
    return 100.0 * (1.0 - float(np.linalg.norm(y - simulated)) / spread)


@dataclass(frozen=True)
class CorrelationTest:
    """Correlation coefficients at ``lags``, the per-lag 99 % band, the test statistic with its 99 % threshold
    (autocorrelation: portmanteau vs chi-square; cross-correlation: largest standardised value vs the Bonferroni
    normal quantile), lags outside the band, and the decision ``passed`` (statistic <= threshold)."""

    lags: np.ndarray
    values: np.ndarray
    band: float
    statistic: float
    threshold: float
    outside: list[int]

    @property
    def passed(self) -> bool:
        return self.statistic <= self.threshold

    def as_dict(self) -> dict[str, Any]:
        return {"lags": self.lags.tolist(), "values": self.values.tolist(), "band": self.band,
                "statistic": self.statistic, "threshold": self.threshold, "lags_outside_band": self.outside,
                "passed": self.passed}


def _correlation(a: np.ndarray, b: np.ndarray, lag: int) -> float:
    """sum_t a[t - lag] b[t] / sqrt(sum a^2 sum b^2) (a, b zero-mean; lag may be negative)."""
    n = a.size
    if lag >= 0:
        value = float(a[:n - lag] @ b[lag:])
    else:
        value = float(a[-lag:] @ b[:n + lag])
    return value / math.sqrt(float(a @ a) * float(b @ b))


def autocorrelation_test(residual: np.ndarray, lags: int = 25, confidence: float = CONFIDENCE) -> CorrelationTest:
    """Whiteness of the residual: r_e(1..lags), band and portmanteau decision (module docstring)."""
    from scipy.stats import chi2  # here: scipy.stats costs about a second to import

    e = np.asarray(residual, dtype=float) - np.mean(residual)
    n = e.size
    taus = np.arange(1, lags + 1)
    values = np.array([_correlation(e, e, int(k)) for k in taus])
    band = float(_normal_quantile(confidence) / math.sqrt(n))
    statistic = float(n * np.sum(values ** 2))
    return CorrelationTest(taus, values, band, statistic, float(chi2.ppf(confidence, lags)),
                           [int(k) for k, v in zip(taus, values) if abs(v) > band])


def _normal_quantile(confidence: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(0.5 + confidence / 2))


def _autocorrelations(x: np.ndarray, lags: int) -> np.ndarray:
    """rho_x(0..lags) of a zero-mean series."""
    return np.array([_correlation(x, x, k) for k in range(lags + 1)])


def cross_correlation_test(inputs: np.ndarray, residual: np.ndarray, lags: int = 25,
                           confidence: float = CONFIDENCE) -> CorrelationTest:
    """Independence of residual and input: r_ue(-lags..lags), per-lag band and decision (module docstring)."""
    u = np.asarray(inputs, dtype=float) - np.mean(inputs)
    e = np.asarray(residual, dtype=float) - np.mean(residual)
    if not np.any(u):
        raise ValueError("the input is constant: no cross-correlation test")
    n = u.size
    taus = np.arange(-lags, lags + 1)
    values = np.array([_correlation(u, e, int(k)) for k in taus])
    rho_u, rho_e = _autocorrelations(u, lags), _autocorrelations(e, lags)
    spread = max(float(rho_u[0] * rho_e[0] + 2 * np.sum(rho_u[1:] * rho_e[1:])), 1e-3)
    sigma = math.sqrt(spread / n)
    band = _normal_quantile(confidence) * sigma
    simultaneous = _normal_quantile(1 - (1 - confidence) / taus.size)
    return CorrelationTest(taus, values, float(band), float(np.max(np.abs(values)) / sigma), float(simultaneous),
                           [int(k) for k, v in zip(taus, values) if abs(v) > band])


@dataclass
class Validation:
    """Re-simulation of a model on a recording: measured and simulated output, residual, fit %, RMS, the two
    correlation tests, the estimated initial states and the controller/loop used."""

    spec: ModelSpec
    time: np.ndarray
    measured: np.ndarray
    simulated: np.ndarray
    inputs: np.ndarray
    fit_percent: float
    rms: float
    autocorrelation: CorrelationTest
    cross_correlation: CorrelationTest
    initial: dict[str, float]
    closed_loop: bool
    output: str
    input: str
    unit: str = "m"                     # the output's unit as the recording declares it (m, rad, ...)
    prediction: Any = None              # unknown controller: ident.observer.Prediction (k-step-ahead), or None
    rms_definition: str = RMS_DEFINITION    # how the free run started (RMS_DEFINITION or RMS_FROM_DATA)

    @property
    def residual(self) -> np.ndarray:
        return self.measured - self.simulated


def free_run(model: symbolic.SymbolicModel, values: dict[str, float], rec: Recording, *,
             controller: Controller | None = None, signals: oe.Signals = oe.Signals(), initial: str = "samples",
             estimate_initial: bool = True, where: str = "") -> oe.Fit:
    """The free run that defines the RMS output error (``Fit.rms_q``) of ``identify oe`` and ``validate``:
    ``model`` at ``values`` along ``rec`` (closed loop with ``controller``, fed r and u_ext; else open loop from
    the input column), the initial position and velocity estimated by least squares on the output alone
    (``estimate_initial``; else the first sample), starting from ``initial`` ("samples": the slope of the first
    samples and, in closed loop, the controller state from its first outputs; "rest": at rest). ``where`` names
    the model in errors."""
    if initial not in ("samples", "rest"):
        raise ValueError(f"initial must be 'samples' or 'rest', not {initial!r}")
    steps = np.diff(rec.time)
    if controller is not None:
        controller = at_recording_step(controller, rec.time, where or "recording")
    ts = controller.sample_time if controller is not None else float(rec.sample_time or np.median(steps))
    bad = np.flatnonzero(np.abs(steps - ts) > 1e-3 * ts)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"recording row {i + 3}, column 'time': step {steps[i]:.9g} s differs from the sample period "
                         f"{ts:.9g} s (the re-simulation needs uniform sampling)")
    tracking = None
    i_pos = oe.output_state(model, signals.output)
    i_vel = None if i_pos is None else plant_states.velocity_state(model, i_pos)
    if initial == "samples" and i_vel is not None:
        tracking = {model.states[i_vel].name: "dq"}
    loop = oe.build_loop(model, controller, signals.output, [], dict(values), rec.time.size, ts=ts,
                         signals=signals, tracking=tracking, input_name=signals.input if signals.input in
                         [v.name for v in model.inputs] else None)
    estimated = oe.initial_motion_states(model, signals.output) if estimate_initial else []
    q0, u0 = oe.simulate(loop, rec)
    # the output alone decides the initial state: the force channel (closed loop) is weighted down by 1e6
    weights = oe.Weights(oe._rms_weight(rec[signals.output] - q0),
                         1e6 * oe._rms_weight(rec[signals.input] - u0) if controller is not None else 1.0)
    result = oe.fit(loop, rec, weights, estimate_initial=estimated)
    if not np.all(np.isfinite(result.q_sim)):
        raise ValueError(f"{where or model.name}: the re-simulation diverged (non-finite output); check the "
                         "parameter values and, in closed loop, the controller")
    return result


def validate(model: symbolic.SymbolicModel, spec: ModelSpec, rec: Recording, *, controller: Controller | None = None,
             signals: oe.Signals = oe.Signals(), lags: int = 25, estimate_initial: bool = True,
             initial: str | None = None, horizon: int | None = None) -> Validation:
    """Re-simulate ``model`` at ``spec.values`` along ``rec`` and compute the compare/resid measures.

    Parameters
    ----------
    model : the symbolic model of ``spec.class_name`` (:func:`load_model`).
    spec : class and parameter values (unknown names raise, naming the class's parameters).
    rec : recording with the input (open loop) or the reference (closed loop; u_ext added when recorded) and the
        measured output.
    controller : closed loop when given (the recording then needs the reference column).
    signals : recording column names.
    lags : correlation lags M.
    estimate_initial : estimate the initial position and velocity (else start at the first sample).
    initial : start of that estimate, "samples" or "rest" (default: ``spec.initial``), see :func:`free_run`.
    horizon : with the unknown controller's observer: the k-step-ahead horizon [samples] (None: not scored).

    Returns
    -------
    Validation with fit %, RMS, both correlation tests and the simulated output.
    """
    names = [v.name for v in model.parameters]
    unknown = sorted(set(spec.values) - set(names))
    if unknown:
        raise KeyError(f"{spec.source}: class {spec.class_name} has no parameter {', '.join(map(repr, unknown))}; "
                       f"its parameters are {', '.join(names)}")
    for var in model.parameters:
        value = spec.values.get(var.name)
        if value is not None and not var.min <= value <= var.max:
            bound = f"below its minimum {var.min:g}" if value < var.min else f"above its maximum {var.max:g}"
            raise ValueError(f"{spec.source}: parameter {var.name} = {value:g} is {bound} (class {spec.class_name})")
    if isinstance(lags, bool) or not isinstance(lags, (int, np.integer)) or not 1 <= lags < rec.time.size // 2:
        raise ValueError(f"lags = {lags}: must be a whole number from 1 to {rec.time.size // 2 - 1} (half the "
                         f"{rec.time.size} samples)")
    needed = [signals.output, signals.input] + ([signals.reference] if controller is not None else [])
    missing = [c for c in needed if c not in rec.columns]
    if missing:
        raise KeyError(f"recording has no column {', '.join(map(repr, missing))} (columns: {', '.join(rec.columns)})")
    result = free_run(model, spec.values, rec, controller=controller, signals=signals,
                      initial=initial or spec.initial, estimate_initial=estimate_initial,
                      where=f"{spec.class_name} at {spec.source}")
    measured = rec[signals.output]
    residual = measured - result.q_sim
    predictor = signals.reference == signals.output
    u = rec[signals.input] if controller is None or predictor else rec[signals.reference]
    prediction = None
    if horizon is not None and controller is not None:
        from motiontwin.ident.observer import k_step_ahead

        prediction = k_step_ahead(model, spec.values, rec, controller, signals, horizon, result.initial)
    return Validation(spec, rec.time, measured, result.q_sim, u, fit_percent(measured, result.q_sim),
                      result.rms_q, autocorrelation_test(residual, lags),
                      cross_correlation_test(u, residual, lags), result.initial, controller is not None,
                      signals.output, signals.input if controller is None or predictor else signals.reference,
                      rec.units.get(signals.output) or "m", prediction,
                      RMS_DEFINITION if estimate_initial else RMS_FROM_DATA)


def validation_document(result: Validation, recording_path: str) -> dict[str, Any]:
    """The JSON ``motiontwin validate --out`` writes."""
    return {"model": {"class": result.spec.class_name, "modelica": str(result.spec.modelica),
                      "values": result.spec.values, "values_from": result.spec.source},
            "recording": recording_path, "loop": "closed" if result.closed_loop else "open",
            "output": result.output, "input": result.input, "samples": int(result.time.size),
            "fit_percent": result.fit_percent, "rms": result.rms, "rms_definition": result.rms_definition,
            "initial_states": result.initial,
            "k_step_ahead": result.prediction.as_dict() if result.prediction is not None else None,
            "confidence": CONFIDENCE, "residual_autocorrelation": result.autocorrelation.as_dict(),
            "input_residual_cross_correlation": result.cross_correlation.as_dict()}


def plot_validation(result: Validation, path: Path) -> Path:
    """Four panels: measured vs simulated output (compare), the residual over time, residual autocorrelation
    and input-residual cross-correlation with their 99 % bands (resid). Written atomically (temporary file, then rename)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(8, 11))
    ax = axes[0]
    ax.plot(result.time, result.measured, label=f"measured {result.output}", lw=1)
    ax.plot(result.time, result.simulated, "--", label=f"simulated (fit {result.fit_percent:.3f} %)", lw=1)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{result.output} [{result.unit}]")
    ax.legend(loc="best")
    ax.set_title(f"{result.spec.class_name}: RMS error {result.rms:.3g} {result.unit}")
    ax = axes[1]
    scale, shown = (1e6, "u" + result.unit) if result.unit in ("m", "rad") else (1.0, result.unit)
    ax.plot(result.time, scale * result.residual, lw=0.7)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"measured - simulated [{shown}]")
    ax.set_title("output residual")
    for ax, test, title, measure in (
            (axes[2], result.autocorrelation, "residual autocorrelation", "Q"),
            (axes[3], result.cross_correlation, f"cross-correlation {result.input} -> residual", "max |r|/sigma")):
        ax.stem(test.lags, test.values, basefmt=" ")
        ax.axhspan(-test.band, test.band, color="tab:blue", alpha=0.15, label="99 % band")
        verdict = "passed" if test.passed else "failed"
        ax.set_title(f"{title}: {measure} = {test.statistic:.3g}, 99 % limit {test.threshold:.3g} ({verdict})")
        ax.set_xlabel("lag [samples]")
        ax.legend(loc="upper right")
    fig.tight_layout()
    try:
        return write_figure(path, fig, dpi=110)
    finally:
        plt.close(fig)
