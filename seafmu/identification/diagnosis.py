"""Diagnosis: from "the simulation is wrong" to "this is why, and this is the gain".

Fit the baseline; extend it by each catalogue effect that the trial can show and refit (output
error for time series, least squares for tables); accept the best extension only if it clearly
wins on held-out data AND on the information criterion AND its parameter is significant. If
none qualifies the answer is "no effect found": a false alarm on clean data is as wrong as a miss.

Acceptance rule (all must hold; documented in docs/identification.md):
    held-out NRMSE ratio r = baseline/extended >= 1.02 and n_val ln(r^2) >= 10 (the held-out error
    drops by more than noise explains: a likelihood-ratio margin on data the fit never saw),
    dAIC = AIC_ext - AIC_base <= -10 on the fitting data,
    95 % CI of the effect parameter excludes its "effect absent" value.
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.identification import catalogue, static, timeseries
from seafmu.identification.catalogue import CATALOGUE, effect_params, null_value
from seafmu.identification.fitting import FitResult
from seafmu.identification.trial import DOF_INDEX, Run, Trial, TrialError, make_trial, maneuver_factors

# The outcome when no candidate effect was fitted at all (e.g. a maneuver trial: the catalogue
# extends 1-2-DOF trial models). Distinct from "none", which means "tested, and nothing found".
NOT_TESTED = "not_tested"


@dataclass(frozen=True)
class Rule:
    """Thresholds of the acceptance rule."""

    min_ratio: float = 1.02
    min_heldout_gain: float = 10.0  # n_val ln(ratio^2): held-out log-likelihood gain
    max_delta_aic: float = -10.0


@dataclass
class Candidate:
    effect: str
    fit: FitResult | None
    ratio: float = math.nan  # held-out NRMSE baseline / extended (> 1: extension better)
    delta_aic: float = math.nan
    significant: bool = False
    accepted: bool = False
    reason: str = ""
    seconds: float = 0.0

    def row(self) -> dict[str, Any]:
        f = self.fit
        return {"effect": self.effect,
                "nrmse_validation": _num(f.nrmse_validation) if f else None,
                "nrmse_fit": _num(f.nrmse_fit) if f else None,
                "delta_aic": _num(self.delta_aic), "ratio": _num(self.ratio),
                "significant": self.significant, "accepted": self.accepted, "reason": self.reason,
                "params": {k: float(f.params[k]) for k in effect_params(self.effect, f.param_names)}
                if f else {}}


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


@dataclass
class Diagnosis:
    trial: Trial
    baseline: FitResult
    candidates: list[Candidate]
    skipped: dict[str, str]
    cause: Candidate | None
    evidence: str
    rule: Rule = field(default_factory=Rule)
    seconds: float = 0.0

    @property
    def extended(self) -> FitResult:
        return self.cause.fit if self.cause and self.cause.fit else self.baseline

    @property
    def tested(self) -> bool:
        """False when no catalogue effect could be fitted: "none" would read as "tested and clean"."""
        return any(c.fit is not None for c in self.candidates)

    @property
    def effect(self) -> str:
        if self.cause:
            return self.cause.effect
        return "none" if self.tested else NOT_TESTED

    def ranking(self) -> list[Candidate]:
        ok = [c for c in self.candidates if c.fit is not None]
        return sorted(ok, key=lambda c: (c.fit.nrmse_validation if math.isfinite(c.fit.nrmse_validation)
                                         else math.inf))  # type: ignore[union-attr]

    def to_json(self) -> dict[str, Any]:
        """The --json shape of the issue, plus the full fit reports."""
        def summary(f: FitResult) -> dict[str, Any]:
            d = f.to_dict()
            d["params"] = {k: float(v) for k, v in f.params.items()}
            return d

        b, e = self.baseline, self.extended
        ratio = b.nrmse_validation / e.nrmse_validation if e.nrmse_validation > 0 else math.nan
        return {
            "trial": {"name": self.trial.name, "kind": self.trial.kind, "dof": self.trial.dof,
                      "baseline_model": self.trial.baseline, "provenance": self.trial.provenance},
            "baseline": summary(b),
            "cause": {"effect": self.effect, "evidence": self.evidence, "tested": self.tested,
                      "ranking": [c.row() for c in self.ranking()],
                      "not_applicable": self.skipped},
            "extended": summary(e),
            "gain": {"validation_nrmse_ratio": _num(ratio), "delta_aic": _num(e.aic - b.aic),
                     "nrmse_validation_before": _num(b.nrmse_validation),
                     "nrmse_validation_after": _num(e.nrmse_validation)},
            "rule": {"min_ratio": self.rule.min_ratio, "min_heldout_gain": self.rule.min_heldout_gain,
                     "max_delta_aic": self.rule.max_delta_aic,
                     "significance": "95 % CI of the effect parameter excludes its 'absent' value"},
            "seconds": round(self.seconds, 3),
        }


# -- fitting dispatch ------------------------------------------------------------------------------

def fit_baseline(trial: Trial, diagnosis: bool = False) -> FitResult:
    """The baseline model of the trial, fitted.

    A maneuver diagnosis always uses the output-error baseline: its extensions are output-error
    fits, and comparing them with an LS baseline would credit the method, not the effect.
    """
    if trial.kind == "static":
        return static.fit_static(trial, static.baseline_model(trial))
    if trial.kind == "maneuver":
        return fit_maneuver(trial, "output_error" if diagnosis else trial.baseline)
    return timeseries.fit_timeseries(trial, timeseries.baseline_model(trial))


def fit_extension(trial: Trial, base: FitResult, effect: str) -> FitResult:
    if trial.kind == "static":
        model = static.extend(base.extras["model"], effect, trial)
        return static.fit_static(trial, model, start={**base.params})
    if trial.kind == "maneuver":  # refit from the baseline's damping with the effect's parameters
        return fit_maneuver(trial, "output_error", effect=effect, start=dict(base.params))
    return timeseries.fit_effect(trial, base, effect)


def fit_maneuver(trial: Trial, method: str, effect: str | None = None,
                 start: dict[str, float] | None = None) -> FitResult:
    """Multi-DOF maneuver log: delegated to the maneuver module (Minerva 2 LS or output error)."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.maneuver import identify_maneuver

    if not trial.vessel:
        raise TrialError(f"{trial.name}: a maneuver trial needs a vessel (trial 'vessel' or --vessel)")
    vessel = load_vessel(trial.vessel)
    data = maneuver_data(trial, vessel)
    return identify_maneuver(data, vessel, method=method, validation_fraction=trial.validation_fraction,
                             effect=effect, oe_start=start)


