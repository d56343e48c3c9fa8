"""95 % intervals of an output-error fit whose residuals are not white.

``fit_timeseries`` reports s^2 (J^T J)^-1, the least-squares covariance for white residuals. A test
plan's residuals are not white: a velocity differentiated from position fixes (Savitzky-Golay over
15 % of the release) carries noise correlated over tens of samples, and the 1-DOF model's misfit
(whatever of the held DOFs' motion the file's model does not remove) is slow. The white-noise
intervals of the supply's X_u, Y_v and N_r all missed the file's values (X_u +0.10 % outside
+-0.06 %); for a straight line under noise correlated like a Savitzky-Golay slope's they hold the
true slope in a quarter of the records (``tests/test_testplan.py``). Two estimates that do not
assume whiteness, the wider one per parameter taken:

- **sensor noise, propagated**: ``NOISE_DRAWS`` realisations of the file's sensor noise, processed
  as the measurement was (``measure.noise_draws``), mapped through the fit's linearisation
  (d theta = J^+ d y): the spread the stated noise alone gives, autocorrelation included; a noise
  that enters as an input comes in as the model's response to it (``more_draws``);
- **the residuals, autocorrelation-robust** (Newey-West): (J^T J)^-1 S (J^T J)^-1 with S the
  Bartlett-weighted long-run covariance of the scores J_t r_t, per run, the bandwidth the lag where
  the residuals' autocorrelation has died out (at least the noise's correlation length): what the
  record itself says, model misfit included.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from seafmu.identification.fitting import FitResult
from seafmu.identification.timeseries import IC_NAMES, simulate

NOISE_DRAWS = 400
NOISE_SEED = 1
Z95 = 1.959963984540054


def fit_theta(fit: FitResult) -> tuple[list[str], np.ndarray, int]:
    """A time-series fit's parameter vector: its free parameters, then every fit run's initial state."""
    model = fit.extras["model"]
    vals = fit.extras["values"]
    ics = fit.extras["initial_states"]
    names = list(model.free) + [f"{n}[{i}]" for i in range(len(ics)) for n in IC_NAMES[model.family]]
    theta = np.array([float(vals[q]) for q in model.free] + [float(x) for ic in ics for x in ic])
    return names, theta, len(model.free)


def fit_outputs(fit: FitResult) -> Callable[[np.ndarray], list[np.ndarray]]:
    """theta -> the fitted model's output on every fit run (free parameters, then initial states)."""
    model = fit.extras["model"]
    nfree = len(model.free)
    nic = len(IC_NAMES[model.family])

    def outputs(theta: np.ndarray) -> list[np.ndarray]:
        vals = model.at(theta[:nfree])
        out = []
        for i, p in enumerate(fit.extras["split"].fit):
            ic = tuple(float(q) for q in theta[nfree + nic * i: nfree + nic * (i + 1)])
            out.append(simulate(model, vals, p.t, p.u, ic, uniform=p.uniform))
        return out

    return outputs


def jacobian(outputs: Callable[[np.ndarray], list[np.ndarray]], theta: np.ndarray, steps: np.ndarray
             ) -> np.ndarray:
    """Central-difference Jacobian of the concatenated outputs (rows: every run's samples in order)."""
    cols = []
    for k, h in enumerate(steps):
        up, dn = theta.copy(), theta.copy()
        up[k] += h
        dn[k] -= h
        pairs = zip(outputs(up), outputs(dn), strict=True)
        cols.append(np.concatenate([(a - b) / (2.0 * h) for a, b in pairs]))
    return np.column_stack(cols)


