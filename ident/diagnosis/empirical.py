"""Empirical force term for a residual no catalogue effect explains: sparse regression (PySINDy's sequentially
thresholded least squares) of the inverse-dynamics force residual over a library of functions of position x,
velocity v, acceleration a and actuator force u, written as a Modelica expression for the augmented model.

The result is labelled empirical: it reproduces the residual on the data's operating range and names the
functions it needs, but it is not a physical law and should not be extrapolated. Units: SI (m, m/s, m/s2, N).

Conventions: columns of the library are scaled to unit RMS and the residual to unit RMS before the regression,
so the threshold is the smallest contribution a term may make, as a fraction of the residual's RMS. The
threshold is chosen by cross-validation over contiguous time blocks (one-standard-error rule: the sparsest
model whose error is within one standard error of the best).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.axis_units import AxisUnits

THRESHOLDS = tuple(np.logspace(-3, 0, 13))   # fractions of the residual RMS
FOLDS = 5
MAX_SAMPLES = 3000                            # the residual is decimated to this many samples for the fit
MIN_GAIN = 0.05                               # a term set must cut the cross-validated RMS by 5 %
EMPIRICAL = "empirical_force"                 # name and family of the empirical effect in the augmented model
PRUNE_SHARE = 0.05                            # after the output-error refit, a term must carry 5 % of the force
POWER_SHARE = 0.9                             # the reported frequency band holds this share of the power
#: unit of each library function's coefficient (the force is in N)
TERM_UNITS = {"1": "N", "x": "N/m", "x^2": "N/m2", "v": "N.s/m", "v*|v|": "N.s2/m2", "v^3": "N.s3/m3", "a": "kg",
              "u": "1", "sign(v)": "N", "sign(v)*exp(-|v|/v_eps)": "N", "x*sign(v)": "N/m", "|u|*sign(v)": "1",
              "x*v": "N.s/m2"}


@dataclass(frozen=True)
class Term:
    """One library function: its name, numpy form and Modelica form.

    The Modelica text uses the placeholders {x}, {v}, {a}, {u} and {v_eps} for the model's own names.
    ``degree``: the power of the motion (x, v, a together) in the term, so that its coefficient in the plant's
    state coordinates is ``position_gain**degree`` times the one in the measured output's metres.
    """

    name: str
    evaluate: Callable[[dict[str, np.ndarray], float], np.ndarray]
    modelica: str
    degree: int = 0


def default_library() -> list[Term]:
    """Functions of (x, v, a, u) a motion axis' missing force is commonly made of: polynomial corrections
    of mass, damping and stiffness, drag, friction shapes (Coulomb sign, velocity-weakening), friction that
    grows with position or load, and a constant force."""
    sign = "tanh({v}/{v_eps})"
    return [
        Term("1", lambda s, e: np.ones_like(s["v"]), "1"),
        Term("x", lambda s, e: s["x"], "{x}", 1),
        Term("x^2", lambda s, e: s["x"] ** 2, "{x}^2", 2),
        Term("v", lambda s, e: s["v"], "{v}", 1),
        Term("v*|v|", lambda s, e: s["v"] * np.abs(s["v"]), "{v}*abs({v})", 2),
        Term("v^3", lambda s, e: s["v"] ** 3, "{v}^3", 3),
        Term("a", lambda s, e: s["a"], "{a}", 1),
        Term("u", lambda s, e: s["u"], "{u}"),
        Term("sign(v)", lambda s, e: np.tanh(s["v"] / e), sign),
        Term("sign(v)*exp(-|v|/v_eps)", lambda s, e: np.tanh(s["v"] / e) * np.exp(-np.abs(s["v"]) / (10 * e)),
             f"{sign}*exp(-abs({{v}})/(10*{{v_eps}}))"),
        Term("x*sign(v)", lambda s, e: s["x"] * np.tanh(s["v"] / e), f"{{x}}*{sign}", 1),
        Term("|u|*sign(v)", lambda s, e: np.abs(s["u"]) * np.tanh(s["v"] / e), f"abs({{u}})*{sign}"),
        Term("x*v", lambda s, e: s["x"] * s["v"], "{x}*{v}", 2),
    ]


#: the force itself: the inverse-dynamics residual of a model is u - (the force the model needs), so a
#: regression over u (with v and a) reproduces the residual's own definition; left out of the library
INPUT_TERMS = ("u",)
#: terms the nominal refit already owns (damping, mass): in the regression, so that a parameter the refit
#: biased to absorb the missing force does not distort the other terms, but not added to the empirical effect
PARAMETER_TERMS = ("v", "a")


def residual_library() -> list[Term]:
    """:func:`default_library` without :data:`INPUT_TERMS`: the functions a residual of a refitted model is
    regressed on in the diagnosis."""
    return [t for t in default_library() if t.name not in INPUT_TERMS]


@dataclass
class EmpiricalForce:
    """A sparse force law F = sum coefficient_k * term_k fitted to a force residual.

    Attributes
    ----------
    terms, coefficients : the selected library functions and their coefficients (SI).
    threshold : the chosen threshold (fraction of the residual RMS).
    cv_rms, cv_rms_zero : cross-validated RMS of the residual left by the law and by no law [N].
    v_eps : velocity scale of the sign functions [m/s].
    """

    terms: list[Term]
    coefficients: np.ndarray
    threshold: float
    cv_rms: float
    cv_rms_zero: float
    v_eps: float
    path: list[tuple[float, float, int]] = field(default_factory=list)   # (threshold, cv rms, term count)

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    @property
    def gain(self) -> float:
        """Cross-validated RMS of the residual with the law over without it (below 1: the law explains part)."""
        return self.cv_rms / self.cv_rms_zero

    def evaluate(self, signals: dict[str, np.ndarray]) -> np.ndarray:
        """The law's force at the samples of ``signals`` (keys x, v, a, u)."""
        total = np.zeros_like(np.asarray(signals["v"], dtype=float))
        for term, c in zip(self.terms, self.coefficients):
            total = total + c * term.evaluate(signals, self.v_eps)
        return total

    def modelica(self, x: str, v: str, a: str, u: str) -> str:
        """The law as a Modelica expression in the model's names for position, velocity, acceleration
        (e.g. ``der(v)``) and input; ``0`` when no term was selected."""
        if not self.terms:
            return "0"
        names = {"x": x, "v": v, "a": a, "u": u, "v_eps": f"{float(self.v_eps):.17g}"}
        parts = [f"({float(c):.17g})*({t.modelica.format(**names)})" for t, c in zip(self.terms, self.coefficients)]
        return " + ".join(parts)

    def describe(self, units: AxisUnits = AxisUnits()) -> str:
        law = " + ".join(f"{c:.4g}*{n}" for n, c in zip(self.names, self.coefficients)) or "none"
        return (f"empirical force F = {law} (v_eps {self.v_eps:.3g} {units.si('m/s')}); cross-validated residual "
                f"RMS {self.cv_rms:.3g} {units.force} vs {self.cv_rms_zero:.3g} {units.force} without it")