def maneuver_data(trial: Trial, vessel: Any) -> Any:
    """The maneuver trial's log in SI units (column units from the trial YAML applied)."""
    from seafmu.identification.maneuver import load_maneuver_csv

    return load_maneuver_csv(trial.files[0], vessel, trial.columns or None, maneuver_factors(trial))


# -- identification and diagnosis ------------------------------------------------------------------

@dataclass
class Identification:
    """The baseline fit of a trial plus any alternative fits worth showing side by side."""

    trial: Trial
    fit: FitResult
    alternatives: dict[str, FitResult] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"trial": {"name": self.trial.name, "kind": self.trial.kind, "dof": self.trial.dof,
                          "baseline_model": self.trial.baseline, "provenance": self.trial.provenance},
                "fit": self.fit.to_dict(),
                "alternatives": {k: v.to_dict() for k, v in self.alternatives.items()},
                "notes": self.notes, "seconds": round(self.seconds, 3)}


def identify(trial: Trial) -> Identification:
    """Fit the trial's baseline model (and, for the pendulum, the equation-error variants)."""
    t0 = time.perf_counter()
    if trial.kind == "maneuver":
        fit = fit_maneuver(trial, trial.baseline)
        alt = {}
        other = "output_error" if trial.baseline == "ls" else "ls"
        try:
            alt[other] = fit_maneuver(trial, other)
        except (TrialError, ValueError, np.linalg.LinAlgError) as exc:
            alt = {}
            notes = [f"{other} fit failed: {exc}"]
        else:
            notes = []
        return Identification(trial, fit, alt, notes, time.perf_counter() - t0)
    fit = fit_baseline(trial)
    ident = Identification(trial, fit)
    if trial.kind == "static":
        ident.notes.append(f"RMSE {fit.extras['rmse']:.4g} with n - p in the denominator, "
                           f"{fit.extras['rmse_plain']:.4g} with n ({fit.n_samples} points"
                           f"{', mirrored to negative speeds' if trial.mirror else ''}).")
    if trial.kind == "pendulum":
        ident.alternatives, notes = pendulum_equation_error(trial, fit)
        ident.notes += notes
    ident.seconds = time.perf_counter() - t0
    return ident


