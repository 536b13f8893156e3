"""(Weighted) Gauss-Markov least squares with parameter statistics and identifiability checks.

Solves Gamma = Psi p + eta (Abdellatif eqs. 8-11): p_hat = (Psi^T S^-1 Psi)^-1 Psi^T S^-1 Gamma with
covariance P = (Psi^T S^-1 Psi)^-1, standard deviations, correlation matrix rho and its condition number
(the criterion Abdellatif uses to choose a friction parametrisation). A rank-deficient regressor raises
UnidentifiableError naming the parameters (and linear combinations) the data cannot determine, instead
of returning a silent wrong answer. base_parameters() regroups parameters into an identifiable base set
by QR with column pivoting (Gautier & Khalil's numerical method, Bona sec. 2.1).

Coloured residuals: P assumes white noise of the stated (or estimated) variance. Model error and loop
dynamics colour the residual, and then P is too small by roughly the residual's correlation time in samples.
Every fit therefore also carries a heteroskedasticity- and autocorrelation-consistent (HAC) sandwich
covariance, ``robust_covariance`` = B^-1 S B^-1 with B = Psi^T Psi (whitened) and S the Newey-West (Bartlett
kernel) long-run covariance of the scores psi_k e_k, its bandwidth chosen by Andrews' (1991) AR(1) plug-in
rule (:func:`hac_covariance`); for white residuals it agrees with P within sampling error.

Units: whatever the caller's regressor and measurement use; the covariance is in (parameter unit)^2.
Rows of a stacked multi-channel problem are sample-major: row = sample * n_channels + channel.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

__all__ = [
    "UnidentifiableError",
    "andrews_bandwidth",
    "hac_covariance",
    "IdentifiabilityReport",
    "check_identifiability",
    "LeastSquaresResult",
    "gauss_markov",
    "BaseParameters",
    "base_parameters",
]

DEFAULT_RCOND = 1e-8


class UnidentifiableError(ValueError):
    """The data do not determine some parameters; ``parameters`` lists their names."""

    def __init__(self, message: str, parameters: list[str], null_directions: list[str]):
        super().__init__(message)
        self.parameters = parameters
        self.null_directions = null_directions


@dataclass(frozen=True)
class IdentifiabilityReport:
    """Rank analysis of a regressor with columns scaled to unit norm.

    rank: numerical rank; singular_values: of the column-scaled regressor, descending;
    unidentifiable: names of parameters involved in a null direction;
    null_directions: each null direction as readable text, e.g. '0.707*J - 0.707*m' (scaled units).
    """

    rank: int
    n_parameters: int
    singular_values: np.ndarray
    unidentifiable: list[str]
    null_directions: list[str]

    @property
    def identifiable(self) -> bool:
        return self.rank == self.n_parameters

    def message(self) -> str:
        """One readable sentence naming what the data cannot determine."""
        if self.identifiable:
            return f"all {self.n_parameters} parameters are identifiable"
        return (
            f"regressor is rank deficient (rank {self.rank} of {self.n_parameters}): the data do not "
            f"determine {', '.join(repr(n) for n in self.unidentifiable)}; "
            f"unexcited directions (column-scaled): {'; '.join(self.null_directions)}. "
            "Excite the motion that makes these columns vary (e.g. both velocity signs, acceleration), "
            "or remove/regroup these parameters."
        )


def _names(names: Sequence[str] | None, n: int) -> list[str]:
    if names is None:
        return [f"p{i}" for i in range(n)]
    names = list(names)
    if len(names) != n:
        raise ValueError(f"{len(names)} parameter names given for a regressor with {n} columns")
    return names


def _describe_direction(vector: np.ndarray, names: list[str], tol: float = 1e-3) -> tuple[list[str], str]:
    vector = vector / vector[np.argmax(np.abs(vector))]
    involved = [i for i in np.argsort(-np.abs(vector)) if abs(vector[i]) > tol]
    if len(involved) == 1:
        return [names[involved[0]]], f"{names[involved[0]]!r} has no effect on the data"
    terms = " ".join(f"{'+' if vector[i] >= 0 else '-'} {abs(vector[i]):.3g}*{names[i]}" for i in involved)
    return [names[i] for i in involved], terms.lstrip("+ ")


def _scaled_svd(regressor: np.ndarray):
    norms = np.linalg.norm(regressor, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    u, s, vt = np.linalg.svd(regressor / scale, full_matrices=False)
    return scale, u, s, vt, norms


def _report(s: np.ndarray, vt: np.ndarray, norms: np.ndarray, names: list[str], rcond: float):
    threshold = rcond * max(s[0], np.finfo(float).tiny) if s.size else 0.0
    null = [k for k in range(len(s)) if s[k] <= threshold]
    zero_columns = [i for i in range(len(names)) if norms[i] == 0.0]
    unidentifiable: list[str] = []
    directions: list[str] = []
    for i in zero_columns:
        unidentifiable.append(names[i])
        directions.append(f"{names[i]!r} has no effect on the data (its regressor column is zero)")
    for k in null:
        v = vt[k].copy()
        v[zero_columns] = 0.0
        if np.max(np.abs(v)) < 1e-6:
            continue
        involved, text = _describe_direction(v, names)
        unidentifiable.extend(n for n in involved if n not in unidentifiable)
        directions.append(text)
    rank = len(s) - len(null)
    return IdentifiabilityReport(rank, len(names), s, unidentifiable, directions)


def check_identifiability(
    regressor: np.ndarray, names: Sequence[str] | None = None, *, rcond: float = DEFAULT_RCOND
) -> IdentifiabilityReport:
    """Numerical rank of the column-scaled regressor and the parameters spanning its null space.

    Singular values below ``rcond`` times the largest count as zero. Column scaling makes the test
    independent of parameter units.
    """
    psi = np.asarray(regressor, dtype=float)
    if psi.ndim != 2:
        raise ValueError(f"regressor must be 2-D (rows x parameters), got shape {psi.shape}")
    labels = _names(names, psi.shape[1])
    _, _, s, vt, norms = _scaled_svd(psi)
    return _report(s, vt, norms, labels, rcond)


@dataclass(frozen=True)
class LeastSquaresResult:
    """Gauss-Markov estimate and its statistics.

    estimate: p_hat; covariance: P = (Psi^T S^-1 Psi)^-1 (times residual_variance_factor when the noise
    level was estimated from the residuals); std: sqrt(diag P); relative_std: std/|p_hat|;
    correlation: rho_ij = P_ij / sqrt(P_ii P_jj) (Abdellatif eq. 11); correlation_condition: cond(rho);
    weighted_rss: whitened residual sum of squares; dof: rows - parameters;
    residual_variance_factor: weighted_rss/dof (close to 1 when the stated noise covariance is right);
    noise_known: True if a noise covariance was given (covariance not rescaled);
    regressor_condition: cond of the raw (unweighted) regressor, from its Gram matrix (a diagnostic,
    accurate up to ~1e7; identifiability is decided on the column-scaled SVD instead);
    robust_covariance: HAC (Newey-West) sandwich covariance that holds for coloured residuals, or None;
    robust_lags: its Bartlett bandwidth [samples]; robust_std: sqrt(diag robust_covariance) (NaN if None);
    at_bound: parameters held on a bound of a bounded fit (name: bound value): no statistics of their own (std,
    relative std NaN, zero rows in the covariances, which are those of the others conditional on them).
    """

    estimate: np.ndarray
    covariance: np.ndarray
    names: list[str]
    weighted_rss: float
    dof: int
    noise_known: bool
    regressor_condition: float
    robust_covariance: np.ndarray | None = None
    robust_lags: int | None = None
    at_bound: dict[str, float] = field(default_factory=dict)
    std: np.ndarray = field(init=False)
    relative_std: np.ndarray = field(init=False)
    correlation: np.ndarray = field(init=False)
    correlation_condition: float = field(init=False)

    def __post_init__(self) -> None:
        held = np.array([n in self.at_bound for n in self.names], dtype=bool)
        std = np.where(held, np.nan, np.sqrt(np.abs(np.diag(self.covariance))))
        object.__setattr__(self, "std", std)
        with np.errstate(divide="ignore", invalid="ignore"):
            object.__setattr__(self, "relative_std", std / np.abs(self.estimate))
        corr = np.eye(len(self.names))
        free = np.flatnonzero(~held)
        corr[np.ix_(free, free)] = self.covariance[np.ix_(free, free)] / np.outer(std[free], std[free])
        object.__setattr__(self, "correlation", corr)
        object.__setattr__(self, "correlation_condition",
                           float(np.linalg.cond(corr[np.ix_(free, free)])) if free.size else 1.0)

    @property
    def robust_std(self) -> np.ndarray:
        """HAC standard deviations (coloured residuals), NaN when not computed."""
        if self.robust_covariance is None:
            return np.full(len(self.names), np.nan)
        return np.sqrt(np.diag(self.robust_covariance))

    @property
    def residual_variance_factor(self) -> float:
        return self.weighted_rss / self.dof if self.dof > 0 else float("nan")

    def as_dict(self) -> dict[str, float]:
        """Estimate by parameter name."""
        return dict(zip(self.names, self.estimate.tolist()))

    def confidence_interval(self, level: float = 0.95) -> np.ndarray:
        """Two-sided normal confidence intervals, shape (n_parameters, 2)."""
        from scipy.stats import norm

        z = norm.ppf(0.5 + level / 2)
        return np.column_stack([self.estimate - z * self.std, self.estimate + z * self.std])

    def summary(self) -> str:
        """Plain-text table: name, estimate, std, relative std in %, and the HAC std when computed."""
        robust = self.robust_covariance is not None
        lines = [f"{'parameter':>12} {'estimate':>13} {'std':>11} {'rel.std %':>9}"
                 + (f" {'HAC std':>11} {'HAC rel %':>9}" if robust else "")]
        for name, p, s, h in zip(self.names, self.estimate, self.std, self.robust_std):
            if name in self.at_bound:
                lines.append(f"{name:>12} {p:13.6g} {'at bound ' + format(self.at_bound[name], '.6g'):>21}"
                             + (f" {'at bound':>21}" if robust else ""))
                continue
            line = f"{name:>12} {p:13.6g} {s:11.3g} {_percent(s, p)}"
            lines.append(line + (f" {h:11.3g} {_percent(h, p)}" if robust else ""))
        lines.append(
            f"cond(correlation) = {self.correlation_condition:.3g}, cond(regressor) = "
            f"{self.regressor_condition:.3g}, weighted RSS/dof = {self.residual_variance_factor:.3g}"
        )
        if robust:
            lines.append(f"HAC std: Newey-West sandwich, Bartlett bandwidth {self.robust_lags} samples "
                         "(holds for coloured residuals; std assumes white noise)")
        return "\n".join(lines)


def _percent(std: float, estimate: float) -> str:
    """100 std/|estimate| in a 9-wide column; beyond 1e5 % (an estimate near zero) '>1e5', not an absurd ratio."""
    if not np.isfinite(std):
        return f"{'-':>9}"
    ratio = 100 * std / abs(estimate) if estimate else np.inf
    return f"{ratio:9.3f}" if ratio <= 1e5 else f"{'>1e5':>9}"


def andrews_bandwidth(scores: np.ndarray) -> float:
    """Andrews' (1991) AR(1) plug-in bandwidth of the Bartlett kernel for the score series (rows = samples).

    Each column gets an AR(1) fit (rho_a, innovation variance s_a^2); alpha = sum 4 rho^2 s^4 / ((1-rho)^6
    (1+rho)^2) / sum s^4 / (1-rho)^4 and the bandwidth is 1.1447 (alpha n)^(1/3) samples.
    """
    v = np.asarray(scores, dtype=float)
    v = v[:, None] if v.ndim == 1 else v
    x0, x1 = v[:-1], v[1:]
    ss = np.einsum("ij,ij->j", x0, x0)
    used = ss > 0
    if not np.any(used):
        return 0.0
    rho = np.clip(np.einsum("ij,ij->j", x0, x1)[used] / ss[used], -0.97, 0.97)
    s2 = np.mean((x1[:, used] - rho * x0[:, used]) ** 2, axis=0)
    denominator = float(np.sum(s2**2 / (1 - rho) ** 4))
    alpha = float(np.sum(4 * rho**2 * s2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2))) / denominator
    return 1.1447 * (alpha * v.shape[0]) ** (1 / 3)


def hac_covariance(regressor: np.ndarray, residual: np.ndarray, *, lags: int | None = None,
                   rows_per_sample: int = 1, bread: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Newey-West HAC sandwich covariance of a least-squares estimate, and the bandwidth used.

    Parameters
    ----------
    regressor : (rows, parameters) whitened regressor (or residual Jacobian) Psi at the estimate.
    residual : (rows,) whitened residual e at the estimate.
    lags : Bartlett bandwidth L [samples]; None: Andrews' AR(1) plug-in (:func:`andrews_bandwidth`).
    rows_per_sample : channels stacked sample-major per time sample (their scores are summed per sample).
    bread : (Psi^T Psi)^-1 if the caller has it (computed here otherwise).

    Returns
    -------
    (covariance, lags): (Psi^T Psi)^-1 S (Psi^T Psi)^-1 with S = G_0 + sum_{l=1}^{L} (1 - l/(L+1)) (G_l + G_l^T),
    G_l = sum_k g_k g_{k-l}^T, g_k = Psi_k^T e_k; it is consistent for residuals correlated over time.
    S is computed as sum_t h_t h_t^T / (L+1) with the moving sums h_t = g_t + ... + g_{t-L} over the zero-padded
    scores, which is the Bartlett sum exactly (the kernel is the autocorrelation of a box of L+1 ones), at the
    cost of one product instead of L.
    """
    psi = np.asarray(regressor, dtype=float)
    e = np.asarray(residual, dtype=float).reshape(-1)
    if psi.ndim != 2 or psi.shape[0] != e.size:
        raise ValueError(f"regressor {psi.shape} and residual {e.shape} do not match")
    scores = psi * e[:, None]
    if rows_per_sample > 1:
        scores = scores.reshape(-1, rows_per_sample, psi.shape[1]).sum(axis=1)
    n = scores.shape[0]
    if lags is None:
        lags = int(np.floor(andrews_bandwidth(scores)))
    lags = int(min(max(lags, 0), n - 1))
    if lags:
        padded = np.vstack([np.zeros((1, scores.shape[1])), scores, np.zeros((lags, scores.shape[1]))])
        cumulative = np.cumsum(padded, axis=0)
        ends = np.arange(1, n + lags + 1)
        moving = cumulative[ends] - cumulative[np.maximum(ends - lags - 1, 0)]
        long_run = moving.T @ moving / (lags + 1)
    else:
        long_run = scores.T @ scores
    if bread is None:
        col = np.linalg.norm(psi, axis=0)
        col = np.where(col > 0, col, 1.0)
        bread = np.linalg.inv((psi / col).T @ (psi / col)) / np.outer(col, col)
    return bread @ long_run @ bread, lags