def _stlsq(theta: np.ndarray, y: np.ndarray, threshold: float) -> np.ndarray:
    """PySINDy's sequentially thresholded least squares on unit-RMS columns (tiny ridge, unbiased refit)."""
    import pysindy

    optimizer = pysindy.STLSQ(threshold=threshold, alpha=1e-8, max_iter=50, unbias=True)
    with warnings.catch_warnings():   # "eliminated all coefficients" is an answer here, not a problem
        warnings.simplefilter("ignore", UserWarning)
        optimizer.fit(theta, y)
    return np.asarray(optimizer.coef_, dtype=float).ravel()


def cross_validation_bound(theta: np.ndarray, y: np.ndarray, blocks: list[np.ndarray]) -> float:
    """A lower bound of every threshold's cross-validated RMS: the mean over the blocks of the RMS that least
    squares over *all* columns leaves when fitted on the block itself (no coefficient vector, sparse or fitted on
    the other blocks, does better on a block). When even this bound misses the :data:`MIN_GAIN` cut, no term set
    can pass and the 65 sparse regressions of the threshold path are skipped with the same answer."""
    rms = []
    for test in blocks:
        xi = np.linalg.lstsq(theta[test], y[test], rcond=None)[0]
        rms.append(np.sqrt(np.mean((y[test] - theta[test] @ xi) ** 2)))
    return float(np.mean(rms))


