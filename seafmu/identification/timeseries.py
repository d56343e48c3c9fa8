"""Time-series trials (decay, step, 2nd-order decay, pendulum, coupled sway-yaw) by output error.

The model is simulated over the whole record and its parameters chosen so the simulated output
matches the measured one (scipy least_squares). Equation error (regression on differentiated data)
only gives the start guess: differentiating noisy or quantised data biases damping.

Simulation is a fixed-step RK4 at the sample instants written in plain Python floats: for one or two
states this is faster than numpy on tiny arrays and fast enough that a fit takes tens of
milliseconds on a few hundred samples. Input nonlinearities (delay, deadband, saturation, lag,
thrust law) are applied to the whole command array before the loop, vectorised.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from seafmu.identification import effects, ts_kernels
from seafmu.identification.fitting import (
    FitResult,
    aic_bic,
    confidence_intervals,
    correlation_matrix,
    correlation_warnings,
    covariance_from_jacobian,
    nonidentifiable_pairs,
    nrmse,
    unidentifiable_warnings,
    whiteness_test,
)
from seafmu.identification.trial import Run, Trial, TrialError

# The baseline models' own parameters; each effect adds its parameters at their neutral values
# to the families whose simulator has them (``effects/<name>.py``: ``families``, ``neutral``).
_BASE_DEFAULTS: dict[str, dict[str, float]] = {
    "first": {"M": 1.0, "k": 1.0, "eps": 0.0},
    "second": {"M": 1.0, "c": 0.0, "eps": 0.0},
    "pendulum": {"alpha": 0.0, "beta": 0.0, "gamma": 0.0, "eps": 0.0},
    "sway_yaw": {"m22": 1.0, "m26": 0.0, "m66": 1.0, "Y_v": 0.0, "N_r": 0.0},
}


def _defaults() -> dict[str, dict[str, float]]:
    out = {fam: dict(vals) for fam, vals in _BASE_DEFAULTS.items()}
    for obj in effects.all_effects():
        for fam in obj.families:
            out[fam].update(obj.neutral_values())
    return out


DEFAULTS = _defaults()
BOUNDS = effects.bounds("timeseries")  # each effect's own (effects/<name>.py)
IC_NAMES = {"first": ("x0",), "second": ("x0", "xd0"), "pendulum": ("x0", "xd0"), "sway_yaw": ("v0", "r0")}


@dataclass
class TSModel:
    """A time-series model: its family, all parameter values, and which of them are fitted."""

    family: str
    values: dict[str, float]
    free: list[str]
    input_kind: str | None = None  # rpm | force | None (no input)
    thrust_law: str = "linear"
    restoring: str = "linear"  # linear | sin
    effect: str | None = None

    def at(self, theta: np.ndarray | list[float]) -> dict[str, float]:
        v = dict(self.values)
        v.update(zip(self.free, (float(x) for x in theta), strict=True))
        return v

    def copy(self, **kw: Any) -> TSModel:
        d = {"family": self.family, "values": dict(self.values), "free": list(self.free),
             "input_kind": self.input_kind, "thrust_law": self.thrust_law, "restoring": self.restoring,
             "effect": self.effect}
        d.update(kw)
        return TSModel(**d)


# -- simulation -----------------------------------------------------------------------------------

@dataclass
class _Prep:
    """A run's arrays in the forms the loops want, computed once per fit."""

    t: np.ndarray
    u: np.ndarray | None
    y: np.ndarray
    rate: np.ndarray | None = None  # measured derivatives, when the trial has them (pendulum)
    accel: np.ndarray | None = None
    uniform: bool = True
    h: float = 0.0
    before: float | None = None  # the command before the first sample (command_before)

    def __post_init__(self) -> None:
        d = np.diff(self.t)
        self.h = float(np.median(d)) if d.size else 0.0
        self.uniform = bool(d.size and np.allclose(d, self.h, rtol=1e-6, atol=1e-12))
        self.before = command_before(self.u, self.y)


def command_before(u: np.ndarray | None, y: np.ndarray) -> float | None:
    """0.0 when a run starts at rest with its command already on (a step logged from the instant of
    the step: before it the command was 0, as a step trial starts from rest); None where the run
    starts in motion (steady state under its first command, which a lag or delay then holds).
    At rest: the first output within a tenth of the largest (noise of a few per cent passes)."""
    if u is None:
        return None
    u0 = np.asarray(u, dtype=float).reshape(len(y), -1)[0]
    ya = np.abs(np.asarray(y, dtype=float))
    if not u0.any() or ya.size == 0 or ya.ndim != 1:
        return None
    return 0.0 if ya[0] <= 0.1 * ya.max() else None


def _stages() -> list[effects.CatalogueEffect]:
    """The effects acting on the input chain, in the order they act."""
    return sorted((o for o in effects.all_effects() if o.input_stage is not None),
                  key=lambda o: (o.input_stage, o.name))


def thrust(v: dict[str, float], law: str, n: np.ndarray, extra_terms: bool = True) -> np.ndarray:
    """Thrust k g(n) of a shaft speed n: the baseline law g (n or n|n|) unless an effect reshapes
    it, every effect's gain on it, then (``extra_terms``) every effect's added thrust."""
    g = None
    for obj in effects.all_effects():
        g = obj.thrust_law(n, v)
        if g is not None:
            break
    if g is None:
        g = n if law == "linear" else n * np.abs(n)
    tau = v.get("k", 0.0) * g
    for obj in effects.all_effects():
        gain = obj.thrust_gain(n, v)
        if gain is not None:
            tau = tau * gain
    if extra_terms:
        for obj in effects.all_effects():
            term = obj.thrust_term(n, v)
            if term is not None:
                tau = tau + term
    return tau


def generalised_force(v: dict[str, float], model: TSModel, t: np.ndarray, u: np.ndarray | None,
                      uniform: bool = True, before: float | None = None) -> tuple[np.ndarray, bool]:
    """Force from the command through the effects' input chain (delay, deadband, saturation, lag)
    and the thrust law; ``before``: the command before the first sample (``command_before``).

    Returns the force at the samples and whether it varies continuously between them (after a lag),
    in which case the integrator interpolates instead of holding it.
    """
    if u is None or model.input_kind is None:
        return np.zeros(len(t)), False
    x = np.asarray(u, dtype=float)
    continuous = False
    for obj in _stages():
        x, cont = obj.command(t, x, v, uniform, before)
        continuous = continuous or cont
    if model.input_kind == "force":
        return x, continuous
    return thrust(v, model.thrust_law, x), continuous


