"""Estimation: equation-error least squares (acceleration and force forms) and output error
(simulation error by Levenberg-Marquardt on the block-structured Jacobian, ``arrowlm``).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import math
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

import numpy as np
from threadpoolctl import ThreadpoolController

from seafmu.components.vessel_spec import NU_NAMES, VesselSpec
from seafmu.identification import arrowlm, fitting
from seafmu.identification.effects import CatalogueEffect
from seafmu.identification.effects.base import Combined
from seafmu.identification.maneuver.preprocessing import _Prepared, noise_ratios
from seafmu.identification.maneuver.simulation import _sim_residual, _SimSetup, _Simulator
from seafmu.identification.maneuver.statistics import _autocorr_factors, _mean_factor
from seafmu.identification.maneuver.terms import (
    _Restoring,
    _sym,
    coriolis_force,
    maneuver_effect,
)
from seafmu.identification.trial import TrialError

_BLAS: list[ThreadpoolController] = []  # made once: finding the loaded libraries costs ~1-6 ms a time


def _one_blas_thread() -> AbstractContextManager[Any]:
    """A context in which BLAS runs single-threaded (``threadpoolctl``; the libraries looked up
    once per process, entering the context then costs microseconds)."""
    if not _BLAS:
        _BLAS.append(ThreadpoolController())
    return _BLAS[0].limit(limits=1, user_api="blas")


@dataclass
class _LSResult:
    M: np.ndarray
    D_L: np.ndarray
    D_Q: np.ndarray
    names: list[str]
    values: np.ndarray
    cov: np.ndarray
    residual: np.ndarray  # (n, d) equation error
    n_rows: int
    note: str
    iterations: int = 1


def _names(prefix: str, d: int, entries: str) -> list[tuple[str, int, int]]:
    if entries == "diag":
        return [(f"{prefix}[{i},{i}]", i, i) for i in range(d)]
    if entries == "upper":
        return [(f"{prefix}[{i},{j}]", i, j) for i in range(d) for j in range(i, d)]
    return [(f"{prefix}[{i},{j}]", i, j) for i in range(d) for j in range(d)]


def _coriolis_of(vessel: VesselSpec) -> Any:
    """C_M(nu) nu as the vessel's model has it: none for a file with ``coriolis: none`` (the supply
    vessel's linear low-speed DP model, which the plant simulates so; with the term put back, a
    clean log of it was named `coupling`)."""
    if vessel.coriolis != "none":
        return coriolis_force
    return lambda M, nu: np.zeros_like(nu)


def _ls_acceleration(prep: _Prepared, rows: np.ndarray, g: np.ndarray, M0: np.ndarray,
                     iterate: bool = False, warnings: list[str] | None = None,
                     cor: Any = coriolis_force) -> _LSResult:
    """Thesis form: Y = nu_dot + M0^-1 (C_M0 nu + g) = Theta^T [tau, nu, |nu| nu], per row.

    ``iterate``: replace M0 by the symmetric part of the estimated M and refit until Theta
    settles (only Y changes, so the normal equations are factored once).
    """
    d = prep.nu.shape[1]
    nu, tau = prep.nu[rows], prep.tau[rows]
    Phi = np.hstack([tau, nu, np.abs(nu) * nu])
    # normal equations with unit-scaled columns (condition ~20 on a rich trial; an SVD of the
    # tall regressor matrix is what makes numpy slow on a busy multi-threaded BLAS)
    A = Phi.T @ Phi
    cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
    G = np.linalg.pinv(A / np.outer(cs, cs), hermitian=True) / np.outer(cs, cs)
    P = G @ Phi.T

    def fit(Mc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Y = prep.nu_dot[rows] + np.linalg.solve(Mc, (cor(Mc, nu) + g[rows]).T).T
        return Y, P @ Y

    Y, Theta = fit(M0)
    iterations = 1
    if iterate:
        for iterations in range(2, 201):  # noqa: B007 - the count is reported
            M_new = _sym(np.linalg.inv(Theta[:d].T))
            if np.any(np.linalg.eigvalsh(M_new) <= 0):
                if warnings is not None:
                    warnings.append("Coriolis iteration stopped: the estimated M is not positive definite")
                break
            Y, nxt = fit(M_new)
            change = float(np.max(np.abs(nxt - Theta)) / max(float(np.max(np.abs(Theta))), 1e-300))
            Theta = nxt
            if change < 1e-10:
                break
        else:
            if warnings is not None:
                warnings.append("Coriolis iteration did not settle in 200 iterations")
    E = Y - Phi @ Theta
    n, p = Phi.shape
    Sigma = E.T @ E / max(n - p, 1)
    cov_theta = np.kron(Sigma, G)  # vec by output row: theta_i = Theta[:, i]

    A, BL, BQ = Theta[:d].T, Theta[d : 2 * d].T, Theta[2 * d :].T
    M = np.linalg.inv(A)
    D_L, D_Q = -M @ BL, -M @ BQ
    # delta method: d[M, D_L, D_Q] = -M dA [M, D_L, D_Q] - M [0, dB_L, dB_Q]
    out_idx = _names("M", d, "full") + _names("D_L", d, "full") + _names("D_Q", d, "full")
    values = np.concatenate([M.ravel(), D_L.ravel(), D_Q.ravel()])
    Jd = np.zeros((3 * d * d, p * d))
    for i in range(d):  # output row i of Theta^T
        for k in range(p):
            dA, dBL, dBQ = np.zeros((d, d)), np.zeros((d, d)), np.zeros((d, d))
            blk, col = divmod(k, d)
            (dA, dBL, dBQ)[blk][i, col] = 1.0
            dM = -M @ dA @ M
            dDL = -M @ dA @ D_L - M @ dBL
            dDQ = -M @ dA @ D_Q - M @ dBQ
            Jd[:, i * p + k] = np.concatenate([dM.ravel(), dDL.ravel(), dDQ.ravel()])
    cov = Jd @ cov_theta @ Jd.T
    return _LSResult(M, D_L, D_Q, [nm for nm, _, _ in out_idx], values, cov, E, n * d,
                     "acceleration form (Minerva 2 study)", iterations)


def _ls_joint(prep: _Prepared, rows: np.ndarray, g: np.ndarray, damping: str,
              cor: Any = coriolis_force) -> _LSResult:
    """Force form, linear in a symmetric M (incl. its Coriolis terms), D_L and D_Q:
    tau - g = M nu_dot + C_M(nu) nu + D_L nu + D_Q |nu| nu, all DOF rows in one weighted LS."""
    d = prep.nu.shape[1]
    nu, nud = prep.nu[rows], prep.nu_dot[rows]
    y = prep.tau[rows] - g[rows]
    n = nu.shape[0]
    entries = "full" if damping == "full" else "diag"
    m_idx = _names("M", d, "upper")
    l_idx = _names("D_L", d, entries)
    q_idx = _names("D_Q", d, entries)
    P = len(m_idx) + len(l_idx) + len(q_idx)
    # regressors (DOF row, sample, parameter), filled in place; each DOF's block contiguous (a
    # strided Gram product is about 10x slower)
    X = np.zeros((d, n, P))
    for k, (_, i, j) in enumerate(m_idx):
        E = np.zeros((d, d))
        E[i, j] = E[j, i] = 1.0
        X[:, :, k] = (nud @ E.T + cor(E, nu)).T
    nq = np.abs(nu) * nu
    k = len(m_idx)
    for src, idx in ((nu, l_idx), (nq, q_idx)):
        for _, i, j in idx:
            X[i, :, k] = src[:, j]
            k += 1
    # per-DOF Gram matrices once (the weights only scale them), in one batched BLAS product
    Xt = X.transpose(0, 2, 1)
    grams = np.matmul(Xt, X)  # (d, P, P)
    cross = np.matmul(Xt, y.T[:, :, None])[:, :, 0]  # (d, P)

    def solve(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted normal equations (column-scaled): theta and (X^T W X)^-1."""
        A = np.tensordot(w**2, grams, axes=1)
        b = w**2 @ cross
        cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
        G = np.linalg.pinv(A / np.outer(cs, cs), hermitian=True) / np.outer(cs, cs)
        return G @ b, G

    w = 1.0 / np.maximum(y.std(axis=0), 1e-12)  # first pass: each DOF row scaled to unit spread
    theta, G = solve(w)
    E = y - (X @ theta).T
    sd = np.sqrt(np.sum(E**2, axis=0) / max(n - P / d, 1))
    w = 1.0 / np.maximum(sd, 1e-12 * max(float(np.max(sd)), 1e-300))
    theta, G = solve(w)  # second pass: weights from the residual spread per DOF (feasible GLS)
    E = y - (X @ theta).T
    s2 = float(np.sum((E * w) ** 2)) / max(n * d - P, 1)
    cov = s2 * G
    M = np.zeros((d, d))
    for k, (_, i, j) in enumerate(m_idx):
        M[i, j] = M[j, i] = theta[k]
    D_L, D_Q = np.zeros((d, d)), np.zeros((d, d))
    off = len(m_idx)
    for k, (_, i, j) in enumerate(l_idx):
        D_L[i, j] = theta[off + k]
    off += len(l_idx)
    for k, (_, i, j) in enumerate(q_idx):
        D_Q[i, j] = theta[off + k]
    names = [nm for nm, _, _ in m_idx + l_idx + q_idx]
    # residual as acceleration-equivalent for reporting (force residual / M row scale)
    return _LSResult(M, D_L, D_Q, names, theta, cov, E, n * d,
                     f"force form, symmetric M with its Coriolis terms solved jointly ({damping} damping)")


