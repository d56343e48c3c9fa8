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

Then combinations of effects (``search_combinations``; maneuver logs: ``_maneuver_combinations``,
pairs of effects or of located thrusters, screened by one Gauss-Newton step from the single fits,
growing by one effect at a time): each must pass the same rule and beat each of its sub-models by
its margins; the cause is the smallest, most specific explanation the data
support (``choose``), and every other one that passes is reported with its Akaike weight and the
experiment that would tell it apart (``alternatives``, ``ambiguity.py``). An extension whose claim
the data contradict (``check_claims``) is rejected.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import zip_longest
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from seafmu.identification import catalogue, static, timeseries
from seafmu.identification import effects as effect_objects
from seafmu.identification.ambiguity import akaike_weights, discriminating_experiment, noise_level
from seafmu.identification.catalogue import CATALOGUE, effect_params, null_value
from seafmu.identification.effects.base import Combined
from seafmu.identification.fitting import FitResult, noise_only_text

# synthetic trials live in ``synthetic``; importable from here for existing callers (benchmarks)
from seafmu.identification.synthetic import DEMO_EFFECTS, SURGE, demo_trial
from seafmu.identification.trial import Trial, TrialError, maneuver_factors

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
    """One extension of the baseline: a catalogue effect, or a combination of them ("a+b")."""

    effect: str
    fit: FitResult | None
    ratio: float = math.nan  # held-out NRMSE baseline / extended (> 1: extension better)
    delta_aic: float = math.nan
    significant: bool = False
    accepted: bool = False
    reason: str = ""
    seconds: float = 0.0
    effects: tuple[str, ...] = ()  # the catalogue effects it adds (one for a single effect)
    flags: list[str] = field(default_factory=list)  # claims of the model the data contradict
    # the fit parameters of each effect in ``effects`` (same order); empty: the effect's own names
    # found in the fit. Given where one effect appears twice (two thrusters lost, each located).
    groups: tuple[tuple[str, ...], ...] = ()
    # whether each effect in ``effects`` has a significant parameter in this fit (``judge``)
    significant_each: tuple[bool, ...] = ()
    # the cause's model fitted again with the damping the log cannot tell held at the vessel file's
    # (``_settle``): the model a user takes away; ``fit`` is what every comparison and rule uses
    settled: FitResult | None = None

    def __post_init__(self) -> None:
        if not self.effects:
            self.effects = tuple(self.effect.split("+"))

    @property
    def size(self) -> int:
        return len(self.effects)

    def member_groups(self) -> tuple[tuple[str, ...], ...]:
        """The fit parameters of each of its effects."""
        if self.groups:
            return self.groups
        names = self.fit.param_names if self.fit is not None else []
        return tuple(tuple(effect_params(e, names)) for e in self.effects)

    def members(self) -> list[tuple[str, tuple[str, ...]]]:
        """Each effect with its parameters (sorted): what a combination's sub-models are matched by."""
        return [(e, tuple(sorted(g))) for e, g in zip(self.effects, self.member_groups(), strict=True)]

    def label(self) -> str:
        """The name with each located effect's parameters (which thruster): ``thruster_loss
        (eta_T[3])+thruster_loss (eta_T[6])``."""
        out = []
        for e, g in self.members():
            located = getattr(effect_objects.get(e), "maneuver_variants", None) is not None and g
            out.append(f"{e} ({', '.join(g)})" if located else e)
        return "+".join(out)

    def effect_params(self) -> dict[str, float]:
        f = self.fit
        if f is None:
            return {}
        return {k: float(f.params[k]) for g in self.member_groups() for k in g if k in f.params}

    def row(self) -> dict[str, Any]:
        f = self.fit
        return {"effect": self.effect, "effects": list(self.effects), "label": self.label(),
                "nrmse_validation": _num(f.nrmse_validation) if f else None,
                "nrmse_fit": _num(f.nrmse_fit) if f else None,
                "delta_aic": _num(self.delta_aic), "ratio": _num(self.ratio),
                "significant": self.significant, "accepted": self.accepted, "reason": self.reason,
                "params": self.effect_params(), "flags": list(self.flags)}


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


