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
5. roll and pitch: the release from an angle (the DOFs its inertia couples to left free, so no
   hold takes energy out of the swing) fitted first as the plan's 1-DOF free oscillation
   m_eff phi'' + d phi' (+ d_Q phi'|phi'|) + c phi = 0 (restoring included, as the brief asks):
   omega_n, zeta; then, for the coefficient written, as row k of the 6-DOF model with the other
   DOFs' measured motion and the thrusters' measured moment as inputs (``coupled_release_fit``):
   the coupled motion no longer reads as damping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, savgol_filter, sosfiltfilt

from seafmu.components.dynamics import coriolis_force, restoring_coefficients, restoring_force
from seafmu.components.vessel_spec import VesselSpec
from seafmu.identification.fitting import (
    FitResult,
    aic_bic,
    correlation_warnings,
    fit_statistics,
    nrmse,
    whiteness_test,
)
from seafmu.identification.timeseries import TSModel, baseline_model, fit_timeseries, simulate
from seafmu.identification.trial import Run, Trial, make_trial
from seafmu.testplan.design import AXES, TrialPlan
from seafmu.testplan.intervals import NOISE_DRAWS, NOISE_SEED, fit_robust_ci, robust_ci
from seafmu.testplan.measure import Measurement, noise_draws

COUPLED_DRAWS = 300  # sensor-noise realisations behind a coupled term's interval
COUPLED_SEED = 0
RELEASE_INPUT_DRAWS = 32  # a release's held-velocity noise realisations (each one simulation, ~0.1 s)
INPUT_CUTOFF = 3.0  # low-pass of a release's measured inputs, in natural frequencies
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
    coupled_ci: dict[str, tuple[float, float]] = field(default_factory=dict)  # held tau name -> 95 % CI

    @property
    def damping(self) -> dict[str, float]:
        """d_L, d_Q (and c) of the written fit."""
        f = self.fits["record"]
        return {k: float(v) for k, v in f.params.items() if k in ("d_L", "d_Q", "c")}


def _segment(m: Measurement, t0: float, t1: float, name: str, force: np.ndarray | None) -> Run:
    sel = (m.t >= t0) & (m.t < t1)
    t = m.t[sel] - m.t[sel][0]
    return Run(name=name, y=m.y[sel].copy(), t=t, u=force[sel].copy() if force is not None else None)


def coupling_force(vessel: VesselSpec, j: int, t: np.ndarray, nu: np.ndarray, eta: np.ndarray | None
                   ) -> np.ndarray:
    """Row j of the file's model less its own damping and inertia, from the measured motion
    nu (..., n, dof), as each sample interval's mean (..., n): restoring g_j(eta), Coriolis
    C(nu)nu_j, the off-diagonal damping D_ji nu_i and the coupled inertia M_ji nu_i' (its
    interval mean is the velocity difference over the interval: integrated by the model it is
    (M_ji / M_jj) nu_i on the output, so the held velocities' noise enters scaled by that small
    ratio, not differentiated)."""
    DL, DQ = vessel.D_L[j].copy(), vessel.D_Q[j].copy()
    DL[j] = DQ[j] = 0.0
    c = nu @ DL + (np.abs(nu) * nu) @ DQ
    if vessel.coriolis != "none":
        c = c + coriolis_force(vessel.M_RB + vessel.M_A, nu)[..., j]
    if vessel.dof == 6 and vessel.restoring is not None and eta is not None:
        rs = vessel.restoring
        c = c + restoring_force(restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b),
                                eta[:, 3], eta[:, 4])[:, j]
    c[..., :-1] = 0.5 * (c[..., :-1] + c[..., 1:])  # the interval's mean, as the thrusters' force
    Mo = np.asarray(vessel.M[j], dtype=float).copy()
    Mo[j] = 0.0
    c[..., :-1] += (np.diff(nu, axis=-2) @ Mo) / np.diff(t)
    return c


def _motion(m: Measurement) -> tuple[np.ndarray, np.ndarray | None]:
    nu = np.where(np.isfinite(m.nu), m.nu, 0.0)
    nu[:, m.plan.index] = m.y
    eta = np.where(np.isfinite(m.eta), m.eta, 0.0) if m.eta is not None else None
    return nu, eta


