"""Unknown controller: the prediction-error predictor that replaces it (issue 23, item 2).

Most lab recordings come from a drive whose controller is proprietary. Without it a double integrator driven
open loop by the measured force drifts (any force error integrates twice). The predictor closes the loop on
the measurements instead: the model is driven by the measured force ``u_meas`` plus the output of an
observer ``L``, a discrete PD on the prediction error ``q_meas - q_model``:

    plant input = u_meas + L(q_meas - q_model)

This is the closed loop the output-error engine already runs (:mod:`ident.oeloop`) with the controller ``L``,
the reference column = the measured position and the disturbance column = the measured force
(:func:`predictor_signals`). Its output residual ``q_meas - q_model`` is the prediction error; its force
residual ``u_meas - u_model = -L(q_meas - q_model)`` is the innovation correction, penalised by the same
weighted cost. With a known linear controller ``K`` the recorded loop satisfies u_meas = K(r - q_meas) + u_ext,
so the engine's known-controller loop is this predictor with ``L = K``: the two differ only in the observer's
bandwidth. The noise machinery stays exact for a linear plant: the encoder noise fed back through ``L`` and a
process force added to the disturbance column give the same residual statistics as the predictor's on data.

The observer's gain: the mass [force unit per acceleration of the measured output], first from the recording's
inverse dynamics (least squares of u on acceleration, velocity, Coulomb level and offset, :func:`recording_mass`),
after a refit the plant's own (:func:`plant_mass`, :func:`fitted_with_plant`), damping
``DAMPING``, a derivative filter at ``FILTER_RATIO`` times the bandwidth, discretised by Tustin, and the
bandwidth fitted with the plant by prediction error (:func:`fit_bandwidth`): the one that minimises the RMS of
the predictor's one-step-ahead error ``q_meas - q_model`` between ``fs / 100`` / 10**``SEARCH_DECADES`` and
``fs / 100``. That is the prediction-error method's criterion: for a linear plant with white force and encoder
noise its minimiser is the Kalman predictor's gain (its bandwidth grows with the force noise over the encoder
noise as sqrt(s_w / (m s_v)) / 2 pi, its damping is 1/sqrt(2), hence ``DAMPING``;
tests/test_unknown_controller.py holds it to the gain of the discrete Riccati equation). Where the force noise
dominates, the optimum lies above ``fs / 100`` and the fit stops at that bound and says so: a faster observer
would follow the encoder and leave every force error to its correction (session 27 measured the prediction
error falling as 1 / bandwidth^2 up to 20 Hz on a 250 Hz robot recording).
A ``mass`` or ``bandwidth_hz`` given by the user is kept. ``identify oe --controller unknown`` and the diagnosis
fit the observer this way; both estimate the predictor's start (the plant's position and velocity) in their
fits, since a slow observer's start transient from the first noisy samples was taken for an effect (a
backlash, docs/diagnose.md). Below the bandwidth a missing
force shows in the force residual, above it in the output residual as in a free run; the error of a wrong mass
integrates for at most about 1 / (2 pi bandwidth) before the observer pulls it back.

Scoring on a recording (:func:`k_step_ahead`): the predictor's free run (the RMS ``validate`` prints), and the
k-step-ahead prediction: from the predictor's state at the start of each segment of ``k`` samples, the model
alone (measured force, no observer) runs over the segment; reported are the RMS over every segment sample and
the RMS at the k-th sample. Units: those of the recording (s, and the plant's force and position units).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import loopstart, oefit, oeloop, plant_states
from motiontwin.ident.controller import Controller
from motiontwin.ident.oeloop import Signals
from motiontwin.ident.startvalues import derivative_cutoff, mirror_derivatives

UNKNOWN_KIND = "unknown"       # the ``controller.kind`` (or the CLI's ``--controller unknown``) that selects it
DEFAULT_BANDWIDTH_HZ = 20.0    # observer bandwidth [Hz] before it is fitted
MAX_BANDWIDTH_FRACTION = 1 / 100   # of the sample rate
DAMPING = 0.7
FILTER_RATIO = 5.0             # derivative filter pole over the bandwidth
SEARCH_DECADES = 2.0           # the bandwidth is fitted from its upper bound / 10**SEARCH_DECADES up to that bound
GRID_POINTS = 9                # log-spaced bandwidths tried first, then ...
REFINE_STEPS = 6               # ... golden-section steps (in log bandwidth) around the best of them
DEFAULT, GIVEN = "the default", "given"
MASS_FROM_RECORDING = "the recording's inverse dynamics"
METHOD = ("prediction-error predictor: the model driven by the measured force plus a PD observer on the "
          "measured position (no controller given)")


class ObserverError(ValueError):
    """The recording cannot give an observer (no motion, a non-positive mass); the message names the source."""


@dataclass(frozen=True)
class Observer:
    """The PD observer: mass [force / (output unit / s^2)], bandwidth [Hz], sample period ts [s]."""

    mass: float
    bandwidth_hz: float
    ts: float
    mass_from: str = MASS_FROM_RECORDING                    # where the mass came from, for the report
    bandwidth_from: str = DEFAULT                           # DEFAULT, GIVEN or how it was fitted

    @property
    def upper_bandwidth_hz(self) -> float:
        """The fastest bandwidth allowed (a fit's upper bound) [Hz]."""
        return MAX_BANDWIDTH_FRACTION / self.ts

    @property
    def kp(self) -> float:
        return self.mass * (2 * math.pi * self.bandwidth_hz) ** 2

    @property
    def kd(self) -> float:
        return 2 * DAMPING * self.mass * 2 * math.pi * self.bandwidth_hz

    def controller(self) -> Controller:
        """L as a sampled controller on y = [r; q] (r = the measured position): PD with a first-order filtered
        derivative, Kp + Kd s / (tau s + 1), Tustin at ``ts``."""
        from scipy.signal import cont2discrete   # here: scipy.signal takes 0.3-0.7 s to import

        tau = 1 / (2 * math.pi * self.bandwidth_hz * FILTER_RATIO)
        a, b, c, d, _ = cont2discrete((np.array([[-1 / tau]]), np.array([[1.0]]), np.array([[-self.kd / tau ** 2]]),
                                           np.array([[self.kp + self.kd / tau]])), self.ts, method="bilinear")
        b, d = float(np.ravel(b)[0]), float(np.ravel(d)[0])
        return Controller(self.ts, np.atleast_2d(a), np.array([[b, -b]]), np.atleast_2d(c), np.array([[d, -d]]))

    def as_dict(self) -> dict[str, object]:
        return {"kind": UNKNOWN_KIND, "method": METHOD, "mass": self.mass, "bandwidth_hz": self.bandwidth_hz,
                "bandwidth_from": self.bandwidth_from, "damping": DAMPING, "Kp": self.kp, "Kd": self.kd, "Ts": self.ts}

    def describe(self) -> str:
        return (f"{METHOD}; observer Kp {self.kp:.4g}, Kd {self.kd:.4g} (bandwidth {self.bandwidth_hz:.4g} Hz, "
                f"{self.bandwidth_from}; damping {DAMPING}, mass {self.mass:.4g} from {self.mass_from})")


def predictor_signals(output: str = "q", input_name: str = "u") -> Signals:
    """The predictor's column roles: reference = the measured position, disturbance = the measured force."""
    return Signals(output=output, input=input_name, reference=output, disturbance=input_name)


def recording_mass(q: np.ndarray, u: np.ndarray, ts: float, source: str = "recording") -> float:
    """Force per acceleration of ``q``: least squares of the force held over each sample on the filtered
    acceleration, velocity, a Coulomb level and an offset. Raises :class:`ObserverError` when not positive."""
    fs = 1 / ts
    _, v, a = mirror_derivatives(np.asarray(q, float), fs, derivative_cutoff(fs))
    u = np.asarray(u, float)
    held = 0.5 * (np.concatenate([u[:1], u[:-1]]) + u)
    held = mirror_derivatives(held, fs, derivative_cutoff(fs))[0]
    scale = max(1e-3 * float(np.ptp(v)), 1e-300)
    design = np.column_stack([a, v, np.tanh(v / scale), np.ones_like(v)])
    coef = np.linalg.lstsq(design, held, rcond=None)[0]
    if not (math.isfinite(coef[0]) and coef[0] > 0):
        raise ObserverError(f"{source}: the force does not accelerate the position (inverse-dynamics mass "
                            f"{coef[0]:.4g}); without a controller the predictor needs motion driven by the "
                            f"recorded force (check the force and position columns, their units and sign)")
    return float(coef[0])


def plant_mass(model: symbolic.SymbolicModel, values: dict[str, float], output: str = "q",
               input_name: str | None = None) -> float | None:
    """The plant's force per acceleration of its measured ``output`` at its start state (``values``: every
    parameter): the mass a fitted model gives the observer, so that its error dynamics on that model have the
    bandwidth and damping asked for. None when the output is not carried by one state with a velocity state,
    or the figure is not a positive number."""
    import casadi as ca

    i_pos = plant_states.output_state(model, output)
    i_vel = None if i_pos is None else plant_states.velocity_state(model, i_pos)
    inputs = [v.name for v in model.inputs]
    if i_vel is None or not inputs:
        return None
    k = inputs.index(input_name) if input_name in inputs else 0
    p = np.array([values[v.name] for v in model.parameters])
    x0 = plant_states.start_state(model, p)
    rate = ca.Function("g", [model.x, model.u, model.p], [ca.jacobian(model.dx[i_vel], model.u[k])])
    per_force = float(np.array(rate(x0, np.zeros(model.u.numel()), p)).item())
    gain = oeloop._output_gain(model, output, x0, p)
    mass = 1 / (per_force * gain) if per_force and gain else math.nan
    return mass if math.isfinite(mass) and mass > 0 else None


def observer_for(rec: Recording, output: str = "q", input_name: str = "u", ts: float | None = None,
                 bandwidth_hz: float | None = None, source: str = "recording", mass: float | None = None) -> Observer:
    """The observer for ``rec`` (sample period ``ts``: the median step when None; ``mass``: from ``rec``'s
    inverse dynamics when None)."""
    ts = float(np.median(np.diff(rec.time))) if ts is None else float(ts)
    bandwidth = min(DEFAULT_BANDWIDTH_HZ if bandwidth_hz is None else float(bandwidth_hz),
                    MAX_BANDWIDTH_FRACTION / ts)
    return Observer(recording_mass(rec[output], rec[input_name], ts, source) if mass is None else float(mass),
                    bandwidth, ts, bandwidth_from=DEFAULT if bandwidth_hz is None else GIVEN)


def observer_from_document(doc: dict, rec: Recording, where: str, source: str) -> Observer:
    """The observer of a ``{"kind": "unknown"}`` controller object: its optional ``Ts`` (default: the median
    step of ``rec``), ``bandwidth_hz`` and ``mass`` (default: from ``rec``'s inverse dynamics). The object a fit
    writes (:meth:`Observer.as_dict`, in ``identify oe --out`` and ``diagnosis.json``) is read back as it was, so
    a validation uses the fit's own observer: its derived fields (Kp, Kd, damping) must agree with it; ``method``
    and ``bandwidth_from`` are read as they were written. Errors name ``where`` and the field."""
    for key in ("Ts", "bandwidth_hz", "mass"):
        value = doc.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value) or value <= 0):
            raise ObserverError(f"{where}: field 'controller.{key}' must be a positive number, got {value!r}")
    derived = {"Kp", "Kd", "damping", "method", "bandwidth_from"}
    extra = sorted(set(doc) - {"kind", "Ts", "bandwidth_hz", "mass"} - derived)
    if extra:
        raise ObserverError(f"{where}: field 'controller.{extra[0]}' is not used by kind {UNKNOWN_KIND!r} (it "
                            f"takes 'Ts', 'bandwidth_hz' and 'mass')")
    if doc.get("mass") is None:
        if derived & set(doc):
            raise ObserverError(f"{where}: field 'controller.{sorted(derived & set(doc))[0]}' is derived from "
                                f"'mass', which is missing")
        return observer_for(rec, ts=doc.get("Ts"), bandwidth_hz=doc.get("bandwidth_hz"), source=source)
    found = replace(observer_for(rec, ts=doc.get("Ts"), bandwidth_hz=doc.get("bandwidth_hz"), source=source,
                                 mass=float(doc["mass"])), mass_from=source)
    if isinstance(doc.get("bandwidth_from"), str):
        found = replace(found, bandwidth_from=doc["bandwidth_from"])
    for key, value in found.as_dict().items():
        if key in derived & set(doc) and key not in ("method", "bandwidth_from") and (
                doc[key] != value if isinstance(value, str)
                else not math.isclose(float(doc[key]), value, rel_tol=1e-9)):
            raise ObserverError(f"{where}: field 'controller.{key}' = {doc[key]!r} does not follow from its mass, "
                                f"bandwidth and Ts ({value!r}); give 'mass' and 'bandwidth_hz' only")
    return found


