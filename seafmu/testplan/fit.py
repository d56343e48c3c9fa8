"""From measured trials to damping coefficients: the plan's question, answered step by step.

Per body axis (surge, sway, yaw), from one accelerate-hold-release-step record:

1. decay (release segment): output-error fit of M v' + d v (+ d_Q v|v|) = 0 with M the file's
   inertia, i.e. of u = u0 e^(-t/T): the time constant T = M/d (method one);
2. step from rest (step segment, measured force F): u = u_ss (1 - e^(-t/T)), so d = F/u_ss, and
   with T from the decay the inertia m = d T (method one's "input force" step);
3. the coefficient written: one output-error fit of the whole accelerate-hold-release record with
   the measured force, damping and inertia free (the inertia correction m_a), validated on the
   step record it did not see (held-out NRMSE);
4. coupled terms: while the trial axis moves at steady speed the hold controller keeps the others
   still, so the force the thrusters put on a held axis k is the hull's coupled damping force,
   tau_k = D_kj v_j at steady state (Fossen's D = -[[.., Y_v, Y_r], [.., N_v, N_r]]). A line through
   the steady levels (rest, step, hold) gives D_kj = -N_v (sway trial, yaw moment) and -Y_r (yaw
   trial, sway force); the intercept takes any constant offset (trim, current);
5. roll and pitch: the release from an angle fitted as m_eff phi'' + d phi' (+ d_Q phi'|phi'|)
   + c phi = 0 (restoring included, as the brief asks): c, d and zeta = d / (2 sqrt(c m_eff)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seafmu.identification.fitting import FitResult
from seafmu.identification.timeseries import TSModel, baseline_model, fit_timeseries
from seafmu.identification.trial import Run, Trial, make_trial
from seafmu.testplan.design import AXES, TrialPlan
from seafmu.testplan.measure import Measurement

PROVENANCE = "seafmu testplan: simulated or measured trial, sensors as the vessel file states them"


@dataclass
class AxisResult:
    """What one trial gave: the fits, the method-one numbers, the steady levels."""

    plan: TrialPlan
    trials: dict[str, Trial] = field(default_factory=dict)  # decay, step, record (joint)
    fits: dict[str, FitResult] = field(default_factory=dict)
    method_one: dict[str, float] = field(default_factory=dict)
    levels: dict[str, dict[str, float]] = field(default_factory=dict)  # window -> {v, tau_<k>}
    # held tau name -> (D_kj, impulse int tau_k dt, displacement int nu_j dt)
    coupled: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    @property
    def damping(self) -> dict[str, float]:
        """d_L, d_Q (and c) of the written fit."""
        f = self.fits["record"]
        return {k: float(v) for k, v in f.params.items() if k in ("d_L", "d_Q", "c")}


def _segment(m: Measurement, t0: float, t1: float, name: str, force: bool) -> Run:
    sel = (m.t >= t0) & (m.t < t1)
    t = m.t[sel] - m.t[sel][0]
    return Run(name=name, y=m.y[sel].copy(), t=t, u=m.tau[sel, m.plan.index].copy() if force else None)


def _baseline(tp: TrialPlan) -> str:
    """The terms the vessel file's model has on this axis (its structure; the values are fitted)."""
    lin, quad = tp.prior.get("d_L", 0.0) != 0.0, tp.prior.get("d_Q", 0.0) != 0.0
    if quad:
        return "linear_quadratic" if lin else "quadratic"
    return "linear"


def _free_damping(tp: TrialPlan) -> list[str]:
    return {"linear": ["d_L"], "quadratic": ["d_Q"], "linear_quadratic": ["d_L", "d_Q"]}[_baseline(tp)]