def axis_force(m: Measurement, vessel: VesselSpec | None) -> np.ndarray:
    """The force the 1-DOF model of axis j is driven by: the thrusters' (``force_held``, each sample
    interval's mean) less what row j of the file's model puts on the axis from the other DOFs'
    measured motion (``coupling_force``). Small forces, but correlated with the trial's
    acceleration, so the fit reads them as inertia and damping: Minerva 2's net buoyancy (-30 N)
    tilted by the roll its sway acceleration induces moved Y_|v|v by +0.55 % with true velocities;
    the supply's M_62 v' and N_v v moved N_r by +0.2 %."""
    j = m.plan.index
    f = m.force_held()[:, j].copy()
    if vessel is None:
        return f
    nu, eta = _motion(m)
    return f - coupling_force(vessel, j, m.t, nu, eta)


def noise_in_fit(m: Measurement, vessel: VesselSpec | None) -> tuple[np.ndarray, np.ndarray] | None:
    """``NOISE_DRAWS`` realisations of the file's sensor noise as the fit meets it: on the output
    (B, n) and on the force through ``coupling_force`` (B, n), from the same draws of every
    velocity channel (the output is one of them). The angles' noise in the restoring term (AHRS,
    0.2 deg on 30 N of net buoyancy) is left out. None where no noise model is known."""
    j = m.plan.index
    if m.plan.nu not in m.noise_model:
        return None
    names = vessel.nu_names if vessel is not None else [m.plan.nu]
    nd = noise_draws(m.noise_model, names, m.t, NOISE_DRAWS, np.random.default_rng(NOISE_SEED))
    jj = names.index(m.plan.nu)
    if vessel is None:
        return nd[:, :, jj], np.zeros_like(nd[:, :, jj])
    nu, eta = _motion(m)
    df = -(coupling_force(vessel, j, m.t, nu + nd, eta) - coupling_force(vessel, j, m.t, nu, eta))
    return nd[:, :, jj], df


def _baseline(tp: TrialPlan) -> str:
    """The terms the vessel file's model has on this axis (its structure; the values are fitted)."""
    lin, quad = tp.prior.get("d_L", 0.0) != 0.0, tp.prior.get("d_Q", 0.0) != 0.0
    if quad:
        return "linear_quadratic" if lin else "quadratic"
    return "linear"


def _free_damping(tp: TrialPlan) -> list[str]:
    return {"linear": ["d_L"], "quadratic": ["d_Q"], "linear_quadratic": ["d_L", "d_Q"]}[_baseline(tp)]


def identify_axis(m: Measurement, vessel: VesselSpec | None = None) -> AxisResult:
    """Fit one trial (method one, or a roll/pitch release; the coupled fit of a release needs
    the vessel's model of the other DOFs)."""
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
        res.fits["decay"] = fit_timeseries(tr, model)
        v = res.fits["decay"].extras["values"]
        m_eff = v["M"] + v["m_a"]
        if v["c"] > 0 and m_eff > 0:
            res.method_one["natural_frequency"] = math.sqrt(v["c"] / m_eff)
            res.method_one["zeta"] = v["d_L"] / (2.0 * math.sqrt(v["c"] * m_eff))
            res.method_one["m_eff"] = m_eff
        if vessel is not None and m.eta is not None:
            start = {p: float(res.fits["decay"].params.get(p, tp.prior.get(p, 0.0)))
                     for p in _free_damping(tp)}
            res.fits["record"] = coupled_release_fit(m, vessel, start)
        else:
            res.fits["record"] = res.fits["decay"]
        return res

    lead = 2.0  # s of rest before a segment: the fit sees the force start
    force = axis_force(m, vessel)
    decay = _segment(m, tp.t_release, tp.t_step, "release", None)
    step = _segment(m, tp.t_step - lead, m.t[-1] + 1.0, "step", force)
    record = _segment(m, tp.t_accelerate - lead, tp.t_step, "accelerate_hold_release", force)
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
    noise = noise_in_fit(m, vessel)
    spec = m.noise_model.get(tp.nu, {})
    if "derived" in spec and len(spec["derived"]["t"]) == len(m.t):
        res.fits["record"] = derived_velocity_fit(res.fits["record"], m, force, lead, noise)
    else:
        sel = (m.t >= tp.t_accelerate - lead) & (m.t < tp.t_step)
        _honest_intervals(res.fits["record"], m, sel, noise)

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


