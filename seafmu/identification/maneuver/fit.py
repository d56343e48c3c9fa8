"""Orchestration: ``identify_maneuver`` checks the log, prepares it, runs LS (choosing the
smoothing), optionally output error, and reports a ``FitResult``.
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from seafmu.components.thrusters import thruster_matrix
from seafmu.components.vessel_spec import NU_NAMES, TAU_NAMES, VesselSpec
from seafmu.identification import fitting
from seafmu.identification.effects import CatalogueEffect
from seafmu.identification.fitting import FitResult
from seafmu.identification.maneuver.estimation import (
    JAC_COARSEN,
    _LSResult,
    _output_error,
    _output_error_one,
    _run_ls,
    holding_untold_damping,
)
from seafmu.identification.maneuver.io import (
    SAMPLES_PER_REGRESSOR,
    ManeuverData,
    _excitation_problems,
    _gap_problems,
)
from seafmu.identification.maneuver.preprocessing import (
    DERIVATIVES,
    _prepare,
    _Prepared,
    _uniform,
    noise_ratio,
)
from seafmu.identification.maneuver.simulation import (
    _nrmse_per_dof,
    _sim_setup,
    _SimSetup,
    _trace,
    shooting_nodes,
)
from seafmu.identification.maneuver.statistics import (
    NOISE_REPLICATES,
    _autocorr_inflation,
    _is_diag,
    _rel_halfwidth,
    _sanity,
    whiteness,
)
from seafmu.identification.maneuver.terms import _sym, effect_names, plant_matrices
from seafmu.identification.trial import (
    MAX_ABS,
    TrialError,
)

METHODS = ("ls", "output_error")
CORIOLIS = ("auto", "vessel", "iterate", "joint")


def identify_maneuver(
    data: ManeuverData,
    vessel: VesselSpec,
    method: str = "ls",
    validation_fraction: float = 0.3,
    *,
    coriolis: str = "auto",
    damping: str = "full",
    derivative: str = "auto",
    smoothing: float | None = None,
    polyorder: int = 4,
    oe_added_mass: bool = False,
    oe_base: str = "vessel",
    segment: float = 30.0,
    sim_dt: float = 0.05,
    max_nfev: int = 40,
    effect: str | CatalogueEffect | None = None,
    oe_start: dict[str, float] | None = None,
) -> FitResult:
    """Identify M, D_L, D_Q from a maneuver log (see the module docstring for the methods).

    The first 1 − ``validation_fraction`` of the log is fitted, the rest held out.
    ``coriolis``: "vessel" (C and g from the vessel file's M, the thesis's variant), "iterate"
    (C from the estimated M until it settles), "joint" (force form, M solved with its own
    Coriolis terms; ``damping="diagonal"`` restricts D_L, D_Q to diagonals), "auto" (= "vessel"
    when the thrusters span all DOFs, else "joint"). ``derivative``/``smoothing``: how nu_dot is
    obtained (``_prepare``). Output error: ``oe_added_mass`` also fits the added-mass diagonal;
    ``oe_base`` = "vessel" keeps every other entry from the vessel file, "ls" from the LS fit.
    ``segment`` s: restart length of the simulations, on a grid of about ``sim_dt`` s.
    ``effect`` (output error only): a diagnosis extension, "current" (NED current fitted, damping
    on nu - nu_c) or "constant_force" (a force per DOF), or an effect object (a located variant,
    a combination: ``effects.base.Combined``); ``oe_start``: start values by name.

    The same as ``fit_prepared(prepare_maneuver(...), ...)``: a diagnosis prepares the log once
    and fits it with each extension.
    """
    _check_args(vessel, method, oe_base, effect)
    problem = prepare_maneuver(data, vessel, validation_fraction, coriolis=coriolis, damping=damping,
                               derivative=derivative, smoothing=smoothing, polyorder=polyorder,
                               segment=segment, sim_dt=sim_dt)
    return fit_prepared(problem, method, oe_added_mass=oe_added_mass, oe_base=oe_base, max_nfev=max_nfev,
                        effect=effect, oe_start=oe_start)


@dataclass
class ManeuverProblem:
    """A checked, prepared maneuver log: what every fit of it shares (resampling, nu_dot, the LS
    start with its smoothing choice, the simulation setups of the fitted and held-out parts).
    Fits never modify it."""

    vessel: VesselSpec
    data: ManeuverData
    prep: _Prepared
    rows: np.ndarray
    ls: _LSResult
    fit_setup: _SimSetup
    val_setup: _SimSetup | None
    plant: dict[str, np.ndarray]
    derivative: str
    validation_fraction: float
    warnings: list[str]
    extras: dict[str, Any]


def prepare_maneuver(data: ManeuverData, vessel: VesselSpec, validation_fraction: float = 0.3, *,
                     coriolis: str = "auto", damping: str = "full", derivative: str = "auto",
                     smoothing: float | None = None, polyorder: int = 4, segment: float = 30.0,
                     sim_dt: float = 0.05) -> ManeuverProblem:
    """Check the log and the arguments, resample, prepare nu_dot, fit LS (choosing the
    smoothing) and set up the simulations (``identify_maneuver`` for the arguments)."""
    _check_log(data, vessel, validation_fraction, coriolis, damping)
    d = vessel.dof
    warnings: list[str] = []
    data = _uniform(data, warnings)
    if derivative not in DERIVATIVES:
        raise ValueError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {derivative!r}")
    if derivative == "auto":
        derivative = "measured" if data.nu_dot is not None else "savgol"
    n = data.n
    i_split = n if validation_fraction == 0 else round(n * (1.0 - validation_fraction))

    plant = plant_matrices(vessel)
    coriolis = _coriolis_form(vessel, coriolis, damping, warnings)

    smoothing, prep, rows, ls, fit_setup, ratio, scores = _ls_with_smoothing(
        data, vessel, plant, derivative, smoothing, polyorder, i_split, segment, sim_dt, coriolis, damping,
        warnings)
    tau_cov = np.cov((prep.tau[rows] / np.maximum(prep.tau[rows].std(axis=0), 1e-12)).T)
    tau_rank = int(np.sum(np.linalg.eigvalsh(tau_cov) > 1e-8))
    if tau_rank < d:
        warnings.append(f"the logged forces excite only {tau_rank} of {d} independent directions")
    nodes = shooting_nodes(vessel, prep, 0, i_split, segment, sim_dt, plant["M"], plant["D_L"], plant["D_Q"],
                           align=math.lcm(*JAC_COARSEN))
    if nodes.size:  # segments along which the model amplifies a start error get more starts
        fit_setup = _sim_setup(vessel, prep, 0, i_split, segment, sim_dt, nodes=nodes) or fit_setup
    val_setup = _sim_setup(vessel, prep, i_split, n, segment, sim_dt, scale=fit_setup.scale)
    extras: dict[str, Any] = {
        "preprocessing": prep.note,
        "noise_ratio": ratio,
        "smoothing_s": smoothing,
        "smoothing_scores": scores,
        "source": data.source,
        "coriolis": coriolis,
        "ls_form": ls.note,
        "segment_s": segment,
        "shooting_nodes_s": [float(fit_setup.t[k]) for k in nodes] if fit_setup.t is not None else [],
        "sim_dt_s": fit_setup.sim.h,
        "ls_matrices": {"M": ls.M.tolist(), "D_L": ls.D_L.tolist(), "D_Q": ls.D_Q.tolist()},
        "vessel_matrices": {k: v.tolist() for k, v in plant.items()},
        "equation_error_rms": np.sqrt(np.mean(ls.residual**2, axis=0)).tolist(),
        "fit_samples": [0, i_split],
        "validation_samples": [i_split, n],
    }
    return ManeuverProblem(vessel, data, prep, rows, ls, fit_setup,
                           val_setup if validation_fraction > 0 else None, plant, derivative,
                           validation_fraction, warnings, extras)


def fit_prepared(problem: ManeuverProblem, method: str = "ls", *, oe_added_mass: bool = False,
                 oe_base: str = "vessel", max_nfev: int = 40, effect: str | CatalogueEffect | None = None,
                 oe_start: dict[str, float] | None = None, noise_null: bool = True,
                 untold_at_file: bool = False) -> FitResult:
    """One fit of a prepared log: LS itself, or output error (with an extension ``effect``, a
    name or an effect object) started from it; the simulation scores and the warnings.
    ``untold_at_file``: the damping of DOFs the log cannot tell is held at the vessel file's where
    the log does not reject it (``estimation.holding_untold_damping``; ``extras["held_at_file"]`` names it).
    ``noise_null=False``: the residual's whiteness against white noise only, its test against what
    the sensor noise alone leaves (199 simulations of the log) left for ``complete_whiteness``, which a
    diagnosis calls for its cause only, not for every candidate (it tripled a diagnosis's time)."""
    _check_args(problem.vessel, method, oe_base, effect)
    vessel, prep, ls, fit_setup = problem.vessel, problem.prep, problem.ls, problem.fit_setup
    d = vessel.dof
    warnings = list(problem.warnings)
    if prep.dt > 0.05 and problem.derivative != "measured" and method == "ls":
        warnings.append(f"coarse sampling ({prep.dt:g} s): differentiation bias grows as dt^2 and the "
                        "95 % CIs count the noise, not this bias (they may miss the true value); prefer "
                        "method='output_error' for final numbers")
    rows = problem.rows
    nu_names = NU_NAMES[d]
    nu_rms = np.sqrt(np.mean(prep.nu_raw[rows] ** 2, axis=0))
    extras: dict[str, Any] = dict(problem.extras)

    with holding_untold_damping() if untold_at_file else contextlib.nullcontext():
        M, D_L, D_Q, names, values, ci, corr, n_res, method_label = _estimate(
            method, vessel, prep, fit_setup, ls, problem.plant, oe_added_mass, oe_base, max_nfev, warnings,
            effect, oe_start, extras)
    fitted = set(names)

    # simulation NRMSE (same for both methods)
    eff = extras.get("effect_terms") if method != "ls" else None
    nrmse_fit, nrmse_validation, res_ok = _simulation_scores(
        fit_setup, problem.val_setup, M, D_L, D_Q, eff, extras, warnings)
    rss = float(np.sum(res_ok**2))
    aic, bic = fitting.aic_bic(rss, res_ok.size, len(names))
    test = functools.partial(whiteness, fit_setup, M, D_L, D_Q, eff, prep, res_ok, nu_names)
    white = test(replicates=NOISE_REPLICATES if noise_null else 0)
    if not noise_null:
        extras[_PENDING] = test

    warnings += _sanity(M, D_L, D_Q, problem.plant["M_RB"], ci, nu_rms, nu_names, fitted)
    nonid = fitting.nonidentifiable_pairs(names, corr)
    warnings += _evidence_warnings(names, values, ci, nonid, n_res)
    extras["matrices"] = {"M": M.tolist(), "D_L": D_L.tolist(), "D_Q": D_Q.tolist()}
    return FitResult(
        params=dict(zip(names, (float(v) for v in values), strict=True)),
        ci95=ci,
        correlation=corr,
        param_names=list(names),
        nonidentifiable=nonid,
        nrmse_fit=nrmse_fit,
        nrmse_validation=nrmse_validation,
        aic=aic,
        bic=bic,
        whiteness=white,
        warnings=warnings,
        n_samples=int(rows.size),
        method=method_label,
        extras=extras,
    )


_PENDING = "whiteness_against_noise"  # extras key: the whiteness test a fit left for later


def complete_whiteness(fit: FitResult) -> None:
    """The residual's whiteness of a fit made with ``noise_null=False`` tested against what the sensor
    noise alone leaves, as every other fit's is; nothing for any other fit."""
    pending = fit.extras.pop(_PENDING, None)
    if pending is not None:
        fit.whiteness = pending()


def _check_args(vessel: VesselSpec, method: str, oe_base: str, effect: str | CatalogueEffect | None) -> None:
    """The fit's own arguments: a ValueError naming the wrong one."""
    if isinstance(effect, str):
        effect_names(effect, vessel.dof)  # validates the name
    if effect is not None and method != "output_error":
        raise ValueError("an effect extension is fitted by output error (method='output_error')")
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if oe_base not in ("vessel", "ls"):
        raise ValueError(f"oe_base must be 'vessel' or 'ls', got {oe_base!r}")


def _check_log(data: ManeuverData, vessel: VesselSpec, validation_fraction: float, coriolis: str,
               damping: str) -> None:
    """The preparation's arguments and the log, before anything is computed: a ValueError for a
    wrong argument, a TrialError (one line per problem) for a log that cannot be fitted."""
    if coriolis not in CORIOLIS:
        raise ValueError(f"coriolis must be one of {', '.join(CORIOLIS)}, got {coriolis!r}")
    if damping not in ("full", "diagonal"):
        raise ValueError(f"damping must be 'full' or 'diagonal', got {damping!r}")
    if not 0.0 <= validation_fraction < 0.9:
        raise ValueError(f"validation_fraction must be in [0, 0.9), got {validation_fraction}")
    if data.dof != vessel.dof:
        raise TrialError(
            f"{data.source}: the log has {data.dof} DOF, vessel '{vessel.name}' has {vessel.dof}"
        )
    d = vessel.dof
    min_n = SAMPLES_PER_REGRESSOR * 3 * d
    if data.n < min_n:
        raise TrialError(
            f"{data.source}: only {data.n} samples; a {d}-DOF maneuver fit needs at least {min_n}"
        )
    for name in ("t", "eta", "nu", "tau"):
        arr = getattr(data, name)
        if not np.all(np.isfinite(arr)):
            raise TrialError(f"{data.source}: {name} contains NaN or inf")
        if np.any(np.abs(arr) > MAX_ABS):
            raise TrialError(f"{data.source}: {name} has values out of range (|value| > {MAX_ABS:g}; "
                             "squares in the fit would overflow)")
    if np.any(np.diff(data.t) <= 0):
        raise TrialError(f"{data.source}: time is not strictly increasing")
    problems = _gap_problems(data.t, "sample ", 2) + _excitation_problems(
        data.nu, data.tau, list(NU_NAMES[d]), [f"tau_{n}" for n in TAU_NAMES[d]], NU_NAMES[d])
    if problems:
        raise TrialError("\n".join(f"{data.source}: {p}" for p in problems))


def _ls_with_smoothing(data: ManeuverData, vessel: VesselSpec, plant: dict[str, np.ndarray],
                       derivative: str, smoothing: float | None, polyorder: int, i_split: int,
                       segment: float, sim_dt: float, coriolis: str, damping: str,
                       warnings: list[str]) -> tuple:
    """The LS fit with its preprocessing; returns (smoothing, prep, rows, ls, fit_setup, noise ratio,
    smoothing scores)."""
    n, d = data.n, vessel.dof
    min_n = SAMPLES_PER_REGRESSOR * 3 * d
    # Smoothing: a clean log needs none; on a noisy one (second-difference noise estimate) the
    # window is chosen among a few by the LS model's simulated NRMSE on the fitted part.
    candidates: list[float | None] = [smoothing]
    ratio = noise_ratio(data.nu)
    if derivative == "savgol" and smoothing is None and ratio > 2e-3:
        dt = float(np.median(np.diff(data.t)))
        candidates = [None] + [s for s in (0.25, 0.5, 1.0, 2.0) if s / dt < 0.05 * n and s > 8 * dt]
    best: tuple | None = None
    scores: dict[str, float] = {}
    for sm in candidates:
        prep = _prepare(data, derivative, sm, polyorder)
        rows = np.arange(prep.edge, min(i_split, n - prep.edge))
        if rows.size < min_n:
            raise TrialError(
                f"{data.source}: {rows.size} samples left to fit after the hold-out; need {min_n}"
            )
        ls = _run_ls(prep, rows, vessel, plant, coriolis, damping, warnings if len(candidates) == 1 else [])
        fit_setup = _sim_setup(vessel, prep, 0, i_split, segment, sim_dt)
        if fit_setup is None:
            raise TrialError(f"{data.source}: too few samples to simulate the fitted part")
        score = float("nan")
        if len(candidates) > 1:
            sc, _ = _nrmse_per_dof(fit_setup, _sym(ls.M), ls.D_L, ls.D_Q)
            score = float(np.mean(sc))
            scores["none" if sm is None else f"{sm:g} s"] = score
        if best is None or (np.isfinite(score) and not score >= best[0]):
            best = (score, sm, prep, rows, ls, fit_setup)
    assert best is not None
    _, smoothing, prep, rows, ls, fit_setup = best
    if len(candidates) > 1:  # rerun to collect the chosen fit's warnings
        ls = _run_ls(prep, rows, vessel, plant, coriolis, damping, warnings)
    return smoothing, prep, rows, ls, fit_setup, ratio, scores


def _simulation_scores(fit_setup: _SimSetup, val_setup: _SimSetup | None, M: np.ndarray, D_L: np.ndarray,
                       D_Q: np.ndarray, eff: dict[str, np.ndarray] | None, extras: dict[str, Any],
                       warnings: list[str]) -> tuple[float, float, np.ndarray]:
    """Simulation NRMSE on the fitted and the held-out part (per DOF into ``extras``, with the
    prediction traces) and the normalised residual of the fitted part (``fitting.DIVERGED_RESIDUAL``
    where it diverged)."""
    d = M.shape[0]
    nu_names = NU_NAMES[d]
    nr_fit, res_fit = _nrmse_per_dof(fit_setup, M, D_L, D_Q, eff)
    if val_setup is not None:
        nr_val, _ = _nrmse_per_dof(val_setup, M, D_L, D_Q, eff)
        extras["n_validation"] = int(val_setup.mask.sum() * d)
        nrmse_validation = float(np.mean(nr_val))
        extras["nrmse_validation_per_dof"] = dict(zip(nu_names, nr_val.tolist(), strict=True))
    else:
        nrmse_validation = float("nan")
    nrmse_fit = float(np.mean(nr_fit))
    extras["nrmse_fit_per_dof"] = dict(zip(nu_names, nr_fit.tolist(), strict=True))
    extras["nu_names"] = list(nu_names)
    extras["predictions"] = [_trace(fit_setup, M, D_L, D_Q, "fit", eff)]
    if val_setup is not None:
        extras["predictions"].append(_trace(val_setup, M, D_L, D_Q, "validation", eff))
    if not np.all(np.isfinite(res_fit)):
        warnings.append(f"{fitting.DIVERGED} (unstable)")
        res_ok = np.nan_to_num(res_fit, nan=fitting.DIVERGED_RESIDUAL)
    else:
        res_ok = res_fit
    return nrmse_fit, nrmse_validation, res_ok


def _evidence_warnings(names: list[str], values: np.ndarray, ci: dict[str, tuple[float, float]],
                       nonid: list, n_res: int) -> list[str]:
    """Warnings about how well the trial determines the parameters."""
    warnings: list[str] = []
    if nonid:
        warnings.append(f"{len(nonid)} parameter pair(s) with |correlation| > "
                        f"{fitting.NONIDENTIFIABLE_CORR}: not separately identifiable from this trial "
                        "(see nonidentifiable)")
    wide = [k for k in names if _is_diag(k) and _rel_halfwidth(ci[k], values[names.index(k)]) > 0.5]
    if wide:
        warnings.append(f"{len(wide)} diagonal parameter(s) with a 95 % CI wider than +-50 % of the value "
                        f"(poorly excited): {', '.join(wide[:8])}{' ...' if len(wide) > 8 else ''}")
    if SAMPLES_PER_REGRESSOR * len(names) > n_res:
        warnings.append(f"{len(names)} parameters from {n_res} equations: too few data per parameter")
    return warnings


def _coriolis_form(vessel: VesselSpec, coriolis: str, damping: str, warnings: list[str]) -> str:
    """The LS form: "auto" resolves to "vessel" when the thrusters span all DOFs, else "joint"."""
    d = vessel.dof
    B = thruster_matrix(vessel.thrusters, d)
    rank = int(np.sum(np.linalg.eigvalsh(B @ B.T) > 1e-10 * np.max(np.linalg.eigvalsh(B @ B.T))))
    if coriolis == "auto":
        coriolis = "vessel" if rank == d else "joint"
    if coriolis != "joint" and damping != "full":
        raise ValueError("damping='diagonal' needs coriolis='joint' (the acceleration form is per row, full)")
    if coriolis != "joint" and rank < d:
        warnings.append(f"the thrusters span only {rank} of {d} DOFs: in the acceleration form M^-1 is not "
                        "identifiable from tau (use coriolis='joint')")
    return coriolis


def _estimate(method: str, vessel: VesselSpec, prep: _Prepared, fit_setup: _SimSetup, ls: _LSResult,
              plant: dict[str, np.ndarray], oe_added_mass: bool, oe_base: str, max_nfev: int,
              warnings: list[str], effect: str | CatalogueEffect | None, oe_start: dict[str, float] | None,
              extras: dict[str, Any]) -> tuple:
    """The final estimate: the LS fit itself, or output error started from it; its CIs and label.
    An effect object (a located variant, a combination) is fitted as it is; a name goes through
    ``_output_error``, which locates an effect with variants (which thruster)."""
    if method == "ls":
        M, D_L, D_Q = ls.M, ls.D_L, ls.D_Q
        names, values = ls.names, ls.values
        infl = _autocorr_inflation(ls.residual)
        cov = ls.cov * infl
        n_res = ls.n_rows
        ci = fitting.confidence_intervals(names, values, cov, n_res)
        corr = fitting.correlation_matrix(cov)
        extras["ci_inflation"] = infl
        method_label = f"maneuver LS ({ls.note})"
    else:
        oe = _output_error_one if isinstance(effect, CatalogueEffect) else _output_error
        (M, D_L, D_Q, names, values, cov, ci, corr, n_res, oe_info) = oe(
            vessel, prep, fit_setup, ls, plant, oe_added_mass, oe_base, max_nfev, warnings, effect, oe_start)
        extras.update(oe_info)
        form = oe_info.get("effect_form")  # the form of an effect with several, said in the label
        if form and len(oe_info.get("forms", ())) > 1:
            form += ", which fits the log better than the other form"
        method_label = (f"maneuver output error (diagonal D_L, D_Q{', added mass' if oe_added_mass else ''}; "
                        f"start: {ls.note}; other entries from the "
                        f"{'vessel file' if oe_base == 'vessel' else 'LS fit'}{f'; {form}' if form else ''})")
    return M, D_L, D_Q, names, values, ci, corr, n_res, method_label


# -- screening combinations of extensions (the diagnosis's pair search) ---------------------------

@dataclass
class Screened:
    """One set of extensions after a joint Gauss-Newton step from a reference fit: the fitting cost
    (sum of squared normalised residuals, the reference's segment states), the held-out NRMSE
    (as ``FitResult.nrmse_validation``) and the stepped values, where a refit starts."""

    members: tuple[int, ...]
    cost: float
    nrmse_validation: float
    start: dict[str, float]
    rows: int  # residuals in the cost


def _coarse_setup(setup: _SimSetup) -> _SimSetup:
    """The setup on the output-error Jacobian's coarser grid (every c-th sample, ``_coarse_sim``):
    a screen compares models, which the coarse grid does as well at a fraction of the cost."""
    from seafmu.identification.maneuver.estimation import _coarse_sim

    got = _coarse_sim(setup)
    if got is None:
        return setup
    sim, c = got
    return _SimSetup(sim, setup.meas[:, ::c], setup.mask[:, ::c], setup.scale, None)


def _reference_model(plant: dict[str, np.ndarray], start: dict[str, float], d: int) -> tuple:
    """(M, D_L, D_Q, fitted damping diagonals as (name, DOF)): the vessel file's matrices with the
    diagonals a fit gives in ``start``."""
    M0, DL0, DQ0 = plant["M"].copy(), plant["D_L"].copy(), plant["D_Q"].copy()
    damp: list[tuple[str, int]] = []
    for i in range(d):
        for name, mat in ((f"D_L[{i},{i}]", DL0), (f"D_Q[{i},{i}]", DQ0)):
            if name in start:
                mat[i, i] = start[name]
                damp.append((name, i))
        M0[i, i] = start.get(f"M[{i},{i}]", M0[i, i])
    return M0, DL0, DQ0, damp


def _gauss_newton_steps(J: np.ndarray, r0: np.ndarray, nD: int, effect_cols: list[list[int]]) -> np.ndarray:
    """One Gauss-Newton step per subset (rows): in the first ``nD`` columns of ``J`` (nP, rows),
    always, and the subset's effect columns (``nD +`` each); zero in the others."""
    G, b = J @ J.T, J @ r0
    steps = np.zeros((len(effect_cols), J.shape[0]))
    for k, ecols in enumerate(effect_cols):
        cols = list(range(nD)) + [nD + j for j in ecols]
        A = G[np.ix_(cols, cols)]
        cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
        steps[k, cols] = -np.linalg.lstsq(A / np.outer(cs, cs), b[cols] / cs, rcond=None)[0] / cs
    return steps


def _nrmse_of(s: _SimSetup, r: np.ndarray) -> np.ndarray:
    """Mean per-DOF NRMSE (as ``FitResult.nrmse_validation``) of K models' normalised residuals
    r (K, compared samples, d); inf where a model diverged."""
    y = s.meas[s.mask]
    spread = np.sqrt(np.sum((y - y.mean(axis=0)) ** 2, axis=0)) / s.scale
    nr = np.mean(np.sqrt(np.sum(r**2, axis=1)) / np.maximum(spread, 1e-300), axis=1)
    return np.where(np.isfinite(nr), nr, np.inf)


def screen_extensions(problem: ManeuverProblem, start: dict[str, float], members: list[CatalogueEffect],
                      subsets: list[tuple[int, ...]]) -> list[Screened] | None:
    """Each subset of ``members`` (effect objects: located variants, or effects) screened without a
    fit: from a fitted model ``start`` (its damping diagonals and the effect values it has), the
    residuals' Jacobian in the damping and in every member's parameters is taken once (one batched
    simulation), then each subset gets a Gauss-Newton step in the damping and its own members'
    parameters (small normal equations), and is simulated there on the fitted part and on the
    held-out part (two batched simulations for all subsets). A pair whose members act together
    shows here even where each member's own fit was stuck. None when the baseline itself does not
    simulate."""
    from seafmu.identification.effects.base import Combined  # the effects package is light
    from seafmu.identification.maneuver.estimation import _log_key, _recall_states, formed
    from seafmu.identification.maneuver.simulation import _sim_residual

    vessel, plant, prep = problem.vessel, problem.plant, problem.prep
    # the fitted part's segments restart from the states fitted with the reference (the measured
    # ones carry the sensor noise, whose transients would swamp the step); the held-out part's from
    # the measured states, as its NRMSE does
    key = _log_key(problem.fit_setup)
    x0 = _recall_states(key, start)
    setup = _coarse_setup(problem.fit_setup)
    val = _coarse_setup(problem.val_setup) if problem.val_setup is not None else None
    d = vessel.dof
    # a member with several forms (a current's inertia) in the form the log's fits kept
    members = [formed(m, key, vessel) for m in members]
    M0, DL0, DQ0, damp = _reference_model(plant, start, d)
    allm = Combined(members, d)
    enames = allm.maneuver_params(d)
    sizes = [len(m.maneuver_params(d)) for m in members]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    # the reference: the start's values of the members it has (a fit with some of them), else absent
    absent = np.concatenate([np.full(n, m.absent) for m, n in zip(members, sizes, strict=True)])
    ref = np.array([start.get(nm, a) for nm, a in zip(enames, absent, strict=True)])
    h_e = np.asarray(allm.maneuver_scales(prep.tau, prep.nu_raw), dtype=float)
    nu_rms = np.sqrt(np.mean(prep.nu_raw**2, axis=0))
    sQ = np.maximum(np.abs(np.diag(DQ0)), 1e-3 * np.diag(M0))
    h_d = np.array([1e-2 * (sQ[i] if nm.startswith("D_Q") else max(abs(DL0[i, i]), sQ[i] * nu_rms[i] + 1e-6))
                    for nm, i in damp])
    nD, nE = len(damp), len(enames)

    def simulate(s: _SimSetup, dD: np.ndarray, E: np.ndarray, states: np.ndarray | None) -> np.ndarray:
        """Flat residuals (K, rows) of K models: damping changes dD (K, nD), effect values E (K, nE)."""
        K = E.shape[0]
        M, DL, DQ = (np.repeat(a[None], K, axis=0) for a in (M0, DL0, DQ0))
        for j, (nm, i) in enumerate(damp):
            (DQ if nm.startswith("D_Q") else DL)[:, i, i] += dD[:, j]
        X0 = None if states is None else np.broadcast_to(states, (K, *states.shape))
        r = _sim_residual(s, M, DL, DQ, X0, **allm.maneuver_terms(E))[:, s.mask]
        return r.reshape(K, -1)

    # the Jacobian: the reference, each damping diagonal moved, each effect parameter moved
    K = 1 + nD + nE
    dD = np.zeros((K, nD))
    dD[1 + np.arange(nD), np.arange(nD)] = h_d
    E = np.repeat(ref[None], K, axis=0)
    E[1 + nD + np.arange(nE), np.arange(nE)] += h_e
    R = simulate(setup, dD, E, x0)
    if not np.all(np.isfinite(R[0])):
        return None
    R = np.where(np.isfinite(R), R, 1e3)
    J = (R[1:] - R[0]) / np.concatenate([h_d, h_e])[:, None]  # (nD + nE, rows)
    steps = _gauss_newton_steps(J, R[0], nD, [[j for m in sub for j in range(offs[m], offs[m + 1])]
                                               for sub in subsets])
    Es = ref[None] + steps[:, nD:]
    fit_r = simulate(setup, steps[:, :nD], Es, x0)
    costs = np.where(np.all(np.isfinite(fit_r), axis=1), np.sum(fit_r**2, axis=1), np.inf)
    if val is not None:
        nr = _nrmse_of(val, simulate(val, steps[:, :nD], Es, None).reshape(len(subsets), -1, d))
    else:
        nr = np.full(len(subsets), np.nan)
    out = []
    for k, sub in enumerate(subsets):
        st = {nm: float(start[nm] + steps[k, j]) for j, (nm, _) in enumerate(damp)}
        st = {k2: (max(v, 0.0) if k2.startswith("D_Q") else v) for k2, v in st.items()}
        for m in sub:
            st.update({enames[j]: float(Es[k, j]) for j in range(offs[m], offs[m + 1])})
        out.append(Screened(tuple(sub), float(costs[k]), float(nr[k]), st, int(fit_r.shape[1])))
    return out