def diagnose(trial: Trial, effects: list[str] | None = None, rule: Rule | None = None) -> Diagnosis:
    """Baseline fit, every applicable catalogue effect as an extension, the acceptance rule."""
    rule = rule or Rule()
    t0 = time.perf_counter()
    unknown = [e for e in effects or [] if e not in CATALOGUE]
    if unknown:
        raise TrialError(f"unknown effect(s) {', '.join(unknown)}; catalogue: {', '.join(CATALOGUE)}")
    base = fit_baseline(trial, diagnosis=True)
    skipped: dict[str, str] = {}
    cands: list[Candidate] = []
    for name in effects or list(CATALOGUE):
        why = catalogue.not_applicable(name, trial)
        if why:
            skipped[name] = why
            continue
        t1 = time.perf_counter()
        try:
            fit = fit_extension(trial, base, name)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            cands.append(Candidate(name, None, reason=f"fit failed: {exc}", seconds=time.perf_counter() - t1))
            continue
        cands.append(judge(name, base, fit, trial, rule, time.perf_counter() - t1))
    cause = choose(cands)
    evidence = explain(trial, base, cands, cause, skipped)
    return Diagnosis(trial, base, cands, skipped, cause, evidence, rule, time.perf_counter() - t0)


def judge(name: str, base: FitResult, fit: FitResult, trial: Trial, rule: Rule,
          seconds: float = 0.0) -> Candidate:
    """Apply the acceptance rule to one refitted extension."""
    ev = fit.nrmse_validation
    ratio = base.nrmse_validation / ev if ev > 0 and math.isfinite(ev) else (math.inf if ev == 0 else 0.0)
    dAIC = fit.aic - base.aic
    sig = False
    for p in effect_params(name, fit.param_names):
        if p in fit.ci95:
            lo, hi = fit.ci95[p]
            null = null_value(p, trial)
            if math.isfinite(lo) and math.isfinite(hi) and not (lo <= null <= hi):
                sig = True
    reasons = []
    n_val = int(fit.extras.get("n_validation", 0))
    gain = n_val * 2.0 * math.log(ratio) if ratio > 0 and math.isfinite(ratio) else (
        math.inf if ratio == math.inf else -math.inf)
    if not ratio >= rule.min_ratio:
        reasons.append(f"held-out ratio {ratio:.3f} < {rule.min_ratio}")
    elif not gain >= rule.min_heldout_gain:
        reasons.append(f"held-out gain n ln(ratio^2) = {gain:.1f} < {rule.min_heldout_gain:g} "
                       f"({n_val} held-out samples)")
    if not dAIC <= rule.max_delta_aic:
        reasons.append(f"dAIC {dAIC:.1f} > {rule.max_delta_aic:g}")
    if not sig:
        reasons.append("parameter not significant (CI includes the no-effect value)")
    return Candidate(name, fit, ratio, dAIC, sig, not reasons, "; ".join(reasons) or "accepted", seconds)


def choose(cands: list[Candidate]) -> Candidate | None:
    """Best accepted candidate: lowest held-out NRMSE; within 1 % of it, the lowest AIC."""
    ok = [c for c in cands if c.accepted and c.fit is not None]
    if not ok:
        return None
    best = min(c.fit.nrmse_validation for c in ok)  # type: ignore[union-attr]
    near = [c for c in ok if c.fit.nrmse_validation <= best * 1.01]  # type: ignore[union-attr]
    return min(near, key=lambda c: c.fit.aic)  # type: ignore[union-attr]


