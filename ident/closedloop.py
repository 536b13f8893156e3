"""Closed-loop identification by the projection method (Forssell & Ljung 2000; Bona & Curatella eqs. 10-12).

In closed loop the plant input u = S r - (noise fed back by the controller) is correlated with the output
noise, so fitting G directly from (u, y) is biased. The projection method:

  1. fits a non-causal FIR model u(t) = sum_{k=-M1}^{M2} s_k r(t-k) + residual (eq. 10) by least squares
     and forms the projection u_hat = S_hat r (eq. 11), which is uncorrelated with the noise;
  2. identifies G with an open-loop method from (u_hat, y) (eq. 12); here an output-error model
     y = B(q)/F(q) u_hat fitted by nonlinear least squares.

No assumption on the controller structure is needed.

Units: discrete time, samples; signals in their own SI units.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal

__all__ = ["ProjectionResult", "project_on_reference", "OutputErrorModel", "fit_output_error",
           "ClosedLoopIdentification", "identify_projection", "model_features", "identify_projection_recording"]


@dataclass(frozen=True)
class ProjectionResult:
    """Non-causal FIR projection of a signal on the reference.

    lags: k = -M1..M2; coefficients: s_k; projected: u_hat (same length as the input, zero-padded
    reference at the edges); residual: u - u_hat; correlation: correlation coefficient between u_hat and
    the residual over the fitted samples (close to 0 when M1, M2 are long enough, Bona sec. 3.4).
    """

    lags: np.ndarray
    coefficients: np.ndarray
    projected: np.ndarray
    residual: np.ndarray
    correlation: float


def _shifted(r: np.ndarray, lags: np.ndarray, periodic: bool) -> np.ndarray:
    n = r.size
    out = np.zeros((n, lags.size))
    for j, k in enumerate(lags):
        if periodic:
            out[:, j] = np.roll(r, k)
        elif k >= 0:
            out[k:, j] = r[: n - k]
        else:
            out[: n + k, j] = r[-k:]
    return out


def project_on_reference(
    reference: np.ndarray,
    signal: np.ndarray,
    n_noncausal: int,
    n_causal: int,
    *,
    periodic: bool = False,
) -> ProjectionResult:
    """Least-squares non-causal FIR fit of ``signal`` from ``reference`` (Bona eqs. 10-11).

    ``n_noncausal`` = M1 (future reference samples), ``n_causal`` = M2 (past samples). With
    ``periodic`` the shifts wrap around (data covering whole periods); otherwise the edge samples whose
    regressors are incomplete are excluded from the fit.
    """
    r = np.asarray(reference, dtype=float).reshape(-1)
    u = np.asarray(signal, dtype=float).reshape(-1)
    if r.shape != u.shape:
        raise ValueError(f"reference and signal must have the same length, got {r.size} and {u.size}")
    if n_noncausal < 0 or n_causal < 0:
        raise ValueError("n_noncausal and n_causal must be >= 0")
    lags = np.arange(-n_noncausal, n_causal + 1)
    if r.size <= 2 * lags.size:
        raise ValueError(f"{r.size} samples are too few for an FIR with {lags.size} taps")
    phi = _shifted(r, lags, periodic)
    rows = slice(None) if periodic else slice(n_causal, r.size - n_noncausal)
    fit_phi, fit_u = phi[rows], u[rows]
    gram = fit_phi.T @ fit_phi
    if np.linalg.cond(gram) < 1e8:  # normal equations: ~10x faster than SVD for long records
        coefficients = scipy.linalg.solve(gram, fit_phi.T @ fit_u, assume_a="pos")
    else:
        coefficients, *_ = np.linalg.lstsq(fit_phi, fit_u, rcond=None)
    projected = phi @ coefficients
    residual = u - projected
    corr = np.corrcoef(projected[rows], residual[rows])[0, 1]
    return ProjectionResult(lags, coefficients, projected, residual, float(corr))


@dataclass(frozen=True)
class OutputErrorModel:
    """y(t) = B(q)/F(q) u(t): b = [b_0..b_nb] on q^-delay.., f = [1, f_1..f_nf] (scipy.signal.lfilter form)."""

    b: np.ndarray
    f: np.ndarray
    rms_error: float

    def simulate(self, u: np.ndarray) -> np.ndarray:
        return scipy.signal.lfilter(self.b, self.f, u)

    def frequency_response(self, frequency: np.ndarray, sample_rate: float) -> np.ndarray:
        """Complex response at ``frequency`` [Hz]."""
        _, h = scipy.signal.freqz(self.b, self.f, worN=np.asarray(frequency), fs=sample_rate)
        return h


def fit_output_error(
    u: np.ndarray, y: np.ndarray, n_b: int, n_f: int, *, delay: int = 1, skip: int = 0
) -> OutputErrorModel:
    """Output-error model fitted by nonlinear least squares on the simulation error.

    Starts from the ARX least-squares estimate. ``skip`` initial samples are excluded from the cost
    (transient of the zero initial state). Raises if the estimate is unstable.
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    if u.shape != y.shape:
        raise ValueError(f"u and y must have the same length, got {u.size} and {y.size}")
    lag = max(n_f, delay + n_b - 1)
    rows = np.arange(lag, y.size)
    columns = [-y[rows - i] for i in range(1, n_f + 1)]
    columns += [u[rows - delay - i] for i in range(n_b)]
    arx, *_ = np.linalg.lstsq(np.column_stack(columns), y[rows], rcond=None)

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate([np.zeros(delay), x[n_f:]]), np.concatenate([[1.0], x[:n_f]])

    def residual(x: np.ndarray) -> np.ndarray:
        b, f = unpack(x)
        if np.any(np.abs(np.roots(f)) >= 1.0):
            return np.full(y.size - skip, 1e6)
        return (scipy.signal.lfilter(b, f, u) - y)[skip:]

    sol = scipy.optimize.least_squares(residual, arx, method="trf")
    b, f = unpack(sol.x)
    if np.any(np.abs(np.roots(f)) >= 1.0):
        raise RuntimeError("output-error fit converged to an unstable model; check the orders and data")
    return OutputErrorModel(b, f, float(np.sqrt(np.mean(sol.fun**2))))