def _honest_intervals(fit: FitResult, m: Measurement, sel: np.ndarray,
                      noise: tuple[np.ndarray, np.ndarray] | None) -> None:
    """Replace the fit's white-noise intervals by ``intervals.robust_ci``'s (the sensor noise as the
    fit meets it, and the residuals' autocorrelation); the three standard errors go to
    ``fit.extras["intervals"]`` for the report."""
    draws = None
    if noise is not None:
        model, vals = fit.extras["model"], fit.extras["values"]
        p, ic = fit.extras["split"].fit[0], fit.extras["initial_states"][0]
        base = simulate(model, vals, p.t, p.u, ic, uniform=p.uniform)
        dy, df = noise[0][:, sel], noise[1][:, sel]
        # the output's noise less the model's response to the force's
        draws = np.array([dy[b] - (simulate(model, vals, p.t, p.u + df[b], ic, uniform=p.uniform) - base)
                          for b in range(len(dy))])
    ci = fit_robust_ci(fit, draws, 1)
    for q, row in ci.items():
        fit.ci95[q] = (row["lo"], row["hi"])
    fit.extras["intervals"] = ci


def derived_velocity_fit(fit: FitResult, m: Measurement, force: np.ndarray, lead: float,
                         noise: tuple[np.ndarray, np.ndarray] | None) -> FitResult:
    """Refit a velocity differentiated from position fixes with the model seen through the same
    differentiator: the model's velocity (the whole trial from rest, the measured force), integrated
    to a position and Savitzky-Golay differentiated with the measurement's window, is compared with
    the measured velocity on the accelerate-hold-release record.

    A quadratic Savitzky-Golay slope over 53 s cannot follow the velocity's corners where the force
    starts and stops (up to 0.2 m/s off for 25 s on either side of the supply's release); the
    1-DOF fit read that smoothing as dynamics: X_u +0.10 % (the smoothing of the true motion, the
    same on any seed), against its +-0.003 % of sensor noise. Through the same filter the model's
    smoothing error is the measurement's, so the fit is unbiased; its residuals carry the filter's
    correlation, so the interval is ``intervals.robust_ci`` (noise draws processed as the
    measurement, Newey-West). The step from rest, after the record, is predicted (held out)."""
    tp = m.plan
    d = m.noise_model[tp.nu]["derived"]
    w, dt = int(d["w"]), float(d["dt"])
    model = fit.extras["model"]
    free = list(model.free)
    nfree = len(free)
    i0 = int(np.searchsorted(m.t, tp.t_accelerate - lead))
    i1 = int(np.searchsorted(m.t, tp.t_step))
    t = m.t - m.t[0]

    def velocity(theta: np.ndarray, f: np.ndarray = force) -> np.ndarray:
        return np.asarray(simulate(model, model.at(theta[:nfree]), t, f, (float(theta[nfree]),)))

    def seen(theta: np.ndarray, f: np.ndarray = force) -> np.ndarray:
        v = velocity(theta, f)
        pos = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        return np.asarray(savgol_filter(pos, w, 2, deriv=1, delta=dt))

    theta0 = np.array([float(fit.extras["values"][q]) for q in free] + [0.0])
    mass = float(fit.extras["values"]["M"])
    vspan = max(float(np.max(np.abs(m.y))), 1e-9)
    scale = np.array([max(abs(x), 1e-3 * mass) for x in theta0[:nfree]] + [1e-3 * vspan])
    y = m.y[i0:i1]
    sol = least_squares(lambda z: seen(theta0 + scale * z)[i0:i1] - y, np.zeros(len(theta0)),
                        x_scale="jac", xtol=1e-10, ftol=1e-12)
    theta = theta0 + scale * sol.x
    yhat = seen(theta)
    draws = None
    if noise is not None:  # the output's noise less the model's response to the force's
        draws = np.array([noise[0][b, i0:i1] - (seen(theta, force + noise[1][b]) - yhat)[i0:i1]
                          for b in range(len(noise[0]))])
    names = [*free, "x0"]
    # Newey-West's bandwidth at least two windows: a differentiated noise is correlated over one
    # window and anticorrelated over the next; cut at one it overstated X_u's error 2.6 times
    ci = robust_ci(names, theta, nfree, sol.jac / scale, [y - yhat[i0:i1]], draws, 2 * w)
    vals = model.at(theta[:nfree])
    j0 = int(np.searchsorted(m.t, tp.t_step - lead))
    extras = {**fit.extras, "values": vals, "initial_states": [(float(theta[nfree]),)], "intervals": ci,
              "velocity": velocity(theta),
              "predictions": [
                  {"run": "fit", "t": m.t[i0:i1] - m.t[i0], "y": y, "yhat": yhat[i0:i1], "u": None},
                  {"run": "validation", "t": m.t[j0:] - m.t[j0], "y": m.y[j0:], "yhat": yhat[j0:],
                   "u": None}],
              "nfev": int(sol.nfev)}
    return replace(fit, params={q: float(vals[q]) for q in free},
                   ci95={q: (row["lo"], row["hi"]) for q, row in ci.items()},
                   nrmse_fit=nrmse(y, yhat[i0:i1]), nrmse_validation=nrmse(m.y[j0:], yhat[j0:]),
                   whiteness=whiteness_test(y - yhat[i0:i1]),
                   method=f"output error through the measurement's differentiator (Savitzky-Golay, {w} "
                          "samples, on the model's integrated velocity)", extras=extras)


