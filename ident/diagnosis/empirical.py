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

THRESHOLDS = tuple(np.logspace(-3, 0, 13))   # fractions of the residual RMS
FOLDS = 5
MAX_SAMPLES = 3000                            # the residual is decimated to this many samples for the fit
MIN_GAIN = 0.05                               # a term set must cut the cross-validated RMS by 5 %


@dataclass(frozen=True)
class Term:
    """One library function: its name, numpy form and Modelica form.

    The Modelica text uses the placeholders {x}, {v}, {a}, {u} and {v_eps} for the model's own names.
    """

    name: str
    evaluate: Callable[[dict[str, np.ndarray], float], np.ndarray]
    modelica: str


def default_library() -> list[Term]:
    """Functions of (x, v, a, u) a motion axis' missing force is commonly made of: polynomial corrections
    of mass, damping and stiffness, drag, friction shapes (Coulomb sign, velocity-weakening), friction that
    grows with position or load, and a constant force."""
    sign = "tanh({v}/{v_eps})"
    return [
        Term("1", lambda s, e: np.ones_like(s["v"]), "1"),
        Term("x", lambda s, e: s["x"], "{x}"),
        Term("x^2", lambda s, e: s["x"] ** 2, "{x}^2"),
        Term("v", lambda s, e: s["v"], "{v}"),
        Term("v*|v|", lambda s, e: s["v"] * np.abs(s["v"]), "{v}*abs({v})"),
        Term("v^3", lambda s, e: s["v"] ** 3, "{v}^3"),
        Term("a", lambda s, e: s["a"], "{a}"),
        Term("u", lambda s, e: s["u"], "{u}"),
        Term("sign(v)", lambda s, e: np.tanh(s["v"] / e), sign),
        Term("sign(v)*exp(-|v|/v_eps)", lambda s, e: np.tanh(s["v"] / e) * np.exp(-np.abs(s["v"]) / (10 * e)),
             f"{sign}*exp(-abs({{v}})/(10*{{v_eps}}))"),
        Term("x*sign(v)", lambda s, e: s["x"] * np.tanh(s["v"] / e), f"{{x}}*{sign}"),
        Term("|u|*sign(v)", lambda s, e: np.abs(s["u"]) * np.tanh(s["v"] / e), f"abs({{u}})*{sign}"),
        Term("x*v", lambda s, e: s["x"] * s["v"], "{x}*{v}"),
    ]


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

    def describe(self) -> str:
        law = " + ".join(f"{c:.4g}*{n}" for n, c in zip(self.names, self.coefficients)) or "none"
        return (f"empirical force F = {law} (v_eps {self.v_eps:.3g} m/s); cross-validated residual RMS "
                f"{self.cv_rms:.3g} N vs {self.cv_rms_zero:.3g} N without it")


def _stlsq(theta: np.ndarray, y: np.ndarray, threshold: float) -> np.ndarray:
    """PySINDy's sequentially thresholded least squares on unit-RMS columns (tiny ridge, unbiased refit)."""
    import pysindy

    optimizer = pysindy.STLSQ(threshold=threshold, alpha=1e-8, max_iter=50, unbias=True)
    with warnings.catch_warnings():   # "eliminated all coefficients" is an answer here, not a problem
        warnings.simplefilter("ignore", UserWarning)
        optimizer.fit(theta, y)
    return np.asarray(optimizer.coef_, dtype=float).ravel()


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
    EmpiricalForce : the selected terms (none when no term set cuts the cross-validated RMS by ``MIN_GAIN``).
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
    path = []
    for threshold in thresholds:
        errors, count = cv(threshold)
        path.append((threshold, errors, count))
    means = np.array([e.mean() for _, e, _ in path])
    best = int(np.argmin(means))
    limit = means[best] + path[best][1].std(ddof=1) / np.sqrt(folds)
    chosen = max(i for i in range(len(path)) if means[i] <= limit)
    threshold = path[chosen][0]
    cv_rms, cv_zero = float(means[chosen]) * y_scale, float(zero_errors.mean()) * y_scale
    report = [(t, float(e.mean()) * y_scale, c) for t, e, c in path]
    xi = _stlsq(theta, y, threshold)
    keep = np.flatnonzero(xi)
    if cv_rms > (1 - MIN_GAIN) * cv_zero or keep.size == 0:
        return EmpiricalForce([], np.zeros(0), threshold, cv_zero, cv_zero, v_eps, report)
    coefficients = xi[keep] * y_scale / scale[usable][keep]
    return EmpiricalForce([terms[i] for i in keep], coefficients, threshold, cv_rms, cv_zero, v_eps, report)