def fit_bandwidth(observer: Observer, prediction_rms: Callable[[Observer], float]
                  ) -> tuple[Observer, list[tuple[float, float]]]:
    """The bandwidth of ``observer`` fitted by prediction error: the one whose predictor leaves the lowest RMS
    one-step-ahead error ``prediction_rms(observer at that bandwidth)`` (the caller's model and recording; a
    diverging or failing run counts as infinite), searched on ``GRID_POINTS`` log-spaced bandwidths from the upper bound
    (:attr:`Observer.upper_bandwidth_hz`) down ``SEARCH_DECADES`` decades, then by golden section between the
    best one's neighbours. Returns the fitted observer (its ``bandwidth_from`` says so, and names the bound
    when it ends on one) and every (bandwidth [Hz], RMS) tried, by bandwidth."""
    hi = observer.upper_bandwidth_hz
    lo = hi / 10 ** SEARCH_DECADES
    tried: dict[float, float] = {}

    def rms(f: float) -> float:
        if f not in tried:
            try:
                value = float(prediction_rms(replace(observer, bandwidth_hz=f)))
            except (RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError):   # a run that fails
                value = math.inf
            tried[f] = value if math.isfinite(value) else math.inf
        return tried[f]

    grid = [lo * (hi / lo) ** (k / (GRID_POINTS - 1)) for k in range(GRID_POINTS - 1)] + [hi]
    best = min(range(GRID_POINTS), key=lambda k: rms(grid[k]))
    a, b = math.log(grid[max(best - 1, 0)]), math.log(grid[min(best + 1, GRID_POINTS - 1)])
    golden = (math.sqrt(5) - 1) / 2
    for _ in range(REFINE_STEPS):
        c, d = b - golden * (b - a), a + golden * (b - a)
        if rms(math.exp(c)) <= rms(math.exp(d)):
            b = d
        else:
            a = c
    f = min(tried, key=lambda k: (tried[k], -k))
    where = " at its upper bound fs/100" if f == hi else " at its lower bound" if f == lo else ""
    how = f"fitted by prediction error{where}, one-step RMS {tried[f]:.3g} over {lo:.3g}-{hi:.3g} Hz"
    if math.isclose(f, observer.bandwidth_hz, rel_tol=1e-6):   # its own, to the sample period's round-off
        f = observer.bandwidth_hz                                 # (a median step 8.6e-7 off 0.5 ms): kept
    return replace(observer, bandwidth_hz=f, bandwidth_from=how), sorted(tried.items())