def _axpy(a: list[float], c: float, b: list[float]) -> list[float]:
    return [x + c * y for x, y in zip(a, b, strict=True)]


class _ReleaseModel:
    """Row block b (the released DOF and the DOFs left free with it) of the 6-DOF model.

    The held DOFs' measured velocities, the other angles and the thrusters' measured forces are
    inputs, low-passed (zero phase, ``INPUT_CUTOFF`` natural frequencies: their sensor noise would
    otherwise enter the free DOFs' motion); the free DOFs' velocities and the released angle are
    states, so no noisy measurement of a free DOF enters the model. Momentum form:
    h_b = M_bb z + M_bh nu_h, h_b' = tau_b - D(nu)_b - C(nu)_b - g(eta)_b, z = M_bb^-1 (h_b - M_bh nu_h).
    """

    def __init__(self, m: Measurement, vessel: VesselSpec) -> None:
        tp = m.plan
        d = vessel.dof
        self.k = tp.index
        self.b = [self.k] + [vessel.eta_names.index(f) for f in tp.free]
        self.h = [i for i in range(d) if i not in self.b]
        M = 0.5 * (vessel.M + vessel.M.T)
        self.M = M.tolist()
        self.Mbb = M[np.ix_(self.b, self.b)]
        self.DL, self.DQ = vessel.D_L.tolist(), vessel.D_Q.tolist()
        self.coriolis = vessel.coriolis != "none"
        rs = vessel.restoring
        self.g = restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b)
        nu = np.where(np.isfinite(m.nu), m.nu, 0.0)
        eta = np.where(np.isfinite(m.eta), m.eta, 0.0) if m.eta is not None else np.zeros_like(nu)
        tau = m.tau
        fs = 1.0 / float(np.median(np.diff(m.t)))
        fc = INPUT_CUTOFF * math.sqrt(tp.prior["c"] / tp.mass) / (2.0 * math.pi)
        if fc < 0.45 * fs and len(m.t) > 30:
            sos = butter(2, fc, fs=fs, output="sos")
            nu, eta, tau = (sosfiltfilt(sos, a, axis=0) for a in (nu, eta, tau))
        self.t = m.t - m.t[0]
        self.nu_h = nu.tolist()  # the block's columns are overwritten by the states
        self.eta = eta[:, 3:5].tolist()
        self.mom = (nu[:, self.h] @ M[np.ix_(self.b, self.h)].T).tolist()
        self.tau = tau[:, self.b].tolist()

    def simulate(self, mass_k: float, dL: float, dQ: float, x0: float, z0: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """RK4 on the sample times, inputs linear between samples: (angle, rate of DOF k)."""
        b, k, nb = self.b, self.k, len(self.b)
        Mbb = self.Mbb.copy()
        Mbb[0, 0] = mass_k
        Minv = np.linalg.inv(Mbb).tolist()
        M, DL, DQ = self.M, [r[:] for r in self.DL], [r[:] for r in self.DQ]
        DL[k][k], DQ[k][k] = dL, dQ
        _, gx, gy, gz = self.g
        wb = self.g[0]
        roll = k == 3
        nuh, eta, mom, tau, t = self.nu_h, self.eta, self.mom, self.tau, self.t
        cos, sin, tan = math.cos, math.sin, math.tan

        def f(x: float, hb: list[float], i: int, j: int) -> tuple[float, list[float]]:
            nu = [0.5 * (nuh[i][c] + nuh[j][c]) for c in range(6)]
            mo = [0.5 * (mom[i][r] + mom[j][r]) for r in range(nb)]
            z = [sum(Minv[r][c] * (hb[c] - mo[c]) for c in range(nb)) for r in range(nb)]
            for r in range(nb):
                nu[b[r]] = z[r]
            phi_m, th_m = 0.5 * (eta[i][0] + eta[j][0]), 0.5 * (eta[i][1] + eta[j][1])
            phi, th = (x, th_m) if roll else (phi_m, x)
            sp, cp, st, ct = sin(phi), cos(phi), sin(th), cos(th)
            g = [wb * st, -wb * ct * sp, -wb * ct * cp, -gy * ct * cp + gz * ct * sp,
                 gz * st + gx * ct * cp, -gx * ct * sp - gy * st]
            u, v, w, p, q, r = nu
            if self.coriolis:
                a1, a2, a3, b1, b2, b3 = (sum(M[i2][c] * nu[c] for c in range(6)) for i2 in range(6))
                cor = [q * a3 - r * a2, r * a1 - p * a3, p * a2 - q * a1,
                       v * a3 - w * a2 + q * b3 - r * b2, w * a1 - u * a3 + r * b1 - p * b3,
                       u * a2 - v * a1 + p * b2 - q * b1]
            else:
                cor = [0.0] * 6
            aq = [abs(c) * c for c in nu]
            dh = [0.5 * (tau[i][rr] + tau[j][rr]) - cor[row] - g[row]
                  - sum(DL[row][c] * nu[c] + DQ[row][c] * aq[c] for c in range(6))
                  for rr, row in enumerate(b)]
            dx = p + tan(th) * (sp * q + cp * r) if roll else cp * q - sp * r
            return dx, dh

        n = len(t)
        xs, ws = np.empty(n), np.empty(n)
        x = x0
        hb = [float(v) for v in (Mbb @ z0 + np.asarray(mom[0]))]
        xs[0], ws[0] = x0, float(z0[0])
        for i in range(n - 1):
            dt = t[i + 1] - t[i]
            k1x, k1h = f(x, hb, i, i)
            k2x, k2h = f(x + 0.5 * dt * k1x, _axpy(hb, 0.5 * dt, k1h), i, i + 1)
            k3x, k3h = f(x + 0.5 * dt * k2x, _axpy(hb, 0.5 * dt, k2h), i, i + 1)
            k4x, k4h = f(x + dt * k3x, _axpy(hb, dt, k3h), i + 1, i + 1)
            x += dt / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
            hb = [a + dt / 6.0 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
                  for a, c1, c2, c3, c4 in zip(hb, k1h, k2h, k3h, k4h, strict=True)]
            xs[i + 1] = x
            ws[i + 1] = sum(Minv[0][c] * (hb[c] - mom[i + 1][c]) for c in range(nb))
        return xs, ws


def coupled_release_fit(m: Measurement, vessel: VesselSpec, start: dict[str, float]) -> FitResult:
    """Output-error fit of a roll/pitch release as the free DOFs' rows of the 6-DOF model.

    ``_ReleaseModel``: the released DOF and the DOFs left free with it are simulated, the held
    ones' measured motion and the thrusters' measured forces are inputs; the released angle and its
    rate are the outputs (each weighted by its sensor noise). Free parameters: the damping terms
    the file's model has on the axis, an inertia correction m_a (the scale comes from the file's
    restoring, as in the 1-DOF fit), the initial angle and the free DOFs' initial velocities. The
    file's coupling inertias, the other DOFs' damping and Coriolis are used as they are: what the
    trial measures is the axis' own damping.
    """
    tp = m.plan
    k = tp.index
    sim = _ReleaseModel(m, vessel)
    nb = len(sim.b)
    mass = float(sim.Mbb[0, 0])
    fixed = {"d_L": float(vessel.D_L[k, k]), "d_Q": float(vessel.D_Q[k, k])}
    znames = [f"{vessel.nu_names[i]}0" for i in sim.b]
    names = [*start, "m_a", "x0", *znames]
    rate = m.nu[:, k]
    sig_rate = m.noise_nu.get(tp.nu, 0.0)
    use_rate = bool(np.isfinite(rate).all()) and sig_rate > 0.0
    z_start = [float(m.nu[0, i]) if np.isfinite(m.nu[0, i]) else 0.0 for i in sim.b]
    p0 = np.array([*start.values(), 0.0, float(m.y[0]), *z_start])
    scale = np.array([max(abs(v), 1e-3 * mass) for v in start.values()] + [0.1 * mass, 0.01] + [0.01] * nb)

    def model(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = dict(zip(names, p, strict=True))
        return sim.simulate(mass + v["m_a"], v.get("d_L", fixed["d_L"]), v.get("d_Q", fixed["d_Q"]),
                            v["x0"], p[len(start) + 2:])

    def resid(zz: np.ndarray) -> np.ndarray:
        x, w = model(p0 + scale * zz)
        r = (x - m.y) / max(m.noise, 1e-12)
        if use_rate:
            r = np.concatenate([r, (w - rate) / sig_rate])
        return np.where(np.isfinite(r), r, 1e6)

    sol = least_squares(resid, np.zeros(len(p0)), xtol=1e-8, ftol=1e-10)
    p = p0 + scale * sol.x
    r = sol.fun
    _, corr, nonid = fit_statistics(names, p, sol.jac / scale, r)
    # residuals in units of the stated sensor noise: unit white draws are that noise; per output
    # channel (angle, rate) a run of its own for Newey-West
    n = len(m.y)
    runs = [-r[:n], -r[n:]] if use_rate else [-r]
    unit = np.random.default_rng(NOISE_SEED).standard_normal((NOISE_DRAWS, r.size))
    x, w = model(p)
    inputs = _release_input_noise(m, vessel, p, names, len(start), x, w, use_rate)
    rows = robust_ci(names, p, len(start) + 1, sol.jac / scale, runs, unit, 1, inputs)
    ci = {q: (row["lo"], row["hi"]) for q, row in rows.items()}
    keep = [*start, "m_a"]
    aic, bic = aic_bic(float(np.sum(r**2)), r.size, len(p))
    return FitResult(
        params={n: float(v) for n, v in zip(names, p, strict=True) if n in keep},
        ci95={n: ci[n] for n in keep}, correlation=corr, param_names=names, nonidentifiable=nonid,
        nrmse_fit=nrmse(m.y, x), nrmse_validation=float("nan"), aic=aic, bic=bic,
        whiteness=whiteness_test(x - m.y), warnings=correlation_warnings(names, corr),
        n_samples=len(m.t), method="coupled output error (the free DOFs' rows of the 6-DOF model)",
        extras={"predictions": [{"run": "fit", "t": sim.t, "yhat": x, "rate": w}],
                "values": {**fixed, **dict(zip(names, (float(v) for v in p), strict=True)), "M": mass},
                "uses_rate": use_rate, "free_dofs": [vessel.nu_names[i] for i in sim.b], "intervals": rows,
                "nfev": sol.nfev})


def _release_input_noise(m: Measurement, vessel: VesselSpec, p: np.ndarray, names: list[str], nfree: int,
                         x: np.ndarray, w: np.ndarray, use_rate: bool) -> np.ndarray | None:
    """The fitted model's response (in the residuals' noise units) to ``RELEASE_INPUT_DRAWS``
    realisations of the held DOFs' velocity noise, which enters as an input (low-passed). It is
    most of a release's error: Minerva 2's pitch, seed 2, M_|q|q +1.8 % with the measured held
    velocities (DVL heave, 0.01 m/s, through M_35 and Coriolis), -0.02 % with the true ones,
    against +-0.9 % from the angle and rate noise alone."""
    if not m.noise_model:
        return None
    rng = np.random.default_rng(NOISE_SEED + 1)
    nd = noise_draws(m.noise_model, vessel.nu_names, m.t, RELEASE_INPUT_DRAWS, rng)
    v = dict(zip(names, p, strict=True))
    tp = m.plan
    k = tp.index
    mass = float((0.5 * (vessel.M + vessel.M.T))[k, k])
    out = []
    for b in range(RELEASE_INPUT_DRAWS):
        sim = _ReleaseModel(replace(m, nu=m.nu + nd[b]), vessel)
        xb, wb = sim.simulate(mass + v["m_a"], v.get("d_L", float(vessel.D_L[k, k])),
                              v.get("d_Q", float(vessel.D_Q[k, k])), v["x0"], p[nfree + 2:])
        d = (xb - x) / max(m.noise, 1e-12)
        if use_rate:
            d = np.concatenate([d, (wb - w) / m.noise_nu[tp.nu]])
        out.append(d)
    return np.array(out)


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
                  vessel: VesselSpec) -> None:
    """D_kj (k held, j the trial axis) from the impulse on the held axis over a rest-to-rest window.

    Integrating row k of M nu' + C(nu) nu + D_L nu + D_Q |nu| nu + g(eta) = tau from rest (before
    the force: nu = 0 by design) to rest (the end of the release, nu measured):
    int tau_k dt = M_k. dnu + int (C_k + sum_i D_L,ki nu_i + D_Q,ki |nu_i| nu_i + g_k) dt. The trial
    axis travels far (int nu_j dt is its displacement, from the position fixes or the heading), the
    held axes hardly move, so D_kj = (int tau_k dt - everything else) / int nu_j dt: no derivative
    of noisy data, the measured forces averaged over the whole record. The held axis' own damping
    is the identified one, the other terms the file's. The 95 % interval: ``_coupled_ci``.
    """
    own = {}
    for r in results.values():
        if r.plan.kind == "method_one":
            i = r.plan.index
            own[i] = {p: r.damping.get(p, float((vessel.D_L if p == "d_L" else vessel.D_Q)[i, i]))
                      for p in ("d_L", "d_Q")}
    for name, r in results.items():
        if r.plan.kind != "method_one":
            continue
        m = measurements[name]
        tp = r.plan
        j = tp.index
        sel = m.t <= tp.t_step  # from the first sample: the plant starts at rest
        t = m.t[sel]
        nu = np.where(np.isfinite(m.nu[sel]), m.nu[sel], 0.0)
        nu[:, j] = m.y[sel]
        eta = np.where(np.isfinite(m.eta[sel]), m.eta[sel], 0.0) if m.eta is not None else None
        edge = max(3, len(t) // 100)
        disp = float(np.trapezoid(nu[:, j], t))
        for k in own:
            if k == j:
                continue
            impulse = _impulse(m, t[0], t[-1], k)
            bal = _Balance(vessel, k, j, own[k], t, eta, edge)
            dkj = (impulse - float(bal.rest(nu))) / disp
            r.coupled[vessel.tau_names[k]] = (dkj, impulse, disp)
            se_kk = _own_se(results, k, nu, t)
            r.coupled_ci[vessel.tau_names[k]] = _coupled_ci(m, sel, vessel.nu_names, bal, nu, impulse,
                                                            dkj, se_kk / abs(disp))


def _impulse(m: Measurement, t0: float, t1: float, k: int) -> float:
    """int tau_k dt over [t0, t1] on the log's every step (shaft speeds are logged each step; the
    hold's fast corrections would alias on the slower sensor grid)."""
    if m.t_log is None or m.tau_log is None:
        sel = (m.t >= t0) & (m.t <= t1)
        return float(np.trapezoid(m.tau[sel, k], m.t[sel]))
    tl = m.t_log
    inner = (tl > t0) & (tl < t1)
    ts = np.concatenate([[t0], tl[inner], [t1]])
    f = np.interp(ts, tl, m.tau_log[:, k])
    return float(np.trapezoid(f, ts))


class _Balance:
    """Everything of row k's impulse balance but the unknown D_kj int nu_j, for nu (..., n, dof)."""

    def __init__(self, vessel: VesselSpec, k: int, j: int, own: dict[str, float], t: np.ndarray,
                 eta: np.ndarray | None, edge: int) -> None:
        self.k, self.j, self.t, self.edge = k, j, t, edge
        self.M_k = 0.5 * (vessel.M + vessel.M.T)[k]
        self.DL, self.DQ = vessel.D_L[k].copy(), vessel.D_Q[k].copy()
        self.DL[k], self.DQ[k] = own["d_L"], own["d_Q"]
        self.DL[j] = 0.0  # the unknown
        self.M_cor = vessel.M_RB + vessel.M_A if vessel.coriolis != "none" else None
        self.g = 0.0
        if vessel.dof == 6 and vessel.restoring is not None and eta is not None:
            rs = vessel.restoring
            co = restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b)
            self.g = float(np.trapezoid(restoring_force(co, eta[:, 3], eta[:, 4])[:, k], t))

    def rest(self, nu: np.ndarray) -> np.ndarray:
        """M_k. dnu (the start at rest) + int (D_L nu + D_Q |nu| nu + C(nu) nu)_k dt + int g_k dt."""
        f = nu @ self.DL + (np.abs(nu) * nu) @ self.DQ
        if self.M_cor is not None:
            f = f + coriolis_force(self.M_cor, nu)[..., self.k]
        return nu[..., -self.edge:, :].mean(axis=-2) @ self.M_k + np.trapezoid(f, self.t, axis=-1) + self.g


def _own_se(results: dict[str, AxisResult], k: int, nu: np.ndarray, t: np.ndarray) -> float:
    """Standard error of the held axis' own damping force impulse (its fit's CIs, independent)."""
    for r in results.values():
        if r.plan.kind == "method_one" and r.plan.index == k:
            ci = r.fits["record"].ci95
            var = 0.0
            for p, x in (("d_L", nu[:, k]), ("d_Q", np.abs(nu[:, k]) * nu[:, k])):
                if p in ci:
                    var += (0.5 * (ci[p][1] - ci[p][0]) / 1.96 * float(np.trapezoid(x, t))) ** 2
            return math.sqrt(var)
    return 0.0


def _coupled_ci(m: Measurement, sel: np.ndarray, nu_names: list[str], bal: _Balance, nu: np.ndarray,
                impulse: float, dkj: float, se_own: float) -> tuple[float, float]:
    """95 % interval of an impulse estimate D_kj, from the sensor noise the file states.

    With the measured forces exact (shaft speeds through the thrust law) the estimate's error is
    the noise in the measured velocities: at the window's end (M_k. dnu; the start is rest by
    design) and in their integrals (the trial axis' displacement, the held axes' drift).
    ``COUPLED_DRAWS`` realisations of that noise, processed as the measurement was
    (``noise_draws``: white on a sensor's samples, or position fixes differentiated and rotated),
    are added to the measured velocities and go through the same balance; their spread, with the
    held axis' identified damping's own standard error, gives the interval (normal).
    """
    rng = np.random.default_rng(COUPLED_SEED)
    noisy = nu + noise_draws(m.noise_model, nu_names, m.t[sel], COUPLED_DRAWS, rng)  # (B, n, dof)
    draws = (impulse - bal.rest(noisy)) / np.trapezoid(noisy[..., bal.j], bal.t, axis=-1)
    sd = math.sqrt(float(np.var(draws)) + se_own**2)
    return (dkj - 1.96 * sd, dkj + 1.96 * sd)


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