def fit_empirical_force(signals: dict[str, np.ndarray], residual: np.ndarray, v_eps: float | None = None,
                        library: list[Term] | None = None, thresholds: tuple[float, ...] = THRESHOLDS,
                        folds: int = FOLDS) -> EmpiricalForce:
    """Sparse regression of a force residual over ``library`` (default :func:`default_library`).

    Parameters
    ----------
    signals : dict with arrays ``x`` [m], ``v`` [m/s], ``a`` [m/s2], ``u`` [N], one value per sample.
    residual : the force the model misses at each sample [N] (e.g. measured force minus the inverse dynamics).
    v_eps : velocity scale of the sign functions [m/s]; default 1 % of the largest speed.
    thresholds : candidate thresholds, fractions of the residual RMS.
    folds : contiguous time blocks of the cross-validation.

    Returns
    -------
    EmpiricalForce : the selected terms (none when no term set cuts the cross-validated RMS by ``MIN_GAIN``; its
    ``path`` is empty when :func:`cross_validation_bound` decided that without the threshold path).
    """
    residual = np.asarray(residual, dtype=float)
    n = residual.size
    for key in ("x", "v", "a", "u"):
        if key not in signals or np.shape(signals[key]) != (n,):
            raise ValueError(f"signals[{key!r}]: expected {n} samples like the residual")
    if not np.all(np.isfinite(residual)):
        raise ValueError("residual: contains NaN or inf")
    if n < 10 * folds:
        raise ValueError(f"residual: {n} samples are too few for {folds}-fold cross-validation")
    library = library or default_library()
    v_eps = float(v_eps or 0.01 * np.max(np.abs(signals["v"])) or 1e-3)
    stride = -(-n // MAX_SAMPLES)   # a force law varies slowly against kHz sampling: every stride-th sample
    signals = {key: np.asarray(signals[key], dtype=float)[::stride] for key in ("x", "v", "a", "u")}
    residual = residual[::stride]
    n = residual.size
    columns = np.column_stack([t.evaluate(signals, v_eps) for t in library])
    scale = np.sqrt(np.mean(columns**2, axis=0))
    usable = scale > 0
    theta = columns[:, usable] / scale[usable]
    terms = [t for t, ok in zip(library, usable) if ok]
    y_scale = float(np.sqrt(np.mean(residual**2))) or 1.0
    y = residual / y_scale
    blocks = np.array_split(np.arange(n), folds)

    def cv(threshold: float) -> tuple[np.ndarray, int]:
        errors, counts = [], []
        for test in blocks:
            train = np.setdiff1d(np.arange(n), test)
            xi = _stlsq(theta[train], y[train], threshold) if threshold > 0 else np.zeros(theta.shape[1])
            errors.append(np.sqrt(np.mean((y[test] - theta[test] @ xi) ** 2)))
            counts.append(np.count_nonzero(xi))
        return np.array(errors), int(np.median(counts))

    zero_errors = np.array([np.sqrt(np.mean(y[test] ** 2)) for test in blocks])
    cv_zero = float(zero_errors.mean()) * y_scale
    if cross_validation_bound(theta, y, blocks) > (1 - MIN_GAIN) * zero_errors.mean():
        return EmpiricalForce([], np.zeros(0), max(thresholds), cv_zero, cv_zero, v_eps, [])
    path = []
    for threshold in thresholds:
        errors, count = cv(threshold)
        path.append((threshold, errors, count))
    means = np.array([e.mean() for _, e, _ in path])
    best = int(np.argmin(means))
    limit = means[best] + path[best][1].std(ddof=1) / np.sqrt(folds)
    chosen = max(i for i in range(len(path)) if means[i] <= limit)
    threshold = path[chosen][0]
    cv_rms = float(means[chosen]) * y_scale
    report = [(t, float(e.mean()) * y_scale, c) for t, e, c in path]
    xi = _stlsq(theta, y, threshold)
    keep = np.flatnonzero(xi)
    if cv_rms > (1 - MIN_GAIN) * cv_zero or keep.size == 0:
        return EmpiricalForce([], np.zeros(0), threshold, cv_zero, cv_zero, v_eps, report)
    coefficients = xi[keep] * y_scale / scale[usable][keep]
    return EmpiricalForce([terms[i] for i in keep], coefficients, threshold, cv_rms, cv_zero, v_eps, report)


NONE, UNEXPLAINED, NOT_VALIDATED = "none", "unexplained", "unexplained, no term validated"


def verdict(cost_reduction: float, null_threshold: float, validation_ratio: float | None,
            validation_gain: float) -> str:
    """The answer for an empirical term, by the catalogue's two rules: "none" unless the cost reduction
    beats the bootstrap null threshold; then "unexplained" when the validation RMS ratio (after/before; None:
    not validated yet) is below ``validation_gain``, else "unexplained, no term validated"."""
    if not cost_reduction > null_threshold:
        return NONE
    if validation_ratio is None or not validation_ratio < validation_gain:
        return NOT_VALIDATED
    return UNEXPLAINED


def without_parameter_terms(law: EmpiricalForce) -> EmpiricalForce:
    """``law`` without the :data:`PARAMETER_TERMS` (what the refitted damping and mass explain)."""
    keep = [i for i, t in enumerate(law.terms) if t.name not in PARAMETER_TERMS]
    return EmpiricalForce([law.terms[i] for i in keep], law.coefficients[keep], law.threshold, law.cv_rms,
                          law.cv_rms_zero, law.v_eps, law.path)


def refitted(law: EmpiricalForce, values: dict[str, float], signals: dict[str, np.ndarray],
             share: float = PRUNE_SHARE) -> EmpiricalForce:
    """``law`` (as written by :func:`as_effect`) at its output-error refitted ``values``, without the terms
    whose contribution (coefficient x RMS of the function over ``signals``) is below ``share`` of the RMS of
    the whole empirical force: the sequential thresholding of STLSQ, repeated on the output-error fit."""
    v_eps = float(values.get("empirical_v_eps", law.v_eps))
    coefficients = np.array([values[f"empirical_c{k}"] for k in range(1, len(law.terms) + 1)], float)
    columns = [t.evaluate(signals, v_eps) for t in law.terms]
    total = float(np.sqrt(np.mean(sum(c * col for c, col in zip(coefficients, columns)) ** 2)))
    keep = [i for i, (c, col) in enumerate(zip(coefficients, columns))
            if abs(c) * np.sqrt(np.mean(col ** 2)) >= share * total]
    return EmpiricalForce([law.terms[i] for i in keep], coefficients[keep], law.threshold, law.cv_rms,
                          law.cv_rms_zero, v_eps, law.path)


def as_effect(law: EmpiricalForce, ctx: effect_models.Context) -> effect_models.Effect:
    """The sparse law (its terms as given: drop :data:`PARAMETER_TERMS` first with
    :func:`without_parameter_terms`) as an effect of the augmented model, labelled empirical: one Modelica parameter
    ``empirical_c<k>`` per selected term (started at the regression's coefficient and at 0, the vanishing point
    where the augmented model is the current one, refitted by output error with the rest), the sign functions'
    velocity scale ``empirical_v_eps`` (fitted too, when a sign term is selected), and the force ``empirical_F``
    in the plant's position ``$x``, velocity ``$v``, acceleration ``der($v)`` and the commanded force ``u``. Not
    part of the catalogue (``effects.VOCABULARY``)."""
    if not law.terms:
        raise ValueError("the empirical law has no term to add")
    params = []
    for k, (term, c) in enumerate(zip(law.terms, law.coefficients), start=1):
        span = max(20 * abs(float(c)), 1e-9)
        params.append(effect_models.Param(f"empirical_c{k}", TERM_UNITS.get(term.name, ""),
                                          f"empirical coefficient of {term.name} (sparse regression, not a "
                                          f"physical law)", (-span, span), zero=0.0))
    uses_sign = any("{v_eps}" in t.modelica for t in law.terms)
    if uses_sign:
        lo, hi = effect_models._eps_bounds(ctx)
        params.append(effect_models.Param("empirical_v_eps", "m/s", "empirical velocity scale of the sign "
                                          "functions tanh(v/v_eps)", (min(lo, law.v_eps), max(hi, law.v_eps))))
    names = {"x": "$x", "v": "$v", "a": "der($v)", "u": "u", "v_eps": "empirical_v_eps"}
    law_text = " + ".join(f"empirical_c{k}*({t.modelica.format(**names)})" for k, t in enumerate(law.terms, 1))
    declaration = ('  Real empirical_F(unit = "N") "empirical force: sparse regression over position, velocity, '
                   'acceleration and force, not a physical law; valid on the recorded range only";\n')
    start = {f"empirical_c{k}": float(c) for k, c in enumerate(law.coefficients, 1)}
    if uses_sign:
        start["empirical_v_eps"] = float(law.v_eps)
    terms = list(law.terms)

    def contract(values: dict[str, float], c: effect_models.Context) -> dict[str, float]:
        """Coefficients in the measured output's units (a gear ratio or sensor gain converted)."""
        return {t.name: float(values[f"empirical_c{k}"]) / c.position_gain ** t.degree
                for k, t in enumerate(terms, 1)}

    return effect_models.Effect(EMPIRICAL, EMPIRICAL, params, declaration, "empirical_F",
                                [f"empirical_F = {law_text}"], [], lambda c: [dict(start)], contract,
                                "An empirical force term (sparse regression of the force residual no catalogue "
                                "effect explains): it names the functions of position, velocity, acceleration "
                                "and force the missing force is made of, not the physics behind them.")


def frequency_band(signal: np.ndarray, ts: float, share: float = POWER_SHARE) -> list[float]:
    """[f_lo, f_hi] Hz holding ``share`` of the power of ``signal`` (between the (1 - share)/2 and (1 + share)/2
    quantiles of its cumulative Welch spectrum, DC excluded)."""
    f, asd = evidence.spectrum(np.asarray(signal, float), ts)
    power = np.cumsum(asd[1:] ** 2)
    if power[-1] <= 0:
        return [float(f[1]), float(f[-1])]
    cumulative = power / power[-1]
    lo = int(np.searchsorted(cumulative, (1 - share) / 2))
    hi = int(np.searchsorted(cumulative, (1 + share) / 2))
    return [float(f[1:][lo]), float(f[1:][min(hi, cumulative.size - 1)])]


def locate_remainder(contribution: np.ndarray, residual_before: np.ndarray, time: np.ndarray, v: np.ndarray,
                     x: np.ndarray, sigma: float, ts: float) -> dict[str, object]:
    """Where the unexplained structure sits: time windows where the output residual ``residual_before`` [m]
    exceeds 3 noise levels ``sigma`` [m], and the velocity [m/s] and position [m] bins and the frequency
    band [Hz] of ``contribution``: the empirical term's part of the simulated output [m] when the term
    validated, else the force residual [N] it was fitted to (where a rejected term acts says nothing: on the
    held-out friction bump at 79 mm it pointed at the axis resting near 12 mm, the force residual at 69-83 mm)."""
    where = evidence.locate(contribution, v, x, ts)
    windows = evidence.flagged_windows(residual_before, time, max(sigma, 1e-15), ts)
    return {"time_windows": [list(w) for w in windows[:10]], "velocity_range": where["velocity_range"],
            "position_range": where["position_range"], "frequency_peak_hz": where["frequency_peak_hz"],
            "frequency_band_hz": frequency_band(contribution, ts)}