def one_step_rms(model: symbolic.SymbolicModel, values: dict[str, float], rec: Recording, observer: Observer,
                 position: str, input_name: str | None = None, signals: Signals | None = None) -> float:
    """RMS one-step-ahead prediction error of ``observer``'s predictor on ``rec`` (plant ``model`` at ``values``,
    its ``position`` state or output compared with the recording's ``signals.output`` column; default signals
    :func:`predictor_signals`), its start state estimated as the prediction-error method does: the start of
    the position and velocity states (:func:`oeloop.initial_motion_states`) by least squares on the predictor's
    response to each (linear in them for a linear plant). A start from the first samples' noisy slope left a
    transient of about 1 / (2 pi bandwidth) that favoured fast observers (8 Hz against the Kalman 3.6 Hz at 5 um
    of encoder noise). inf when the run diverges. The compiled chain: one library for the whole bandwidth search
    (the observer's gains are inputs of its code), 15x less CPU than CasADi's own chain, the same RMS bit for bit."""
    signals = signals or predictor_signals()
    loop = oeloop.build_loop(model, observer.controller(), position, [], dict(values), rec.time.size,
                             signals=signals, input_name=input_name, with_jacobian=False)
    measured = np.asarray(rec[signals.output], float)
    names = [v.name for v in model.states]
    start = loopstart.initial_state(loop, rec, values)
    base = {n: float(start[names.index(n)]) for n in oeloop.initial_motion_states(model, position)}
    step = max(1e-9, 1e-3 * float(np.ptp(measured)))

    def error(initial: dict[str, float]) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):
            return measured - np.asarray(oefit.simulate(loop, rec, values, initial=initial)[0], float)

    e = error(base)
    if base and np.all(np.isfinite(e)):
        columns = np.column_stack([(e - error({**base, n: base[n] + step})) / step for n in base])
        if np.all(np.isfinite(columns)):
            e = e - columns @ np.linalg.lstsq(columns, e, rcond=None)[0]
    with np.errstate(over="ignore", invalid="ignore"):
        rms = float(np.sqrt(np.mean(e ** 2)))
    return rms if math.isfinite(rms) else math.inf


