"""Statistics of a fit: residual autocorrelation (honest CIs), whiteness, physical sanity."""

from __future__ import annotations

from typing import Any

import numpy as np

from seafmu.identification import fitting
from seafmu.identification.maneuver.terms import _sym


def _autocorr_inflation(residual: np.ndarray, max_lag: int = 2000) -> float:
    """1 + 2 sum(rho_k) up to the first non-positive lag, averaged over columns: the factor by
    which correlated residuals shrink the effective sample size (and widen honest CIs)."""
    r = residual.reshape(residual.shape[0], -1)
    factors = []
    for j in range(r.shape[1]):
        x = r[:, j][np.isfinite(r[:, j])]
        if x.size < 8:
            continue
        x = x - x.mean()
        nfft = 1 << int(np.ceil(np.log2(2 * x.size)))
        f = np.fft.rfft(x, nfft)
        acf = np.fft.irfft(f * np.conj(f), nfft)[: min(max_lag, x.size // 4)]
        if acf[0] <= 0.0:
            continue
        rho = acf[1:] / acf[0]
        stop = np.flatnonzero(rho <= 0.0)
        rho = rho[: stop[0]] if stop.size else rho
        factors.append(1.0 + 2.0 * float(np.sum(rho)))
    return float(np.mean(factors)) if factors else 1.0


def _whiteness(residual: np.ndarray, names: list[str]) -> dict[str, Any]:
    per = {n: fitting.whiteness_test(residual[:, j]) for j, n in enumerate(names)}
    finite = [v for v in per.values() if v["lags"] > 0]
    return {
        "lags": max((v["lags"] for v in finite), default=0),
        "fraction_outside": max((v["fraction_outside"] for v in finite), default=float("nan")),
        "ljung_box_p": min((v["ljung_box_p"] for v in finite), default=float("nan")),
        "white": bool(finite) and all(v["white"] for v in finite),
        "per_dof": per,
    }


def _sanity(M: np.ndarray, D_L: np.ndarray, D_Q: np.ndarray, M_RB: np.ndarray,
            ci: dict[str, tuple[float, float]], nu_rms: np.ndarray, names: list[str],
            fitted: set[str]) -> list[str]:
    """Physical sanity of an identified model, one warning per problem (brief section 2)."""
    out = []
    d = M.shape[0]

    def below(key: str, value: float, bound: float, what: str) -> str | None:
        """A warning when value < bound; 'significant' only if the whole CI is below it."""
        if value >= bound:
            return None
        lo, hi = ci.get(key, (value, value))
        if hi < bound:
            return f"{what}: unphysical (significant: 95 % CI [{lo:.4g}, {hi:.4g}] below {bound:.4g})"
        return (f"{what}, but not significantly (95 % CI [{lo:.4g}, {hi:.4g}] reaches {bound:.4g}): "
                "consistent with the physical bound")

    for i in range(d):
        for label, mat in (("linear", D_L), ("quadratic", D_Q)):
            key = f"D_{'L' if label == 'linear' else 'Q'}[{i},{i}]"
            if key in fitted:
                w = below(key, mat[i, i], 0.0, f"negative {label} damping {key} = {mat[i, i]:.4g} in "
                          f"{names[i]} (the force pushes along the motion)")
                if w:
                    out.append(w)
        key = f"M[{i},{i}]"
        if key in fitted:
            w = below(key, M[i, i], M_RB[i, i], f"negative added mass in {names[i]}: {key} = {M[i, i]:.4g} "
                      f"< rigid-body {M_RB[i, i]:.4g}")
            if w:
                out.append(w)
    ev = np.linalg.eigvalsh(_sym(M))
    if np.any(ev <= 0):
        out.append(f"identified mass matrix is not positive definite (smallest eigenvalue {ev.min():.4g}): "
                   "the model cannot be simulated")
    D_eq = _sym(D_L + 2.0 * D_Q * np.abs(nu_rms)[None, :])
    evd = np.linalg.eigvalsh(D_eq)
    if np.any(evd < 0):
        out.append(f"damping linearised at the trial's rms speeds has a negative eigenvalue "
                   f"({evd.min():.4g}): the fitted model injects energy in some direction (unstable drift)")
    return out


def _is_diag(name: str) -> bool:
    """True for a diagonal matrix entry 'X[i,i]' (effect parameters are not matrix entries)."""
    if "[" not in name or "," not in name:
        return False
    i, j = name[name.index("[") + 1 : -1].split(",")
    return i == j


def _rel_halfwidth(ci: tuple[float, float], value: float) -> float:
    return 0.5 * (ci[1] - ci[0]) / max(abs(value), 1e-300)
