"""Statistics of a fit: residual autocorrelation (honest CIs), whiteness, physical sanity."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from seafmu.identification import fitting
from seafmu.identification.maneuver.preprocessing import _Prepared, noise_ratios
from seafmu.identification.maneuver.simulation import _one, _SimSetup
from seafmu.identification.maneuver.terms import _sym


def _autocorr_factors(residual: np.ndarray, max_lag: int = 2000) -> np.ndarray:
    """Per column, 1 + 2 sum(rho_k) up to the first non-positive lag: the factor by which correlated
    residuals shrink the effective sample size; NaN where a column cannot tell (under 8 finite
    samples, or constant)."""
    r = residual.reshape(residual.shape[0], -1)
    factors = np.full(r.shape[1], np.nan)
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
        factors[j] = 1.0 + 2.0 * float(np.sum(rho))
    return factors


def _autocorr_inflation(residual: np.ndarray, max_lag: int = 2000) -> float:
    """``_autocorr_factors`` averaged over the columns that tell: the factor by which correlated
    residuals widen honest CIs."""
    return _mean_factor(_autocorr_factors(residual, max_lag))


def _mean_factor(factors: np.ndarray) -> float:
    """The mean of the columns' factors that are known (1 where none is)."""
    f = factors[np.isfinite(factors)]
    return float(np.mean(f)) if f.size else 1.0


def _whiteness(residual: np.ndarray, names: list[str]) -> dict[str, Any]:
    """Ljung-Box per DOF against white noise (the null of an equation-error residual)."""
    per = {n: fitting.whiteness_test(residual[:, j]) for j, n in enumerate(names)}
    finite = [v for v in per.values() if v["lags"] > 0]
    return {
        "lags": max((v["lags"] for v in finite), default=0),
        "fraction_outside": max((v["fraction_outside"] for v in finite), default=float("nan")),
        "ljung_box_p": min((v["ljung_box_p"] for v in finite), default=float("nan")),
        "white": bool(finite) and all(v["white"] for v in finite),
        "per_dof": per,
    }


NOISE_REPLICATES = 199  # p-values down to 1/200: a 1 % test can reject
NOISE_CHUNK = 32  # replicates simulated at a time


def whiteness(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
              effect: dict[str, np.ndarray] | None, prep: _Prepared, residual: np.ndarray,
              names: list[str], replicates: int = NOISE_REPLICATES, seed: int = 0) -> dict[str, Any]:
    """Does the simulation residual hold structure the model misses? Tested against what sensor
    noise alone leaves, not against white noise.

    Why: the residual of a simulation restarted from measured states is never white, even for the
    true model on a clean log: each segment starts from a noisy state, and the model carries that
    error forward with its own time constants (a yaw rate's over seconds), so a plain Ljung-Box
    test flags structure in every log long enough. The null here is a parametric bootstrap of that
    very procedure: the fitted model's own trajectories, measured with white noise of the std
    estimated from the log (``noise_ratios``) and restarted from states as noisy as the smoother
    leaves them (``_Prepared.noise_gain``). A DOF is white when its Ljung-Box Q is not above
    what 1 % of those noise-only residuals reach (``noise_only_p`` >= 0.01). ``replicates=0``: the
    plain test only (a diagnosis's candidate fits: ``fit.complete_whiteness``)."""
    plain = _whiteness(residual, names)
    finite = bool(np.all(np.isfinite(residual))) and not np.any(np.abs(residual) >= fitting.DIVERGED_RESIDUAL)
    if plain["white"] or not finite or plain["lags"] == 0 or replicates == 0:
        return plain
    d = len(names)
    k = plain["lags"]
    q_real, _ = fitting.ljung_box_q(residual, k)
    key = (k, replicates, seed)
    if key not in setup.noise_q:
        setup.noise_q[key] = _noise_only_q(setup, M, DL, DQ, effect, prep, d, k, replicates, seed)
    q_null = setup.noise_q[key]
    p = (1 + np.sum(q_null >= q_real[None], axis=0)) / (1 + q_null.shape[0])
    for j, n in enumerate(names):
        plain["per_dof"][n]["noise_only_p"] = float(p[j])
        plain["per_dof"][n]["white"] = bool(p[j] >= 0.01)
    plain["noise_only_p"] = float(np.min(p))
    plain["noise_replicates"] = int(q_null.shape[0])
    plain["white"] = bool(np.all(p >= 0.01))
    plain["null"] = ("the residuals sensor noise alone leaves (parametric bootstrap of the restarted "
                     "simulation, noise std from the log)")
    return plain