def _forcing(t: np.ndarray, tau: np.ndarray, interp: bool, scale: float, offset: float) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step sizes and the per-unit-inertia force at the start, middle and end of every RK4 step."""
    hs = np.ascontiguousarray(np.diff(t), dtype=float)
    f = np.asarray(tau, dtype=float) * scale + offset
    c1 = np.ascontiguousarray(f[:-1])
    if interp:
        c4 = np.ascontiguousarray(f[1:])
        return hs, c1, 0.5 * (c1 + c4), c4
    return hs, c1, c1, c1


def _sim_first(t: np.ndarray, tau: np.ndarray, interp: bool, v: dict[str, float], x0: float) -> np.ndarray:
    """M v_dot = tau + F_0 - d_L w - d_Q w|w|^(p_v-1) - f_c sign(v), w = v - v_c (RK4, one step per
    sample; compiled, ``ts_kernels.first_rk4``)."""
    iM = 1.0 / float(v["M"] + v["m_a"])
    a, b = float(v["d_L"]) * iM, float(v["d_Q"]) * iM
    fm, vc = float(v["f_c"]) * iM, float(v["v_c"])
    pq = float(v.get("p_v", 2.0))
    hs, C1, C2, C4 = _forcing(t, tau, interp, iM, float(v["F_0"]) * iM)
    extra = _state_force(v, "first")
    eps = float(v.get("eps", 0.0))
    if extra is not None:
        return np.array(_sim_first_general(hs.tolist(), C1.tolist(), C2.tolist(), C4.tolist(),
                                           (a, b, fm, vc, iM, eps, pq), extra, x0))
    if hs.size == 0:
        return np.array([float(x0)])
    if fm == 0.0:
        mode, ie = ts_kernels.MODE_NONE, 0.0
    elif eps > 0.0:
        # Regularised friction f_c tanh(v/eps): smooth in the parameters, which output-error fitting
        # needs; eps is kept above f_c h / 2 so that RK4 stays stable in the steep part.
        mode, ie = ts_kernels.MODE_SMOOTH, 1.0 / max(eps, 0.5 * fm * float(np.max(hs)))
    else:  # exact stick-slip (used to generate test data)
        mode, ie = ts_kernels.MODE_EXACT, 0.0
    return ts_kernels.first_rk4(hs, C1, C2, C4, a, b, pq, fm, vc, ie, mode, float(x0))


StateForce = Callable[[float, float], float]


def _state_force(v: dict[str, float], family: str) -> StateForce | None:
    """The sum of the effects' extra state forces f(x, w) in this family (None: there are none)."""
    fs = [f for obj in effects.all_effects() if family in obj.families
          if (f := obj.state_force(v)) is not None]
    if not fs:
        return None
    if len(fs) == 1:
        return fs[0]
    return lambda x, w: sum(f(x, w) for f in fs)


def _sim_first_general(hs: list[float], C1: list[float], C2: list[float], C4: list[float],
                       coef: tuple[float, ...], extra: StateForce, x0: float) -> list[float]:
    """The 1st-order loop with an effect's extra state force f(0, w) (e.g. a power-law drag):
    the same RK4 and friction laws as ``_sim_first``, with a call per stage (slower)."""
    a, b, fm, vc, iM, eps, pq = coef
    exact = fm > 0.0 and eps <= 0.0
    ie = 1.0 / max(eps, 0.5 * fm * max(hs)) if fm > 0.0 and not exact else 0.0
    th = math.tanh

    def acc(c: float, s: float) -> float:
        w = s - vc
        fr = (fm if s > 0 else (-fm if s < 0 else 0.0)) if exact else (fm * th(s * ie) if fm else 0.0)
        return c - w * (a + b * abs(w) ** (pq - 1.0)) - fr - iM * extra(0.0, w)

    out = [0.0] * (len(hs) + 1)
    x = float(x0)
    out[0] = x
    i = 0
    try:
        for h, c1, c2, c4 in zip(hs, C1, C2, C4, strict=True):
            k1 = acc(c1, x)
            k2 = acc(c2, x + 0.5 * h * k1)
            k3 = acc(c2, x + 0.5 * h * k2)
            k4 = acc(c4, x + h * k3)
            xn = x + h * (k1 + 2.0 * (k2 + k3) + k4) / 6.0
            if exact and (x == 0.0 or x * xn <= 0.0 or x * (x + h * k1) <= 0.0) and abs(
                    c4 - (-vc) * (a + b * abs(vc) ** (pq - 1.0)) - iM * extra(0.0, -vc)) <= fm:
                xn = 0.0  # stuck: the other forces at rest are below the friction force
            x = xn
            i += 1
            out[i] = x
    except (ValueError, OverflowError, ZeroDivisionError):  # diverged
        return out[: i + 1] + [math.nan] * (len(out) - i - 1)
    return out


def _sim_second(t: np.ndarray, tau: np.ndarray, interp: bool, v: dict[str, float], restoring: str,
                x0: float, xd0: float) -> np.ndarray:
    """M x_dd = tau + F_0 - c r(x) - c3 x^3 - d_L x_d - d_Q x_d|x_d|^(p_v-1) - f_c sign(x_d), r = x or
    sin x (compiled, ``ts_kernels.second_rk4``)."""
    iM = 1.0 / float(v["M"] + v["m_a"])
    c, c3 = float(v["c"]) * iM, float(v["c3"]) * iM
    a, b = float(v["d_L"]) * iM, float(v["d_Q"]) * iM
    fm = float(v["f_c"]) * iM
    pq = float(v.get("p_v", 2.0))
    sl = restoring == "sin"
    hs, E1, E2, E4 = _forcing(t, tau, interp, iM, float(v["F_0"]) * iM)
    if hs.size == 0:
        return np.array([float(x0)])
    eps = float(v.get("eps", 0.0))
    smooth = eps > 0.0 and fm > 0.0
    ie = 1.0 / max(eps, 0.5 * fm * float(np.max(hs))) if smooth else 0.0
    extra = _state_force(v, "second")
    if extra is not None:  # an effect's state force (a call per stage: slower)
        th = math.tanh

        def force(pos: float, w: float) -> float:
            if fm == 0.0:
                fr = 0.0
            elif smooth:
                fr = fm * th(w * ie)
            else:
                fr = fm if w > 0 else (-fm if w < 0 else 0.0)
            return fr + iM * extra(pos, w)

        return np.array(_sim_second_general(hs.tolist(), E1.tolist(), E2.tolist(), E4.tolist(),
                                            (c, c3, a, b, fm, pq), sl, smooth, force, x0, xd0))
    return ts_kernels.second_rk4(hs, E1, E2, E4, c, c3, a, b, pq, fm, sl, smooth, ie, float(x0), float(xd0))