def model_features(model: OutputErrorModel, sample_rate: float) -> dict[str, object]:
    """Static gain B(1)/F(1) and the poles of F as continuous modes: natural frequency [Hz] and damping
    ratio from s = ln(z) fs (one entry per real pole or complex pair, slowest first)."""
    poles = np.roots(model.f)
    modes = []
    for z in poles[np.imag(poles) >= 0]:
        s = np.log(complex(z)) * sample_rate
        modes.append({"frequency_hz": float(abs(s) / (2 * np.pi)), "damping": float(-s.real / abs(s))})
    modes.sort(key=lambda m: m["frequency_hz"])
    return {"b": model.b.tolist(), "f": model.f.tolist(), "static_gain": float(np.sum(model.b) / np.sum(model.f)),
            "modes": modes, "rms_error": model.rms_error}


@dataclass(frozen=True)
class ClosedLoopIdentification:
    """Projection-method model (Bona eq. 12), the naive output-error model fitted on the measured input
    (biased in closed loop, for comparison) and the projection of the input on the reference."""

    projection_model: OutputErrorModel
    naive_model: OutputErrorModel
    projection: ProjectionResult


def identify_projection(
    reference: np.ndarray, u: np.ndarray, y: np.ndarray, n_b: int, n_f: int, *, delay: int = 1,
    n_noncausal: int = 0, n_causal: int = 100, periodic: bool = False, skip: int | None = None,
) -> ClosedLoopIdentification:
    """Projection method: u_hat = S_hat r (eqs. 10-11), then y = B/F u_hat by output error (eq. 12); the
    naive fit y = B/F u is returned beside it. ``skip`` (default ``n_causal``) initial samples are left out
    of both output-error costs (zero-state transient and the incomplete FIR regressors)."""
    skip = n_causal if skip is None else skip
    projection = project_on_reference(reference, u, n_noncausal, n_causal, periodic=periodic)
    return ClosedLoopIdentification(
        fit_output_error(projection.projected, y, n_b, n_f, delay=delay, skip=skip),
        fit_output_error(u, y, n_b, n_f, delay=delay, skip=skip),
        projection,
    )


def identify_projection_recording(recording: dict[str, np.ndarray], reference: str, input: str, output: str,
                                  n_b: int, n_f: int, delay: int = 1, n_noncausal: int = 0, n_causal: int = 100,
                                  periodic: bool = False, skip: int | None = None, source: str = "recording"
                                  ) -> tuple[ClosedLoopIdentification, float]:
    """The projection method on three columns of a closed-loop recording.

    Parameters
    ----------
    recording : mapping of column name to array
        Uniformly sampled closed-loop data with a ``time`` column [s].
    reference, input, output : str
        Columns of the reference r, the plant input u and the plant output y.
    n_b, n_f, delay, n_noncausal, n_causal, periodic, skip
        As in :func:`identify_projection` (``skip`` default: ``n_causal``).
    source : str
        Named in error messages (the file the recording came from).

    Returns
    -------
    ClosedLoopIdentification
        The projection-method and the naive output-error models.
    float
        The sample rate [Hz].

    Raises
    ------
    ValueError
        When the time column is not uniform, a column holds non-finite values, ``skip`` leaves too few
        samples, or the fit fails (naming ``source`` and the orders).
    """
    time = np.asarray(recording["time"], dtype=float)
    steps = np.diff(time)
    if steps.size < 1 or not np.all(steps > 0) or np.ptp(steps) > 1e-6 * np.median(steps):
        raise ValueError(f"{source}: column 'time' must be uniformly sampled (the projection is a discrete FIR)")
    skip = n_causal if skip is None else skip
    if skip >= time.size // 2:
        raise ValueError(f"skip {skip} (default n_causal) leaves too few of the {time.size} samples of {source}")
    signals = [np.asarray(recording[name], dtype=float) for name in (reference, input, output)]
    for name, values in zip((reference, input, output), signals):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{source}: column {name!r} holds non-finite values")
    try:
        result = identify_projection(*signals, n_b, n_f, delay=delay, n_noncausal=n_noncausal, n_causal=n_causal,
                                     periodic=periodic, skip=skip)
    except RuntimeError as exc:
        raise ValueError(f"{source}: {exc} (nb {n_b}, nf {n_f}, delay {delay})") from None
    return result, 1.0 / float(np.median(steps))