def fitted_with_plant(observer: Observer, model: symbolic.SymbolicModel, values: dict[str, float], rec: Recording,
                      position: str, input_name: str | None = None, signals: Signals | None = None) -> Observer:
    """``observer`` fitted with the refitted plant ``model`` at ``values`` on ``rec``: its mass the plant's own
    (:func:`plant_mass`) unless one was given, then its bandwidth by prediction error (:func:`fit_bandwidth`,
    :func:`one_step_rms`) unless one was given. ``identify oe --controller unknown`` and the diagnosis
    (``nominal.fit_observer``) refit the plant under it when it moved."""
    if observer.mass_from == MASS_FROM_RECORDING:
        mass = plant_mass(model, values, position, input_name)
        if mass is not None:
            observer = replace(observer, mass=mass, mass_from="the refitted plant")
    if observer.bandwidth_from == GIVEN:
        return observer
    return fit_bandwidth(observer, lambda trial: one_step_rms(model, values, rec, trial, position, input_name,
                                                              signals))[0]


@dataclass(frozen=True)
class Prediction:
    """k-step-ahead scores: the horizon [samples], RMS over every segment sample and at the horizon."""

    horizon: int
    segment_rms: float
    horizon_rms: float

    def as_dict(self) -> dict[str, float]:
        return {"horizon_samples": self.horizon, "segment_rms": self.segment_rms, "horizon_rms": self.horizon_rms}


