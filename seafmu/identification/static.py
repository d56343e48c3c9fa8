"""Static tables: steady force vs speed (tow carriage, CFD) and thrust vs shaft speed (bollard pull).

Models linear in their parameters are solved exactly by linear least squares; the few catalogue
extensions that are not (current, deadband, saturation, asymmetry) by scipy's least_squares. Held-out
error is leave-one-out: a table has no second run, and each point is a separate steady measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from seafmu.identification import effects, timeseries
from seafmu.identification.fitting import (
    FitResult,
    aic_bic,
    correlation_warnings,
    fit_statistics,
    nrmse,
    rmse,
    unidentifiable_warnings,
)
from seafmu.identification.trial import Trial, TrialError

# The parameters the table models are nonlinear in: those whose effect gives a start grid.
_NONLINEAR = set(effects.static_grids(1.0))
_BOUNDS = effects.bounds("static")  # each effect's own (effects/<name>.py)


def _stages() -> list[effects.CatalogueEffect]:
    return timeseries._stages()


def _nonlinear() -> set[str]:
    """The parameters the table models are nonlinear in (the registered effects' _NONLINEAR)."""
    return set(effects.static_grids(1.0))


@dataclass
class StaticModel:
    table: str  # force_speed | thrust_rpm
    law: str  # thrust law of a thrust table: linear | quadratic
    free: list[str]
    values: dict[str, float] = field(default_factory=dict)
    effect: str | None = None

    def predict(self, x: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """The table's law: the input through the effects' ``static_input`` (current, deadband,
        saturation), a thrust table's thrust law, plus every effect's ``static_term``."""
        v = dict(self.values)
        if theta is not None:
            v.update(zip(self.free, theta, strict=True))
        w = x
        for obj in _stages():
            w = obj.static_input(w, v)
        out = timeseries.thrust(v, self.law, w) if self.table == "thrust_rpm" else None
        for obj in effects.all_effects():
            term = obj.static_term(x, w, v)
            if term is not None:
                out = term if out is None else out + term
        if out is None:
            return np.zeros_like(np.asarray(x, dtype=float))
        return out + np.zeros_like(x) if np.ndim(out) == 0 else out

    def design(self, x: np.ndarray) -> np.ndarray:
        """Regressor matrix when the model is linear in its free parameters."""
        cols = []
        for p in self.free:
            e = np.zeros(len(self.free))
            e[self.free.index(p)] = 1.0
            zero = StaticModel(self.table, self.law, self.free,
                               {**self.values, **dict.fromkeys(self.free, 0.0)})
            cols.append(zero.predict(x, e) - zero.predict(x, np.zeros(len(self.free))))
        return np.column_stack(cols)

    @property
    def linear(self) -> bool:
        """Linear in its free parameters (none of them has a start grid): solved exactly."""
        return not (set(self.free) & _nonlinear())


def table_data(trial: Trial) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y and a group id per point; mirrored points share the group of their original."""
    xs, ys, gs = [], [], []
    gid = 0
    for run in trial.runs:
        x = np.asarray(run.u, dtype=float)
        y = np.asarray(run.y, dtype=float)
        for xi, yi in zip(x, y, strict=True):
            xs.append(xi)
            ys.append(yi)
            gs.append(gid)
            if trial.mirror and xi != 0:
                xs.append(-xi)
                ys.append(-yi)
                gs.append(gid)
            gid += 1
    order = np.argsort(xs, kind="stable")
    return np.array(xs)[order], np.array(ys)[order], np.array(gs)[order]


def baseline_model(trial: Trial) -> StaticModel:
    if trial.table == "force_speed":
        free = {"linear": ["d_L"], "quadratic": ["d_Q"], "linear_quadratic": ["d_L", "d_Q"]}[trial.baseline]
        return StaticModel("force_speed", "linear", free)
    return StaticModel("thrust_rpm", trial.baseline, ["k"])


def extend(model: StaticModel, effect: str, trial: Trial) -> StaticModel:
    """The table model with the effect's parameters free (and the values it fixes)."""
    obj = effects.get(effect)
    assert obj is not None, effect
    m = StaticModel(model.table, model.law, [*model.free, *obj.params],
                    {**model.values, **obj.fixed_values(trial)}, effect)
    if not obj.start_at_absent:  # e.g. a saturation cap: set, but inactive
        m.values.update(obj.absent_values(trial))
    return m


def _solve(model: StaticModel, x: np.ndarray, y: np.ndarray, start: np.ndarray | None,
           multistart: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Parameter vector and Jacobian (design matrix) at the solution (from ``start`` and, with
    ``multistart``, the start grid too)."""
    if model.linear:
        A = model.design(x)
        theta, *_ = np.linalg.lstsq(A, y, rcond=None)
        return theta, A
    bounds = effects.bounds("static")  # the registered effects' (_BOUNDS at import)
    lo = np.array([bounds.get(p, (-np.inf, np.inf))[0] for p in model.free])
    hi = np.array([bounds.get(p, (-np.inf, np.inf))[1] for p in model.free])
    best = None
    starts = [start] if start is not None else []
    if multistart or not starts:
        starts += _starts(model, x, y)
    for s0 in starts:
        with np.errstate(invalid="ignore"):
            inside_lo = np.where(np.isfinite(lo), lo + 1e-9 * (np.abs(lo) + 1), lo)
            inside_hi = np.where(np.isfinite(hi), hi - 1e-9 * (np.abs(hi) + 1), hi)
        s0 = np.clip(s0, inside_lo, inside_hi)
        res = least_squares(lambda th: model.predict(x, th) - y, s0, bounds=(lo, hi), method="trf",
                            x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    return best.x, best.jac


def _starts(model: StaticModel, x: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
    """A few start points: linear part from least squares, nonlinear part on a small grid."""
    nonlinear = _nonlinear()
    lin = [p for p in model.free if p not in nonlinear]
    nl = [p for p in model.free if p in nonlinear]
    xmax = float(np.max(np.abs(x))) or 1.0
    grids = effects.static_grids(xmax)  # each effect's own (effects/<name>.py)
    out = []
    combos: list[dict[str, float]] = [{}]
    for p in nl:
        combos = [{**c, p: g} for c in combos for g in grids[p]]
    for c in combos:
        sub = StaticModel(model.table, model.law, lin, {**model.values, **c})
        theta_lin, *_ = np.linalg.lstsq(sub.design(x), y, rcond=None)
        d = dict(zip(lin, theta_lin, strict=True)) | c
        out.append(np.array([d[p] for p in model.free]))
    return out


def combined(trial: Trial, base: FitResult, names: tuple[str, ...]) -> StaticModel:
    """The baseline table model extended by every effect of ``names``."""
    model = base.extras["model"]
    for name in names:
        model = extend(model, name, trial)
    if len(names) > 1:
        model.effect = "+".join(names)
    return model


def screen(trial: Trial, base: FitResult, names: tuple[str, ...], seeds: list[dict[str, float]]) -> tuple[
        dict[str, float] | None, float]:
    """The best start of a combined table model and its RSS, from ``seeds`` and the start grid of its
    nonlinear parameters (linear ones solved): no fit. Ranks combinations before fitting any."""
    model = combined(trial, base, names)
    x, y, _ = table_data(trial)
    starts = [np.array([s[q] for q in model.free]) for s in seeds if all(q in s for q in model.free)]
    starts += _starts(model, x, y)
    best, best_cost = None, np.inf
    for s0 in starts:
        with np.errstate(all="ignore"):
            cost = float(np.sum((model.predict(x, s0) - y) ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best, best_cost = dict(zip(model.free, (float(v) for v in s0), strict=True)), cost
    return best, best_cost


def fit_static(trial: Trial, model: StaticModel, start: dict[str, float] | None = None) -> FitResult:
    """Fit a table by least squares; held-out error by leave-one-out over groups (mirror pairs)."""
    x, y, groups = table_data(trial)
    p = len(model.free)
    if len(np.unique(groups)) <= p:
        raise TrialError(f"{trial.name}: {len(np.unique(groups))} table points cannot fit {p} parameters")
    s0 = np.array([start[q] for q in model.free]) if start and all(q in start for q in model.free) else None
    theta, jac = _solve(model, x, y, s0)
    yhat = model.predict(x, theta)
    resid = y - yhat
    ci, corr, nonid = fit_statistics(model.free, theta, jac, resid)

    loo = np.empty_like(y)
    for g in np.unique(groups):
        keep = groups != g
        # A combination's leave-one-out refits start from its full-data solution only (its grid is
        # a product of the effects' grids: the multistart of every refit would dominate the search).
        th_g, _ = _solve(model, x[keep], y[keep], theta, multistart="+" not in (model.effect or ""))
        loo[~keep] = model.predict(x[~keep], th_g)
    n = y.size
    aic, bic = aic_bic(float(np.sum(resid**2)), n, p)
    params = dict(zip(model.free, (float(t) for t in theta), strict=True))
    result = FitResult(
        params=params, ci95=ci, correlation=corr, param_names=list(model.free), nonidentifiable=nonid,
        nrmse_fit=nrmse(y, yhat), nrmse_validation=nrmse(y, loo), aic=aic, bic=bic,
        whiteness={"lags": 0, "fraction_outside": float("nan"), "white": None,
                   "note": "table: points are independent steady measurements, whiteness not tested"},
        warnings=sanity(params, trial, x) + correlation_warnings(model.free, corr)
        + unidentifiable_warnings(ci, model.free), n_samples=n,
        method="linear least squares" if model.linear else "nonlinear least squares (trf)",
        extras={"rmse": rmse(resid, p), "rmse_plain": rmse(resid), "x": x, "y": y, "yhat": yhat,
                "loo": loo, "residual": resid, "n_validation": int(n), "rss": float(np.sum(resid**2)),
                "model": model, "effect": model.effect,
                "validation": "leave-one-out" + (" (mirror pairs left out together)"
                                                 if trial.mirror else "")},
    )
    return result


def sanity(params: dict[str, float], trial: Trial, x: np.ndarray) -> list[str]:
    """Physical-sanity warnings of a table fit (the sources hit negative linear damping three times)."""
    w = []
    dL, dQ = params.get("d_L"), params.get("d_Q")
    if dL is not None and dL < 0:
        msg = f"negative linear damping d_L = {dL:.4g}: unphysical (the drag pushes along the motion"
        if dQ is not None and dQ > 0:
            msg += f" below |v| = {-dL / dQ:.3g}"
        w.append(msg + "); a simulation should use d_L = 0 or refit with d_L >= 0")
    if dQ is not None and dQ < 0:
        w.append(f"negative quadratic damping d_Q = {dQ:.4g}: unphysical, the model would accelerate itself")
    if params.get("k", 1.0) <= 0:
        w.append(f"non-positive thrust coefficient k = {params['k']:.4g}")
    if params.get("f_c", 0.0) < 0:
        w.append("negative Coulomb friction")
    return w