def _autocorr_length(r: np.ndarray, floor: int) -> int:
    """First lag where the residuals' autocorrelation falls below 0.05 (at least ``floor``)."""
    r = r - r.mean()
    n = len(r)
    if n < 8:
        return max(1, floor)
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0] if ac[0] > 0 else ac
    below = np.flatnonzero(ac < 0.05)
    lag = int(below[0]) if below.size else n // 4
    return int(min(max(lag, floor, 1), n // 4))


def _scale(jac: np.ndarray) -> np.ndarray:
    """Column norms of J (the parameters' units differ by 20 orders: N.m.s/rad against rad/s)."""
    c = np.linalg.norm(jac, axis=0)
    return np.where(c > 0, c, 1.0)


def _inv_normal(jac: np.ndarray) -> np.ndarray:
    """(J^T J)^-1, computed on the column-scaled J."""
    c = _scale(jac)
    return np.linalg.pinv((jac / c).T @ (jac / c)) / np.outer(c, c)


def newey_west(jac: np.ndarray, resid: list[np.ndarray], floor: int) -> np.ndarray:
    """(J^T J)^-1 S (J^T J)^-1, S the Bartlett-weighted long-run covariance of the scores per run."""
    JtJ_inv = _inv_normal(jac)
    S = np.zeros((jac.shape[1], jac.shape[1]))
    row = 0
    for r in resid:
        n = len(r)
        g = jac[row: row + n] * r[:, None]
        row += n
        L = _autocorr_length(r, floor)
        S += g.T @ g
        for lag in range(1, L + 1):
            w = 1.0 - lag / (L + 1.0)
            c = g[lag:].T @ g[:-lag]
            S += w * (c + c.T)
    return JtJ_inv @ S @ JtJ_inv


def noise_propagated(jac: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Covariance of J^+ d y over noise draws (B, n)."""
    c = _scale(jac)
    d_theta = (draws @ np.linalg.pinv(jac / c).T) / c
    return np.atleast_2d(np.cov(d_theta, rowvar=False))


def robust_ci(names: list[str], theta: np.ndarray, nfree: int, jac: np.ndarray, resid: list[np.ndarray],
              draws: np.ndarray | None, corr_len: int, more_draws: np.ndarray | None = None
              ) -> dict[str, dict[str, float]]:
    """Per free parameter (the first ``nfree``): value, the three standard errors (white LS, noise
    propagated, Newey-West) and the 95 % interval from the wider of the last two. ``jac``: d output
    / d theta on the fit samples; ``resid``: measured - model per run; ``draws`` (B, n): the sensor
    noise on the same samples (None: not propagated); ``corr_len``: the noise's correlation length
    in samples (the Newey-West bandwidth's floor); ``more_draws`` (B2, n): an independent noise
    (fewer draws: an input's noise through the model's response), whose covariance adds."""
    r_all = np.concatenate(resid)
    dof = max(len(r_all) - len(theta), 1)
    ls = float(np.sum(r_all**2)) / dof * _inv_normal(jac)
    hac = newey_west(jac, resid, corr_len)
    prop = noise_propagated(jac, draws) if draws is not None else np.zeros_like(hac)
    if more_draws is not None and len(more_draws) > 1:
        prop = prop + noise_propagated(jac, more_draws)
    out = {}
    for k, q in enumerate(names[:nfree]):
        se_ls, se_hac, se_noise = (math.sqrt(max(float(c[k, k]), 0.0)) for c in (ls, hac, prop))
        se = max(se_hac, se_noise)
        out[q] = {"value": float(theta[k]), "se_white": se_ls, "se_newey_west": se_hac,
                  "se_noise": se_noise, "se": se, "lo": float(theta[k]) - Z95 * se,
                  "hi": float(theta[k]) + Z95 * se}
    return out


def fit_robust_ci(fit: FitResult, draws: np.ndarray | None, corr_len: int) -> dict[str, dict[str, float]]:
    """``robust_ci`` of a ``fit_timeseries`` result (its Jacobian by central differences)."""
    names, theta, nfree = fit_theta(fit)
    preps = fit.extras["split"].fit
    yspan = max(float(np.max(np.abs(p.y))) for p in preps) or 1.0
    mass = float(fit.extras["values"].get("M", 1.0))
    steps = np.array([1e-5 * max(abs(x), 1e-3 * (mass if k < nfree else yspan)) for k, x in enumerate(theta)])
    outputs = fit_outputs(fit)
    jac = jacobian(outputs, theta, steps)
    resid = [p.y - yh for p, yh in zip(preps, outputs(theta), strict=True)]
    return robust_ci(names, theta, nfree, jac, resid, draws, corr_len)