def _run_ls(prep: _Prepared, rows: np.ndarray, vessel: VesselSpec, plant: dict[str, np.ndarray],
            coriolis: str, damping: str, warnings: list[str]) -> _LSResult:
    """The equation-error fit in the requested form, BLAS single-threaded (``_output_error``)."""
    with _one_blas_thread():
        return _run_ls_form(prep, rows, vessel, plant, coriolis, damping, warnings)


def _run_ls_form(prep: _Prepared, rows: np.ndarray, vessel: VesselSpec, plant: dict[str, np.ndarray],
                 coriolis: str, damping: str, warnings: list[str]) -> _LSResult:
    d = vessel.dof
    n = prep.t.size
    g_all = _Restoring(vessel)(prep.eta[:, 3], prep.eta[:, 4]) if d == 6 else np.zeros((n, 3))
    if coriolis == "joint":
        return _ls_joint(prep, rows, g_all, damping, _coriolis_of(vessel))
    ls = _ls_acceleration(prep, rows, g_all, plant["M"], coriolis == "iterate", warnings,
                          _coriolis_of(vessel))
    if vessel.coriolis == "none":
        ls.note += ", no Coriolis terms (the vessel file's coriolis: none)"
    elif coriolis == "iterate":
        ls.note += f", Coriolis from the estimated M ({ls.iterations} iterations)"
    else:
        ls.note += ", Coriolis and restoring from the vessel file's M"
    return ls



def _rank_variants(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup, ls: _LSResult,
                   plant: dict[str, np.ndarray], base: str, start: dict[str, float] | None,
                   cands: list[CatalogueEffect]) -> tuple:
    """(variant indices best first, how many to fit, output-error screening costs, each variant's
    start, equation-error costs or None): ranked by equation error and started from its estimate
    where the log allows (``_screen_equation_error``), else by the output-error screen."""
    d = vessel.dof
    got = _screen_equation_error(vessel, prep, setup, cands)
    if got is not None:  # ranked by equation error, started from the baseline and its estimate
        ee, steps = got
        scores = [np.nan] * len(cands)
        starts = [{c.maneuver_params(d)[-1]: c.absent + float(np.clip(st, -0.95, 1.0))}
                  for c, st in zip(cands, steps, strict=True)]
        order = sorted(range(len(cands)), key=lambda i: ee[i])
        gains = ee[-1] - np.array([ee[i] for i in order[:2]])  # ee[-1]: no variant
        clear = len(order) < 2 or gains[0] > LOCATE_CLEAR * max(gains[1], 0.0)
        keep = 1 if clear else LOCATE_KEEP
    else:
        ee = None
        screen = _screen_variants(vessel, prep, setup, ls, plant, base, start, cands)
        scores, starts = screen if screen is not None else ([np.inf] * len(cands), [{} for _ in cands])
        order = sorted(range(len(cands)), key=lambda i: scores[i])
        keep = LOCATE_KEEP if screen is not None else len(cands)
    return order, keep, scores, starts, ee


def _output_error(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                  plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                  warnings: list[str], effect: str | None = None,
                  start: dict[str, float] | None = None) -> tuple:
    """Diagonal D_L, D_Q (and added mass) by simulation error, started from the LS estimate.

    ``effect`` adds a diagnosis extension's parameters (``effect_names``), started at "absent";
    ``start`` (name -> value, e.g. a baseline fit's) replaces the LS start where it has a value.
    An effect that must first be located (``maneuver_variants``: which thruster is lost) is
    screened over its variants (``_rank_variants``): ranked by equation error (one linear least
    squares per variant) and started from its estimate there and the baseline's fit (where equation
    error cannot rank, by one output-error Gauss-Newton step, ``_screen_variants``); the best is
    fitted alone when its equation-error gain is ``LOCATE_CLEAR`` times the runner-up's, else the
    ``LOCATE_KEEP`` best are, briefly (``LOCATE_NFEV``), and the one with the lowest cost is kept,
    fitted to convergence (the variants have the same number of parameters, so also the lowest AIC);
    the brief fits stop at the first that leaves at most ``LOCATE_EXPLAINS`` of the cost of the
    fitted model it starts from (it has located the effect), and a brief fit that converged is kept
    as it is. ``info["variants"]`` lists every variant, best first: its screening costs and, where
    fitted, its value, CI, cost and AIC.
    """
    # BLAS single-threaded: its matrices here are small (a few hundred columns at most), and threads
    # contending on a busy 2-core machine made a fit 2-5x slower (measured)
    with _one_blas_thread():
        return _output_error_located(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, warnings,
                                     effect, start)


def _output_error_located(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                          plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                          warnings: list[str], effect: str | None, start: dict[str, float] | None) -> tuple:
    """``_output_error`` (see there): one fit, or the effect's variants screened and the best fitted."""
    eff = maneuver_effect(effect) if effect is not None else None
    variants = getattr(eff, "maneuver_variants", None)
    if eff is None or variants is None:
        return _output_error_one(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, warnings, eff,
                                 start)
    if prep.thrust is None:
        raise TrialError(f"effect '{effect}' needs one thrust column per thruster (thrust_1 ... or "
                         "plant.thrust_i); this log gives the generalised force only")
    if setup is None:
        raise TrialError("too few samples for an output-error fit")
    cands = variants(prep.thrust.shape[1])
    order, keep, scores, starts, ee = _rank_variants(vessel, prep, setup, ls, plant, base, start, cands)
    fits = []
    # several candidates: each fitted briefly (warm started, LOCATE_NFEV evaluations), the best
    # then to convergence from where it stopped; the first (best screened) alone when its brief fit
    # already leaves at most LOCATE_EXPLAINS of the fitted start model's cost (``_start_cost``)
    nfev = max_nfev if keep == 1 else min(max_nfev, LOCATE_NFEV)
    start_cost = _start_cost(_log_key(setup), start)
    for i in order[:keep]:
        w: list[str] = []
        one = _output_error_one(vessel, prep, setup, ls, plant, added_mass, base, nfev, w, cands[i],
                                {**(start or {}), **starts[i]})
        fits.append((one, w, i))
        if start_cost is not None and one[9]["oe_cost"] <= LOCATE_EXPLAINS * start_cost:
            break
    fits.sort(key=lambda f: f[0][9]["oe_cost"])  # the best continued where its brief fit was stopped
    if keep > 1 and nfev < max_nfev and fits[0][0][9]["oe_status"] == arrowlm.MESSAGES[5]:
        (_, _, _, fnames, fp, *_), _, i = fits[0]
        w = []
        one = _output_error_one(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, w, cands[i],
                                {**(start or {}), **dict(zip(fnames, fp.tolist(), strict=True))})
        fits[0] = (one, w, i)
    fits.sort(key=lambda f: f[0][9]["oe_cost"])
    best, w_best, _ = fits[0]
    warnings += w_best
    rows = []
    for (_, _, _, names, p, _, ci, _, n_res, info), _, i in fits:
        k = names[-1]  # the variant's own parameter comes last
        # AIC from the fitting cost (sum of squared normalised residuals) and the parameter count
        aic = n_res * float(np.log(max(2.0 * info["oe_cost"], 1e-300) / n_res)) + 2.0 * len(names)
        rows.append({"param": k, "screen_cost": _finite(scores[i]),
                     "equation_error_cost": None if ee is None else _finite(ee[i]), "value": float(p[-1]),
                     "ci95": [float(ci[k][0]), float(ci[k][1])], "cost": info["oe_cost"], "aic": aic,
                     "delta_aic": aic - (rows[0]["aic"] if rows else aic)})
    done = {i for _, _, i in fits}
    rows += [{"param": cands[i].maneuver_params(vessel.dof)[-1], "screen_cost": _finite(scores[i]),
              "equation_error_cost": None if ee is None else _finite(ee[i])} for i in order if i not in done]
    best[9]["variants"] = rows
    floor = float(getattr(eff, "min_effect", 0.0))
    value = float(best[4][-1])
    if abs(value - eff.absent) < floor:  # the best variant's effect is below what the model is known to
        raise TrialError(f"effect '{effect}': the best variant ({rows[0]['param']} = {value:.4g}) differs "
                         f"from {eff.absent:g} by less than {floor:g}, the accuracy its model is known to: "
                         "not reported")
    return best