def _sim_second_general(hs: list[float], E1: list[float], E2: list[float], E4: list[float],
                        coef: tuple[float, ...], sl: bool, smooth: bool, force: StateForce, x0: float,
                        xd0: float) -> list[float]:
    """``_sim_second``'s loop with friction and the effects' state forces as one call force(x, x_d)."""
    c, c3, a, b, fm, pq = coef
    sin = math.sin

    def acc(e: float, p: float, w: float) -> float:
        r = sin(p) if sl else p
        return e - c * r - c3 * p * p * p - w * (a + b * abs(w) ** (pq - 1.0)) - force(p, w)

    n = len(hs) + 1
    out = [0.0] * n
    x, xd = float(x0), float(xd0)
    out[0] = x
    i = 0
    try:
        for h, e1, e2, e4 in zip(hs, E1, E2, E4, strict=True):
            a1 = acc(e1, x, xd)
            x2, v2 = x + 0.5 * h * xd, xd + 0.5 * h * a1
            a2 = acc(e2, x2, v2)
            x3, v3 = x + 0.5 * h * v2, xd + 0.5 * h * a2
            a3 = acc(e2, x3, v3)
            x4, v4 = x + h * v3, xd + h * a3
            a4 = acc(e4, x4, v4)
            xn = x + h * (xd + 2.0 * (v2 + v3) + v4) / 6.0
            vn = xd + h * (a1 + 2.0 * (a2 + a3) + a4) / 6.0
            if fm > 0.0 and not smooth and (xd == 0.0 or xd * vn <= 0.0 or xd * (xd + h * a1) <= 0.0):
                r = sin(xn) if sl else xn
                if abs(e4 - c * r - c3 * xn * xn * xn) <= fm:
                    vn = 0.0  # stuck: friction exceeds the restoring force at rest
            x, xd = xn, vn
            i += 1
            out[i] = x
    except (ValueError, OverflowError, ZeroDivisionError):  # diverged
        return out[: i + 1] + [math.nan] * (n - i - 1)
    return out