def k_step_ahead(model: symbolic.SymbolicModel, values: dict[str, float], rec: Recording, controller: Controller,
                 signals: Signals, horizon: int, initial: dict[str, float] | None = None) -> Prediction:
    """The model alone (measured force, no observer) restarted every ``horizon`` samples from the state of the
    predictor's free run (``controller`` = the observer, ``signals`` = :func:`predictor_signals`; plant states
    ``initial`` at t = 0, the velocity otherwise from the first samples), compared with the measured output
    1..``horizon`` samples after each restart (the last incomplete segment dropped)."""
    n = rec.time.size
    if not 1 <= horizon <= n // 2:
        raise ValueError(f"horizon {horizon} samples: must be from 1 to {n // 2} (half the recording)")
    driven = signals.input if signals.input in [v.name for v in model.inputs] else None
    i_pos = oeloop.output_state(model, signals.output)
    i_vel = None if i_pos is None else plant_states.velocity_state(model, i_pos)
    tracking = {} if i_vel is None else {model.states[i_vel].name: "dq"}
    predictor = oeloop.build_loop(model, controller, signals.output, [], dict(values), n, signals=signals,
                                  input_name=driven, tracking=tracking, with_jacobian=False, native=False)
    states = oefit.simulate_states(predictor, rec, values, initial)
    span = horizon + 1          # the restart sample, then 1..horizon samples ahead
    starts = np.arange(0, n - span + 1, horizon)
    plant = oeloop.build_loop(model, None, signals.output, [], predictor.values, span, ts=predictor.ts,
                              input_name=driven, with_jacobian=False, native=False, substeps=predictor.substeps)
    chain = plant.step.mapaccum("segment", span, [0], [0]).map(starts.size)
    u = np.asarray(rec[signals.input], float)
    w = np.zeros((3, span * starts.size))
    w[1] = np.concatenate([u[j:j + span] for j in starts])
    pf = np.array([plant.values[name] for name in plant.fixed])
    q = np.array(chain(states[:, starts], w, np.zeros((0, starts.size)), np.tile(pf[:, None], starts.size))[1])
    measured = np.concatenate([rec[signals.output][j:j + span] for j in starts])
    err = (measured - q.ravel()).reshape(starts.size, span)[:, 1:]
    return Prediction(horizon, float(np.sqrt(np.mean(err ** 2))), float(np.sqrt(np.mean(err[:, -1] ** 2))))
