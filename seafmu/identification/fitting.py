"""Shared fit result and statistics helpers for every identification method.

Every fit (static table, decay, step, maneuver) reports the same quantities so that the diagnosis
can compare candidate models on one scale; these helpers compute them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

NONIDENTIFIABLE_CORR = 0.95


@dataclass
class FitResult:
    """Outcome of one fit; the same shape for every trial kind and method."""

    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    correlation: np.ndarray
    param_names: list[str]
    nonidentifiable: list[tuple[str, str]]
    nrmse_fit: float
    nrmse_validation: float
    aic: float
    bic: float
    whiteness: dict[str, Any]
    warnings: list[str]
    n_samples: int
    method: str
    extras: dict[str, Any] = field(default_factory=dict)

    def fit_percent(self, validation: bool = False) -> float:
        """Fit % = 100 (1 − NRMSE), the number the system-identification literature quotes."""
        return 100.0 * (1.0 - (self.nrmse_validation if validation else self.nrmse_fit))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (numpy types converted)."""
        return {
            "params": {k: float(v) for k, v in self.params.items()},
            "ci95": {k: [float(a), float(b)] for k, (a, b) in self.ci95.items()},
            "correlation": np.asarray(self.correlation, dtype=float).tolist(),
            "param_names": list(self.param_names),
            "nonidentifiable": [list(p) for p in self.nonidentifiable],
            "nrmse_fit": _f(self.nrmse_fit),
            "nrmse_validation": _f(self.nrmse_validation),
            "aic": _f(self.aic),
            "bic": _f(self.bic),
            "whiteness": {k: _jsonable(v) for k, v in self.whiteness.items()},
            "warnings": list(self.warnings),
            "n_samples": int(self.n_samples),
            "method": self.method,
        }