# A DOF is fitted only where its motion is clearly above the sensor noise: the noise (second
# differences, robust) at most this fraction of the measured velocity's spread.
NOISE_MAX = 0.5


def excited_dofs(nu: np.ndarray, vessel: VesselSpec) -> list[int]:
    """The DOFs whose measured velocity moves clearly above its sensor noise (``NOISE_MAX``): the
    noise seen in the log, and at least the vessel file's sensor noise (a noise-free simulated log
    is judged as its vessel would measure it)."""
    d = nu.shape[1]
    std = {c: float(s) for sen in vessel.sensors for c, s in zip(sen.channels, sen.noise_std, strict=True)}
    floor = np.array([std.get(n, 0.0) for n in NU_NAMES[d]])
    spread = np.maximum(nu.std(axis=0), 1e-300)
    ratios = np.maximum(noise_ratios(nu), floor / spread)
    return [j for j in range(d) if ratios[j] <= NOISE_MAX]


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


# How many of an effect's variants (e.g. which thruster is lost) are fitted after the screening;
# only the best one when its equation-error gain is LOCATE_CLEAR times the runner-up's.
LOCATE_KEEP = 3
LOCATE_CLEAR = 3.0
LOCATE_NFEV = 10  # function evaluations of each candidate's brief fit when several are fitted
# The best screened candidate's brief fit that leaves at most this fraction of the cost of the fitted
# model it starts from (the baseline) has located the effect: the next candidates are not fitted.
# (Measured: a lost thruster's own variant leaves 2-4 %, another thruster's 90-100 %; on a clean log
# every variant leaves about 100 %.)
LOCATE_EXPLAINS = 0.25


def _screen_equation_error(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup,
                           cands: list[CatalogueEffect]) -> tuple[list[float], list[float]] | None:
    """Each variant's equation-error cost, and the cost without any (last), and each variant's
    estimated parameter change from "absent": the force form
    tau - g = M nu_dot + C_M(nu) nu + D_L nu + D_Q |nu| nu (symmetric M, diagonal damping) is
    linear in the variant's parameter too (a thruster's gain scales its column of B times its
    thrust), so every variant is one more column of the same least squares, solved on the fitted
    part. None when the variants have no such column (``maneuver_terms`` without thrust_gain)."""
    if prep.thrust is None:
        return None
    d = vessel.dof
    n = prep.t.size
    end = min(int(np.searchsorted(prep.t, setup.t[-1] if setup.t is not None else prep.t[-1])) + 1,
              n - prep.edge)
    rows = np.arange(prep.edge, end)
    if rows.size < 10 * (d * d + 2 * d):
        return None
    g = _Restoring(vessel)(prep.eta[rows, 3], prep.eta[rows, 4]) if d == 6 else np.zeros((rows.size, d))
    nu, nud, y = prep.nu[rows], prep.nu_dot[rows], prep.tau[rows] - g
    m_idx = _names("M", d, "upper")
    cols = []
    cor = _coriolis_of(vessel)
    for _, i, j in m_idx:
        E = np.zeros((d, d))
        E[i, j] = E[j, i] = 1.0
        cols.append(nud @ E.T + cor(E, nu))
    for src in (nu, np.abs(nu) * nu):
        for i in range(d):
            c = np.zeros_like(nu)
            c[:, i] = src[:, i]
            cols.append(c)
    if "thrust_gain" not in cands[0].maneuver_terms(np.array([[1.0]])):
        return None
    Bm = setup.sim.B  # (d, m)
    extra = []
    for c in cands:
        gain = c.maneuver_terms(np.array([[0.0]]))["thrust_gain"][0]  # 0 on the variant's thruster
        k = int(np.argmin(gain))
        extra.append(-prep.thrust[rows, k][:, None] * Bm[:, k][None, :])  # d tau / d (eta_k - 1), moved left
    w = 1.0 / np.maximum(y.std(axis=0), 1e-12)  # each DOF row scaled to unit spread
    X = np.stack(cols + extra, axis=-1) * w[None, :, None]  # (n, d, P + m)
    yw = (y * w).reshape(-1)
    Xf = X.reshape(-1, X.shape[-1])
    G = Xf.T @ Xf
    b = Xf.T @ yw
    yy = float(yw @ yw)
    P = len(cols)

    def sse(idx: list[int]) -> tuple[float, float]:
        A, r = G[np.ix_(idx, idx)], b[idx]
        cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
        th = np.linalg.lstsq(A / np.outer(cs, cs), r / cs, rcond=None)[0] / cs
        return yy - float(r @ th), float(th[-1])

    base = list(range(P))
    fits = [sse([*base, P + k]) for k in range(len(cands))]
    return [c for c, _ in fits] + [sse(base)[0]], [st for _, st in fits]


def _screen_variants(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup, ls: _LSResult,
                     plant: dict[str, np.ndarray], base: str, start: dict[str, float] | None,
                     cands: list[CatalogueEffect]) -> tuple[list[float], list[dict[str, float]]] | None:
    """Each variant's screening cost: the fitting cost after one joint Gauss-Newton step in the
    damping diagonals and its own parameter, from the start model (the baseline's damping) and from
    the vessel file's, whichever step ends lower (a baseline fitted without the effect may sit in
    another basin than the true model). Per start model two batched simulations: the model with each
    damping diagonal and each variant's parameter moved (the Jacobian), then every variant at its
    step. Also the step of each variant, where its fit starts. None when nothing can be simulated."""
    d = vessel.dof
    Ms, DLs, DQs = (_sym(ls.M), ls.D_L.copy(), ls.D_Q.copy()) if base == "ls" else (
        plant["M"].copy(), plant["D_L"].copy(), plant["D_Q"].copy())
    start = start or {}
    for i in range(d):
        DLs[i, i] = start.get(f"D_L[{i},{i}]", ls.D_L[i, i] if np.isfinite(ls.D_L[i, i]) else DLs[i, i])
        DQs[i, i] = start.get(f"D_Q[{i},{i}]", ls.D_Q[i, i] if ls.D_Q[i, i] > 0 else DQs[i, i])
        Ms[i, i] = start.get(f"M[{i},{i}]", Ms[i, i])
    costs = [np.inf] * len(cands)
    starts: list[dict[str, float]] = [{} for _ in cands]
    for model in ((Ms, DLs, DQs), (plant["M"], plant["D_L"], plant["D_Q"])):
        got = _screen_from(vessel, prep, setup, plant, model, cands)
        if got is None:
            continue
        for j, (c, st) in enumerate(zip(*got, strict=True)):
            if c < costs[j]:
                costs[j], starts[j] = c, st
    if not np.any(np.isfinite(costs)):
        return None
    return costs, starts


def _screen_from(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup, plant: dict[str, np.ndarray],
                 model: tuple[np.ndarray, np.ndarray, np.ndarray],
                 cands: list[CatalogueEffect]) -> tuple[list[float], list[dict[str, float]]] | None:
    """Screening costs and steps of every variant from one start model (M, D_L, D_Q)."""
    d = vessel.dof
    M0, DL0, DQ0 = model
    nu_rms = np.sqrt(np.mean(prep.nu_raw**2, axis=0))
    h = 0.1
    n_c, K = len(cands), 1 + 2 * d + len(cands)
    terms = [c.maneuver_terms(np.array([[c.absent], [c.absent + h]])) for c in cands]
    batch = {k: np.concatenate([np.repeat(terms[0][k][:1], 1 + 2 * d, axis=0)] + [t[k][1:] for t in terms])
             for k in terms[0]}
    sQ = np.maximum(np.abs(np.diag(DQ0)), 1e-3 * np.diag(plant["M"]))
    sL = np.maximum(np.abs(np.diag(DL0)), sQ * nu_rms + 1e-6)
    hd = 1e-2 * np.concatenate([sL, sQ])  # damping steps
    M, DL, DQ = (np.repeat(a[None], K, axis=0) for a in (M0, DL0, DQ0))
    for i in range(d):
        DL[1 + i, i, i] += hd[i]
        DQ[1 + d + i, i, i] += hd[d + i]
    r = _sim_residual(setup, M, DL, DQ, **batch)[:, setup.mask]  # (K, compared samples, d)
    if not np.all(np.isfinite(r[: 1 + 2 * d])):
        return None
    r = np.where(np.isfinite(r), r, 1e3).reshape(K, -1)  # a variant's step that diverges: large
    r0 = r[0]
    JD = ((r[1 : 1 + 2 * d] - r0) / hd[:, None]).T  # (rows, 2d)
    steps = []
    for k in range(1 + 2 * d, K):  # joint Gauss-Newton step in the damping and the variant's parameter
        J = np.column_stack([JD, (r[k] - r0) / h])
        cs = np.maximum(np.linalg.norm(J, axis=0), 1e-300)
        steps.append(np.linalg.lstsq(J / cs, -r0, rcond=None)[0] / cs)
    # the actual cost after each variant's step (nonlinear: a large loss is far from the start)
    st = np.array(steps)
    M, DL, DQ = (np.repeat(a[None], n_c, axis=0) for a in (M0, DL0, DQ0))
    ii = np.arange(d)
    DL[:, ii, ii] += st[:, :d]
    DQ[:, ii, ii] += st[:, d : 2 * d]
    terms = [c.maneuver_terms(np.array([[c.absent + st[j, -1]]])) for j, c in enumerate(cands)]
    batch = {k: np.concatenate([t[k] for t in terms]) for k in terms[0]}
    r1 = _sim_residual(setup, M, DL, DQ, **batch)[:, setup.mask].reshape(n_c, -1)
    costs, starts = [], []
    for j, (c, x) in enumerate(zip(cands, r1, strict=True)):
        ok = bool(np.all(np.isfinite(x)))
        costs.append(float(x @ x) if ok else np.inf)
        starts.append({**{f"D_L[{i},{i}]": float(DL[j, i, i]) for i in range(d)},
                       **{f"D_Q[{i},{i}]": float(max(DQ[j, i, i], 0.0)) for i in range(d)},
                       c.maneuver_params(d)[-1]: float(c.absent + st[j, -1])} if ok else {})
    return costs, starts