def identify_axis(m: Measurement) -> AxisResult:
    """Fit one trial (method one, or a roll/pitch release)."""
    tp = m.plan
    res = AxisResult(tp)
    consts = {"mass": tp.mass}
    if tp.kind == "release":
        run = Run(name="release", y=m.y.copy(), t=m.t - m.t[0])
        # a free decay fixes only ratios (c/m_eff, d/m_eff): the scale comes from the hydrostatic
        # stiffness of the file (weight x metacentric height), known better than any damping, and
        # the effective inertia (held DOFs couple in) is fitted with the damping
        consts["stiffness"] = tp.prior["c"]
        base = "linear" if _baseline(tp) == "linear" else "linear_quadratic"  # decay2's baselines
        tr = make_trial("decay2", [run], dof=tp.axis, baseline=base, constants=consts,
                        name=f"{tp.axis}_release", provenance=PROVENANCE)
        res.trials["record"] = tr
        model = baseline_model(tr)
        free = [p for p in model.free if p not in ("d_L", "d_Q")] + _free_damping(tp)
        model = TSModel("second", dict(model.values), [*free, "m_a"], restoring=model.restoring)
        res.fits["record"] = fit_timeseries(tr, model)
        v = res.fits["record"].extras["values"]
        m_eff = v["M"] + v["m_a"]
        if v["c"] > 0 and m_eff > 0:
            res.method_one["natural_frequency"] = math.sqrt(v["c"] / m_eff)
            res.method_one["zeta"] = v["d_L"] / (2.0 * math.sqrt(v["c"] * m_eff))
            res.method_one["m_eff"] = m_eff
        return res

    lead = 2.0  # s of rest before a segment: the fit sees the force start
    decay = _segment(m, tp.t_release, tp.t_step, "release", False)
    step = _segment(m, tp.t_step - lead, m.t[-1] + 1.0, "step", True)
    record = _segment(m, tp.t_accelerate - lead, tp.t_step, "accelerate_hold_release", True)
    base = _baseline(tp)
    tr_decay = make_trial("decay", [decay], dof=tp.axis, baseline=base, constants=consts,
                          name=f"{tp.axis}_decay", provenance=PROVENANCE)
    tr_step = make_trial("step", [step], dof=tp.axis, baseline=base, constants=consts, input_kind="force",
                         name=f"{tp.axis}_step", provenance=PROVENANCE)
    tr_rec = make_trial("step", [record, step], dof=tp.axis, baseline=base, constants=consts,
                        input_kind="force", name=f"{tp.axis}_record", provenance=PROVENANCE)
    res.trials = {"decay": tr_decay, "step": tr_step, "record": tr_rec}
    res.fits["decay"] = fit_timeseries(tr_decay, baseline_model(tr_decay))
    res.fits["step"] = fit_timeseries(tr_step, baseline_model(tr_step))
    joint = baseline_model(tr_rec)
    joint = TSModel("first", dict(joint.values), [*joint.free, "m_a"], "force")
    res.fits["record"] = fit_timeseries(tr_rec, joint)

    # method one in numbers: T from the decay, u_ss and d from the step, m = d T
    d_dec = res.fits["decay"].params
    lin_dec = d_dec.get("d_L", 0.0) + 2.0 * d_dec.get("d_Q", 0.0) * abs(float(decay.y[0]))
    levels = steady_levels(m)
    res.levels = levels
    F = levels["step"]["force"]
    v_ss = levels["step"]["v"]
    mo = res.method_one
    mo["u0"] = float(decay.y[0])
    mo["T_decay"] = tp.mass / lin_dec if lin_dec > 0 else math.inf
    mo["force_step"] = F
    mo["v_ss_step"] = v_ss
    mo["d_step"] = F / v_ss if v_ss != 0 else math.nan
    mo["m_method_one"] = mo["d_step"] * mo["T_decay"]
    return res