def explain(trial: Trial, base: FitResult, cands: list[Candidate], cause: Candidate | None,
            skipped: dict[str, str]) -> str:
    if cause is None:
        tried = [c for c in cands if c.fit is not None]
        if not tried:
            failed = [c for c in cands if c.fit is None]
            if failed:
                why = f"every candidate fit failed ({failed[0].effect}: {failed[0].reason})"
            elif trial.kind == "maneuver":
                why = ("none of the maneuver-level extensions (current, constant_force) was asked for; "
                       "the other catalogue effects extend 1-2-DOF trial models")
            else:
                why = f"no catalogue effect is observable in this {trial.kind} trial"
            return f"Not tested: {why} ({len(skipped)} not applicable). This is not a clean bill of health."
        top = max(tried, key=lambda c: c.ratio)
        text = (f"No effect found: none of the {len(tried)} candidate effects beats the baseline clearly on "
                f"held-out data (best: {top.effect}, ratio {top.ratio:.3f}, dAIC {top.delta_aic:.1f}; "
                f"{top.reason})")
        w = base.whiteness
        if w.get("white") is False:
            # The model is still wrong somewhere: say so rather than imply the data are explained.
            text += (f"; but the baseline residual is not white (Ljung-Box p = {w['ljung_box_p']:.2g}): "
                     "structure remains that no catalogue effect explains")
        return text + "."
    # A second accepted effect that is almost as good is named: the data may not separate them.
    runner = None
    for c in cands:
        if c is not cause and c.accepted and c.fit is not None and cause.fit is not None and \
                c.fit.nrmse_validation <= cause.fit.nrmse_validation * 1.02 and \
                abs(c.fit.aic - cause.fit.aic) < 4:
            runner = c.effect
    assert cause.fit is not None
    return catalogue.evidence(cause.effect, cause.fit.params, trial, base.nrmse_validation,
                              cause.fit.nrmse_validation, cause.delta_aic, runner)


# -- the pendulum: what differentiation does ---------------------------------------------------------

def pendulum_equation_error(trial: Trial, oe: FitResult) -> tuple[dict[str, FitResult], list[str]]:
    """The paper's method (linear LS on sin θ, θ̇, θ̇|θ̇|) with published and with differentiated rates."""
    from seafmu.identification.fitting import (
        aic_bic,
        correlation_warnings,
        fit_statistics,
        nrmse,
        whiteness_test,
    )

    run = trial.runs[0]
    t, th = np.asarray(run.t), np.asarray(run.y)
    variants: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if run.rate is not None and run.accel is not None:
        variants["equation_error_published_rates"] = (np.asarray(run.rate), np.asarray(run.accel))
    d1 = np.gradient(th, t)
    variants["equation_error_differentiated_theta"] = (d1, np.gradient(d1, t))
    out: dict[str, FitResult] = {}
    names = ["alpha", "beta", "gamma"]
    model = timeseries.baseline_model(trial)
    for key, (rate, acc) in variants.items():
        # A regression on all samples, as the paper did; held-out error by leave-one-out (PRESS),
        # as for any table of independent rows.
        A = np.column_stack([np.sin(th), -rate, -rate * np.abs(rate)])
        coef, *_ = np.linalg.lstsq(A, acc, rcond=None)
        pred = A @ coef
        resid = acc - pred
        hat = np.einsum("ij,ji->i", A, np.linalg.pinv(A))
        loo = acc - resid / np.where(hat < 1 - 1e-12, 1 - hat, np.inf)
        ci, corr, nonid = fit_statistics(names, coef, A, resid)
        aic, bic = aic_bic(float(np.sum(resid**2)), len(t), 3)
        vals = dict(model.values) | dict(zip(names, (float(c) for c in coef), strict=True))
        # How good are these numbers as a simulation model? Simulate θ from the OE initial state.
        with np.errstate(all="ignore"):
            sim = timeseries.simulate(model, vals, t, None, oe.extras["initial_states"][0])
        params = dict(zip(names, (float(c) for c in coef), strict=True))
        out[key] = FitResult(
            params=params, ci95=ci, correlation=corr, param_names=names, nonidentifiable=nonid,
            nrmse_fit=nrmse(acc, pred), nrmse_validation=nrmse(acc, loo),
            aic=aic, bic=bic, whiteness=whiteness_test(resid),
            warnings=timeseries.sanity(model, vals, trial) + correlation_warnings(names, corr),
            n_samples=len(t),
            method="equation error (linear least squares on theta_dd, all samples)",
            extras={"theta_simulation_nrmse": nrmse(th, sim) if np.all(np.isfinite(sim)) else math.inf,
                    "target": "theta_dd", "validation": "leave-one-out over samples (PRESS)"},
        )
    notes = [
        "NRMSE of the equation-error fits is of theta_dd (the regression target), not of theta.",
        "The published rates are smoothed by the authors while theta is tracker-quantised (steps of about "
        "0.01 rad at 30 frames/s): differentiating theta twice turns each quantisation step into an "
        "acceleration spike of order 0.01/(1/30)^2 = 9 rad/s^2, larger than the signal, so the "
        "differentiated fit is noise (its signs are not even physical). Smoothing before differentiating "
        "removes the spikes but also lowers the peaks: it biases beta and gamma.",
        f"Output error on theta alone has {len(oe.params) + 2} unknowns (alpha, beta, gamma and the initial "
        f"angle and rate) for {oe.n_samples} samples of one half-swing: the intervals are wide and "
        "beta-gamma are not separable; the published multi-swing trials are what makes this identifiable.",
    ]
    return out, notes