def _f(x: float) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def _jsonable(v: Any) -> Any:
    if isinstance(v, (np.floating, float)):
        return _f(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def nrmse(y: np.ndarray, yhat: np.ndarray) -> float:
    """‖y − ŷ‖ / ‖y − ȳ‖ over all elements (columns of a 2-D y are pooled after centring each).

    Normalising by the signal's own spread makes runs and DOFs of different scale comparable;
    0 is perfect, 1 is no better than the mean.
    """
    y = np.asarray(y, dtype=float)
    yhat = np.asarray(yhat, dtype=float)
    if not np.all(np.isfinite(yhat)):
        return float("inf")  # a diverged simulation
    with np.errstate(over="ignore", invalid="ignore"):
        den = float(np.linalg.norm(y - (y.mean() if y.ndim == 1 else y.mean(axis=0))))
        num = float(np.linalg.norm(y - yhat))
    if not np.isfinite(num):
        return float("inf")
    if den == 0.0:
        return float("inf") if num > 0 else 0.0
    return float(num / den)


def rmse(residual: np.ndarray, n_params: int = 0) -> float:
    """sqrt(RSS / (n − p)); with p = 0 the plain RMSE. The tow-test figure uses n − p."""
    r = np.asarray(residual, dtype=float).ravel()
    dof = max(r.size - n_params, 1)
    return float(np.sqrt(np.sum(r**2) / dof))


def aic_bic(rss: float, n: int, k: int) -> tuple[float, float]:
    """Gaussian AIC and BIC from the residual sum of squares: n ln(RSS/n) + 2k (resp. k ln n)."""
    rss = max(float(rss), 1e-300)
    base = n * np.log(rss / n)
    return float(base + 2 * k), float(base + k * np.log(n))


def covariance_from_jacobian(jac: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Parameter covariance s² (JᵀJ)⁻¹ with s² = RSS/(n − p).

    Where the data cannot move the fit along some direction of the parameters (a singular value
    of J at rounding level: a saturation cap above every command, a parameter with no effect on
    the output), every parameter on that direction has an infinite variance — unidentifiable, not
    known exactly — and the rest of the covariance comes from the pseudo-inverse.
    """
    jac = np.asarray(jac, dtype=float)
    r = np.asarray(residual, dtype=float).ravel()
    n, p = jac.shape
    s2 = float(np.sum(r**2)) / max(n - p, 1)
    # vt holds every direction of the parameters (full_matrices only when rows < parameters: cheap)
    _, sv, vt = np.linalg.svd(jac, full_matrices=n < p)
    tol = np.finfo(float).eps * max(jac.shape) * (sv[0] if sv.size else 0.0)
    full = np.zeros(p)
    full[: sv.size] = sv
    ok = full > tol
    inv = np.where(ok, 1.0 / np.where(ok, full, 1.0) ** 2, 0.0)
    cov = s2 * (vt.T * inv) @ vt
    null = vt[~ok]  # directions the data do not determine
    if null.size:
        lost = np.any(np.abs(null) > 1e-8, axis=0)
        idx = np.flatnonzero(lost)
        cov[idx, idx] = np.inf  # off-diagonals keep the pseudo-inverse's (correlation_matrix)
    return cov


def confidence_intervals(
    names: list[str], values: np.ndarray, cov: np.ndarray, n: int, level: float = 0.95
) -> dict[str, tuple[float, float]]:
    """Student-t intervals from the covariance diagonal (n − p degrees of freedom)."""
    p = len(names)
    tq = float(stats.t.ppf(0.5 + level / 2, max(n - p, 1)))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {nm: (float(v - tq * s), float(v + tq * s)) for nm, v, s in zip(names, values, se, strict=True)}


def correlation_matrix(cov: np.ndarray) -> np.ndarray:
    """Correlation from covariance; zero-variance parameters get a unit diagonal. Two parameters of
    infinite variance (unidentifiable) that the pseudo-inverse still couples trade off exactly: +-1."""
    cov = np.asarray(cov, dtype=float)
    d = np.diag(cov)
    sd = np.sqrt(np.clip(d, 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    lost = ~np.isfinite(d)
    if np.count_nonzero(lost) > 1:
        both = np.outer(lost, lost)
        finite = np.where(np.isfinite(cov), cov, 0.0)
        corr = np.where(both & (finite != 0), np.sign(finite), corr)
    np.fill_diagonal(corr, 1.0)
    return np.clip(corr, -1.0, 1.0)


def nonidentifiable_pairs(
    names: list[str], corr: np.ndarray, threshold: float = NONIDENTIFIABLE_CORR
) -> list[tuple[str, str]]:
    """Parameter pairs whose |correlation| exceeds the threshold: the data cannot separate them."""
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > threshold:
                out.append((names[i], names[j]))
    return out


# the warning of a fit whose model diverges when simulated (maneuver fits); write-back refuses such a fit
DIVERGED = "the fitted model diverges when simulated against the trial"
DIVERGED_RESIDUAL = 1e3  # what a diverged simulation's residual is set to (normalised: far beyond any fit)


def lags(n: int, max_lag: int = 20) -> int:
    """The lags a whiteness test of n samples looks at: 1..min(max_lag, n/4)."""
    return int(min(max_lag, max(n // 4, 1)))


def white_noise_std(x: np.ndarray) -> np.ndarray:
    """Std of the white noise on a smooth signal, per column (a 1-D signal: a scalar array), from its
    second differences (6 sigma^2 for white noise; the median absolute deviation keeps the signal's
    own curvature and outliers out)."""
    d2 = np.diff(x, n=2, axis=0)
    return 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)


def ljung_box_q(r: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(Ljung–Box Q, autocorrelations at lags 1..k) of each column of r (n, c), mean removed;
    Q is nan for a column that is constant."""
    r = np.asarray(r, dtype=float)
    r = r - r.mean(axis=0)
    n = r.shape[0]
    den = np.einsum("ij,ij->j", r, r)
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = np.stack([np.einsum("ij,ij->j", r[:-lag], r[lag:]) for lag in range(1, k + 1)]) / den
    q = n * (n + 2) * np.sum(acf**2 / (n - np.arange(1, k + 1))[:, None], axis=0)
    return q, acf


def p_text(p: float, replicates: int) -> str:
    """'= 0.21', or '<= 0.005' at the smallest p-value a test of that many replicates resolves."""
    return f"<= {p:.2g}" if p <= 1.0 / (1 + replicates) else f"= {p:.2g}"


def noise_only_text(w: dict[str, Any]) -> str:
    """'Ljung-Box p <= 0.005 over 199 noise-only replicates' of a maneuver whiteness result."""
    n = w["noise_replicates"]
    return f"Ljung-Box p {p_text(w['noise_only_p'], n)} over {n} noise-only replicates"


def whiteness_test(residual: np.ndarray, max_lag: int = 20) -> dict[str, Any]:
    """Autocorrelation test of residuals over lags 1..k (k = min(max_lag, n/4)).

    White residuals mean the model explains all structure; a coloured residual says a dynamic
    effect is missing. Reports the fraction of lags whose ACF falls outside ±1.96/√n and the
    Ljung–Box p-value; "white" is the Ljung–Box test at the 1 % level (p >= 0.01).
    """
    r = np.asarray(residual, dtype=float).ravel()
    r = r[np.isfinite(r)]
    n = r.size
    k = lags(n, max_lag)
    if n < 8:
        return {"lags": 0, "fraction_outside": float("nan"), "ljung_box_p": float("nan"), "white": False}
    if float(np.ptp(r)) == 0.0:
        return {"lags": k, "fraction_outside": 0.0, "ljung_box_p": 1.0, "white": True}
    q, acf = ljung_box_q(r[:, None], k)
    frac = float(np.mean(np.abs(acf[:, 0]) > 1.96 / np.sqrt(n)))
    p_lb = float(stats.chi2.sf(float(q[0]), k))
    return {"lags": k, "fraction_outside": frac, "ljung_box_p": p_lb, "white": bool(p_lb >= 0.01)}


def fit_statistics(
    names: list[str],
    values: np.ndarray,
    jac: np.ndarray,
    residual: np.ndarray,
) -> tuple[dict[str, tuple[float, float]], np.ndarray, list[tuple[str, str]]]:
    """CIs, correlation and non-identifiable pairs from a Jacobian in one call."""
    cov = covariance_from_jacobian(jac, residual)
    n = np.asarray(residual).size
    ci = confidence_intervals(names, np.asarray(values, dtype=float), cov, n)
    corr = correlation_matrix(cov)
    return ci, corr, nonidentifiable_pairs(names, corr)


def correlation_warnings(names: list[str], corr: np.ndarray,
                         threshold: float = NONIDENTIFIABLE_CORR) -> list[str]:
    """One warning line per parameter pair the data cannot separate."""
    out = []
    for a, b in nonidentifiable_pairs(names, corr, threshold):
        r = float(corr[names.index(a), names.index(b)])
        out.append(f"{a} and {b} are correlated (r = {r:+.3f}): not separately identifiable from this data")
    return out


def unidentifiable_warnings(ci: dict[str, tuple[float, float]], names: list[str]) -> list[str]:
    """One warning per parameter with an infinite interval (the data do not determine it)."""
    return [f"{p} is not identifiable from this data (infinite variance): the fit cannot tell its value"
            for p in names if p in ci and not (np.isfinite(ci[p][0]) and np.isfinite(ci[p][1]))]


def ci_excludes_zero(ci: tuple[float, float]) -> bool:
    """True when the 95 % interval lies entirely on one side of zero (parameter significant)."""
    lo, hi = ci
    return bool((lo > 0 and hi > 0) or (lo < 0 and hi < 0))