# The output-error Jacobian is taken on a grid this many times coarser (at most JAC_MAX_H s): the
# sensitivities are smooth in time, so interpolating them between coarse samples costs nothing in the
# fit (the minimum is the fine grid's: the residuals are always simulated on it), and each Jacobian
# costs a fraction of the fine simulations. The covariance uses the fine-grid Jacobian at the solution.
# Each segment starts on the coarsest grid that fits and moves to the next finer one (then the fine
# grid) where it misleads (``COARSE_MISMATCH``).
JAC_COARSEN = (4, 2)
JAC_MAX_H = 0.2
# A segment's coarse-grid residuals may differ from its fine-grid ones by at most this rms (in units of
# each DOF's measured spread, as the residuals) for its coarse sensitivities to be used; else the next
# finer grid is used for that segment for the rest of the fit. Measured on the benchmark's logs: 0.0005-
# 0.01 (RK4's error at the coarse step); a stiff model (a large roll damping: RK4 unstable on the coarse
# step) 10-1000 in the segments where it moves.
COARSE_MISMATCH = 0.05


# A segment whose coarse-grid Jacobian differs from the fine grid's by more than this (relative, in the
# Frobenius norm of its model block or of its state block) at a fit's solution is misleading there. Measured:
# 0.0005-0.009 on the review logs; 0.14 in one AMV segment where a fitted baseline was nearly unstable,
# whose coarse gradient then had the wrong sign and stopped the fit (and every extension's after it) on
# `xtol` short of the fine grid's minimum.
JAC_CHECK = 0.03


# A start whose damping differs from the vessel file's by more than this many times the file's value
# (``far_from_file``) has taken up something the file does not: the effect's fit also starts from
# the file (``_effect_steps``). A DP log in a current has its yaw damping at 40 000 x the file's (a
# supply vessel's surge at 240 x); two of the ten plant-made benchmark logs' baselines pass 20 x too
# (their roll D_L, ~110 x its floor; benchmarks/bench_maneuver_pairs.py: the same answers, the
# three-effect log +3-7 %, 4.8 -> 4.9-5.1 s in a fresh process).
FAR_FROM_FILE = 20.0


def damping_diagonal(name: str) -> int | None:
    """i of a damping diagonal's name (``D_L[i,i]``, ``D_Q[i,i]``); None for any other name."""
    if not name.startswith(("D_L[", "D_Q[")) or not name.endswith("]"):
        return None
    i, _, j = name[4:-1].partition(",")
    return int(i) if i == j and i.isdigit() else None


def far_from_file(plant: dict[str, np.ndarray], nu: np.ndarray, names: list[str], values: np.ndarray) -> bool:
    """Is any damping diagonal (``D_L[i,i]``, ``D_Q[i,i]`` in ``names``) more than
    ``FAR_FROM_FILE`` times the vessel file's value away from it? The measure is the file's value,
    or where that is smaller (a 0 in the file) the DOF's other term at the log's rms speed (D_Q |nu|
    for a linear entry, D_L / |nu| for a quadratic one), and a thousandth of the inertia per second
    at least: the DOFs' damping differ by orders of magnitude (a supply vessel's yaw D_L is 5000
    times its surge D_L), so no one scale serves all."""
    rms = np.maximum(np.sqrt(np.mean(nu**2, axis=0)), 1e-6)
    m = np.diag(plant["M"])
    for name, value in zip(names, values, strict=True):
        i = damping_diagonal(name)
        if i is None:
            continue
        lin, quad = plant["D_L"][i, i], plant["D_Q"][i, i]
        if name.startswith("D_L["):
            file, floor = lin, max(abs(quad) * rms[i], 1e-3 * m[i])
        else:
            file, floor = quad, max(abs(lin) / rms[i], 1e-3 * m[i] / rms[i])
        if abs(value - file) > FAR_FROM_FILE * max(abs(file), floor):
            return True
    return False


def _effect_steps(residuals: Callable[[np.ndarray], np.ndarray], z: np.ndarray, e0: int, npar: int,
                  steps: int = 2) -> tuple[np.ndarray, float] | None:
    """``z`` with its effect parameters (``z[e0:npar]``, scaled) moved by up to ``steps``
    Gauss-Newton steps on them alone (the model and the segment states held), each halved until
    it lowers the cost, and that cost; None if not one did. A few simulations per step (one per
    parameter)."""
    ne = npar - e0
    moved = False
    for _ in range(steps):
        Z = np.repeat(z[None], 1 + ne, axis=0)
        h = 1e-4 * np.maximum(1.0, np.abs(z[e0:npar]))
        Z[1 + np.arange(ne), e0 + np.arange(ne)] += h
        R = residuals(Z).reshape(1 + ne, -1)
        cost = float(np.sum(R[0] ** 2))  # of z itself
        J = ((R[1:] - R[0]) / h[:, None]).T
        dz = np.linalg.lstsq(J, -R[0], rcond=None)[0]
        for a in (1.0, 0.5, 0.25):
            zn = z.copy()
            zn[e0:npar] += a * dz
            cn = float(np.sum(residuals(zn[None]) ** 2))
            if cn < cost:
                z, cost, moved = zn, cn, True
                break
        else:
            break
    return (z, cost) if moved else None


def _coarse_misleading(Jc: arrowlm.ArrowJacobian, Jf: arrowlm.ArrowJacobian) -> np.ndarray:
    """Per segment: does its coarse Jacobian differ from the fine one by more than ``JAC_CHECK``?"""
    out = np.zeros(Jf.Jp.shape[0], dtype=bool)
    for a, b in ((Jc.Jp, Jf.Jp), (Jc.Jx, Jf.Jx)):
        diff = np.sqrt(np.sum((a - b) ** 2, axis=(1, 2)))
        ref = np.sqrt(np.sum(b**2, axis=(1, 2)))
        out |= diff > JAC_CHECK * np.maximum(ref, 1e-300)
    return out


def _coarse_sim(setup: _SimSetup) -> tuple[_Simulator, int] | None:
    """The setup's simulator on every c-th sample (the first c of ``JAC_COARSEN`` that fits), same
    segments and starts; RK4 midpoints at the fine samples halfway (c even). None when no c fits."""
    levels = _coarse_sims(setup)
    return levels[0] if levels else None