# -- writing back into a vessel file --------------------------------------------------------------

def vessel_updates(trial: Trial, fit: FitResult, vessel_dof: int) -> tuple[dict[str, float], dict[str, str],
                                                                           list[str]]:
    """Vessel-file field paths and values from a fit, the fit parameter behind each, and notes."""
    notes: list[str] = []
    idx_map = DOF_INDEX[vessel_dof]
    p = dict(fit.params)
    up: dict[str, float] = {}
    origin: dict[str, str] = {}
    if trial.dof == "sway_yaw":
        i, j = idx_map["sway"], idx_map["yaw"]
        for key, (a, b) in {"Y_v": (i, i), "Y_r": (i, j), "N_v": (j, i), "N_r": (j, j)}.items():
            if key in p:
                up[f"linear_damping[{a}][{b}]"] = -p[key]
                origin[f"linear_damping[{a}][{b}]"] = f"-{key}"
        return up, origin, notes
    if trial.dof not in idx_map:
        return {}, {}, [f"the vessel has no {trial.dof} DOF"]
    i = idx_map[trial.dof]
    physical = trial.kind == "static" or "mass" in trial.constants
    if trial.kind == "pendulum":
        d = fit.extras.get("derived", {})
        if "K_L" in d and "K_Q" in d:
            p = {"d_L": d["K_L"], "d_Q": d["K_Q"]}
        else:
            return {}, {}, ["pendulum alpha, beta, gamma need weight, buoyancy and rod length to become "
                            "K_L, K_Q"]
    elif not physical:
        return {}, {}, ["no 'mass' constant: the parameters are per unit inertia and cannot go into a "
                        "vessel file"]
    if trial.kind == "static" and trial.table == "thrust_rpm":
        return {}, {}, ["thrust coefficients are per thruster: edit thrusters.units[*].k_forward by hand"]
    for key, field_name in (("d_L", "linear_damping"), ("d_Q", "quadratic_damping")):
        if key in p:
            val = p[key]
            if val < 0:
                notes.append(f"fitted {key} = {val:.4g} < 0 is unphysical: written as 0")
                val = 0.0
            up[f"{field_name}[{i}][{i}]"] = val
            origin[f"{field_name}[{i}][{i}]"] = key
    if "m_a" in p:
        up[f"added_mass[{i}][{i}]"] = trial.constants.get("added_mass", 0.0) + p["m_a"]
        origin[f"added_mass[{i}][{i}]"] = "m_a"
    rest = [k for k in p if k not in ("d_L", "d_Q", "m_a", "k", "c")]
    if rest:
        notes.append(f"not written (no vessel-file field): {', '.join(rest)}")
    return up, origin, notes