def _noise_only_q(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                  effect: dict[str, np.ndarray] | None, prep: _Prepared, d: int, k: int, replicates: int,
                  seed: int) -> np.ndarray:
    """Ljung-Box Q per DOF (B, d) of ``replicates`` noise-only residuals of this model on this log
    (``whiteness``). Made by the first fit of a log and reused by the others (the setup keeps it):
    it costs 199 simulations of the log (a third of a 6-DOF diagnosis when every candidate made
    its own), and what it measures, noise in the restart states and the samples carried forward
    by the hull's dynamics, differs little between a baseline and its extension by one effect."""
    sigma = noise_ratios(prep.nu_raw) * prep.nu_raw.std(axis=0)  # white noise std per DOF, physical
    rng = np.random.default_rng(seed)
    one = _one(effect)
    x = setup.sim.run(M[None], DL[None], DQ[None], **one)[0]  # (S, L+1, nx): the model's trajectories
    x0 = np.repeat(x[None, :, 0], replicates, axis=0)
    x0[..., -d:] += rng.standard_normal(x0[..., -d:].shape) * (sigma * prep.noise_gain)
    n = int(setup.mask.sum())
    q = np.empty((replicates, d))
    # a few replicates at a time: the states and the noise of all 199 at once were ~150 MB for a
    # 10 000-sample log, written once and read once; the noise is drawn in the same order either way
    for a in range(0, replicates, NOISE_CHUNK):
        b = min(a + NOISE_CHUNK, replicates)

        def rep(v: np.ndarray, m: int = b - a) -> np.ndarray:
            return np.repeat(v, m, axis=0)

        xs = setup.sim.run(rep(M[None]), rep(DL[None]), rep(DQ[None]), x0=x0[a:b],
                           **{key: rep(v) for key, v in one.items()})
        q[a:b] = _noise_q(xs, x, setup.mask, rng.standard_normal((b - a, n, d)), sigma, setup.scale, k)
    return q[np.all(np.isfinite(q), axis=1)]  # a replicate that diverged says nothing


@numba.njit(cache=True, nogil=True)
def _noise_q(xs: np.ndarray, x: np.ndarray, mask: np.ndarray, eps: np.ndarray, sigma: np.ndarray,
             scale: np.ndarray, k: int) -> np.ndarray:
    """Ljung-Box Q (B, d) of each replicate's residual (xs[b] - x - sigma eps[b]) / scale over the
    compared samples (``mask``), as ``fitting.ljung_box_q`` of each column; NaN for a replicate with
    a non-finite sample. Why compiled: in NumPy the (B, N, d) residual and its lagged products were
    ~0.6 s of a 6-DOF diagnosis (199 replicates of 7000 samples), here one pass per column."""
    B, S, L1, nx = xs.shape
    d = sigma.size
    n = eps.shape[1]
    out = np.empty((B, d))
    buf = np.empty(n)
    for b in range(B):
        for j in range(d):
            c = nx - d + j
            m, tot = 0, 0.0
            for s in range(S):
                for i in range(L1):
                    if mask[s, i]:
                        v = (xs[b, s, i, c] - x[s, i, c] - eps[b, m, j] * sigma[j]) / scale[j]
                        buf[m] = v
                        tot += v
                        m += 1
            if not math.isfinite(tot):
                out[b, :] = np.nan
                break
            mean = tot / n
            den = 0.0
            for i in range(n):
                buf[i] -= mean
                den += buf[i] * buf[i]
            q = 0.0
            for lag in range(1, k + 1):
                a = 0.0
                for i in range(n - lag):
                    a += buf[i] * buf[i + lag]
                q += (a / den) ** 2 / (n - lag)
            out[b, j] = n * (n + 2) * q
    return out


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
