"""When several candidate explanations pass the acceptance rule: how credible each is (Akaike
weights), and which experiment would tell them apart (where their predictions differ most,
against the noise).

A table's candidates are compared over both directions of its input, to a fifth beyond the
largest measured |input|; a time series' over new runs of the same kind (a step from rest to each of a grid
of command levels, or a release from each of a grid of initial speeds or angles), simulated by
both fitted models. The experiment named is the one whose predicted difference is largest; it is
worth running when that difference is several times the noise of the measurement (the residual
RMS of the best fit).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from seafmu.identification import timeseries
from seafmu.identification.catalogue import param_unit
from seafmu.identification.fitting import FitResult
from seafmu.identification.trial import ROTATIONAL, Trial


def akaike_weights(aics: list[float]) -> list[float]:
    """exp(-Δ_i/2) / Σ exp(-Δ_j/2), Δ_i = AIC_i − min AIC: the relative likelihood of each model."""
    if not aics:
        return []
    lo = min(aics)
    rel = [math.exp(-0.5 * (a - lo)) if math.isfinite(a) else 0.0 for a in aics]
    s = sum(rel)
    return [r / s for r in rel]


def noise_level(fit: FitResult) -> float:
    """The measurement noise as the best fit sees it: its residual RMS (n − p for a table)."""
    if "rmse" in fit.extras:
        return float(fit.extras["rmse"])
    rss, n = float(fit.extras.get("rss", math.nan)), max(int(fit.n_samples), 1)
    return math.sqrt(rss / n) if math.isfinite(rss) else math.nan


def discriminating_experiment(trial: Trial, best: FitResult, other: FitResult, best_name: str,
                              other_name: str) -> dict[str, Any] | None:
    """The input (table) or run (time series) where the two fitted models' predictions differ most."""
    noise = noise_level(best)
    if trial.kind == "static":
        return _table(trial, best, other, best_name, other_name, noise)
    if trial.kind in ("step", "decay", "decay2", "pendulum") and trial.dof != "sway_yaw":
        return _series(trial, best, other, best_name, other_name, noise)
    return None


def _predict_table(fit: FitResult, x: np.ndarray) -> np.ndarray:
    model = fit.extras["model"]
    return model.predict(x, np.array([fit.params[p] for p in fit.param_names]))


def _table(trial: Trial, best: FitResult, other: FitResult, bn: str, on: str,
           noise: float) -> dict[str, Any]:
    x = np.asarray(best.extras["x"], dtype=float)
    lo, hi = float(np.min(x)), float(np.max(x))
    span = max(abs(lo), abs(hi))
    # both directions, a fifth beyond the largest |input|: running astern is often the experiment
    grid = np.linspace(-1.2 * span, 1.2 * span, 601)
    with np.errstate(all="ignore"):
        d = np.abs(_predict_table(best, grid) - _predict_table(other, grid))
    d = np.where(np.isfinite(d), d, 0.0)
    i = int(np.argmax(d))
    where = grid[d > 2.0 * noise] if noise > 0 else grid[:0]
    unit = param_unit("u_sat", trial) if trial.table == "thrust_rpm" else ("rad/s" if trial.dof in ROTATIONAL
                                                                          else "m/s")
    yunit = "N·m" if trial.dof in ROTATIONAL and trial.table != "thrust_rpm" else "N"
    what = "shaft speed" if trial.table == "thrust_rpm" else "speed"
    inside = lo <= grid[i] <= hi
    pb = float(_predict_table(best, grid[i:i + 1])[0])
    po = float(_predict_table(other, grid[i:i + 1])[0])
    text = (f"measure at {what} {grid[i]:.3g} {unit} ({'inside' if inside else 'beyond'} the measured "
            f"range {lo:.3g} to {hi:.3g}): '{bn}' predicts {pb:.3g} {yunit}, '{on}' {po:.3g} {yunit}, a "
            f"difference of {d[i]:.3g} {yunit}")
    if noise > 0:
        text += f" = {d[i] / noise:.1f} x the noise ({noise:.3g} {yunit})"
    if where.size:
        text += (f"; they differ by more than twice the noise for {what} {where.min():.3g} to "
                 f"{where.max():.3g} {unit}")
    return {"between": [bn, on], "input": float(grid[i]), "input_unit": unit, "difference": float(d[i]),
            "noise": noise, "difference_over_noise": float(d[i] / noise) if noise > 0 else None,
            "inside_measured_range": bool(inside), "text": text}


def _series(trial: Trial, best: FitResult, other: FitResult, bn: str, on: str,
            noise: float) -> dict[str, Any]:
    runs = trial.runs
    t = np.asarray(runs[0].t, dtype=float)
    model_b, model_o = best.extras["model"], other.extras["model"]
    vb, vo = best.extras["values"], other.extras["values"]
    if trial.kind == "step":
        U = max(float(np.max(np.abs(np.asarray(r.u, dtype=float)))) for r in runs if r.u is not None)
        levels = [s * U for s in (-1.2, -1.0, -0.6, -0.3, -0.1, 0.1, 0.3, 0.6, 1.0, 1.2)]
        what, unit = "a step from rest to", param_unit("u_sat", trial) if trial.input_kind == "rpm" else "N"
    else:
        V = max(float(np.max(np.abs(np.asarray(r.y, dtype=float)))) for r in runs)
        levels = [s * V for s in (-1.5, -1.0, -0.5, -0.2, 0.2, 0.5, 1.0, 1.5)]
        rot = trial.dof in ROTATIONAL or trial.kind == "pendulum"
        if trial.kind == "decay":
            what, unit = "a release at the speed", "rad/s" if rot else "m/s"
        else:
            what, unit = "a release from", "rad" if rot else "m"
    best_i, best_d, best_t = 0, -1.0, 0.0
    for i, lev in enumerate(levels):
        if trial.kind == "step":
            u = np.full(t.size, lev)
            u[0] = 0.0
            ic: tuple[float, ...] = (0.0,)
        else:
            u = None
            ic = (lev,) if model_b.family == "first" else (lev, 0.0)
        with np.errstate(all="ignore"):
            yb = timeseries.simulate(model_b, vb, t, u, ic)
            yo = timeseries.simulate(model_o, vo, t, u, ic)
        d = np.abs(yb - yo)
        d = np.where(np.isfinite(d), d, 0.0)
        if float(np.max(d)) > best_d:
            best_i, best_d, best_t = i, float(np.max(d)), float(t[int(np.argmax(d))] - t[0])
    lev = levels[best_i]
    ratio = best_d / noise if noise > 0 else math.inf
    text = (f"run {what} {lev:.3g} {unit} for {t[-1] - t[0]:.3g} s: the predictions of '{bn}' and '{on}' "
            f"differ most there, by {best_d:.3g} at t = {best_t:.3g} s, {ratio:.1f} x the noise "
            f"({noise:.3g})")
    return {"between": [bn, on], "experiment": what, "level": float(lev), "level_unit": unit,
            "difference": best_d, "at_time_s": best_t, "noise": noise,
            "difference_over_noise": ratio if math.isfinite(ratio) else None, "text": text}