def write_vessel(trial: Trial, fit: FitResult, out_path: Path, method: str, vessel: str | None = None) -> str:
    """Write identified values into a copy of the trial's vessel file; returns a one-line message."""
    return write_vessel_file(trial, fit, out_path, method, vessel)[0]


def write_vessel_file(trial: Trial, fit: FitResult, out_path: Path, method: str,
                      vessel: str | None = None) -> tuple[str, Path | None]:
    """As write_vessel, plus the written path (None if nothing was written), for the replay."""
    name = vessel or trial.vessel
    if not name:
        return "write-back skipped: the trial names no vessel (trial 'vessel' or --vessel)", None
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.writeback import write_back

    spec = load_vessel(name)
    if trial.kind == "maneuver":  # the maneuver module knows its own parameter names
        from seafmu.identification.writeback import updates_from_fit

        updates, mprov = updates_from_fit(fit, spec, trial=trial.name)
        if not updates:
            return "write-back skipped: the maneuver fit has no vessel-file parameters", None
        mprov = {**mprov, "date": _dt.date.today().isoformat(), "method": method}
        path = write_back(name, updates, out_path, mprov)
        return f"wrote {len(updates)} entries ({', '.join(sorted(updates)[:6])}, ...) to {path}", path
    updates, origin, notes = vessel_updates(trial, fit, spec.dof)
    if not updates:
        return "write-back skipped: " + "; ".join(notes or ["nothing to write"]), None
    prov = {"trial": trial.name, "date": _dt.date.today().isoformat(), "method": method}
    if notes:
        prov["note"] = "; ".join(notes)
    for key, par in origin.items():
        bare = par.lstrip("-")
        if bare in fit.ci95:
            lo, hi = fit.ci95[bare]
            lo, hi = (-hi, -lo) if par.startswith("-") else (lo, hi)
            prov[key] = f"95 % CI [{lo:.4g}, {hi:.4g}]"
    path = write_back(name, updates, out_path, prov)
    extra = f" ({'; '.join(notes)})" if notes else ""
    return f"wrote {', '.join(f'{k} = {v:.5g}' for k, v in updates.items())} to {path}{extra}", path


# -- synthetic trials with a hidden effect ---------------------------------------------------------

# Truth of the synthetic surge vessel: AMV-like (40 kg + 10 kg added mass, d_Q = 34.08, k = 12.63).
SURGE = {"M": 50.0, "d_L": 3.0, "d_Q": 34.0, "k": 12.63}