def _whiten(psi, gamma, noise_covariance, channel_covariance):
    n = psi.shape[0]
    if noise_covariance is not None and channel_covariance is not None:
        raise ValueError("give noise_covariance or channel_covariance, not both")
    if channel_covariance is not None:
        sigma = np.atleast_2d(np.asarray(channel_covariance, dtype=float))
        m = sigma.shape[0]
        if sigma.shape != (m, m) or n % m:
            raise ValueError(
                f"channel_covariance shape {sigma.shape} does not fit {n} sample-major rows"
            )
        inv_chol = np.linalg.inv(np.linalg.cholesky(sigma))
        psi_w = np.einsum("ij,njp->nip", inv_chol, psi.reshape(n // m, m, -1)).reshape(n, -1)
        gamma_w = np.einsum("ij,nj->ni", inv_chol, gamma.reshape(n // m, m)).reshape(n)
        return psi_w, gamma_w
    if noise_covariance is None:
        return psi, gamma
    cov = np.asarray(noise_covariance, dtype=float)
    if cov.ndim == 0:
        if cov <= 0:
            raise ValueError(f"noise variance must be > 0, got {float(cov)}")
        w = 1.0 / np.sqrt(cov)
        return psi * w, gamma * w
    if cov.ndim == 1:
        if cov.shape != (n,) or np.any(cov <= 0):
            raise ValueError(f"noise variances must be {n} positive values, got shape {cov.shape}")
        w = 1.0 / np.sqrt(cov)
        return psi * w[:, None], gamma * w
    if cov.shape != (n, n):
        raise ValueError(f"noise_covariance must be ({n}, {n}), got {cov.shape}")
    import scipy.linalg  # here: the output-error path never whitens, and scipy.linalg costs its import

    chol = np.linalg.cholesky(cov)
    return (
        scipy.linalg.solve_triangular(chol, psi, lower=True),
        scipy.linalg.solve_triangular(chol, gamma, lower=True),
    )


def gauss_markov(
    regressor: np.ndarray,
    measurement: np.ndarray,
    *,
    names: Sequence[str] | None = None,
    noise_covariance: float | np.ndarray | None = None,
    channel_covariance: np.ndarray | None = None,
    rcond: float = DEFAULT_RCOND,
) -> LeastSquaresResult:
    """Gauss-Markov (weighted) least squares of ``measurement = regressor @ p + noise``.

    Noise model, one of:
      - nothing: ordinary least squares, noise variance estimated from the residuals;
      - ``noise_covariance``: a variance, per-row variances (1-D), or the full row covariance (2-D);
      - ``channel_covariance``: (m, m) covariance of the m channels of one sample, rows sample-major
        (block-diagonal Sigma_eta_eta of Abdellatif, e.g. PeriodAverage.mean_covariance).

    Raises UnidentifiableError (naming the parameters) if the whitened regressor is rank deficient.
    """
    psi = np.asarray(regressor, dtype=float)
    gamma = np.asarray(measurement, dtype=float).reshape(-1)
    if psi.ndim != 2:
        raise ValueError(f"regressor must be 2-D (rows x parameters), got shape {psi.shape}")
    if psi.shape[0] != gamma.shape[0]:
        raise ValueError(f"regressor has {psi.shape[0]} rows but measurement has {gamma.shape[0]}")
    for label, arr in (("regressor", psi), ("measurement", gamma)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise ValueError(f"{label} has a non-finite value at index {tuple(int(i) for i in bad)}")
    labels = _names(names, psi.shape[1])
    if psi.shape[0] < psi.shape[1]:
        raise UnidentifiableError(
            f"{psi.shape[0]} equations for {psi.shape[1]} parameters: not enough data",
            labels,
            [],
        )
    psi_w, gamma_w = _whiten(psi, gamma, noise_covariance, channel_covariance)
    n_par = psi.shape[1]
    norms = np.linalg.norm(psi_w, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    # QR of [Psi_w/scale | Gamma_w] (R only): Q^T Gamma and the residual norm come for free, and the
    # SVD of the small triangular factor gives the same singular values as the tall matrix
    r_aug = np.linalg.qr(np.column_stack([psi_w / scale, gamma_w]), mode="r")
    u, s, vt = np.linalg.svd(r_aug[:n_par, :n_par])
    report = _report(s, vt, norms, labels, rcond)
    if not report.identifiable:
        raise UnidentifiableError(report.message(), report.unidentifiable, report.null_directions)
    estimate = (vt.T @ ((u.T @ r_aug[:n_par, n_par]) / s)) / scale
    rss = float(r_aug[n_par, n_par] ** 2) if r_aug.shape[0] > n_par else 0.0
    dof = psi.shape[0] - n_par
    unscaled_cov = (vt.T / s**2) @ vt / np.outer(scale, scale)
    noise_known = noise_covariance is not None or channel_covariance is not None
    covariance = unscaled_cov if noise_known else unscaled_cov * (rss / dof if dof > 0 else np.nan)
    gram_eig = np.linalg.eigvalsh(psi.T @ psi)
    regressor_condition = float(np.sqrt(gram_eig[-1] / gram_eig[0])) if gram_eig[0] > 0 else float("inf")
    rows_per_sample = 1 if channel_covariance is None else np.atleast_2d(channel_covariance).shape[0]
    robust, lags = hac_covariance(psi_w, gamma_w - psi_w @ estimate, rows_per_sample=rows_per_sample,
                                  bread=unscaled_cov)
    return LeastSquaresResult(
        estimate, covariance, labels, rss, dof, noise_known, regressor_condition, robust, lags
    )


@dataclass(frozen=True)
class BaseParameters:
    """An identifiable regrouping: theta_base = theta[independent] + beta @ theta[dependent].

    independent / dependent: column indices into the full parameter vector;
    beta: (n_independent, n_dependent) regrouping coefficients; names: readable base-parameter names.
    """

    independent: np.ndarray
    dependent: np.ndarray
    beta: np.ndarray
    names: list[str]

    def reduce_regressor(self, regressor: np.ndarray) -> np.ndarray:
        """Columns of the base regressor."""
        return np.asarray(regressor)[:, self.independent]

    def from_full(self, parameters: np.ndarray) -> np.ndarray:
        """Base parameters that a full (e.g. CAD) parameter vector maps to."""
        p = np.asarray(parameters, dtype=float)
        return p[self.independent] + self.beta @ p[self.dependent]


def base_parameters(
    regressor: np.ndarray, names: Sequence[str] | None = None, *, rcond: float = 1e-8
) -> BaseParameters:
    """Base parameter set by QR with column pivoting of the column-scaled regressor.

    The regressor should come from a rich random trajectory so that only structural (not excitation)
    dependencies remain. Dependent columns satisfy Psi_dep = Psi_indep @ beta.
    """
    psi = np.asarray(regressor, dtype=float)
    labels = _names(names, psi.shape[1])
    norms = np.linalg.norm(psi, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    import scipy.linalg

    _, r, perm = scipy.linalg.qr(psi / scale, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > rcond * diag[0])) if diag.size and diag[0] > 0 else 0
    independent, dependent = perm[:rank], perm[rank:]
    beta_scaled = scipy.linalg.solve_triangular(r[:rank, :rank], r[:rank, rank:])
    beta = beta_scaled / scale[independent][:, None] * scale[dependent][None, :]
    beta[np.abs(beta) < 1e-10 * max(1.0, np.max(np.abs(beta), initial=0.0))] = 0.0
    order = np.argsort(independent)
    independent, beta = independent[order], beta[order]
    base_names = []
    for i, col in enumerate(independent):
        terms = [labels[col]] + [
            f"{'+' if beta[i, j] >= 0 else '-'} {abs(beta[i, j]):.6g}*{labels[d]}"
            for j, d in enumerate(dependent)
            if beta[i, j] != 0.0
        ]
        base_names.append(" ".join(terms))
    return BaseParameters(independent, np.asarray(dependent), beta, base_names)