def steady_levels(m: Measurement) -> dict[str, dict[str, float]]:
    """Mean velocity of the trial axis and force on every axis in three steady windows."""
    tp = m.plan
    hold_len = (tp.t_release - tp.t_accelerate) / 3.0
    step_len = (m.t[-1] - tp.t_step) / 6.0
    rest_len = 0.15 * (tp.t_step - tp.t_release)
    windows = {"hold": (tp.t_release - hold_len, tp.t_release), "step": (m.t[-1] - step_len, m.t[-1] + 1),
               "rest": (tp.t_step - rest_len, tp.t_step)}
    out = {}
    for name, (a, b) in windows.items():
        sel = (m.t >= a) & (m.t < b)
        row = {"v": float(np.mean(m.y[sel])), "force": float(np.mean(m.tau[sel, tp.index])),
               "t0": float(a), "t1": float(min(b, m.t[-1]))}
        for k in range(m.tau.shape[1]):
            row[f"tau_{k}"] = float(np.mean(m.tau[sel, k]))
            row[f"nu_{k}"] = float(np.nanmean(m.nu[sel, k])) if np.isfinite(m.nu[sel, k]).any() else 0.0
        out[name] = row
    return out


def coupled_terms(results: dict[str, AxisResult], measurements: dict[str, Measurement],
                  M: np.ndarray, D_file: np.ndarray, tau_names: list[str]) -> None:
    """D_kj (k held, j the trial axis) from the impulse on the held axis over a rest-to-rest window.

    Integrating row k of M nu' + D nu = tau from rest (before the force) to rest (the end of the
    release): int tau_k dt = sum_i M_ki dnu_i + sum_i D_ki int nu_i dt. The trial axis travels far
    (int nu_j dt is its displacement, from the position fixes or the heading), the held axes
    hardly move, so D_kj = (int tau_k dt - M_k. dnu - D_kk int nu_k dt - others) / int nu_j dt:
    no derivative of noisy data, the measured forces averaged over the whole record. D_kk is the
    identified value, other cross terms the file's.
    """
    diag = {r.plan.index: r.damping.get("d_L", float(D_file[r.plan.index, r.plan.index]))
            for r in results.values() if r.plan.kind == "method_one"}
    for name, r in results.items():
        if r.plan.kind != "method_one":
            continue
        m = measurements[name]
        tp = r.plan
        j = tp.index
        sel = (m.t >= tp.t_accelerate - 2.0) & (m.t <= tp.t_step)
        t = m.t[sel]
        nu = np.where(np.isfinite(m.nu[sel]), m.nu[sel], 0.0)
        nu[:, j] = m.y[sel]
        integ = np.trapezoid(nu, t, axis=0)
        edge = max(3, len(t) // 100)
        dnu = nu[-edge:].mean(axis=0) - nu[:edge].mean(axis=0)
        for k in diag:
            if k == j:
                continue
            impulse = float(np.trapezoid(m.tau[sel, k], t))
            rest = float(M[k] @ dnu) + diag[k] * integ[k]
            rest += sum(float(D_file[k, i]) * integ[i] for i in range(len(integ)) if i not in (j, k))
            r.coupled[tau_names[k]] = ((impulse - rest) / integ[j], impulse, float(integ[j]))


def coefficient_names(axis: str) -> dict[str, str]:
    """Fossen's names of an axis' damping terms (D = -diag(X_u, ...), D_Q = -diag(X_|u|u, ...))."""
    tau, _, nu, _ = AXES[axis]
    return {"d_L": f"{tau}_{nu}", "d_Q": f"{tau}_|{nu}|{nu}", "c": f"c_{axis}"}


def summary(results: dict[str, AxisResult]) -> dict[str, Any]:
    """Identified values by Fossen's name (sign convention of the vessel file: D entries > 0)."""
    out: dict[str, Any] = {}
    for r in results.values():
        names = coefficient_names(r.plan.axis)
        f = r.fits["record"]
        for p, val in f.params.items():
            if p in names:
                out[names[p]] = {"value": float(val), "ci95": [float(x) for x in f.ci95[p]]}
    return out