@dataclass
class Alternative:
    """A credible explanation beside (or being) the cause: its Akaike weight among the credible ones."""

    candidate: Candidate
    weight: float
    delta_aic: float  # AIC minus the lowest AIC of the credible ones (Akaike's delta)
    experiment: dict[str, Any] | None = None  # where it and the cause differ most (ambiguity.py)

    def to_json(self) -> dict[str, Any]:
        c = self.candidate
        return {"effect": c.effect, "effects": list(c.effects), "weight": _num(self.weight),
                "validation_nrmse_ratio": _num(c.ratio), "delta_aic": _num(self.delta_aic),
                "delta_aic_vs_baseline": _num(c.delta_aic), "params": c.effect_params(),
                "discriminating_experiment": self.experiment}


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
    alternatives: list[Alternative] = field(default_factory=list)  # credible ones, the cause first

    @property
    def extended(self) -> FitResult:
        """The model a user takes away: the cause's (settled where it was, ``_settle``), else the
        baseline."""
        if self.cause and self.cause.fit:
            return self.cause.settled or self.cause.fit
        return self.baseline

    @property
    def tested(self) -> bool:
        """False when no catalogue effect could be fitted: "none" would read as "tested and clean"."""
        return any(c.fit is not None for c in self.candidates)

    @property
    def effect(self) -> str:
        """The cause's (main) effect: the one contributing most when several act together."""
        if self.cause:
            return self.effects[0]
        return "none" if self.tested else NOT_TESTED

    @property
    def effects(self) -> list[str]:
        """Every effect of the cause, largest contribution first (empty: none found)."""
        if not self.cause:
            return []
        return contribution_order(self.cause, self.candidates)

    def members(self) -> list[dict[str, Any]]:
        """Each effect of the cause with its fitted parameters, largest contribution first (two
        located thrusters are two members of one effect)."""
        if not self.cause or self.cause.fit is None:
            return []
        f, groups = self.extended, self.cause.member_groups()
        return [{"effect": self.cause.effects[i], "params": {k: float(f.params[k]) for k in groups[i]}}
                for i in _member_order(self.cause, self.candidates)]

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
        alts = [a.to_json() for a in self.alternatives]
        return {
            "trial": {"name": self.trial.name, "kind": self.trial.kind, "dof": self.trial.dof,
                      "baseline_model": self.trial.baseline, "provenance": self.trial.provenance},
            "baseline": summary(b),
            "cause": {"effect": self.effect, "effects": self.effects, "members": self.members(),
                      "evidence": self.evidence,
                      "tested": self.tested, "alternatives": alts,
                      "discriminating_experiment": next((a["discriminating_experiment"] for a in alts[1:]
                                                         if a["discriminating_experiment"]), None),
                      "ranking": [c.row() for c in self.ranking()],
                      "not_applicable": self.skipped},
            "extended": summary(e),
            "gain": {"validation_nrmse_ratio": _num(ratio), "delta_aic": _num(e.aic - b.aic),
                     "nrmse_validation_before": _num(b.nrmse_validation),
                     "nrmse_validation_after": _num(e.nrmse_validation)},
            "rule": {"min_ratio": self.rule.min_ratio, "min_heldout_gain": self.rule.min_heldout_gain,
                     "max_delta_aic": self.rule.max_delta_aic,
                     "significance": "95 % CI of each effect's parameter excludes its 'absent' value",
                     "combinations": "a combination must also beat each of its sub-models by the same rule"},
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
    fit = timeseries.fit_timeseries(trial, timeseries.baseline_model(trial))
    fit.warnings[:0] = trial.notes  # what was left out of the data (a hold before a release)
    return fit


def fit_extension(trial: Trial, base: FitResult, effect: str | tuple[str, ...],
                  seeds: list[Any] | None = None, noise_null: bool = True) -> FitResult:
    """The baseline extended by one effect, or by several at once (started from ``seeds``: e.g. the
    single-effect fits' values). ``noise_null=False`` (a diagnosis's candidates): a maneuver fit's
    whiteness against the sensor noise alone is left for ``complete_whiteness``."""
    names = (effect,) if isinstance(effect, str) else tuple(effect)
    if trial.kind == "static":
        model = static.combined(trial, base, names)
        start = next((s for s in seeds or [] if all(q in s for q in model.free)), {**base.params})
        return static.fit_static(trial, model, start=start)
    if trial.kind == "maneuver":  # refit from the baseline's damping with the effect's parameters
        if len(names) == 1:
            return fit_maneuver(trial, "output_error", effect=names[0], start=dict(base.params),
                                noise_null=noise_null)
        objs = [effect_objects.get(n) for n in names]
        located = [n for n, o in zip(names, objs, strict=True) if o is None or not o.maneuver
                   or getattr(o, "maneuver_variants", None) is not None]
        if located:  # which thruster: the diagnosis's search locates it (_maneuver_combinations)
            raise TrialError(f"{trial.name}: {', '.join(located)} cannot be fitted in a named combination "
                             "(a maneuver effect that must be located, or none)")
        start = dict(base.params)
        for seed in seeds or []:  # the parts' fitted values, where given
            start.update(seed if isinstance(seed, dict) else {})
        d = maneuver_problem(trial).vessel.dof
        return fit_maneuver(trial, "output_error", effect=Combined(objs, d), start=start,
                            noise_null=noise_null)
    if len(names) == 1:
        return timeseries.fit_effect(trial, base, names[0])
    return timeseries.fit_effects(trial, base, names, seeds=seeds)


def fit_maneuver(trial: Trial, method: str, effect: str | Any | None = None,
                 start: dict[str, float] | None = None, noise_null: bool = True,
                 untold_at_file: bool = False) -> FitResult:
    """Multi-DOF maneuver log: delegated to the maneuver module (Minerva 2 LS or output error).
    ``effect``: a maneuver effect's name, or an effect object (a located variant, a combination).
    Inside ``identify``/``diagnose`` the log is read and prepared (LS start, simulation setups)
    once for all fits (``_prepared_logs``). ``untold_at_file``: see ``maneuver.fit.fit_prepared``."""
    from seafmu.identification.maneuver.fit import fit_prepared

    return fit_prepared(maneuver_problem(trial), method, effect=effect, oe_start=start, noise_null=noise_null,
                        untold_at_file=untold_at_file)


def maneuver_problem(trial: Trial) -> Any:
    """The trial's log read and prepared for fitting (``maneuver.fit.ManeuverProblem``); made once
    per ``identify``/``diagnose`` (their scope keeps it), else every call."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.maneuver.fit import prepare_maneuver

    if not trial.vessel:
        raise TrialError(f"{trial.name}: a maneuver trial needs a vessel (trial 'vessel' or --vessel)")
    scope = _PREPARED.get(id(trial))
    if scope is not None and scope[0] is trial and scope[1] is not None:
        return scope[1]
    vessel = load_vessel(trial.vessel)
    problem = prepare_maneuver(maneuver_data(trial, vessel), vessel, trial.validation_fraction)
    if scope is not None and scope[0] is trial:
        _PREPARED[id(trial)] = (trial, problem)
    return problem


# Trials inside an identify/diagnose call -> (the trial, its prepared log once made): the log is
# read, resampled, differentiated and fitted by LS once, not once per candidate fit (4 fits and
# more per diagnosis: ~0.5 s each time on a 10 000-sample log).
_PREPARED: dict[int, tuple[Trial, Any]] = {}


@contextmanager
def _prepared_logs(trial: Trial) -> Iterator[None]:
    """Within the block, every maneuver fit of ``trial`` shares one prepared log."""
    key = id(trial)
    mine = key not in _PREPARED
    if mine:
        _PREPARED[key] = (trial, None)
    try:
        yield
    finally:
        if mine:
            _PREPARED.pop(key, None)


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
    """Fit the trial's baseline model (and, for the pendulum, the equation-error variants); BLAS
    single-threaded (see ``diagnose``)."""
    with threadpool_limits(limits=1, user_api="blas"), _prepared_logs(trial):
        return _identify(trial)


def _identify(trial: Trial) -> Identification:
    t0 = time.perf_counter()
    if trial.kind == "maneuver":  # damping the log cannot tell: the vessel file's, written back as is
        fit = fit_maneuver(trial, trial.baseline, untold_at_file=True)
        alt = {}
        other = "output_error" if trial.baseline == "ls" else "ls"
        try:
            alt[other] = fit_maneuver(trial, other, untold_at_file=True)
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


# A combination search stops trying further combinations once the diagnosis has run this long
# (the singles and the best pairs are always fitted).
COMBINATION_BUDGET_S = 3.0
MAX_PAIRS = 15  # pairs fitted at most, best screened first (within the time budget)
MAX_TRIPLES = 3  # extensions of the best accepted pair by a third effect


def diagnose(trial: Trial, effects: list[str] | None = None, rule: Rule | None = None,
             combinations: bool = True) -> Diagnosis:
    """Baseline fit, every applicable catalogue effect as an extension, then combinations of the
    promising ones (``combinations``), the acceptance rule, the credible alternatives.

    BLAS runs single-threaded meanwhile: the fits factor tall, thin Jacobians (10 000 x 10), which
    a threaded BLAS does 5-50 times slower on a busy 2-core machine than one thread does.
    """
    with threadpool_limits(limits=1, user_api="blas"), _prepared_logs(trial):
        return _diagnose(trial, effects, rule or Rule(), combinations)


def _diagnose(trial: Trial, effects: list[str] | None, rule: Rule, combinations: bool) -> Diagnosis:
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
            fit = fit_extension(trial, base, name, noise_null=False)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            cands.append(Candidate(name, None, reason=f"fit failed: {exc}", seconds=time.perf_counter() - t1))
            continue
        cands.append(judge(name, base, fit, trial, rule, time.perf_counter() - t1))
    noise = min((noise_level(c.fit) for c in cands if c.fit is not None), default=noise_level(base))
    for c in cands:
        check_claims(c, trial, noise)
    if combinations:
        cands += search_combinations(trial, base, cands, rule, t0)
    cause = choose(cands, rule)
    if cause is not None and trial.kind == "maneuver":
        _settle(trial, base, cause, rule)
    if cause is not None and cause.fit is not None:  # its residual tested as the baseline's was
        from seafmu.identification.maneuver.fit import complete_whiteness

        complete_whiteness(cause.settled or cause.fit)
    alts = alternatives(trial, cause, cands)
    evidence = explain(trial, base, cands, cause, skipped, alts)
    return Diagnosis(trial, base, cands, skipped, cause, evidence, rule, time.perf_counter() - t0, alts)


def _settle(trial: Trial, base: FitResult, cause: Candidate, rule: Rule) -> None:
    """The cause's model fitted again with the damping of the DOFs the log cannot tell held at the
    vessel file's (``maneuver.estimation.holding_untold_damping``), as ``cause.settled`` where the log does
    not reject the file's values: the model a user takes away. The candidates are compared, and the
    cause chosen, as fitted (so the baseline and every candidate are fitted alike; doing this in every
    fit made a diagnosis 25-50 % slower). A DP log's yaw damping, free, drifted where the log does
    not look: held-out NRMSE 1.09, settled 0.22."""
    from seafmu.identification.maneuver.estimation import untold_dofs

    fit = cause.fit
    problem = maneuver_problem(trial)
    if fit is None or not untold_dofs(fit.param_names, fit.ci95, fit.extras.get("held_at_bound", []),
                                      problem.plant):
        return
    obj = _effect_object(problem, cause)
    if obj is None:
        return
    held = fit_maneuver(trial, "output_error", effect=obj, start=dict(fit.params), noise_null=False,
                        untold_at_file=True)
    # handed over only if it too passes the rule against the baseline (never judged on held-out data
    # against the free fit: that choice would be made on the data that measures it)
    if held.extras.get("held_at_file") and judge(cause.effect, base, held, trial, rule, 0.0,
                                                 cause.groups).accepted:
        cause.settled = held


def _thrust_columns(problem: Any) -> int:
    """How many thrusters the log gives a column each (0: the generalised force only)."""
    return problem.prep.thrust.shape[1] if problem.prep.thrust is not None else 0


def _effect_object(problem: Any, c: Candidate) -> Any:
    """The effect object a maneuver candidate was fitted with: each effect, a located one as the
    variant its parameters name, combined where several, in the physical form its fit kept (a
    current's inertia); None if one is not a maneuver effect."""
    d = problem.vessel.dof
    m = _thrust_columns(problem)
    objs = []
    for e, group in c.members():
        obj = effect_objects.get(e)
        if obj is None or not obj.maneuver:
            return None
        variants = getattr(obj, "maneuver_variants", None)
        if variants is not None:
            obj = next((v for v in variants(m) if set(v.maneuver_params(d)) == set(group)), None)
            if obj is None:
                return None
        objs.append(obj)
    eff = objs[0] if len(objs) == 1 else Combined(objs, d)
    kept = c.fit.extras.get("effect_form") if c.fit is not None else None
    return next((f for f in eff.maneuver_forms(problem.vessel) if f.maneuver_form() == kept), eff)


def judge(name: str, base: FitResult, fit: FitResult, trial: Trial, rule: Rule,
          seconds: float = 0.0, groups: tuple[tuple[str, ...], ...] = ()) -> Candidate:
    """Apply the acceptance rule to one refitted extension (a combination: every effect in it must
    have a significant parameter). ``groups``: each effect's fit parameters, where one effect
    appears more than once (two located thrusters); else the effect's own names in the fit."""
    names = tuple(name.split("+"))
    ratio, gain, dAIC = _compare(base, fit)
    sig_each = []
    at_bound = []
    small = []
    bounds = catalogue.fit_bounds(trial)
    for i, e in enumerate(names):
        sig = False
        own = list(groups[i]) if groups else effect_params(e, fit.param_names)
        floor = float(getattr(effect_objects.get(e), "min_effect", 0.0))
        below = bool(own) and floor > 0
        for p in own:
            null = null_value(p, trial)
            if p in fit.ci95:
                lo, hi = fit.ci95[p]
                if math.isfinite(lo) and math.isfinite(hi) and not (lo <= null <= hi):
                    sig = True
            if p in fit.params and abs(fit.params[p] - null) >= floor:
                below = False
            b = bounds.get(p)
            if b is not None and p in fit.params and _at_bound(fit.params[p], b):
                at_bound.append(p)
        if below:  # closer to "absent" than the effect's model is known to (a thrust law's accuracy)
            sig = False
            small.append(f"{', '.join(own)} within {floor:g} of {null_value(own[0], trial):g}")
        sig_each.append(sig)
    n_val = int(fit.extras.get("n_validation", 0))
    reasons = _rule_reasons(ratio, gain, dAIC, n_val, rule)
    if not all(sig_each):
        which = [e for e, ok in zip(names, sig_each, strict=True) if not ok]
        reasons.append("parameter not significant (CI includes the no-effect value)" if len(names) == 1
                       else f"{', '.join(which)}: parameter not significant")
    if small:
        reasons.append(f"{'; '.join(small)}, the accuracy its model is known to")
    if at_bound:
        reasons.append(f"{', '.join(at_bound)} at the bound of its range: the data push the effect beyond "
                       "what it can mean")
    wrong = unphysical(base, fit)
    if wrong:
        reasons.append(f"unphysical model: {'; '.join(wrong)}")
    return Candidate(name, fit, ratio, dAIC, all(sig_each), not reasons, "; ".join(reasons) or "accepted",
                     seconds, names, groups=groups, significant_each=tuple(sig_each))


# Where fitted parameters mean something physical (a parameter outside: not a property of any hull
# or thruster): quadratic damping (d_Q, the pendulum's gamma) and added mass (m_a) >= 0, restoring
# stiffness (c; the pendulum's alpha) on its side of zero; thrust_quadratic's n|n| term k_q >= 0
# (its claim is a propeller's law; thrust growing slower than linearly is thrust_power's p_n < 1,
# which says so); the sway-yaw damping derivatives Y_v, N_r <= 0 (Fossen's sign). Not the linear
# damping (d_L, the pendulum's beta): beside friction or a quadratic term a negative one still
# dissipates over the speeds a trial covers (the pendulum's friction with its offset fits beta < 0),
# and the sources' own fits have it: brief section 2 makes it a warning. Ranges an effect's own fit
# bounds keep (thrust_asymmetry's eta_rev > -1) are not repeated.
PHYSICAL_RANGE: dict[str, tuple[float, float]] = {
    "d_Q": (0.0, math.inf), "m_a": (0.0, math.inf), "gamma": (0.0, math.inf), "c": (0.0, math.inf),
    "alpha": (-math.inf, 0.0), "k_q": (0.0, math.inf), "Y_v": (-math.inf, 0.0), "N_r": (-math.inf, 0.0)}


def unphysical(base: FitResult, fit: FitResult) -> list[str]:
    """The extension's parameters whose whole 95 % CI lies outside their physical range where the
    baseline's did not (a baseline's own is a warning of the baseline, brief section 2). Why they
    block the effect: an extension that fits only with, say, a drag that pushes harder along the
    motion the faster it goes (d_Q < 0) or a thrust law below linear claimed as a propeller's
    explains the data by a model that cannot be right."""
    out = []
    for p, (lo_ok, hi_ok) in PHYSICAL_RANGE.items():
        ci, v = fit.ci95.get(p), fit.params.get(p)
        if ci is None or v is None or not _outside(ci, lo_ok, hi_ok):
            continue
        b = base.ci95.get(p)
        if b is not None and _outside(b, lo_ok, hi_ok):
            continue
        side = f">= {lo_ok:g}" if math.isfinite(lo_ok) else f"<= {hi_ok:g}"
        out.append(f"{p} = {v:.4g} (95 % CI [{ci[0]:.4g}, {ci[1]:.4g}]; {side} physically)")
    return out


def _outside(ci: tuple[float, float], lo_ok: float, hi_ok: float) -> bool:
    lo, hi = ci
    return bool(hi < lo_ok or lo > hi_ok)


def _at_bound(x: float, b: tuple[float, float]) -> bool:
    lo, hi = b
    return any(math.isfinite(e) and abs(x - e) <= 1e-6 * max(1.0, abs(e)) for e in (lo, hi))


def _compare(ref: FitResult, fit: FitResult) -> tuple[float, float, float]:
    """Held-out ratio ref/fit, held-out gain n ln(ratio^2) and dAIC of fit against ref."""
    ev = fit.nrmse_validation
    ratio = ref.nrmse_validation / ev if ev > 0 and math.isfinite(ev) else (math.inf if ev == 0 else 0.0)
    n_val = int(fit.extras.get("n_validation", 0))
    gain = n_val * 2.0 * math.log(ratio) if ratio > 0 and math.isfinite(ratio) else (
        math.inf if ratio == math.inf else -math.inf)
    return ratio, gain, fit.aic - ref.aic


def _rule_reasons(ratio: float, gain: float, dAIC: float, n_val: int, rule: Rule,
                  against: str = "") -> list[str]:
    """Why the held-out and information criteria are not met (empty: they are)."""
    vs = f" over {against}" if against else ""
    reasons = []
    if not ratio >= rule.min_ratio:
        reasons.append(f"held-out ratio{vs} {ratio:.3f} < {rule.min_ratio}")
    elif not gain >= rule.min_heldout_gain:
        reasons.append(f"held-out gain{vs} n ln(ratio^2) = {gain:.1f} < {rule.min_heldout_gain:g} "
                       f"({n_val} held-out samples)")
    if not dAIC <= rule.max_delta_aic:
        reasons.append(f"dAIC{vs} {dAIC:.1f} > {rule.max_delta_aic:g}")
    return reasons


def check_claims(c: Candidate, trial: Trial, noise: float) -> None:
    """Reject an accepted extension whose claim the measured points contradict beyond the noise
    (each effect's ``contradiction``: thrust measured inside a claimed deadband, a cap above every
    command); an unidentifiable parameter already fails significance (infinite variance)."""
    if c.fit is None:
        return
    for e in c.effects:
        obj = effect_objects.get(e)
        why = obj.contradiction(c.fit.params, trial, c.fit, noise) if obj is not None else None
        if why:
            c.flags.append(why)
    if c.flags and c.accepted:
        c.accepted = False
        c.reason = "claim contradicted by the data: " + "; ".join(c.flags)


def search_combinations(trial: Trial, base: FitResult, singles: list[Candidate], rule: Rule,
                        t0: float) -> list[Candidate]:
    """Pairs (then triples) of effects fitted together, judged by the same rule against the baseline
    and against each of their sub-models, so a combination is accepted only where every effect in it
    earns its parameters.

    A pair can explain data where each effect alone fails (a single fit stuck where its effect is
    absent), so pairs are not built from accepted singles: every compatible pair of applicable
    effects is screened by the cost of its best start (the single fits' values reused, and each
    effect's start grid: simulations, no fit; ``screen``), and the most promising are fitted.
    """
    if trial.kind == "maneuver":
        return _maneuver_combinations(trial, base, singles, rule)
    if trial.dof == "sway_yaw":
        return []  # a sway_yaw trial tests the coupling only
    pool = [c for c in singles if c.fit is not None and math.isfinite(c.fit.nrmse_validation)]
    by_name = {c.effect: c for c in pool}
    pairs = [(a, b) for i, a in enumerate(pool) for b in pool[i + 1:] if _compatible(a.effects + b.effects)]
    ranked = _interleave(_screened(trial, base, [(a, b) for a, b in pairs]),
                         sorted(pairs, key=lambda ab: ab[0].delta_aic + ab[1].delta_aic))
    out: list[Candidate] = []
    noise = min((noise_level(c.fit) for c in pool), default=noise_level(base))
    base_rss = float(base.extras.get("rss", math.inf))
    for k, (parts, start, cost) in enumerate(ranked[:MAX_PAIRS]):
        if k >= 2 and (time.perf_counter() - t0 > COMBINATION_BUDGET_S or not cost < base_rss):
            break
        out.append(_fit_combination(trial, base, parts, list(parts), rule, noise, start))
    accepted_pairs = sorted((c for c in out if c.accepted), key=lambda c: c.fit.aic)  # type: ignore[union-attr]
    if accepted_pairs:
        pair = accepted_pairs[0]
        thirds = [(pair, c) for c in pool if c.effect not in pair.effects
                  and _compatible(pair.effects + c.effects)]
        for parts, start, _ in _screened(trial, base, thirds)[:MAX_TRIPLES]:
            if time.perf_counter() - t0 > COMBINATION_BUDGET_S:
                break
            triple = _fit_combination(trial, base, parts, list(parts), rule, noise, start)
            out.append(triple)
            if triple.accepted:
                out += _against_sub_pairs(trial, base, triple, by_name, out, rule, noise)
    return out


# Maneuver logs: pairs fitted at most (best screened first); a screened pair must beat the screened
# model of each of its parts (stepped from the same reference) by this held-out NRMSE ratio before
# it is fitted (a screen is one Gauss-Newton step: it finds, the fit judges).
MANEUVER_PAIRS = 2
SCREEN_RATIO = 1.02
SCREEN_RATIO_NEAR = 1.005  # ... or this ratio with a fitting-cost drop of SCREEN_DAIC (_screen_passes)
SCREEN_DAIC = -10.0
MANEUVER_REFERENCES = 2  # single-effect fits the pairs are screened from (lowest AIC first)
# Evaluations of a part's own fit (started from the pair's values): a part alone is the worse model
# wherever the pair is right, and its cost falls most in the first few steps.
PART_NFEV = 6
MANEUVER_MAX_EFFECTS = 3  # a combination grows by one effect at a time while each earns its place
# A member is added to a fitted combination when its one step beats the combination's fit held out
# (the fit of the larger one is judged by the rule): one step moves two coupled terms only part of
# the way (a steady force against the negative heave damping that absorbed it: 0.2065 screened,
# 0.1993 fitted, against the pair's 0.209), so the rule's ratio is asked of the fit, not of the step.


def _maneuver_members(trial: Trial, singles: list[Candidate]) -> tuple[list[Any], dict[int, Candidate]]:
    """The maneuver extensions a pair is made of, as effect objects: each applicable effect, or each
    of its located variants (one per thruster) where it has them; and the single-effect candidate
    fitted with each (a located effect: only the variant its fit located)."""
    problem = maneuver_problem(trial)
    d = problem.vessel.dof
    m = _thrust_columns(problem)
    members: list[Any] = []
    single_of: dict[int, Candidate] = {}
    for c in singles:
        obj = effect_objects.get(c.effect)
        if obj is None or not obj.maneuver or c.size != 1:
            continue
        variants = getattr(obj, "maneuver_variants", None)
        for v in (variants(m) if variants is not None else [obj]) if (variants is None or m) else []:
            members.append(v)
            if c.fit is not None and set(v.maneuver_params(d)) <= set(c.fit.param_names):
                single_of[len(members) - 1] = c
    return members, single_of


def _pairable(a: Any, b: Any, d: int) -> bool:
    """Two maneuver extensions that can act at once: two effects fitted together (``excludes``), or
    two variants of one effect that combine (two thrusters lost)."""
    if a.name == b.name:
        return bool(a.variants_combine) and a.maneuver_params(d) != b.maneuver_params(d)
    return _compatible((a.name, b.name))


def _maneuver_combinations(trial: Trial, base: FitResult, singles: list[Candidate],
                           rule: Rule) -> list[Candidate]:
    """Pairs of maneuver extensions (two effects, or two located thrusters), screened cheaply
    (``_screen_pairs``) and the promising ones fitted, warm started, and judged like any
    combination; then an accepted pair grows by one effect at a time (``_grow``).

    The best ``MANEUVER_PAIRS`` screened pairs are fitted, started from the screen's step (and
    from the accepted single fits' values of their own effects); a further pair only while its
    step is about as good as that of a pair already accepted (a rival explanation). Each is judged
    by the rule against the baseline and against each part alone (fitted now from the pair's values
    where the single search did not fit it: a thruster it did not locate). A pair whose warm-started
    fit diverges held out is fitted again from the baseline (``_from_baseline``).
    """
    d = maneuver_problem(trial).vessel.dof
    members, single_of = _maneuver_members(trial, singles)
    noise = min((noise_level(c.fit) for c in singles if c.fit is not None), default=noise_level(base))
    out: list[Candidate] = []
    grown: list[tuple[Candidate, tuple[int, ...]]] = []  # accepted combinations and their members
    best_screen = math.inf  # the screened held-out NRMSE of the first accepted pair
    for pair in _screen_pairs(trial, base, singles, members, single_of, rule, noise)[:MANEUVER_PAIRS]:
        if pair.nrmse_validation > SCREEN_RATIO * best_screen:
            break  # clearly worse than a pair already accepted: not a rival explanation
        objs = tuple(members[k] for k in pair.members)
        start = dict(pair.start)
        for k in pair.members:  # an accepted single fit's values of its own member: a better start
            c = single_of.get(k)
            if c is not None and c.accepted and c.fit is not None:
                start.update({q: c.fit.params[q] for q in members[k].maneuver_params(d)})
        cand = _fit_members(trial, base, objs, start, rule, noise)
        if cand.fit is not None and not math.isfinite(cand.fit.nrmse_validation):
            cand = _fit_members(trial, base, objs, _from_baseline(base, objs, start, d), rule, noise)
        out.append(cand)
        if cand.accepted:
            out += _against_parts(trial, base, cand, objs, singles + out, rule, noise)
        if cand.accepted:
            best_screen = min(best_screen, pair.nrmse_validation)
            grown.append((cand, pair.members))
    while grown:  # a third effect (and further) on the best accepted combination
        grown.sort(key=lambda g: g[0].fit.aic)  # type: ignore[union-attr]
        cand, idx = grown[0]
        if len(idx) >= MANEUVER_MAX_EFFECTS:
            break
        nxt = _grow(trial, base, cand, idx, members, singles + out, rule, noise)
        if nxt is None:
            break
        out += nxt[0]
        grown = [(nxt[0][0], nxt[1])] if nxt[0][0].accepted else []
    return out


def _from_baseline(base: FitResult, objs: tuple[Any, ...], start: dict[str, float],
                   d: int) -> dict[str, float]:
    """A combination's start from the baseline's damping (and its segment states, recalled by
    value) with the effect values of ``start``. A single fit that is accepted may still have
    wandered (one effect absorbing another's force: a current with 1e6 roll damping, negative heave
    damping); a pair warm started from it stays there, unstable held out, where the same pair from
    the baseline converges."""
    own = {q for o in objs for q in o.maneuver_params(d)}
    return {**dict(base.params), **{q: v for q, v in start.items() if q in own}}


def _screen_pairs(trial: Trial, base: FitResult, singles: list[Candidate], members: list[Any],
                  single_of: dict[int, Candidate], rule: Rule, noise: float) -> list[Any]:
    """The pairs worth fitting, best screened held-out NRMSE first (``maneuver.fit.Screened``).

    References: the accepted single-effect fits (lowest AIC first, at most
    ``MANEUVER_REFERENCES``), else the single fit of lowest AIC if it beats the baseline's (a part
    of a pair alone may do worse held out, yet its fit is near the pair's), else the baseline (a
    pair may explain what each part alone cannot). From each, the pairs containing its effect get
    one Gauss-Newton step in the damping and their parameters (``screen_extensions``). A pair is
    kept where its step beats the step of each of its parts from the same reference by
    ``SCREEN_RATIO`` held out, can beat every accepted single fit held out by the rule's ratio (the
    cause must, ``choose``), and claims nothing its effects deny (``contradiction``: a lost
    thruster delivering more than its nominal thrust).
    """
    from seafmu.identification.maneuver.fit import screen_extensions

    problem = maneuver_problem(trial)
    d = problem.vessel.dof
    ranked = sorted((c for c in singles if c.fit is not None and c.delta_aic <= rule.max_delta_aic),
                    key=lambda c: c.fit.aic)  # type: ignore[union-attr]
    chosen = sorted(ranked, key=lambda c: not c.accepted)[:MANEUVER_REFERENCES]  # accepted first
    refs = [(dict(c.fit.params), [i for i, s in single_of.items() if s is c], False)  # type: ignore[union-attr]
            for c in chosen] or [(dict(base.params), [], False)]
    file_ref = _file_reference(problem, base)
    if file_ref is not None:  # the baseline's damping took up what the effects explain: from the file too
        # (one step from that far is rough: such a pair is not held to an accepted single's error
        # before its fit, only after it)
        refs.append((file_ref, [], True))
    best_single = min((c.fit.nrmse_validation for c in singles if c.accepted and c.fit is not None),
                      default=math.inf)
    promising: dict[frozenset[int], Any] = {}
    rough_ones: dict[frozenset[int], Any] = {}
    for values, have, rough in refs:
        pairs = [(i, j) for i in range(len(members)) for j in range(i + 1, len(members))
                 if _pairable(members[i], members[j], d) and (not have or i in have or j in have)]
        subs = [(i,) for i in have] if have else [(), *((i,) for i in range(len(members)))]
        try:
            screened = screen_extensions(problem, values, members, subs + pairs) if pairs else None
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):
            screened = None
        by = {sc.members: sc for sc in screened or []}
        for i, j in pairs if screened else []:
            pair = by[(i, j)]
            parts = [by[(k,)] for k in (i, j) if (k,) in by] or [by[()]]
            if (not rough and pair.nrmse_validation * rule.min_ratio > best_single) or _claim_contradicted(
                    trial, [members[i], members[j]], pair.start, noise):
                continue  # cannot beat an accepted single effect, or claims what the data deny
            into = rough_ones if rough else promising
            old = into.get(frozenset((i, j)))
            if all(_screen_passes(pair, sub, _size(members, pair.members, d) - _size(members, sub.members, d))
                   for sub in parts) and (
                    old is None or pair.nrmse_validation < old.nrmse_validation):
                into[frozenset((i, j))] = pair
    # the pairs from the vessel file's damping after the others: where those are fitted, they are
    # not displaced (a rough step can look better than it fits)
    rough_ones = {k: v for k, v in rough_ones.items() if k not in promising}
    return (sorted(promising.values(), key=lambda sc: sc.nrmse_validation)
            + sorted(rough_ones.values(), key=lambda sc: sc.nrmse_validation))


def _file_reference(problem: Any, base: FitResult) -> dict[str, float] | None:
    """The vessel file's damping diagonals under the baseline's names, where the baseline's are far
    from them (``maneuver.estimation.FAR_FROM_FILE``: a DP log in a current and with a lost
    thruster, yaw damping 40 000 x the file's): a pair screened only from the baseline stays in
    the basin its damping is in. None where the baseline is near the file (no second screen)."""
    from seafmu.identification.maneuver.estimation import damping_diagonal, far_from_file

    plant = problem.plant
    file = {n: float(plant[n[:3]][i, i]) for n in base.params if (i := damping_diagonal(n)) is not None}
    if not file or not far_from_file(plant, problem.prep.nu_raw, list(file),
                                     np.array([base.params[n] for n in file])):
        return None
    return {**dict(base.params), **file}


Grown = tuple[list[Candidate], tuple[int, ...]]


def _grow(trial: Trial, base: FitResult, cand: Candidate, idx: tuple[int, ...], members: list[Any],
          fitted: list[Candidate], rule: Rule, noise: float) -> Grown | None:
    """One more extension on an accepted combination: every compatible member screened from its fit
    (as the pairs are), the best one fitted if its step beats the combination's own step held out
    by ``SCREEN_RATIO`` and the combination's fit at all, then judged against each of
    its sub-combinations (the missing ones fitted now). Returns the candidates fitted (the larger
    combination first) and its members, or None when no member is promising."""
    from seafmu.identification.maneuver.fit import screen_extensions

    assert cand.fit is not None
    problem = maneuver_problem(trial)
    d = problem.vessel.dof
    more = [tuple(sorted((*idx, j))) for j in range(len(members)) if j not in idx
            and all(_pairable(members[j], members[i], d) for i in idx)]
    if not more:
        return None
    try:
        screened = screen_extensions(problem, dict(cand.fit.params), members, [tuple(sorted(idx)), *more])
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None
    if screened is None:
        return None
    own, rest = screened[0], screened[1:]
    ok = [sc for sc in rest if _screen_passes(sc, own, _size(members, sc.members, d) - _size(members, idx, d))
          and sc.nrmse_validation <= cand.fit.nrmse_validation
          and not _claim_contradicted(trial, [members[k] for k in sc.members], sc.start, noise)]
    if not ok:
        return None
    best = min(ok, key=lambda sc: sc.nrmse_validation)
    objs = tuple(members[k] for k in best.members)
    bigger = _fit_members(trial, base, objs, dict(best.start), rule, noise)
    if bigger.accepted:
        return [bigger, *_against_parts(trial, base, bigger, objs, fitted, rule, noise)], best.members
    keep = _explained_away_member(bigger, best.members, idx)
    if keep is None or bigger.fit is None:
        return [bigger], best.members
    kept = tuple(members[k] for k in keep)
    own = {q for o in kept for q in o.maneuver_params(d)}
    dropped = {q for o in objs for q in o.maneuver_params(d)} - own
    start = {q: v for q, v in bigger.fit.params.items() if q not in dropped}
    swapped = _fit_members(trial, base, kept, start, rule, noise)
    parts = []
    if swapped.accepted:
        parts = _against_parts(trial, base, swapped, kept, [*fitted, bigger], rule, noise)
    if swapped.accepted:  # still, after its parts: the combination grows from it
        return [swapped, bigger, *parts], keep
    return [bigger, swapped, *parts], best.members


def _explained_away_member(c: Candidate, idx: tuple[int, ...],
                           old: tuple[int, ...]) -> tuple[int, ...] | None:
    """The members of a grown combination ``c`` without the one old member that lost its
    significance there (the newcomer and the others significant): the newcomer explains what it
    stood for, so the combination is refitted without it. A steady force stood in for a lost
    thruster in an AMV log with a current: current + force was accepted, the three together left
    the force insignificant (held out 6.1x better than the baseline), and current + lost thruster,
    the truth, was never fitted. None where that is not the case."""
    if c.fit is None or len(idx) < 3 or len(c.significant_each) != len(idx):
        return None
    weak = [k for k, ok in zip(idx, c.significant_each, strict=True) if not ok]
    if len(weak) != 1 or weak[0] not in old:
        return None
    names = dict(zip(idx, c.effects, strict=True))
    if not all(_may_explain_away(names[k], names[weak[0]]) for k in idx if k not in old):
        return None  # a general newcomer does not stand for a specific member (_may_explain_away)
    return tuple(k for k in idx if k != weak[0])


def _size(members: list[Any], idx: tuple[int, ...], d: int) -> int:
    """Parameters of the members ``idx`` in a d-DOF fit."""
    return sum(len(members[k].maneuver_params(d)) for k in idx)


def _claim_contradicted(trial: Trial, objs: list[Any], values: dict[str, float], noise: float) -> bool:
    """A screened combination's values already claim what its effects deny (a "lost" thruster
    delivering more than its nominal thrust)."""
    return any(o.contradiction({q: values[q] for q in o.maneuver_params(maneuver_problem(trial).vessel.dof)
                                if q in values}, trial, None, noise) for o in objs)


def _screen_passes(pair: Any, sub: Any, extra: int) -> bool:
    """A screened pair beats a screened sub-model (``extra`` parameters fewer): held out by
    ``SCREEN_RATIO``; or, where its fitting cost falls by the AIC margin ``SCREEN_DAIC``, held out
    by ``SCREEN_RATIO_NEAR`` (one step moves two coupled terms only part of the way: a steady
    force against a quadratic damping that absorbed it). The fitting cost alone is not enough:
    one step from a fit of another model can overshoot there and still point the right way."""
    if not (math.isfinite(pair.nrmse_validation) and pair.nrmse_validation > 0):
        return False
    ratio = sub.nrmse_validation / pair.nrmse_validation
    if ratio >= SCREEN_RATIO:
        return True
    if not (ratio >= SCREEN_RATIO_NEAR and pair.cost > 0 and sub.cost > 0 and math.isfinite(sub.cost)):
        return False
    return pair.rows * math.log(pair.cost / sub.cost) + 2.0 * extra <= SCREEN_DAIC


def _fit_members(trial: Trial, base: FitResult, objs: tuple[Any, ...], start: dict[str, float], rule: Rule,
                 noise: float, max_nfev: int = 40) -> Candidate:
    """Fit the maneuver extensions ``objs`` together (one: itself) from ``start`` and judge it."""
    from seafmu.identification.maneuver.fit import fit_prepared

    d = maneuver_problem(trial).vessel.dof
    name = "+".join(o.name for o in objs)
    groups = tuple(tuple(o.maneuver_params(d)) for o in objs)
    t1 = time.perf_counter()
    try:
        fit = fit_prepared(maneuver_problem(trial), "output_error", max_nfev=max_nfev, oe_start=start,
                           effect=objs[0] if len(objs) == 1 else Combined(objs, d), noise_null=False)
    except (TrialError, ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return Candidate(name, None, reason=f"fit failed: {exc}", seconds=time.perf_counter() - t1,
                         effects=tuple(o.name for o in objs), groups=groups)
    cand = judge(name, base, fit, trial, rule, time.perf_counter() - t1, groups)
    check_claims(cand, trial, noise)
    return cand


def _against_parts(trial: Trial, base: FitResult, cand: Candidate, objs: tuple[Any, ...],
                   fitted: list[Candidate], rule: Rule, noise: float) -> list[Candidate]:
    """A maneuver combination earns its parameters only over each of its sub-combinations (one
    member left out): one the search did not fit (a thruster the single search did not locate) is
    fitted now, from the combination's values without the left-out member's, briefly
    (``PART_NFEV``). Returns the sub-combinations fitted here."""
    assert cand.fit is not None
    have = {frozenset(c.members()): c for c in fitted if c.fit is not None}
    d = maneuver_problem(trial).vessel.dof
    groups = [tuple(o.maneuver_params(d)) for o in objs]
    new: list[Candidate] = []
    n_val = int(cand.fit.extras.get("n_validation", 0))
    for i in range(len(objs)):
        rest, rest_groups = objs[:i] + objs[i + 1:], groups[:i] + groups[i + 1:]
        key = frozenset((o.name, tuple(sorted(g))) for o, g in zip(rest, rest_groups, strict=True))
        sub = have.get(key)
        if sub is None:
            start = {k: v for k, v in cand.fit.params.items() if k not in groups[i]}
            sub = _fit_members(trial, base, rest, start, rule, noise, PART_NFEV)
            new.append(sub)
        if sub.fit is None:
            continue
        ratio, gain, dAIC = _compare(sub.fit, cand.fit)
        earned = _rule_reasons(ratio, gain, dAIC, n_val, rule, against=sub.label())
        if earned and cand.accepted:
            cand.accepted = False
            cand.reason = "does not earn its parameters: " + "; ".join(earned)
    return new


def _against_sub_pairs(trial: Trial, base: FitResult, triple: Candidate, singles: dict[str, Candidate],
                       fitted: list[Candidate], rule: Rule, noise: float) -> list[Candidate]:
    """A triple earns its third parameter only over every pair inside it: the pairs not fitted yet
    are fitted now from the triple's values (they may explain the data themselves), then the
    triple is judged against each. Returns the pairs fitted here."""
    assert triple.fit is not None
    have = {frozenset(c.effects): c for c in fitted if c.fit is not None}
    new: list[Candidate] = []
    for drop in triple.effects:
        names = tuple(e for e in triple.effects if e != drop)
        sub = have.get(frozenset(names))
        if sub is None and all(e in singles for e in names):
            parts = tuple(singles[e] for e in names)
            start = ({k: v for k, v in triple.fit.params.items()},
                     list(triple.fit.extras.get("initial_states", [])))
            sub = _fit_combination(trial, base, parts, list(parts), rule, noise, start)
            new.append(sub)
        if sub is None or sub.fit is None:
            continue
        n_val = int(triple.fit.extras.get("n_validation", 0))
        ratio, gain, dAIC = _compare(sub.fit, triple.fit)
        earned = _rule_reasons(ratio, gain, dAIC, n_val, rule, against=sub.effect)
        if earned and triple.accepted:
            triple.accepted = False
            triple.reason = "does not earn its parameters: " + "; ".join(earned)
    return new


Screened = list[tuple[tuple[Candidate, ...], Any, float]]  # (parts, best start, its cost)


def _interleave(screened: Screened, by_singles: list[tuple[Candidate, Candidate]]) -> Screened:
    """Two rankings taken in turn, each pair once: by the cost of the best start (sees a pair whose
    single fits were stuck where the effect is absent) and by the sum of the single fits' dAIC (sees
    a pair whose parameters must move together: the start from the singles is poor)."""
    info = {frozenset(e for p in r[0] for e in p.effects): r for r in screened}
    second = [info[frozenset(a.effects + b.effects)] for a, b in by_singles
              if frozenset(a.effects + b.effects) in info]
    out, seen = [], set()
    for pair in (x for both in zip_longest(screened, second) for x in both if x is not None):
        key = frozenset(e for p in pair[0] for e in p.effects)
        if key not in seen:
            seen.add(key)
            out.append(pair)
    return out


def _screened(trial: Trial, base: FitResult, combos: list[tuple[Candidate, ...]]) -> list[
        tuple[tuple[Candidate, ...], Any, float]]:
    """Combinations with their best start and its cost, cheapest first."""
    out = []
    for parts in combos:
        names = tuple(e for p in parts for e in p.effects)
        seeds = _seeds(parts)
        try:
            if trial.kind == "static":
                start, cost = static.screen(trial, base, names, [s for s, _ in seeds])
            else:
                start, cost = timeseries.screen(trial, base, names, seeds)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):
            continue
        out.append((parts, start, cost))
    out.sort(key=lambda r: r[2])
    return out


def _seeds(parts: tuple[Candidate, ...]) -> list[tuple[dict[str, float], list[tuple[float, ...]]]]:
    """Starts of a combined fit from its parts' fits: all values of one (with its fitted initial
    states), the others' effect values."""
    seeds = []
    for i, p in enumerate(parts):
        if p.fit is None:
            continue
        seed = dict(p.fit.params)
        for j, q in enumerate(parts):
            if j != i:
                seed.update(q.effect_params())
        seeds.append((seed, list(p.fit.extras.get("initial_states", []))))
    return seeds


def _compatible(names: tuple[str, ...]) -> bool:
    if len(set(names)) < len(names):
        return False
    for n in names:
        obj = effect_objects.get(n)
        if obj is not None and set(obj.excludes) & set(names):
            return False
    return True


def _fit_combination(trial: Trial, base: FitResult, parts: tuple[Candidate, ...], subs: list[Candidate],
                     rule: Rule, noise: float, start: Any = None) -> Candidate:
    """Fit the effects of ``parts`` together (from ``start``, else their fits' values) and judge the
    result against the baseline and against every sub-model in ``subs``."""
    names = tuple(e for p in parts for e in p.effects)
    name = "+".join(names)
    seeds = ([start] if start else []) + _seeds(parts)
    if trial.kind == "static":  # a table's start is its values (no initial states)
        seeds = [s[0] if isinstance(s, tuple) else s for s in seeds]
    t1 = time.perf_counter()
    try:
        fit = fit_extension(trial, base, names, seeds=seeds, noise_null=False)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return Candidate(name, None, reason=f"fit failed: {exc}", seconds=time.perf_counter() - t1,
                         effects=names)
    cand = judge(name, base, fit, trial, rule, time.perf_counter() - t1)
    check_claims(cand, trial, noise)
    n_val = int(fit.extras.get("n_validation", 0))
    earned: list[str] = []
    for sub in subs:
        if sub.fit is None:
            continue
        ratio, gain, dAIC = _compare(sub.fit, fit)
        earned += _rule_reasons(ratio, gain, dAIC, n_val, rule, against=sub.effect)
    if earned and cand.accepted:
        cand.accepted = False
        cand.reason = "does not earn its parameters: " + "; ".join(earned)
    return cand


def contribution_order(cause: Candidate, cands: list[Candidate]) -> list[str]:
    """The cause's effects, largest contribution first: how much worse (AIC) the fit gets without
    each one (its sub-model fitted in the search; a single effect's own dAIC where that is all)."""
    return [cause.effects[i] for i in _member_order(cause, cands)]


def _member_order(cause: Candidate, cands: list[Candidate]) -> list[int]:
    """Indices of the cause's effects, largest contribution first (``contribution_order``)."""
    if cause.size == 1 or cause.fit is None:
        return list(range(cause.size))
    fitted = {frozenset(c.members()): c for c in cands if c.fit is not None}
    mine = cause.members()

    def loss(i: int) -> float:
        rest = fitted.get(frozenset(mine[:i] + mine[i + 1:]))
        if rest is not None:
            return rest.fit.aic - cause.fit.aic  # type: ignore[union-attr]
        one = fitted.get(frozenset([mine[i]]))
        return -one.delta_aic if one is not None else 0.0

    return sorted(range(cause.size), key=lambda i: -loss(i))


def choose(cands: list[Candidate], rule: Rule | None = None) -> Candidate | None:
    """Best accepted candidate: lowest held-out NRMSE; within 1 % of it, the lowest AIC.

    A single effect that a combination with another accepted effect explains away (its parameters
    insignificant there, the other's significant: ``_explained_away``) is not a candidate; a
    general family never explains a specific effect away. Two kinds of candidate must first earn
    their place by the rule's margins (held-out ratio and gain, dAIC) over every simpler accepted
    explanation: a combination over each accepted candidate with fewer effects (the smallest
    combination that explains the data), and a general family (a power law, ``general``) over each
    accepted specific effect (it contains several of their shapes).
    """
    rule = rule or Rule()
    ok = [c for c in cands if c.accepted and c.fit is not None]
    ok = [c for c in ok if not _explained_away(c, cands, ok)] or ok
    eligible = [c for c in ok if not _beaten_by_simpler(c, ok, rule)]
    ok = eligible or ok
    if not ok:
        return None
    best = min(c.fit.nrmse_validation for c in ok)  # type: ignore[union-attr]
    near = [c for c in ok if c.fit.nrmse_validation <= best * 1.01]  # type: ignore[union-attr]
    return min(near, key=lambda c: c.fit.aic)  # type: ignore[union-attr]


def _explained_away(c: Candidate, cands: list[Candidate], ok: list[Candidate]) -> bool:
    """True when a fit of ``c``'s effect together with another accepted one leaves ``c``'s parameters
    insignificant while the other's stay significant, and the other alone has the lower AIC: in
    the model that has both, the other explains what ``c`` did (e.g. a steady force standing in for
    a wrong sway-yaw coupling, found better on the held-out part by chance). A general family does
    not explain a specific effect away (``_may_explain_away``)."""
    if c.size != 1:
        return False
    mine = c.members()[0]
    assert c.fit is not None
    # accepted singles the information criterion prefers to c (lag and delay, fitted together, split
    # their significance by chance: the one with the better AIC alone is not explained away)
    accepted = {m for o in ok if o.size == 1 and o.fit is not None and o.fit.aic < c.fit.aic
                and _may_explain_away(o.effects[0], c.effect) for m in o.members()}
    for pair in cands:
        if pair.fit is None or pair.size < 2 or len(pair.significant_each) != pair.size:
            continue
        members = pair.members()
        if mine not in members:
            continue
        sig = dict(zip(members, pair.significant_each, strict=True))
        if not sig[mine] and any(sig[m] for m in members if m != mine and m in accepted):
            return True
    return False


def _is_general(effect: str) -> bool:
    """A family containing other effects' shapes (a power law: the effect object's ``general``)."""
    return bool(getattr(effect_objects.get(effect), "general", False))


def _general(c: Candidate) -> bool:
    return any(_is_general(e) for e in c.effects)


def _may_explain_away(other: str, effect: str) -> bool:
    """Whether effect ``other``, significant where ``effect`` is not in a fit of both, may explain
    ``effect`` away. Not a general family a specific effect: a power law contains specific shapes
    (d_Q v|v|^(p-1) is linear damping at p = 1; k n|n|^(p-1) thrust_quadratic's law at p = 2), so
    beside such an effect its terms are nearly collinear, and which of the two keeps its
    significance is chance, not evidence. A hidden linear damping of 9 in a drag table was named
    ``damping_power`` (p = 1.82) that way, its held-out gain over linear_damping far below the
    margins. The general family has to beat each specific effect by the rule's margins instead
    (``_beaten_by_simpler``), as the documented rule says."""
    return not (_is_general(other) and not _is_general(effect))


def _beaten_by_simpler(c: Candidate, ok: list[Candidate], rule: Rule) -> bool:
    """True when a simpler accepted candidate explains the data as well as ``c`` within the rule."""
    assert c.fit is not None
    n_val = int(c.fit.extras.get("n_validation", 0))
    for other in ok:
        if other is c or other.fit is None:
            continue
        simpler = other.size < c.size or (other.size == c.size and _general(c) and not _general(other))
        if simpler:
            ratio, gain, dAIC = _compare(other.fit, c.fit)
            if _rule_reasons(ratio, gain, dAIC, n_val, rule):
                return True
    return False


def alternatives(trial: Trial, cause: Candidate | None, cands: list[Candidate]) -> list[Alternative]:
    """Every credible explanation (accepted by the rule), the cause first, with its Akaike weight
    among them and the experiment that would tell it from the cause. An effect that is part of the
    cause is not an alternative to it."""
    if cause is None or cause.fit is None:
        return []
    others = [c for c in cands if c.accepted and c.fit is not None and c is not cause
              and not set(c.members()) <= set(cause.members())]
    credible = [cause, *sorted(others, key=lambda c: c.fit.aic)]  # type: ignore[union-attr]
    aics = [c.fit.aic for c in credible]  # type: ignore[union-attr]
    weights = akaike_weights(aics)
    lo = min(aics)
    out = []
    for c, w, a in zip(credible, weights, aics, strict=True):
        exp = None
        if c is not cause:
            exp = discriminating_experiment(trial, cause.fit, c.fit, cause.effect, c.effect)  # type: ignore[arg-type]
        out.append(Alternative(c, w, a - lo, exp))
    return out


def explain(trial: Trial, base: FitResult, cands: list[Candidate], cause: Candidate | None,
            skipped: dict[str, str], alts: list[Alternative] | None = None) -> str:
    if cause is None:
        tried = [c for c in cands if c.fit is not None]
        if not tried:
            failed = [c for c in cands if c.fit is None]
            if failed:
                why = f"every candidate fit failed ({failed[0].effect}: {failed[0].reason})"
            elif trial.kind == "maneuver":
                why = (f"none of the maneuver-level extensions ({', '.join(catalogue.MANEUVER_EFFECTS)}) was "
                       "asked for; "
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
            if "noise_only_p" in w:  # a maneuver: tested against what the sensor noise alone leaves
                why = f"holds more structure than the sensor noise leaves ({noise_only_text(w)})"
            else:
                why = f"is not white (Ljung-Box p = {w['ljung_box_p']:.2g})"
            text += f"; but the baseline residual {why}: structure remains that no catalogue effect explains"
        return text + "."
    assert cause.fit is not None
    words = _params_for_words(cause.fit)
    order = _member_order(cause, cands)
    # an effect with several physical forms (a current's inertia term in a maneuver): the form fitted
    form = cause.fit.extras.get("effect_form")
    if cause.size == 1:
        text = catalogue.evidence(cause.effect, words, trial, base.nrmse_validation,
                                  cause.fit.nrmse_validation, cause.delta_aic, form=form)
    else:
        groups = cause.member_groups()
        parts = []
        for i in order:  # each effect in its own words: the other effects' parameters left out
            others = {q for j, g in enumerate(groups) if j != i for q in g} - set(groups[i])
            own = {k: v for k, v in words.items()
                   if k not in others and k.removesuffix("_halfwidth") not in others}
            parts.append(catalogue.finding(cause.effects[i], own, trial))
        listed = "; ".join(f"({i + 1}) {p}" for i, p in enumerate(parts)) + (f"; fitted with {form}"
                                                                               if form else "")
        text = (f"{len(order)} effects act together: {listed} (combined: "
                f"{catalogue.held_out_words(base.nrmse_validation, cause.fit.nrmse_validation)}, "
                f"dAIC {cause.delta_aic:.1f}).")
    if cause.settled is not None:
        from seafmu.identification.maneuver.estimation import damping_diagonal

        dofs = sorted({damping_diagonal(k) for k in cause.settled.extras.get("held_at_file", [])} - {None})
        names = ", ".join(cause.settled.extras["nu_names"][i] for i in dofs)  # type: ignore[index]
        text += (f" The extended model handed over keeps the vessel file's damping of {names} (this log "
                 f"cannot determine it and does not contradict the file's value): held-out NRMSE "
                 f"{cause.fit.nrmse_validation:.3g} -> {cause.settled.nrmse_validation:.3g}.")
    others = (alts or [])[1:]
    likely = [a for a in others if a.weight >= 0.01]
    if alts and likely:
        listed = ", ".join(f"'{a.candidate.effect}' (Akaike weight {a.weight:.2f}, held-out ratio "
                           f"{a.candidate.ratio:.2f})" for a in likely)
        text += f" Also credible: {listed}; '{'+'.join(cause.effects)}' has weight {alts[0].weight:.2f}."
        twins = [a for a in likely if _same_fit(cause, a.candidate)]
        if twins:  # named by catalogue order alone: say so, and what would tell them apart
            a = twins[0]
            text += (f" '{a.candidate.effect}' fits these data exactly as well (on them the two are one "
                     f"model, e.g. a friction and a constant force where every speed has one sign): "
                     f"the data cannot tell them apart"
                     + (f"; to do so, {a.experiment['text']}." if a.experiment else "."))
    if len(others) > len(likely):
        text += (f" {len(others) - len(likely)} other explanation(s) pass the rule with an Akaike weight "
                 "below 0.01.")
    return text


def _same_fit(a: Candidate, b: Candidate) -> bool:
    """Two fits that are the same model on this trial: equal residual (AIC within 1e-6 of the
    number of samples' scale) and equal held-out error."""
    if a.fit is None or b.fit is None:
        return False
    return abs(a.fit.aic - b.fit.aic) <= 1e-6 * max(1.0, abs(a.fit.aic)) and math.isclose(
        a.ratio, b.ratio, rel_tol=1e-6)


def _params_for_words(fit: FitResult) -> dict[str, float]:
    """The fitted values, and each parameter's CI half-width as ``<name>_halfwidth``."""
    out = dict(fit.params)
    for p, (lo, hi) in fit.ci95.items():
        if math.isfinite(lo) and math.isfinite(hi):
            out[f"{p}_halfwidth"] = 0.5 * (hi - lo)
    return out


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


__all__ = ["DEMO_EFFECTS", "NOT_TESTED", "SURGE", "Alternative", "Candidate", "Diagnosis", "Identification",
           "Rule", "alternatives", "check_claims", "choose", "contribution_order", "demo_trial", "diagnose",
           "explain", "fit_baseline", "fit_extension", "fit_maneuver", "identify", "judge", "maneuver_data",
           "pendulum_equation_error", "search_combinations"]