def demo_trial(effect: str | None, kind: str | None = None, noise: float = 0.01, amplitude: float = 1.0,
               seed: int = 0) -> Trial:
    """A synthetic trial in which `effect` is hidden (None: clean data of `kind`).

    Each effect gets the trial kind where it is observable, with an effect size a real vessel
    could have. noise is the sensor noise std as a fraction of the largest |output|; amplitude
    scales the excitation (initial speed/angle or command levels). Data are simulated with 10 RK4
    sub-steps per sample, so the fit (one step per sample) does not share the generator's
    discretisation.
    """
    rng = np.random.default_rng(seed)
    A = amplitude
    kind = kind or (_DESIGN[effect] if effect else "decay")
    if kind not in DEMO_EFFECTS:
        raise ValueError(f"demo kind '{kind}': one of {', '.join(DEMO_EFFECTS)}")
    if effect is not None and effect not in DEMO_EFFECTS[kind]:
        raise ValueError(f"demo: '{effect}' is not hidden in a '{kind}' trial "
                         f"(there: {', '.join(sorted(DEMO_EFFECTS[kind]))})")
    fam = {"decay": "first", "step": "first", "decay2": "second", "pendulum": "pendulum",
           "sway_yaw": "sway_yaw", "static": "static", "thrust": "static"}[kind]
    truth = dict(timeseries.DEFAULTS.get(fam, {}))
    baseline = "linear_quadratic"
    constants: dict[str, float] = {}
    name = f"hidden_{effect or 'none'}_{kind}"

    def noisy(y: np.ndarray) -> np.ndarray:
        scale = np.max(np.abs(y), axis=0)
        return y + rng.normal(0.0, 1.0, y.shape) * noise * scale

    if kind in ("static", "thrust"):
        if kind == "static":
            x = A * np.linspace(0.1, 1.0, 16)
            v = {"d_L": 15.6, "d_Q": 42.7}
            if effect == "quadratic_damping":
                baseline = "linear"
            elif effect == "linear_damping":
                baseline = "quadratic"
            m = static.StaticModel("force_speed", "linear", [], v)
            y = m.predict(x)
            return make_trial("static", [Run("table", noisy(y), u=x)], dof="surge", table="force_speed",
                              baseline=baseline, name=name)
        x = A * np.array([-2.2, -1.8, -1.4, -1.0, -0.6, -0.3, 0.3, 0.6, 1.0, 1.4, 1.8, 2.2])
        v = {"k": 12.63}
        law = "linear"
        if effect == "thrust_quadratic":
            v = {"k": 0.0, "k_q": 6.0}
        elif effect == "thrust_asymmetry":
            v["eta_rev"] = -0.35
        elif effect == "deadband":
            v["n_0"] = 0.25 * A
        elif effect == "saturation":
            v["u_sat"] = 0.7 * 2.2 * A
        elif effect == "constant_force":
            v["F_0"] = 1.5
        y = static.StaticModel("thrust_rpm", law, [], v).predict(x)
        return make_trial("static", [Run("bollard", noisy(y), u=x)], dof="surge", table="thrust_rpm",
                          baseline="linear", name=name)

    if kind == "sway_yaw":
        truth.update(m22=91.4, m66=25.4, Y_v=-60.0, N_r=-20.0)
        if effect == "coupling":
            truth.update(Y_r=12.0, N_v=6.0)
        constants = {"mass": 91.4, "inertia": 25.4}
        model = timeseries.TSModel("sway_yaw", truth, [], "force")
        runs = []
        for i, pattern in enumerate(([20, 0, -20, 10, 0], [-10, 25, 0, -25, 5])):
            t = np.arange(0, 40.0, 0.1)
            seg = np.minimum((t // 8).astype(int), 4)
            Y = A * np.array(pattern, dtype=float)[seg]
            N = A * 0.3 * np.array(pattern[::-1], dtype=float)[(seg + 1) % 5]
            u = np.column_stack([Y, N])
            y = timeseries.simulate(model, truth, t, u, (0.0, 0.0), substeps=10)
            runs.append(Run(f"run{i + 1}", noisy(y), t, u))
        return make_trial("step", runs, dof="sway_yaw", baseline="linear", constants=constants, name=name)

    if kind == "pendulum":
        truth.update(alpha=-4.0, beta=0.8, gamma=1.6)
        if effect == "coulomb_friction":
            truth["f_c"] = 0.06
        elif effect == "constant_force":
            truth["F_0"] = 0.15
        model = timeseries.TSModel("pendulum", truth, [], restoring="sin")
        t = np.arange(0, 14.0, 1 / 30)
        runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (th0, 0.0), 10)), t)
                for i, th0 in enumerate((0.5 * A, -0.35 * A, 0.42 * A))]
        return make_trial("pendulum", runs, dof="surge", baseline="pendulum", name=name)

    if kind == "decay2":
        truth.update(M=5.0, c=20.0, d_L=0.5)
        constants = {"mass": 5.0}
        restoring = "linear"
        if effect == "nonlinear_restoring":
            restoring = "sin"
        elif effect == "quadratic_damping":
            truth["d_Q"] = 3.0
        elif effect == "coulomb_friction":
            truth["f_c"] = 0.15
        elif effect == "constant_force":
            truth["F_0"] = 0.8
        elif effect == "added_mass":
            truth["m_a"] = 1.5
            constants["stiffness"] = 20.0
        baseline = "linear"
        model = timeseries.TSModel("second", truth, [], restoring=restoring)
        t = np.arange(0, 25.0, 0.05)
        runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (x0, 0.0), 10)), t)
                for i, x0 in enumerate((0.75 * A, -0.5 * A))]
        return make_trial("decay2", runs, dof="roll", baseline=baseline, constants=constants, name=name)

    truth.update(SURGE)
    constants = {"mass": SURGE["M"]}
    if kind == "decay":
        starts = (1.0 * A, 0.6 * A)
        if effect == "linear_damping":
            truth["d_L"] = 8.0
            baseline = "quadratic"
        elif effect == "quadratic_damping":
            baseline = "linear"
        elif effect in ("current", "constant_force", "coulomb_friction"):
            starts = (1.0 * A, -1.0 * A, 0.7 * A)
            truth.update({"current": {"v_c": 0.1}, "constant_force": {"F_0": 1.0},
                          "coulomb_friction": {"f_c": 1.0}}[effect])
        model = timeseries.TSModel("first", truth, [])
        t = np.arange(0, 25.0, 0.1)
        runs = [Run(f"coast{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (v0,), 10)), t)
                for i, v0 in enumerate(starts)]
        return make_trial("decay", runs, dof="surge", baseline=baseline, constants=constants, name=name)

    # step trials with a shaft-speed command (or a force command for added mass)
    input_kind = "rpm"
    law = "linear"
    levels = [(1.0, 2.0, 0.5, -1.0, -2.0, 0.0), (1.5, 0.8, -1.5, 2.2, 0.3, -0.6)]
    if effect == "thrust_quadratic":
        truth.update(k=6.0)
        law = "quadratic"
    elif effect == "thrust_asymmetry":
        truth["eta_rev"] = -0.35
    elif effect == "deadband":
        truth["n_0"] = 0.3 * A
        levels = [(1.0, 2.0, 0.4, -1.0, -2.0, -0.4), (1.5, 0.6, -1.5, 2.2, 0.3, -0.6)]
    elif effect == "actuator_lag":
        truth["T_lag"] = 0.8
    elif effect == "time_delay":
        truth["t_d"] = 0.5
    elif effect == "saturation":
        truth["u_sat"] = 1.4 * A
    elif effect == "constant_force":
        truth["F_0"] = 1.5
    elif effect == "added_mass":
        input_kind = "force"
        constants = {"mass": 40.0}
        truth.update(M=40.0, m_a=12.0)
        levels = [(20.0, 40.0, 10.0, -20.0, -40.0, 0.0), (30.0, 15.0, -30.0, 45.0, 5.0, -10.0)]
    model = timeseries.TSModel("first", truth, [], input_kind, law)
    runs = []
    for i, lv in enumerate(levels):
        t = np.arange(0, 48.0, 0.1)
        u = A * np.array(lv)[np.minimum((t // 8).astype(int), len(lv) - 1)]
        y = timeseries.simulate(model, truth, t, u, (0.0,), substeps=10)
        runs.append(Run(f"steps{i + 1}", noisy(y), t, u))
    return make_trial("step", runs, dof="surge", baseline=baseline, constants=constants, name=name,
                      input_kind=input_kind)


# effect -> the trial kind where demo_trial hides it by default (where it is observable)
_DESIGN: dict[str, str] = {
    "linear_damping": "decay", "quadratic_damping": "decay", "coulomb_friction": "pendulum",
    "current": "decay", "constant_force": "step", "added_mass": "step",
    "thrust_quadratic": "step", "thrust_asymmetry": "step", "deadband": "step",
    "actuator_lag": "step", "time_delay": "step", "saturation": "step",
    "nonlinear_restoring": "decay2", "coupling": "sway_yaw",
}
# kind -> effects demo_trial can hide in it ("static": force-speed table, "thrust": bollard table)
DEMO_EFFECTS: dict[str, set[str]] = {
    "static": {"linear_damping", "quadratic_damping"},
    "thrust": {"thrust_quadratic", "thrust_asymmetry", "deadband", "saturation", "constant_force"},
    "decay": {"linear_damping", "quadratic_damping", "current", "constant_force", "coulomb_friction"},
    "step": {"thrust_quadratic", "thrust_asymmetry", "deadband", "actuator_lag", "time_delay", "saturation",
             "constant_force", "added_mass"},
    "decay2": {"nonlinear_restoring", "quadratic_damping", "coulomb_friction", "constant_force",
               "added_mass"},
    "pendulum": {"coulomb_friction", "constant_force"},
    "sway_yaw": {"coupling"},
}