def _expm_small(A: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small matrix by scaling and squaring a Taylor series.

    scipy's expm costs milliseconds per call (LAPACK set-up) even for 4x4; this is ~50 us.
    """
    norm = float(np.max(np.sum(np.abs(A), axis=1)))
    s = max(0, math.ceil(math.log2(norm / 0.5)) if norm > 0.5 else 0)
    X = A / (2.0**s)
    E = np.eye(A.shape[0])
    term = np.eye(A.shape[0])
    for k in range(1, 14):
        term = term @ X / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def _sim_sway_yaw(t: np.ndarray, tau: np.ndarray, v: dict[str, float], v0: float, r0: float) -> np.ndarray:
    """Linear coupled sway-yaw (AAUSHIP method one, coupled): exact for inputs held between samples."""
    M = np.array([[v["m22"], v["m26"]], [v["m26"], v["m66"]]])
    D = -np.array([[v["Y_v"], v["Y_r"]], [v["N_v"], v["N_r"]]])
    Minv = np.linalg.inv(M)
    A = -Minv @ D
    n = len(t)
    out = [(0.0, 0.0)] * n
    x1, x2 = float(v0), float(r0)
    out[0] = (x1, x2)
    cache: dict[float, tuple[float, ...]] = {}
    big = np.zeros((4, 4))
    big[:2, :2] = A
    big[:2, 2:] = Minv
    Y, N = np.asarray(tau, dtype=float).T.tolist()
    hs = np.round(np.diff(t), 12).tolist()
    for i, h in enumerate(hs):
        if h not in cache:
            E = _expm_small(big * h)
            cache[h] = tuple(E[:2, :].ravel().tolist())
        a11, a12, b11, b12, a21, a22, b21, b22 = cache[h]
        y, m = Y[i], N[i]
        x1, x2 = a11 * x1 + a12 * x2 + b11 * y + b12 * m, a21 * x1 + a22 * x2 + b21 * y + b22 * m
        out[i + 1] = (x1, x2)
    return np.array(out)


def simulate(model: TSModel, values: dict[str, float], t: np.ndarray, u: np.ndarray | None,
             ic: tuple[float, ...], substeps: int = 1, uniform: bool | None = None,
             before: float | None = None) -> np.ndarray:
    """Simulated output at the sample times t from initial state ic; ``before``: the command
    before the first sample (``command_before``).

    substeps > 1 integrates on a finer grid (command held between samples): used to generate test
    data with a different integrator step than the fit uses.
    """
    t = np.asarray(t, dtype=float)
    if substeps > 1:
        tf = np.concatenate([np.linspace(t[i], t[i + 1], substeps, endpoint=False) for i in range(len(t) - 1)]
                            + [t[-1:]])
        uf = None
        if u is not None:
            idx = np.minimum(np.searchsorted(t, tf, side="right") - 1, len(t) - 1)
            uf = np.asarray(u)[idx]
        return simulate(model, values, tf, uf, ic, before=before)[::substeps]
    if uniform is None:
        d = np.diff(t)
        uniform = bool(d.size and np.allclose(d, d[0], rtol=1e-6))
    if model.family == "sway_yaw":
        tau = np.zeros((len(t), 2)) if u is None else np.asarray(u, dtype=float)
        return _sim_sway_yaw(t, tau, values, *ic)
    tau, interp = generalised_force(values, model, t, u, uniform, before)
    if model.family == "first":
        return np.array(_sim_first(t, tau, interp, values, ic[0]))
    if model.family == "pendulum":
        v2 = {"M": 1.0, "m_a": 0.0, "c": -values["alpha"], "c3": 0.0, "d_L": values["beta"],
              "d_Q": values["gamma"], "f_c": values["f_c"], "F_0": values["F_0"],
              "eps": values.get("eps", 0.0)}
        return np.array(_sim_second(t, tau, interp, v2, "sin", ic[0], ic[1]))
    return np.array(_sim_second(t, tau, interp, values, model.restoring, ic[0], ic[1]))


# -- models of a trial -----------------------------------------------------------------------------

def family_of(trial: Trial) -> str:
    if trial.dof == "sway_yaw":
        return "sway_yaw"
    return {"decay": "first", "step": "first", "decay2": "second", "pendulum": "pendulum"}[trial.kind]


def friction_eps(trial: Trial) -> float:
    """Width of the regularised friction law: 1 % of the largest speed (rate) in the data."""
    fam = family_of(trial)
    peaks = []
    for r in trial.runs:
        p = _Prep(np.asarray(r.t), None, np.asarray(r.y))
        d = _smooth_derivs(p, 1)
        peaks.append(float(np.max(np.abs(d[0] if fam == "first" else d[1]))))
    return 0.01 * max(peaks) if peaks else 0.0


def baseline_model(trial: Trial) -> TSModel:
    fam = family_of(trial)
    c = trial.constants
    vals = dict(DEFAULTS[fam])
    if "eps" in vals:
        vals["eps"] = friction_eps(trial)
    damping = {"linear": ["d_L"], "quadratic": ["d_Q"], "linear_quadratic": ["d_L", "d_Q"]}
    if fam == "first":
        vals["M"] = c.get("mass", 1.0) + c.get("added_mass", 0.0)
        free = list(damping[trial.baseline])
        if trial.kind == "step" and trial.input_kind == "rpm":
            if "thrust_coefficient" in c:
                vals["k"] = c["thrust_coefficient"]
            else:
                free.append("k")
        return TSModel("first", vals, free, trial.input_kind if trial.kind == "step" else None,
                       trial.thrust_law)
    if fam == "second":
        vals["M"] = c.get("mass", 1.0) + c.get("added_mass", 0.0)
        free = []
        if "stiffness" in c:
            vals["c"] = c["stiffness"]
        else:
            free.append("c")
        free += damping[trial.baseline]
        return TSModel("second", vals, free, restoring=trial.restoring)
    if fam == "pendulum":
        return TSModel("pendulum", vals, ["alpha", "beta", "gamma"], restoring="sin")
    if "mass" not in c or "inertia" not in c:
        raise TrialError(f"{trial.name}: a sway_yaw trial needs constants 'mass' (m + Y_vdot) and "
                         f"'inertia' (I_z + N_rdot)")
    vals.update(m22=c["mass"] + c.get("added_mass", 0.0), m66=c["inertia"], m26=c.get("mass_coupling", 0.0))
    return TSModel("sway_yaw", vals, ["Y_v", "N_r"], "force" if trial.kind == "step" else None)


def extend(model: TSModel, effect: str, trial: Trial | None = None) -> TSModel:
    """The model with the effect's parameters free (and the values it fixes, for this trial)."""
    obj = effects.get(effect)
    assert obj is not None, effect
    params = [p for p in obj.params if p not in model.free]
    values = {**obj.neutral_values(), **model.values}
    absent = obj.absent_values(trial) if trial is not None else {}
    for p in obj.params:  # a parameter with no neutral value starts where the effect is absent
        values.setdefault(p, absent.get(p, obj.absent))
    if trial is not None:
        values.update(obj.fixed_values(trial))
    return model.copy(free=[*model.free, *params], effect=effect, values=values)


# -- data splitting ---------------------------------------------------------------------------------

@dataclass
class Split:
    fit: list[_Prep]
    validation: list[_Prep]  # held-out runs (initial state refitted)
    segment_start: int | None = None  # single run: index where the held-out tail starts
    description: str = ""


def split(trial: Trial) -> Split:
    """Held-out data: the trial's validation runs, else its last run, else the tail of the one run."""
    def prep(r: Run, end: int | None = None) -> _Prep:
        sl = slice(0, end)
        cut = (lambda a: None if a is None else np.asarray(a)[sl])  # noqa: E731
        return _Prep(np.asarray(r.t)[sl], cut(r.u), np.asarray(r.y)[sl], rate=cut(r.rate), accel=cut(r.accel))

    if trial.validation_runs:
        return Split([prep(r) for r in trial.runs], [prep(r) for r in trial.validation_runs],
                     description=f"held-out runs: {', '.join(r.name for r in trial.validation_runs)}")
    if len(trial.runs) >= 2:
        return Split([prep(r) for r in trial.runs[:-1]], [prep(trial.runs[-1])],
                     description=f"held-out run: {trial.runs[-1].name} (last of {len(trial.runs)})")
    r = trial.runs[0]
    cut = round(r.n * (1 - trial.validation_fraction))
    cut = min(max(cut, 5), r.n - 3)
    return Split([prep(r, cut)], [prep(r)], segment_start=cut,
                 description=f"held-out segment: last {r.n - cut} of {r.n} samples (t >= {r.t[cut]:.4g} s), "
                             f"simulated on from the fitted start")


# -- start guesses ----------------------------------------------------------------------------------

def _smooth_derivs(p: _Prep, order: int) -> list[np.ndarray]:
    """Savitzky-Golay smoothed signal and derivatives (for start guesses only)."""
    y = p.y
    n = len(p.t)
    win = max(5, min(n // 8 * 2 + 1, 15))
    if win >= n:
        win = n - 1 if n % 2 == 0 else n - 2
    poly = min(3, win - 1)
    out = []
    for d in range(order + 1):
        if p.uniform and win >= 3 and poly >= d:
            out.append(savgol_filter(y, win, poly, deriv=d, delta=p.h, axis=0))
        else:
            z = y
            for _ in range(d):
                z = np.gradient(z, p.t, axis=0)
            out.append(z)
    return out


def initial_state(model: TSModel, p: _Prep) -> tuple[float, ...]:
    d = _smooth_derivs(p, 1)
    if model.family == "first":
        return (float(d[0][0]),)
    if model.family == "sway_yaw":
        return (float(d[0][0, 0]), float(d[0][0, 1]))
    return (float(d[0][0]), float(d[1][0]))


def equation_error(model: TSModel, preps: list[_Prep]) -> dict[str, float]:
    """Start guess by regression on smoothed derivatives (biased by noise: a start, never the answer)."""
    vals = dict(model.values)
    if model.family == "sway_yaw":
        rows_phi, rows_y = [], []
        M = np.array([[vals["m22"], vals["m26"]], [vals["m26"], vals["m66"]]])
        for p in preps:
            x, xd = _smooth_derivs(p, 1)
            tau = np.zeros_like(x) if p.u is None else p.u
            rows_y.append(xd @ M.T - tau)  # = [Y_v v + Y_r r, N_v v + N_r r]
            rows_phi.append(x)
        Y, Phi = np.vstack(rows_y), np.vstack(rows_phi)
        coef, *_ = np.linalg.lstsq(Phi, Y, rcond=None)
        est = {"Y_v": coef[0, 0], "Y_r": coef[1, 0], "N_v": coef[0, 1], "N_r": coef[1, 1]}
        return {k: float(est[k]) for k in model.free if k in est}

    Ys, Phis = [], []
    lin_free: list[str] = []
    for p in preps:
        if model.family == "first":
            x, xd = _smooth_derivs(p, 1)
            M = vals["M"] + vals["m_a"]
            probe = dict(vals)
            probe.update({"k": 1.0, **_thrust_term_neutrals()})
            g, _ = generalised_force(probe, model, p.t, p.u, p.uniform, p.before)
            fixed, _ = generalised_force(vals, model, p.t, p.u, p.uniform, p.before)
            cols = {"k": g, **_effect_columns("first", None, x, xd, p.u)}
            known = M * xd - (fixed if "k" not in model.free else 0.0)
            known = known + vals["d_L"] * x * ("d_L" not in model.free) + vals["d_Q"] * x * np.abs(x) * (
                "d_Q" not in model.free)
        else:
            x, xd, xdd = _smooth_derivs(p, 2)
            if p.rate is not None and p.accel is not None:  # measured rates: a better start
                x, xd, xdd = p.y, p.rate, p.accel
            if model.family == "pendulum":
                cols = {"alpha": np.sin(x), "beta": -xd, "gamma": -xd * np.abs(xd),
                        **_effect_columns("pendulum", x, xd, xdd, None)}
                known = xdd
            else:
                M = vals["M"] + vals["m_a"]
                r = np.sin(x) if model.restoring == "sin" else x
                cols = {"c": -r, **_effect_columns("second", x, xd, xdd, None)}
                known = M * xdd + vals["c"] * r * ("c" not in model.free)
        # the parameters the equation is linear in: the baseline's and the effects' regressors
        lin_free = [q for q in model.free if q in cols]
        Phis.append(np.column_stack([cols[q] for q in lin_free]) if lin_free else np.zeros((len(x), 0)))
        Ys.append(known)
    est: dict[str, float] = {}
    if lin_free:
        coef, *_ = np.linalg.lstsq(np.vstack(Phis), np.concatenate(Ys), rcond=None)
        est = dict(zip(lin_free, (float(c) for c in coef), strict=True))
    # Keep the start physical: a negative damping start can send the simulation to infinity.
    for q in ("d_L", "d_Q", "beta", "gamma"):
        if q in est and est[q] < 0:
            est[q] = abs(est[q]) * 0.1
    if "c" in est and est["c"] <= 0:
        est["c"] = abs(est["c"]) or 1.0
    if "alpha" in est and est["alpha"] >= 0:
        est["alpha"] = -abs(est["alpha"]) or -1.0
    if "k" in est and est["k"] <= 0:
        est["k"] = abs(est["k"]) or 1.0
    return est


def _effect_columns(family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                    u: np.ndarray | None) -> dict[str, np.ndarray]:
    """Equation-error columns of every effect parameter that enters the equation linearly."""
    cols: dict[str, np.ndarray] = {}
    for obj in effects.all_effects():
        cols.update(obj.regressors(family, pos, speed, acc, u))
    return cols


def _thrust_term_neutrals() -> dict[str, float]:
    """Neutral values of the parameters of added thrust terms (the probe of k's column has none)."""
    out: dict[str, float] = {}
    for obj in effects.all_effects():
        if type(obj).thrust_term is not effects.CatalogueEffect.thrust_term:
            out.update(obj.neutral_values())
    return out


def _scales(model: TSModel, vals: dict[str, float], preps: list[_Prep]) -> dict[str, float]:
    """Typical speed, force, command and time scales of the data, for the start grids."""
    ys = np.concatenate([np.abs(p.y).ravel() for p in preps])
    V = float(np.max(ys)) or 1.0
    us = [np.abs(p.u).ravel() for p in preps if p.u is not None]
    U = float(np.max(np.concatenate(us))) if us else 1.0
    M = vals.get("M", 1.0) + vals.get("m_a", 0.0)
    if model.family == "first":
        dlin = abs(vals.get("d_L", 0.0)) + 2 * abs(vals.get("d_Q", 0.0)) * V / 2
        F = dlin * V or M * V
        Tv = M / dlin if dlin > 0 else 1.0
    elif model.family == "second":
        F = abs(vals.get("c", 1.0)) * V
        Tv = 2 * math.pi * math.sqrt(M / abs(vals.get("c", 1.0) or 1.0))
    else:
        F, Tv = abs(vals.get("alpha", 1.0)), 1.0
    h = float(np.median(np.diff(preps[0].t)))
    dur = float(preps[0].t[-1] - preps[0].t[0])
    return {"V": V, "U": U, "F": F, "M": M, "Tv": Tv, "h": h, "dur": dur}


def effect_grid(effect: str, model: TSModel, vals: dict[str, float],
                preps: list[_Prep]) -> list[dict[str, float]]:
    """Start values to try for an effect's parameter(s), from the scales of the data."""
    obj = effects.get(effect)
    assert obj is not None, effect
    return obj.timeseries_start_grid(_scales(model, vals, preps), vals, model, preps)


# -- fitting ----------------------------------------------------------------------------------------

def _outputs(model: TSModel, vals: dict[str, float], p: _Prep, ic: tuple[float, ...]) -> np.ndarray:
    return simulate(model, vals, p.t, p.u, ic, uniform=p.uniform, before=p.before)


def _weights(model: TSModel, preps: list[_Prep]) -> np.ndarray | None:
    """Channel weights of a two-output model (each output scaled by its spread)."""
    if model.family != "sway_yaw":
        return None
    y = np.vstack([p.y for p in preps])
    sd = np.std(y, axis=0)
    return 1.0 / np.where(sd > 0, sd, 1.0)


# A Jacobian entry beyond this (output units per parameter unit) squares to overflow in the statistics:
# only data out of any physical range get there (e.g. a decay jumping from 0 to 1e14 in one sample).
_JAC_MAX = 1e100


def _overflow_message(trial: Trial) -> str:
    """The overflow error, naming the trial file and each output column with its unit, and the
    outputs' range and largest step in the file's unit: numbers the user can hold against the data
    (an angle logged in rad but declared deg swings by a fraction of a degree)."""
    from seafmu.identification.trial import _unit_si

    ys = [np.reshape(r.y, (r.n, -1)) for r in trial.runs if r.n]
    y = np.vstack(ys) if ys else np.zeros((0, 1))
    where, facts = [], []
    for j, role in enumerate(("output", "output2")[: y.shape[1]]):
        col, unit = trial.columns.get(role), trial.units.get(role)
        factor = _unit_si(unit)[1] if unit else 1.0
        unit = unit or "SI units"
        where.append(f"columns.{role} ({col}, unit {unit})" if col else role)
        v = y[:, j] / factor
        steps = [float(np.max(np.abs(np.diff(np.reshape(r.y, (r.n, -1))[:, j])))) / factor
                 for r in trial.runs if r.n > 1]
        if v.size:
            facts.append(f"{col or role} runs from {np.min(v):.3g} to {np.max(v):.3g} {unit} in steps of up "
                         f"to {max(steps, default=0.0):.3g} {unit}")
    return (f"{trial.source or trial.name}: {', '.join(where)}: the output-error fit overflowed"
            f"{' (' + '; '.join(facts) + ')' if facts else ''}: check the unit and the values")


def fit_timeseries(trial: Trial, model: TSModel, start: dict[str, float] | None = None,
                   start_ics: list[tuple[float, ...]] | None = None, sp: Split | None = None,
                   nfev_per_parameter: int = 60) -> FitResult:
    """Output-error fit of a time-series model; held-out error on the split's validation data
    (at most ``nfev_per_parameter`` evaluations per parameter, initial states included)."""
    # Over 80 lines: start values, bounds, the residual closure, the statistics and the held-out
    # predictions all share one parameter layout (free parameters, then initial conditions per run);
    # the FitResult is built field by field.
    sp = sp or split(trial)
    nic = len(IC_NAMES[model.family])
    guess = equation_error(model, sp.fit) if start is None else {}
    vals0 = dict(model.values)
    vals0.update(guess)
    if start:
        vals0.update({k: v for k, v in start.items() if k in vals0})
    ics = start_ics or [initial_state(model, p) for p in sp.fit]
    theta0 = [vals0[q] for q in model.free] + [x for ic in ics for x in ic]
    names = list(model.free) + [f"{n}[{i}]" for i in range(len(sp.fit)) for n in IC_NAMES[model.family]]
    bounds = effects.bounds("timeseries")  # the registered effects' (BOUNDS at import)
    lo = np.array([bounds.get(q, (-np.inf, np.inf))[0] for q in model.free] + [-np.inf] * (nic * len(sp.fit)))
    hi = np.array([bounds.get(q, (-np.inf, np.inf))[1] for q in model.free] + [np.inf] * (nic * len(sp.fit)))
    x0 = np.clip(np.array(theta0, dtype=float), lo, hi)
    # Start strictly inside the bounds (trf needs it); a parameter at its bound gets a small nudge.
    x0 = np.where(x0 <= lo, lo + np.maximum(1e-6, 1e-3 * np.abs(x0)), x0)
    x0 = np.where(x0 >= hi, hi - np.maximum(1e-6, 1e-3 * np.abs(x0)), x0)
    w = _weights(model, sp.fit)
    nfree = len(model.free)

    def residual(theta: np.ndarray) -> np.ndarray:
        vals = model.at(theta[:nfree])
        out = []
        for i, p in enumerate(sp.fit):
            ic = tuple(float(q) for q in theta[nfree + nic * i: nfree + nic * (i + 1)])
            r = _outputs(model, vals, p, ic) - p.y
            out.append((r * w).ravel() if w is not None else r)
        res = np.concatenate(out)
        return np.where(np.isfinite(res), res, 1e6)

    with np.errstate(all="ignore"):
        try:
            sol = least_squares(residual, x0, bounds=(lo, hi), method="trf", x_scale="jac",
                                ftol=1e-9, xtol=1e-9, gtol=1e-10, max_nfev=nfev_per_parameter * (len(x0) + 1))
        except ValueError as exc:  # scipy: "array must not contain infs or NaNs" (a Jacobian overflowed)
            if "inf" not in str(exc) and "NaN" not in str(exc):
                raise
            sol = None
    if sol is None or not np.all(np.abs(sol.jac) < _JAC_MAX):  # also catches NaN
        raise TrialError(_overflow_message(trial))
    theta = sol.x
    vals = model.at(theta[:nfree])
    resid = sol.fun
    fit_ics = [tuple(float(x) for x in theta[nfree + nic * i: nfree + nic * (i + 1)])
               for i in range(len(sp.fit))]

    cov = covariance_from_jacobian(sol.jac, resid)
    n = resid.size
    ci_all = confidence_intervals(names, theta, cov, n)
    corr = correlation_matrix(cov[:nfree, :nfree])
    params = {q: float(vals[q]) for q in model.free}
    ci = {q: ci_all[q] for q in model.free}

    # Measured and simulated output, unweighted, for NRMSE and plots.
    preds = []
    y_fit, yh_fit = [], []
    for p, ic in zip(sp.fit, fit_ics, strict=True):
        yh = _outputs(model, vals, p, ic)
        preds.append({"run": "fit", "t": p.t, "y": p.y, "yhat": yh, "u": p.u})
        y_fit.append(p.y)
        yh_fit.append(yh)
    nr_fit = nrmse(np.concatenate(y_fit), np.concatenate(yh_fit))

    y_val, yh_val = [], []
    if sp.segment_start is not None:
        p = sp.validation[0]
        yh = _outputs(model, vals, p, fit_ics[0])
        cut = sp.segment_start
        preds.append({"run": "validation", "t": p.t[cut:], "y": p.y[cut:], "yhat": yh[cut:],
                      "u": None if p.u is None else p.u[cut:]})
        y_val.append(p.y[cut:])
        yh_val.append(yh[cut:])
    else:
        for p in sp.validation:
            ic = _fit_initial_state(model, vals, p, w)
            yh = _outputs(model, vals, p, ic)
            preds.append({"run": "validation", "t": p.t, "y": p.y, "yhat": yh, "u": p.u})
            y_val.append(p.y)
            yh_val.append(yh)
    nr_val = nrmse(np.concatenate(y_val), np.concatenate(yh_val)) if y_val else float("nan")
    if not np.isfinite(nr_val):
        nr_val = float("inf")

    rss = float(np.sum(resid**2))
    aic, bic = aic_bic(rss, n, len(theta))
    warnings = sanity(model, vals, trial, sp) + correlation_warnings(list(model.free), corr) + \
        unidentifiable_warnings(ci, list(model.free))
    if nr_val > 1.0:
        warnings.append(f"held-out NRMSE {nr_val:.3g} > 1: the model predicts the held-out data worse than "
                        "their mean (over-fitted, or too little data)")
    white_r = np.concatenate(y_fit) - np.concatenate(yh_fit)
    if white_r.ndim == 2:
        white_r = white_r[:, 0]
    return FitResult(
        params=params, ci95=ci, correlation=corr, param_names=list(model.free),
        nonidentifiable=nonidentifiable_pairs(list(model.free), corr), nrmse_fit=nr_fit,
        nrmse_validation=nr_val,
        aic=aic, bic=bic, whiteness=whiteness_test(white_r), warnings=warnings,
        n_samples=int(sum(len(p.t) for p in sp.fit)),
        method="output error (RK4 simulation, scipy least_squares trf)",
        extras={"model": model, "values": vals, "initial_states": fit_ics, "predictions": preds,
                "effect": model.effect, "validation": sp.description, "nfev": int(sol.nfev), "rss": rss,
                "n_validation": int(sum(np.size(y) for y in y_val)),
                "derived": derived(model, vals, trial), "split": sp},
    )


def _fit_initial_state(model: TSModel, vals: dict[str, float], p: _Prep, w: np.ndarray | None) -> tuple[
        float, ...]:
    """Initial state of a held-out run with the model fixed (the model is judged, not its start)."""
    ic0 = np.array(initial_state(model, p))

    def res(ic: np.ndarray) -> np.ndarray:
        r = _outputs(model, vals, p, tuple(float(q) for q in ic)) - p.y
        r = (r * w).ravel() if w is not None else r
        return np.where(np.isfinite(r), r, 1e6)

    with np.errstate(all="ignore"):
        sol = least_squares(res, ic0, method="trf", x_scale="jac", max_nfev=20 * (len(ic0) + 1))
    return tuple(float(x) for x in sol.x)


def derived(model: TSModel, v: dict[str, float], trial: Trial) -> dict[str, float]:
    """Quantities an engineer reads off a fit: time constant, natural frequency, damping ratio, ..."""
    out: dict[str, float] = {}
    if model.family == "first":
        M = v["M"] + v["m_a"]
        if v["d_L"] > 0:
            out["time_constant_s (linear part)"] = M / v["d_L"]
        if "m_a" in model.free:
            out["total_inertia"] = M
    elif model.family == "second":
        M = v["M"] + v["m_a"]
        if v["c"] > 0 and M > 0:
            wn = math.sqrt(v["c"] / M)
            out["natural_frequency_rad_s"] = wn
            out["natural_period_s"] = 2 * math.pi / wn
            out["damping_ratio (linear part)"] = v["d_L"] / (2 * math.sqrt(v["c"] * M))
    elif model.family == "pendulum":
        a, b, g = v["alpha"], v["beta"], v["gamma"]
        if a < 0:
            out["small_angle_period_s"] = 2 * math.pi / math.sqrt(-a)
        c = trial.constants
        if {"weight", "buoyancy", "rod_length"} <= set(c) and a != 0:
            total = (c["buoyancy"] - c["weight"]) / (a * c["rod_length"])
            out["total_mass_kg (M + m_a)"] = total
            out["added_mass_kg"] = total - c["weight"] / 9.81
            out["K_L"] = b * total
            out["K_Q"] = g * total / c["rod_length"]
    return out


def sanity(model: TSModel, v: dict[str, float], trial: Trial, sp: Split | None = None) -> list[str]:
    """Warnings for unphysical fits: negative damping or added mass, unstable model."""
    w = []
    if model.family in ("first", "second"):
        if "d_L" in model.free and v["d_L"] < 0:
            w.append(f"negative linear damping d_L = {v['d_L']:.4g}: unphysical at low speed")
        if "d_Q" in model.free and v["d_Q"] < 0:
            w.append(f"negative quadratic damping d_Q = {v['d_Q']:.4g}: unphysical")
        if "m_a" in model.free and v["m_a"] < 0:
            w.append(f"negative added mass m_a = {v['m_a']:.4g}: the fitted inertia is below the "
                     "rigid-body value")
        if v["M"] + v["m_a"] <= 0:
            w.append("non-positive total inertia: unstable model")
    if model.family == "first":
        vmax = max((float(np.max(np.abs(p.y))) for p in sp.fit), default=1.0) if sp else 1.0
        lin = [v["d_L"] + 2 * v["d_Q"] * s for s in (0.0, vmax)]
        if min(lin) < 0 and (v["M"] + v["m_a"]) > 0:
            w.append("unstable model: the fitted damping is negative over part of the speed range "
                     f"(d_L + 2 d_Q |v| = {min(lin):.4g})")
        if "k" in model.free and v["k"] <= 0:
            w.append(f"non-positive thrust coefficient k = {v['k']:.4g}")
    if model.family == "second":
        if v["c"] <= 0:
            w.append(f"no restoring (c = {v['c']:.4g} <= 0): unstable model")
        elif v["d_L"] < 0:
            w.append("unstable model: negative damping makes the oscillation grow")
    if model.family == "pendulum":
        if v["alpha"] >= 0:
            w.append(f"alpha = {v['alpha']:.4g} >= 0: no restoring, the pendulum would not swing back "
                     "(unstable)")
        if v["beta"] < 0:
            w.append(f"negative linear damping beta = {v['beta']:.4g}: unphysical")
        if v["gamma"] < 0:
            w.append(f"negative quadratic damping gamma = {v['gamma']:.4g}: unphysical")
    if model.family == "sway_yaw":
        if v["Y_v"] > 0 or v["N_r"] > 0:
            w.append(f"negative damping: Y_v = {v['Y_v']:.4g}, N_r = {v['N_r']:.4g} (both should be < 0)")
        M = np.array([[v["m22"], v["m26"]], [v["m26"], v["m66"]]])
        D = -np.array([[v["Y_v"], v["Y_r"]], [v["N_v"], v["N_r"]]])
        ev = np.linalg.eigvals(-np.linalg.solve(M, D))
        if np.max(ev.real) > 0:
            w.append(f"unstable model: eigenvalue {np.max(ev.real):.4g} 1/s > 0 (open-loop unstable in yaw)")
    return w


def fit_effect(trial: Trial, base: FitResult, effect: str, sp: Split | None = None) -> FitResult:
    """Refit the baseline extended by one catalogue effect, from the baseline's parameters."""
    return fit_effects(trial, base, (effect,), sp)


def combined_model(trial: Trial, base: FitResult, names: tuple[str, ...]) -> tuple[TSModel, dict[str, float],
                                                                                    dict[str, float], bool]:
    """The baseline extended by ``names``: model, start values (the baseline's, caps set inactive),
    the effects' absent values, and whether all may start where they are absent."""
    model = base.extras["model"]
    for name in names:
        model = extend(model, name, trial)
    if len(names) > 1:
        model = model.copy(effect="+".join(names))
    vals = dict(base.extras["values"])
    null: dict[str, float] = {}
    at_absent = True
    for name in names:
        obj = effects.get(name)
        assert obj is not None, name
        null.update(obj.absent_values(trial))
        if not obj.start_at_absent:  # e.g. the cap of saturation: no gradient where it is inactive
            vals.update(obj.absent_values(trial))
            at_absent = False
    return model, vals, null, at_absent


Start = tuple[dict[str, float], list[tuple[float, ...]]]  # parameter values and initial states


def screen(trial: Trial, base: FitResult, names: tuple[str, ...], seeds: list[Start],
           sp: Split | None = None) -> tuple[Start | None, float]:
    """The best start of a combined model and its cost (RSS on the fitting runs), from ``seeds``
    (values with their fit's initial states) and each effect's start grid (two points each, over the
    seeds): simulations only, no fit. Used to rank combinations before fitting any."""
    model, vals, null, at_absent = combined_model(trial, base, names)
    sp = sp or base.extras["split"]
    ics = list(base.extras["initial_states"])
    seeded = [({k: v for k, v in s.items() if k in model.free}, list(i)) for s, i in seeds] or [({}, ics)]
    starts = list(seeded)
    for name in names:
        for g in effect_grid(name, model, vals, sp.fit)[:2]:
            starts += [({**s, **g}, i) for s, i in seeded]
    if at_absent:
        starts.append((null, ics))
    return _best_start(model, vals, starts, sp)


def _best_start(model: TSModel, vals: dict[str, float], starts: list[Start], sp: Split) -> tuple[
        Start | None, float]:
    best, best_cost = None, math.inf
    for start in starts:
        g, ics = start
        trial_vals = {**vals, **g}
        cost = 0.0
        with np.errstate(all="ignore"):
            for p, ic in zip(sp.fit, ics, strict=True):
                r = _outputs(model, trial_vals, p, ic) - p.y
                cost += float(np.sum(r**2))
        if np.isfinite(cost) and cost < best_cost:
            best, best_cost = start, cost
    return best, best_cost


def fit_effects(trial: Trial, base: FitResult, names: tuple[str, ...], sp: Split | None = None,
                seeds: list[Start] | None = None) -> FitResult:
    """Refit the baseline extended by one or several catalogue effects.

    One effect starts from the best of its start grid and its "absent" values (by the cost of the
    simulation); several from the best of ``seeds`` (e.g. the single-effect fits' values, reused)
    and the effects' start grids (``screen``). An extension contains the baseline, so a fit worse
    than it is a local minimum and is restarted from the baseline itself.
    """
    model, vals, null, at_absent = combined_model(trial, base, names)
    sp = sp or base.extras["split"]
    ics = list(base.extras["initial_states"])
    if len(names) == 1:
        grid = effect_grid(names[0], model, vals, sp.fit)
        chosen, _ = _best_start(model, vals, [(g, ics) for g in ([*grid, null] if at_absent else grid)], sp)
    else:
        chosen, _ = screen(trial, base, names, seeds or [], sp)
    best, start_ics = chosen if chosen is not None else (None, ics)
    fit = fit_timeseries(trial, model, start={**vals, **(best or null)}, start_ics=list(start_ics), sp=sp)
    if fit.extras["rss"] > base.extras["rss"] * (1 + 1e-6) and best is not null and at_absent:
        # The extension contains the baseline, so it must fit at least as well: a local minimum.
        # Restart from the baseline itself (effect absent) and keep the better of the two.
        again = fit_timeseries(trial, model, start={**vals, **null}, start_ics=list(ics), sp=sp)
        if again.extras["rss"] < fit.extras["rss"]:
            fit = again
    for name in names:
        obj = effects.get(name)
        # A regularised law (friction's tanh) is sharpened only where it is significant and the
        # smooth fit already predicts the held-out data better than the baseline (the
        # continuation costs several refits).
        if obj is not None and obj.regularised is not None and fit.ci95[obj.regularised[0]][0] > 0 \
                and fit.nrmse_validation < base.nrmse_validation:
            fit = _sharpen(trial, fit, sp, obj.regularised[1])
    fit.extras["effects"] = tuple(names)
    return fit


def _sharpen(trial: Trial, fit: FitResult, sp: Split, width: str) -> FitResult:
    """Continuation towards the sharp law of a regularised effect (Coulomb friction's
    f_c tanh(v/eps)): refit with the width 3 and 10 times smaller.

    The smooth law lets a body creep where a real one sticks, and the fit pays for the creep with
    a larger f_c and a distorted damping split; starting each sharper fit from the previous one
    keeps the optimiser in the right valley (a sharp law from a cold start does not converge).
    """
    for k in (3.0, 10.0):
        m = fit.extras["model"]
        sharper = m.copy(values={**m.values, width: m.values[width] / k})
        # a refinement from the previous optimum: a third of a cold fit's evaluation budget, less on
        # long records (10 000 samples: 6 per parameter), which pin the optimum down sooner
        n = sum(len(p.t) for p in sp.fit)
        budget = max(6, round(20 * min(1.0, 3000.0 / max(n, 1))))
        nxt = fit_timeseries(trial, sharper, start=fit.extras["values"],
                             start_ics=fit.extras["initial_states"], sp=sp, nfev_per_parameter=budget)
        if not nxt.extras["rss"] <= fit.extras["rss"]:
            break
        fit = nxt
    return fit