def _coarse_sims(setup: _SimSetup) -> list[tuple[_Simulator, int]]:
    """The setup's simulator on every c-th sample for each c of ``JAC_COARSEN`` that fits (the
    coarsest first)."""
    sim = setup.sim
    L = sim.length
    out = []
    for c in JAC_COARSEN:
        if not (L % c == 0 and L >= 4 * c and c * sim.h <= JAC_MAX_H + 1e-12):
            continue
        co = copy.copy(sim)
        co.length, co.h = L // c, sim.h * c
        co.tau, co.tau_mid = sim.tau[:, ::c], sim.tau[:, c // 2 :: c]
        if sim.psi is not None:
            co.psi, co.psi_mid = sim.psi[:, ::c], sim.psi[:, c // 2 :: c]
        if sim.thrust is not None:
            co.thrust, co.thrust_mid = sim.thrust[:, ::c], sim.thrust[:, c // 2 :: c]
        out.append((co, c))
    return out


def _segments(sim: _Simulator, seg: np.ndarray) -> _Simulator:
    """The simulator of the segments ``seg`` only (their starts, forces, headings and thrusts)."""
    out = copy.copy(sim)
    for name in ("x0", "tau", "tau_mid", "psi", "psi_mid", "thrust", "thrust_mid", "idx", "valid"):
        v = getattr(sim, name, None)
        if v is not None:
            setattr(out, name, v[seg])
    return out


def _interp_rows(Rc: np.ndarray, c: int) -> np.ndarray:
    """(K, S, Lc+1, ...) on the coarse grid -> (K, S, c Lc + 1, ...), linear between coarse samples."""
    K, S, n = Rc.shape[:3]
    rest = Rc.shape[3:]
    a = Rc[:, :, :-1]
    step = Rc[:, :, 1:] - a
    out = np.empty((K, S, (n - 1) * c + 1, *rest))
    body = out[:, :, :-1].reshape(K, S, n - 1, c, *rest)  # a view: row r of each coarse interval
    for r in range(c):  # the r-th fine sample after each coarse one, written in place
        np.multiply(step, r / c, out=body[:, :, :, r])
        body[:, :, :, r] += a
    out[:, :, -1] = Rc[:, :, -1]
    return out


# The segments' fitted initial states of recent output-error fits, by log and model parameters: an
# extension fit started from a baseline's parameters (the diagnosis) starts from its states too (the
# measured ones would undo most of what the baseline's fit gained).
_STATES: list[tuple[str, tuple[str, ...], np.ndarray, np.ndarray, dict[str, float], float]] = []
_STATES_MAX = 16
# A fit warm started so (its model one effect away from a fitted one) takes at most this many function
# evaluations: an effect that is there converges in far fewer (measured: 2-11), one that is not creeps
# on at the cap without ever explaining the log (its held-out error is what the diagnosis judges).
WARM_NFEV = 20
# ... unless it is still speeding up there (``_accelerating``): then it goes on from where it stopped, up
# to the caller's budget. Measured: a current of 0.1 m/s in an AMV log, warm started from a baseline whose
# damping had absorbed it, crept for 12 evaluations (the states fitted without the current make the
# first steps overshoot) and then cut the cost by 3, 4, 7, 11, 20, 34, 55, 74 per step when the cap
# stopped it (v_c 0.025, 0.048 for 0.070, 0.072); on, it converged after 32 (v_c 0.068, 0.071). Fits that
# creep at the cap (effects that are not there, or one of three alone) slow down there instead.
WARM_WINDOW = 3  # accepted steps compared with the ones before them


def _accelerating(costs: list[float]) -> bool:
    """Do the costs of the accepted steps fall faster over the last ``WARM_WINDOW`` steps than over
    the ones before, by at least 1 % of the last?"""
    c = np.asarray(costs, dtype=float)
    n = WARM_WINDOW
    if c.size < 2 * n + 1:
        return False
    recent, before = c[-n - 1] - c[-1], c[-2 * n - 1] - c[-n - 1]
    return bool(recent > before and recent > 0.01 * c[-1])


def _log_key(setup: _SimSetup) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in (setup.meas, setup.sim.tau, setup.sim.x0):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _remember_states(key: str, names: list[str], values: np.ndarray, x0: np.ndarray,
                     hold: dict[str, float] | None = None, cost: float = float("nan")) -> None:
    """Keep a fit's segment states, the damping entries it held and its cost (the oldest of
    ``_STATES_MAX`` dropped)."""
    del _STATES[: max(0, len(_STATES) - _STATES_MAX + 1)]
    _STATES.append((key, tuple(names), np.array(values, dtype=float), x0.copy(), dict(hold or {}), cost))


# The form each effect with several (``maneuver_forms``: a current's inertia) was kept in by the first
# fit of a log that chose one, by (log, the vessel file's current_inertia, effect name): the log's later
# fits with it (pairs, their screening) use that form instead of trying each again (it doubled the
# cost of every combination with a current).
_FORMS: dict[tuple[str, str, str], CatalogueEffect] = {}
_FORMS_MAX = 64
# The other forms' brief fits (function evaluations), from where the first form's fit ended: the
# right form overtakes the other within a few (measured: 13.9 against 19.5 in 7 on a Minerva 2 log
# made with Fossen's form; 327.8 against 353.4 in 5 on an AMV log with a lost thruster whose current
# fit alone had kept the wrong form; the wrong one stays above, 21.1 against 14.0). 3 name the same
# forms and values as 5 on every log tested (tests, the review logs, benchmarks/bench_maneuver_pairs.py)
# and keep a three-effect Minerva 2 log under 5 s (4.8 s; with 5: 5.5 s).
FORM_NFEV = 3
# ... and it is fitted on (with the first) only where it fits clearly better there: by more than this
# fraction of the first's cost. Where the form matters (a current and turns) it is 29-33 % (either way);
# without a current both forms are one model but for the small current a fit finds anyway, 0.4 % apart.
FORM_GAIN = 0.05


def _remember_forms(key: str, vessel: VesselSpec, eff: CatalogueEffect) -> None:
    """Remember the form of each part of ``eff`` that has one (``_FORMS``)."""
    for p in getattr(eff, "parts", (eff,)):
        if p.maneuver_form() is not None:
            _FORMS.pop((key, vessel.current_inertia, p.name), None)
            _FORMS[(key, vessel.current_inertia, p.name)] = p
    while len(_FORMS) > _FORMS_MAX:
        del _FORMS[next(iter(_FORMS))]


def formed(eff: CatalogueEffect, key: str, vessel: VesselSpec) -> CatalogueEffect:
    """``eff`` with each part that has several forms and none fixed in the form a fit of this log
    (``key``, ``_log_key``) kept (``_FORMS``); itself where none was kept."""
    parts = getattr(eff, "parts", None)
    if parts is None:
        if len(eff.maneuver_forms(vessel)) > 1:  # (one of a fixed form has only itself)
            return _FORMS.get((key, vessel.current_inertia, eff.name), eff)
        return eff
    new = [formed(p, key, vessel) for p in parts]
    return eff if all(a is b for a, b in zip(new, parts, strict=True)) else Combined(new, vessel.dof)


def _latest(key: str, values: dict[str, float]) -> None:
    """Make the remembered fit of this log that ``values`` gives every parameter of the latest one
    (``_recalled`` falls back to the latest)."""
    for k in range(len(_STATES) - 1, -1, -1):
        e = _STATES[k]
        if e[0] == key and all(values.get(n) == v for n, v in zip(e[1], e[2].tolist(), strict=True)):
            _STATES.append(_STATES.pop(k))
            return


def _start_cost(key: str, start: dict[str, float] | None) -> float | None:
    """The fitting cost of the remembered fit of this log ``start`` gives every parameter of at
    exactly its fitted value; None when there is none."""
    e = _recalled(key, start)
    if e is None or start is None or any(start.get(n) != v for n, v in zip(e[1], e[2].tolist(), strict=True)):
        return None
    return float(e[5]) if np.isfinite(e[5]) else None


def _recalled(key: str, start: dict[str, float] | None) -> tuple | None:
    """The remembered fit of this log whose every parameter ``start`` gives at exactly its fitted
    value, else the latest fit of this log; None when there is no start or no such fit."""
    if not start:
        return None
    mine = [e for e in _STATES if e[0] == key]
    for e in reversed(mine):
        if all(start.get(n) == v for n, v in zip(e[1], e[2].tolist(), strict=True)):
            return e
    return mine[-1] if mine else None


def _recall_states(key: str, start: dict[str, float] | None) -> np.ndarray | None:
    """The fitted segment states of an earlier fit of this log whose every parameter ``start``
    gives at exactly its fitted value, else of the latest fit of this log (a start the caller
    still compares with the measured states); None when there is no start or no such fit."""
    e = _recalled(key, start)
    return None if e is None else e[3]


def _recall_holds(key: str, start: dict[str, float] | None) -> dict[str, float]:
    """The damping entries the recalled fit (``_recalled``) held at 0, those ``start``
    gives no value of: a fit started from a fitted model starts with its active set."""
    e = _recalled(key, start)
    return {} if e is None else {k: v for k, v in e[4].items() if k not in (start or {})}


def _output_error_one(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                      plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                      warnings: list[str], eff: CatalogueEffect | None,
                      start: dict[str, float] | None) -> tuple:
    """One output-error fit with the effect object ``eff`` (``_output_error_form``). An effect with
    several physical forms (``maneuver_forms``: a current's inertia term) is fitted in the form an
    earlier fit of this log kept (``formed``), else in the vessel file's form, then (where that
    removes more than ``FORM_GAIN`` of the cost of the fitted model it starts from, or that is not
    known) in each other form briefly (``FORM_NFEV``) from where that fit ended; a form that does
    clearly better there (``FORM_GAIN``) is fitted on to convergence, and so is the first (were it
    stopped by its budget, the other would win by its extra steps alone). The form with the lowest
    fitting cost is kept (the same parameters: also the lowest AIC) and remembered for the log.
    ``info["effect_form"]`` says the form fitted, ``info["forms"]`` each tried form's cost."""
    key = _log_key(setup) if setup is not None else ""
    forms: list[CatalogueEffect | None] = [None]
    if eff is not None:  # the form a fit of this log kept first, then the others
        kept = formed(eff, key, vessel).maneuver_form()
        forms = sorted(eff.maneuver_forms(vessel), key=lambda f: f.maneuver_form() != kept)

    def fit(form: CatalogueEffect | None, at: dict[str, float] | None, nfev: int, w: list[str],
            brief: bool = False) -> tuple:
        out = _output_error_form(vessel, prep, setup, ls, plant, added_mass, base, nfev, w, form, at, brief)
        if form is not None and form.maneuver_form() is not None:
            out[9]["effect_form"] = form.maneuver_form()
        return out

    def end(out: tuple) -> dict[str, float]:  # where a fit ended (its segment states come with it)
        return {**(start or {}), **dict(zip(out[3], out[4].tolist(), strict=True))}

    def stopped(out: tuple) -> bool:
        return out[9]["oe_status"] == arrowlm.MESSAGES[5]

    w0: list[str] = []
    first = fit(forms[0], start, max_nfev, w0)
    base_cost = _start_cost(key, start)  # the fitted model it starts from (the baseline's), if known
    if (len(forms) == 1 or max_nfev <= WARM_NFEV
            or (base_cost is not None and first[9]["oe_cost"] > (1.0 - FORM_GAIN) * base_cost)):
        # one form, a short fit (a diagnosis's cheap check of a combination, a few evaluations), or
        # an effect that explains too little for its form to matter by FORM_GAIN
        warnings += w0
        return first
    fits = [[first, w0, forms[0]]]
    costs = [first[9]["oe_cost"]]  # each form's, as far as it was fitted
    for form in forms[1:]:
        w: list[str] = []
        out = fit(form, end(first), FORM_NFEV, w, brief=True)
        if out[9]["oe_cost"] < (1.0 - FORM_GAIN) * first[9]["oe_cost"]:
            w = []
            out = fit(form, end(out), max_nfev, w)  # on to convergence (warm), with its covariance
            if stopped(fits[0][0]):
                fits[0][1] = []
                fits[0][0] = fit(forms[0], end(fits[0][0]), max_nfev, fits[0][1])
                costs[0] = fits[0][0][9]["oe_cost"]
            fits.append([out, w, form])
        costs.append(out[9]["oe_cost"])
    best, w_best, form = min(fits, key=lambda f: f[0][9]["oe_cost"])  # the first form on a tie
    warnings += w_best
    _remember_forms(key, vessel, form)
    _latest(key, end(best))  # the kept fit is the log's latest (a later start falls back to its states)
    best[9]["forms"] = [{"form": f.maneuver_form(), "cost": c} for f, c in zip(forms, costs, strict=True)]
    return best


def _output_error_form(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                       plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                       warnings: list[str], eff: CatalogueEffect | None,
                       start: dict[str, float] | None, brief: bool = False) -> tuple:
    """One output-error fit, with the effect object ``eff``'s parameters (or none). Damping is
    dissipative: each fitted diagonal entry, linear and quadratic, is bounded below by 0 inside the
    iteration (``arrowlm``'s projected step: an active set, so one fit where holding entries fitted
    negative took two; a short, slow log cannot tell v from v|v| and trades one against the other,
    and a short closed-loop log let the linear entries wander negative and name the wrong thruster). An
    entry that ends at 0 is reported held there, said in a warning, and the covariance is the free
    entries'. Started from a fitted model (the diagnosis's extensions, from the baseline), the
    entries that model held (``_recall_holds``) start at 0. ``brief``: only the cost and the values
    are wanted (no covariance: its CIs are NaN)."""
    inherit = _recall_holds(_log_key(setup), start) if setup is not None else {}
    if inherit:
        start = {**inherit, **(start or {})}
    said: list[str] = []  # the kept fit's warnings
    out = _output_error_held(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, said, eff,
                             start, {}, brief)
    if not brief and _UNTOLD_AT_FILE.get():
        out, said = _file_where_untold(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, said,
                                       eff, start, out)
    warnings.extend(said)
    at = out[9]["held_at_bound"]
    if at:
        warnings.append(f"damping {', '.join(at)} held at 0 (dissipative): the fit would take "
                        f"{'it' if len(at) == 1 else 'them'} below 0")
    return out


# A likelihood-ratio test at this level decides whether the log rejects the vessel file's damping of
# the DOFs it cannot tell (``_file_where_untold``).
UNTOLD_LEVEL = 0.95
# Whether the fits in this context hold such damping at the file's (``holding_untold_damping``): a
# context, not a parameter, as it is asked for at the top (an identification, a diagnosis's cause) and
# acts five calls down, in each output-error fit. Every candidate of a diagnosis fitted so made it
# 25-50 % slower.
_UNTOLD_AT_FILE: ContextVar[bool] = ContextVar("untold_at_file", default=False)


@contextlib.contextmanager
def holding_untold_damping() -> Iterator[None]:
    """The output-error fits inside hold the damping of the DOFs the log cannot tell at the vessel
    file's, where the log does not reject it (``_file_where_untold``)."""
    token = _UNTOLD_AT_FILE.set(True)
    try:
        yield
    finally:
        _UNTOLD_AT_FILE.reset(token)


def untold_dofs(names: list[str], ci: dict[str, tuple[float, float]], held_at_bound: list[str],
                plant: dict[str, np.ndarray]) -> list[int]:
    """The DOFs whose fitted damping the log cannot tell from the vessel file's: every free entry's
    95 % interval holds both 0 and the file's value (an entry the bound held at 0 tells nothing
    either), and at least one entry has an interval."""
    by_dof: dict[int, list[bool]] = {}
    for nm in [*names, *held_at_bound]:
        if (dof := damping_diagonal(nm)) is None:
            continue
        if nm in held_at_bound:
            by_dof.setdefault(dof, [])
            continue
        lo, hi = ci[nm]
        file = float(plant["D_L" if nm.startswith("D_L") else "D_Q"][dof, dof])
        by_dof.setdefault(dof, []).append(bool(lo <= 0.0 <= hi and lo <= file <= hi))
    return sorted(i for i, told in by_dof.items() if told and all(told))


def _untold_limit(k: int) -> float:
    from scipy import stats

    return float(stats.chi2.ppf(UNTOLD_LEVEL, k))


def file_not_rejected(free: dict[str, Any], held: dict[str, Any], k: int) -> tuple[bool, float]:
    """Does the log not reject holding ``k`` damping entries at the file's? The likelihood ratio of
    the held fit against the free one, each DOF with its own noise variance (the residuals are
    scaled by each DOF's motion, not its noise): sum_j n ln(RSS_held,j / RSS_free,j), each term
    divided by the free fit's autocorrelation inflation in that DOF (correlated residuals count as
    fewer samples), below chi^2(``UNTOLD_LEVEL``, k). Also the statistic."""
    n = free["dof_n"]
    terms = [n * math.log(max(h, 1e-300) / max(f, 1e-300)) / max(i, 1.0)
             for f, h, i in zip(free["dof_rss"], held["dof_rss"], free["dof_inflation"], strict=True)]
    stat = float(sum(terms))
    return stat < _untold_limit(k), stat


def _file_where_untold(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                       plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                       said: list[str], eff: CatalogueEffect | None, start: dict[str, float] | None,
                       out: tuple) -> tuple[tuple, list[str]]:
    """The fit again with the damping of the DOFs the log cannot tell (``untold_dofs``) held at the
    vessel file's, kept if the log does not reject those values (``file_not_rejected``). A free value
    there drifts where the log does not look: a DP log's yaw damping, fitted to station keeping,
    missed the held-out heading step (NRMSE 1.09, against 0.22 with the file's yaw damping)."""
    names, ci, info = out[3], out[6], out[9]
    dofs = untold_dofs(names, ci, info["held_at_bound"], plant)
    if not dofs:
        return out, said
    hold = {f"{k}[{i},{i}]": float(plant[k][i, i]) for i in dofs for k in ("D_L", "D_Q")}
    said_held: list[str] = []
    warm = {**(start or {}), **dict(zip(names, np.asarray(out[4], dtype=float).tolist(), strict=True))}
    held = _output_error_held(vessel, prep, setup, ls, plant, added_mass, base, max_nfev, said_held, eff,
                              warm, hold)  # from the free fit and its segment states
    kept, stat = file_not_rejected(info, held[9], len(hold))
    if not kept:
        return out, said
    said_held.append(f"damping of {', '.join(NU_NAMES[vessel.dof][i] for i in dofs)} held at the vessel "
                    f"file: the log cannot tell it (95 % intervals hold 0 and the file's values) and "
                    f"does not reject the file's (likelihood-ratio statistic {stat:.1f}, limit "
                    f"{_untold_limit(len(hold)):.1f}, each DOF's residual autocorrelation counted)")
    held[9]["held_at_file"] = sorted(hold)
    return held, said_held


def _output_error_held(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                       plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                       warnings: list[str], eff: CatalogueEffect | None,
                       start: dict[str, float] | None, hold: dict[str, float], brief: bool = False) -> tuple:
    """One output-error fit with the damping entries in ``hold`` (name -> value) kept fixed and the
    fitted damping entries bounded below by 0: those that end there are left out of the names,
    values and covariance, as held (``info["held_at_bound"]``)."""
    # Over 80 lines: the parameter layout (model diagonals, added mass, effect parameters, one initial
    # state per segment) is shared by the closures mats/terms/residuals/jac; split apart, each would
    # need the same ten arrays passed in, and the layout would be written in two places.
    if setup is None:
        raise TrialError("too few samples for an output-error fit")
    d = vessel.dof
    if base == "ls":
        M0, DL0, DQ0 = _sym(ls.M), ls.D_L.copy(), ls.D_Q.copy()
    else:
        M0, DL0, DQ0 = plant["M"].copy(), plant["D_L"].copy(), plant["D_Q"].copy()
    # DOFs whose motion is below the sensor noise keep their damping (the start's, else the vessel
    # file's): a log that barely moves them (roll and pitch under DP) cannot tell their damping,
    # and a free value there wanders to an unstable model
    fl = excited_dofs(prep.nu_raw, vessel) or list(range(d))  # none excited: nothing to prefer
    held = [i for i in range(d) if i not in fl]
    for i in held:
        DL0[i, i] = (start or {}).get(f"D_L[{i},{i}]", plant["D_L"][i, i])
        DQ0[i, i] = (start or {}).get(f"D_Q[{i},{i}]", plant["D_Q"][i, i])
    if held:
        given = start and any(f"{k}[{i},{i}]" in start for i in held for k in ("D_L", "D_Q"))
        warnings.append(f"damping of {', '.join(NU_NAMES[d][i] for i in held)} held at "
                        f"{'the start' if given else 'the vessel file'}: motion below {1 / NOISE_MAX:g}x the "
                        "sensor noise (the log's, at least the vessel file's)")
    for key, val in hold.items():
        i = int(key[key.index("[") + 1 : key.index(",")])
        (DL0 if key.startswith("D_L") else DQ0)[i, i] = val
    fL = [i for i in fl if f"D_L[{i},{i}]" not in hold]
    fQ = [i for i in fl if f"D_Q[{i},{i}]" not in hold]
    nL, nQ = len(fL), len(fQ)
    # start: LS diagonal (falls back to the vessel file where LS is unusable)
    ls_ok_M = np.all(np.linalg.eigvalsh(_sym(ls.M)) > 0)
    start_L = np.where(np.isfinite(np.diag(ls.D_L)), np.diag(ls.D_L), np.diag(plant["D_L"]))[fL]
    start_Q = np.where(np.diag(ls.D_Q) > 0, np.diag(ls.D_Q), np.diag(plant["D_Q"]))[fQ]
    names = [f"D_L[{i},{i}]" for i in fL] + [f"D_Q[{i},{i}]" for i in fQ]
    p0 = [*start_L, *start_Q]
    if added_mass:
        names += [f"M[{i},{i}]" for i in range(d)]
        mdiag = np.diag(ls.M) if ls_ok_M else np.diag(plant["M"])
        p0 += list(np.where(mdiag > 0, mdiag, np.diag(plant["M"])))
    if start:
        p0 = [float(start.get(nm, v)) for nm, v in zip(names, p0, strict=True)]
    e0 = len(names)  # effect parameters follow the model's
    enames = eff.maneuver_params(d) if eff is not None else []
    names += enames
    absent = [eff.absent] * len(enames) if eff is not None else []
    e_start = [(start or {}).get(nm, a) for nm, a in zip(enames, absent, strict=True)]  # absent if not given
    p0 = np.array([*p0, *e_start], dtype=float)
    nu_abs = np.sqrt(np.mean(prep.nu_raw**2, axis=0))
    # parameter scales: a linear coefficient is worth its quadratic one times the rms speed
    q_all = np.diag(DQ0).copy()  # quadratic damping per DOF: the fitted ones at their start
    q_all[fQ] = p0[nL : nL + nQ]
    sQ_all = np.maximum(np.abs(q_all), 1e-3 * np.diag(plant["M"]))
    sQ = sQ_all[fQ]
    sL = np.maximum(np.abs(p0[:nL]), sQ_all[fL] * nu_abs[fL] + 1e-6)
    scales = [*sL, *sQ] + ([*np.abs(p0[nL + nQ : nL + nQ + d])] if added_mass else [])
    if eff is not None:
        scales += eff.maneuver_scales(prep.tau, prep.nu_raw)
    scales = np.maximum(np.array(scales), 1e-9)
    # initial state of every segment is estimated too (multiple shooting without continuity):
    # restarting from a noisy measured state biases the damping (measured: -7 % in sway)
    x0_meas = setup.sim.x0
    S, nx = x0_meas.shape
    x_scale = np.maximum(np.sqrt(np.mean(x0_meas**2, axis=0)), 1e-6)
    npar = p0.size
    mask = setup.mask
    maskd = np.broadcast_to(mask[:, :, None], (*mask.shape, d))  # residuals that count
    unmasked = ~mask

    def mats(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        K = P.shape[0]
        M = np.broadcast_to(M0, (K, d, d)).copy()
        DL = np.broadcast_to(DL0, (K, d, d)).copy()
        DQ = np.broadcast_to(DQ0, (K, d, d)).copy()
        ii = np.arange(d)
        DL[:, fL, fL] = P[:, :nL]
        DQ[:, fQ, fQ] = P[:, nL : nL + nQ]
        if added_mass:
            M[:, ii, ii] = P[:, nL + nQ : nL + nQ + d]
        return M, DL, DQ

    def terms(P: np.ndarray) -> dict[str, np.ndarray]:
        """The effect's terms for the simulator (its object's ``maneuver_terms``: F0, vc)."""
        return eff.maneuver_terms(P[:, e0:]) if eff is not None else {}

    coarse = _coarse_sims(setup)  # the Jacobian's grids, coarsest first (``jac``)

    def residuals(Z: np.ndarray) -> np.ndarray:
        """Residuals per segment (K, S, R) for several scaled parameter sets, R = (L + 1) d rows
        per segment, zero where no sample is compared (the segment start, past the log's end)."""
        P = Z[:, :npar] * scales
        X0 = Z[:, npar:].reshape(-1, S, nx) * x_scale
        r = _sim_residual(setup, *mats(P), X0, **terms(P))
        np.nan_to_num(r, copy=False, nan=1e3, posinf=1e3, neginf=1e3)  # in place: r is new
        r *= maskd
        return r.reshape(P.shape[0], S, -1)

    def sensitivities(Z: np.ndarray, cols: np.ndarray, lv: int,
                      seg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Z[k] - Z[0]) / cols[k - 1] differences of the residuals of the segments ``seg`` on grid
        ``grids[lv]`` (every c-th sample), differenced there, then interpolated to the fine grid
        straight into the Jacobian's blocks (s, R, P) and (s, R, nx): one pass over the fine-grid
        arrays. Also which of the segments are misleading there: their residuals at Z[0] differ
        from the fine grid's (``fun``'s last, at the same point) by more than ``COARSE_MISMATCH``
        rms (a stiff model, a coarse step beyond RK4's stability)."""
        co, c = grids[lv]
        if seg.size != S:
            key = (lv, seg.tobytes())
            if key not in subsets:
                subsets[key] = _segments(co, seg)
            co = subsets[key]
        P = Z[:, :npar] * scales
        x = co.run(*mats(P), Z[:, npar:].reshape(-1, S, nx)[:, seg] * x_scale, **terms(P))
        rc = (x[..., -d:] - setup.meas[None, seg, ::c]) / setup.scale  # (K, s, Lc + 1, d)
        np.nan_to_num(rc, copy=False, nan=1e3, posinf=1e3, neginf=1e3)
        bad = np.zeros(seg.size, dtype=bool)
        if c > 1 and last and np.array_equal(last[0], Z[0]):
            m = mask[seg, ::c, None]
            rf = last[1].reshape(S, -1, d)[seg, ::c]
            err = np.sum(((rc[0] - rf) * m) ** 2, axis=(1, 2)) / np.maximum(np.sum(m, axis=(1, 2)) * d, 1)
            bad = err > COARSE_MISMATCH**2
        D = ((rc[1:] - rc[0]) / cols[:, None, None, None]).transpose(1, 2, 3, 0)  # (s, Lc + 1, d, K - 1)
        out = []
        for blk in (D[..., :npar], D[..., npar:]):
            J = _interp_rows(np.ascontiguousarray(blk)[None], c)[0] if c > 1 else np.array(blk)
            J[unmasked[seg]] = 0.0  # the few rows not compared (segment starts, past the log's end)
            out.append(J.reshape(seg.size, -1, blk.shape[-1]))
        return out[0], out[1], bad

    last: list[np.ndarray] = []  # fun's last point and residuals (where the LM asks for the Jacobian)
    accepted: list[float] = []  # the cost at each point the LM moved to (it asks for the Jacobian there)
    fine_jac: list = []  # the last fine-grid Jacobian and its point (the covariance's, where the fit ended)
    # each segment's grid: the coarsest not found misleading for it in this fit (``sensitivities``);
    # the fine grid last
    grids = [*coarse, (setup.sim, 1)]
    level = np.zeros(S, dtype=int)
    subsets: dict[tuple[int, bytes], _Simulator] = {}

    def fun(z: np.ndarray) -> np.ndarray:
        r = residuals(z[None])[0]
        last[:] = [z.copy(), r]
        return r

    def jac(z: np.ndarray, fine: bool = False) -> arrowlm.ArrowJacobian:
        """Finite differences in one batched simulation: one run per model parameter, and one
        per state component (it perturbs that component in every segment at once; segments
        are independent, so segment s's rows give its own state's column). Kept by blocks
        (arrowlm): a dense matrix would have one column per segment and state, rows x columns
        growing as the square of the log length. On the coarse grid unless ``fine``."""
        if not fine and last and np.array_equal(last[0], z):
            accepted.append(0.5 * float(np.sum(last[1] ** 2)))
        step = 1e-6 * np.maximum(1.0, np.abs(z))
        Z = np.repeat(z[None], 1 + npar + nx, axis=0)
        Z[1 + np.arange(npar), np.arange(npar)] += step[:npar]
        hx = 1e-6
        for j in range(nx):
            Z[1 + npar + j, npar + j :: nx] += hx
        if not fine and coarse:
            cols = np.concatenate([step[:npar], np.full(nx, hx)])
            Jp = Jx = None
            for lv in range(len(grids)):  # a segment misleading on a grid goes to the next, for good
                seg = np.flatnonzero(level == lv)
                if not seg.size:
                    continue
                jp, jx, bad = sensitivities(Z, cols, lv, seg)
                if seg.size == S and not bad.any():
                    return arrowlm.ArrowJacobian(jp, jx)
                if Jp is None or Jx is None:
                    Jp, Jx = np.empty((S, jp.shape[1], npar)), np.empty((S, jx.shape[1], nx))
                Jp[seg], Jx[seg] = jp, jx
                level[seg[bad]] = lv + 1  # redone on the next grid in this same pass
            assert Jp is not None and Jx is not None
            return arrowlm.ArrowJacobian(Jp, Jx)
        if fine_jac and np.array_equal(fine_jac[0], z):
            return fine_jac[1]
        R = residuals(Z)
        Jp = ((R[1 : 1 + npar] - R[0]) / step[:npar, None, None]).transpose(1, 2, 0)
        Jx = ((R[1 + npar :] - R[0]) / hx).transpose(1, 2, 0)
        J = arrowlm.ArrowJacobian(np.ascontiguousarray(Jp), np.ascontiguousarray(Jx))
        fine_jac[:] = [z.copy(), J]
        return J

    # start from the LS diagonal, unless the vessel file's values simulate the trial better
    # (a poorly exciting log gives an LS model that may not even be stable)
    p_file = np.concatenate([np.diag(plant["D_L"])[fL], np.diag(plant["D_Q"])[fQ]]
                            + ([np.diag(plant["M"])] if added_mass else []) + [np.array(absent, dtype=float)])
    x0z = (x0_meas / x_scale).ravel()
    p0[: nL + nQ] = np.maximum(p0[: nL + nQ], 0.0)  # within the bound the fit keeps
    z_ls, z_file = np.concatenate([p0 / scales, x0z]), np.concatenate([p_file / scales, x0z])
    first = "given start" if start else "LS estimate"
    starts = [z_ls, z_file]
    labels = [first, f"vessel file ({first} simulated worse)"]
    log_key = _log_key(setup)
    fitted_x0 = _recall_states(log_key, start)
    if fitted_x0 is not None:  # the given start with the states fitted with it (a warm start)
        starts.append(np.concatenate([p0 / scales, (fitted_x0 / x_scale).ravel()]))
        labels.append(f"{first} with the segment states fitted with it")
    costs = np.sum(residuals(np.vstack(starts)) ** 2, axis=(1, 2))
    best = int(np.argmin(costs))
    z0 = starts[best]
    start_from = labels[best]
    warm = fitted_x0 is not None and best == 2
    if (npar > e0 and not brief and not hasattr(eff, "parts")  # (a combination: from its parts' fits)
            and far_from_file(plant, prep.nu_raw, names[: nL + nQ], p0[: nL + nQ])):
        # the vessel file's model with the effect's values fitted alone: where the given start's
        # damping took up what the effect explains (a DP log in a current: yaw damping x 40 000),
        # the effect's own fit from there is stuck in that basin; from the file it is not. Judged
        # against the given start with the same (measured) segment states: a warm start's fitted
        # states would make any model look better than one simulated from the measured states
        stepped = _effect_steps(residuals, z_file, e0, npar)
        if stepped is not None and stepped[1] < costs[0]:
            z0, warm = stepped[0], False
            start_from = f"vessel file with the effect's values fitted alone ({first} simulated worse)"
    p0 = z0[:npar] * scales
    # MINPACK's Levenberg-Marquardt (as least_squares(method="lm", x_scale=1.0)) on the block
    # structure: time and memory linear in the log length (arrowlm)
    full_nfev = max_nfev
    if warm:  # from a fitted model and its states: near the optimum, or an effect that does not fit
        max_nfev = min(max_nfev, WARM_NFEV)
    lower = np.full(npar, -np.inf)
    lower[: nL + nQ] = 0.0  # damping is dissipative (the scales are positive)
    sol = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=max_nfev, final_jac=not coarse, lower=lower)
    if max_nfev < full_nfev and not sol.success and _accelerating([*accepted, float(sol.cost)]):
        # stopped by the warm cap while still speeding up (an effect that is there, found late): on
        # from where it stopped, up to the caller's budget
        more = arrowlm.levenberg_marquardt(fun, jac, sol.x, max_nfev=full_nfev - sol.nfev,
                                           final_jac=not coarse, lower=lower)
        sol = dataclasses.replace(more, nfev=sol.nfev + more.nfev, njev=sol.njev + more.njev)
    if coarse and sol.success and not brief:
        # converged on the coarse sensitivities: checked at the solution against the fine grid's (the
        # covariance's, computed anyway); segments where they differ go to the fine grid and the fit
        # goes on from there
        wrong = _coarse_misleading(jac(sol.x), jac(sol.x, fine=True))
        if wrong.any():
            level[wrong] = len(grids) - 1
            more = arrowlm.levenberg_marquardt(fun, jac, sol.x, max_nfev=full_nfev, final_jac=False,
                                               lower=lower)
            sol = dataclasses.replace(more, nfev=sol.nfev + more.nfev, njev=sol.njev + more.njev)
    p_all = sol.x[:npar] * scales
    if not sol.success:
        warnings.append(f"output-error optimiser stopped: {sol.message}")
    # the damping entries the bound stopped: held at 0 from here on (names, values, covariance)
    at = [k for k in range(nL + nQ) if sol.x[k] <= 0.0]
    keep = np.setdiff1d(np.arange(npar), at)
    held_now = {names[k]: 0.0 for k in at}
    names_all, names = names, [names[k] for k in keep]
    p = p_all[keep]
    _remember_states(log_key, names, p, sol.x[npar:].reshape(S, nx) * x_scale, {**hold, **held_now},
                     float(sol.cost))
    r = sol.fun[maskd.reshape(S, -1)]  # the compared residuals, in time order
    factors = _autocorr_factors(r.reshape(-1, d))  # per DOF: the inflation, and the hold's test
    infl = _mean_factor(factors)
    # s^2 (J^T J)^-1 over the free model and initial-state parameters (column-scaled pseudo-inverse),
    # model block, from the Jacobian on the fine grid
    if brief:
        cov = np.full((keep.size, keep.size), np.nan)
    else:
        J = jac(sol.x, fine=True) if coarse else sol.jac
        assert J is not None
        if at:
            J = arrowlm.ArrowJacobian(np.ascontiguousarray(J.Jp[:, :, keep]), J.Jx)
        n_cols = keep.size + S * nx
        cov = float(r @ r) / max(r.size - n_cols, 1) * J.scaled(scales[keep]).normal().inverse_pp() * infl
    ci = fitting.confidence_intervals(names, p, cov, r.size)
    corr = fitting.correlation_matrix(cov)
    M, DL, DQ = (a[0] for a in mats(p_all[None]))
    info = {"oe_nfev": int(sol.nfev), "oe_cost": float(sol.cost), "oe_start_from": start_from,
            "oe_start": dict(zip(names_all, p0.tolist(), strict=True)), "ci_inflation": infl,
            "oe_status": sol.message, "effect": None if eff is None else eff.name,
            "effect_terms": {k: v[0] for k, v in terms(p_all[None]).items()},
            "held_at_bound": list(held_now),
            # per DOF: the residuals' sum of squares, count and autocorrelation inflation (the
            # likelihood ratio of a hold, ``file_not_rejected``: each DOF its own noise variance)
            "dof_rss": np.sum(r.reshape(-1, d) ** 2, axis=0).tolist(), "dof_n": int(r.size // d),
            "dof_inflation": np.where(np.isfinite(factors), factors, 1.0).tolist()}
    return M, DL, DQ, names, p, cov, ci, corr, r.size, info
