"""Simulation of the model: batched RK4 over parameter sets and restarted segments (output
error, simulation NRMSE, the prediction traces of the report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from seafmu.components.thrusters import thruster_matrix
from seafmu.components.vessel_spec import VesselSpec
from seafmu.identification import fitting
from seafmu.identification.maneuver.preprocessing import _Prepared
from seafmu.identification.maneuver.terms import _Restoring, _sym, coriolis_tensor


class _Simulator:
    """RK4 of the model for many (M, D_L, D_Q) and many segments at once.

    State: nu (3 DOF) or [roll, pitch, nu] (6 DOF: restoring needs the attitude). tau is linear
    between samples (RK4 stages use tau at t, the midpoint and t + h). Each segment restarts
    from the measured (smoothed) state, so a fit is not dominated by drift from one start.
    Same equations as ``VesselModel.derivative`` without current (checked by a test).

    Diagnosis extensions (``run(..., F0=, vc=)``): a constant generalised force F0 added to tau,
    and a constant NED current vc = (north, east): damping and the added-mass Coriolis terms then
    act on nu_r = nu - R^T [vc; 0] as in the plant (C_RB(nu) nu + C_A(nu_r) nu_r), with R from the
    simulated roll/pitch and the *measured* heading (``psi``, set by ``_sim_setup``).
    """

    def __init__(self, vessel: VesselSpec, t: np.ndarray, tau: np.ndarray, x_meas: np.ndarray,
                 starts: np.ndarray, length: int) -> None:
        self.d = vessel.dof
        self.g = _Restoring(vessel)
        self.length = length
        self.h = float(t[1] - t[0])
        n = t.size
        idx = starts[:, None] + np.arange(length + 1)[None, :]
        self.valid = idx < n
        idx = np.minimum(idx, n - 1)
        self.tau = tau[idx]  # (S, L+1, d)
        self.tau_mid = 0.5 * (self.tau[:, :-1] + self.tau[:, 1:])
        self.x0 = x_meas[starts]  # (S, nx)
        self.idx = idx
        self.M_RB = _sym(np.asarray(vessel.M_RB, dtype=float))
        self.psi: np.ndarray | None = None  # (S, L+1) measured heading (unwrapped), for a current
        self.psi_mid: np.ndarray | None = None  # (S, L)
        # per-thruster thrust on the hull (S, L+1, m) and at the midpoints (S, L), with B (d, m):
        # a thruster's gain (thrust_gain) changes tau by B diag(gain - 1) thrust
        self.thrust: np.ndarray | None = None
        self.thrust_mid: np.ndarray | None = None
        self.B = thruster_matrix(vessel.thrusters, self.d)

    def _current(self, vc: np.ndarray, psi: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Body-frame current nu_c (K, S, d) from the NED current vc (K, 2) at heading psi (1, S)."""
        vn, ve = vc[:, 0, None], vc[:, 1, None]
        cs, sn = np.cos(psi), np.sin(psi)
        out = np.zeros((*x.shape[:-1], self.d))
        if self.d == 3:
            out[..., 0] = cs * vn + sn * ve
            out[..., 1] = -sn * vn + cs * ve
            return out
        phi, th = x[..., 0], x[..., 1]
        cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th)
        out[..., 0] = cs * ct * vn + sn * ct * ve
        out[..., 1] = (-sn * cp + cs * st * sp) * vn + (cs * cp + sp * st * sn) * ve
        out[..., 2] = (sn * sp + cs * cp * st) * vn + (-cs * sp + st * sn * cp) * ve
        return out

    def _f(self, x: np.ndarray, tau: np.ndarray, W: np.ndarray, vc: np.ndarray | None = None,
           psi: np.ndarray | None = None) -> np.ndarray:
        """x_dot; nu_dot = [tau - g, nu (x) nu, nu, |nu| nu] @ W (one matmul per parameter set).

        With a current: [tau - g, nu (x) nu, nu_r (x) nu_r, nu_r, |nu_r| nu_r] @ W (split Coriolis).
        """
        if self.d == 6:
            phi, th, nu = x[..., 0], x[..., 1], x[..., 2:]
            force = tau - self.g(phi, th)
        else:
            nu, force = x, np.broadcast_to(tau, x.shape)
        nn = (nu[..., :, None] * nu[..., None, :]).reshape(*nu.shape[:-1], -1)
        if vc is None or psi is None:
            nu_dot = np.matmul(np.concatenate([force, nn, nu, np.abs(nu) * nu], axis=-1), W)
        else:
            nur = nu - self._current(vc, psi, x)
            nnr = (nur[..., :, None] * nur[..., None, :]).reshape(*nur.shape[:-1], -1)
            nu_dot = np.matmul(np.concatenate([np.broadcast_to(force, nu.shape), nn, nnr, nur,
                                               np.abs(nur) * nur], axis=-1), W)
        if self.d == 3:
            return nu_dot
        p, q, r = nu[..., 3], nu[..., 4], nu[..., 5]
        sp, cp = np.sin(phi), np.cos(phi)
        phi_dot = p + (sp * q + cp * r) * np.tan(th)
        th_dot = cp * q - sp * r
        return np.concatenate([phi_dot[..., None], th_dot[..., None], nu_dot], axis=-1)

    def run(self, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, x0: np.ndarray | None = None,
            F0: np.ndarray | None = None, vc: np.ndarray | None = None,
            thrust_gain: np.ndarray | None = None) -> np.ndarray:
        """Simulated states (K, S, L+1, nx) for K parameter sets (M, DL, DQ each (K, d, d));
        ``x0`` (K, S, nx) replaces the measured segment starts; ``F0`` (K, d) constant force,
        ``vc`` (K, 2) NED current (see the class docstring); ``thrust_gain`` (K, m) the fraction
        of each thruster's thrust that acts (needs ``thrust``, set by ``_sim_setup``)."""
        K = M.shape[0]
        cur = vc is not None and self.psi is not None and self.psi_mid is not None
        d = self.d
        W = np.empty((K, d + (2 if cur else 1) * d**2 + 2 * d, d))
        T_RB = coriolis_tensor(self.M_RB) if cur else None
        for k in range(K):
            Ms = _sym(M[k])
            Minv = np.linalg.inv(Ms)
            if T_RB is not None:  # C_RB(nu) nu + C_A(nu_r) nu_r: Coriolis is linear in M
                cor = [-Minv @ T_RB, -Minv @ coriolis_tensor(Ms - self.M_RB)]
            else:
                cor = [-Minv @ coriolis_tensor(Ms)]
            W[k] = np.hstack([Minv, *cor, -Minv @ DL[k], -Minv @ DQ[k]]).T
        x = np.broadcast_to(self.x0 if x0 is None else x0, (K, *self.x0.shape)).copy()
        out = np.empty((K, *self.x0.shape[:1], self.length + 1, self.x0.shape[-1]))
        out[:, :, 0] = x
        h = self.h
        f0 = 0.0 if F0 is None else np.asarray(F0, dtype=float)[:, None, :]
        dtau = dtau_mid = None
        if thrust_gain is not None and self.thrust is not None and self.thrust_mid is not None:
            dB = (np.asarray(thrust_gain, dtype=float) - 1.0)[:, :, None] * self.B.T[None]  # (K, m, d)
            dtau = np.einsum("slm,kmd->ksld", self.thrust, dB)
            dtau_mid = np.einsum("slm,kmd->ksld", self.thrust_mid, dB)
        vck = np.asarray(vc, dtype=float) if cur and vc is not None else None
        no_psi = (None, None, None)
        with np.errstate(all="ignore"):
            for k in range(self.length):
                t0, tm, t1 = (self.tau[None, :, k] + f0, self.tau_mid[None, :, k] + f0,
                              self.tau[None, :, k + 1] + f0)
                if dtau is not None and dtau_mid is not None:
                    t0, tm, t1 = t0 + dtau[:, :, k], tm + dtau_mid[:, :, k], t1 + dtau[:, :, k + 1]
                p0, pm, p1 = no_psi if vck is None else (
                    self.psi[None, :, k], self.psi_mid[None, :, k], self.psi[None, :, k + 1])  # type: ignore[index]
                k1 = self._f(x, t0, W, vck, p0)
                k2 = self._f(x + 0.5 * h * k1, tm, W, vck, pm)
                k3 = self._f(x + 0.5 * h * k2, tm, W, vck, pm)
                k4 = self._f(x + h * k3, t1, W, vck, p1)
                x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
                x = np.where(np.abs(x) < 1e6, x, np.nan)  # a diverging model stays NaN
                out[:, :, k + 1] = x
        return out


def _state(prep_eta: np.ndarray, nu: np.ndarray, d: int) -> np.ndarray:
    return nu if d == 3 else np.hstack([prep_eta[:, 3:5], nu])


@dataclass
class _SimSetup:
    sim: _Simulator
    meas: np.ndarray  # (S, L+1, d) measured nu on the simulation grid
    mask: np.ndarray  # (S, L+1) samples that exist and are compared (not the start)
    scale: np.ndarray  # (d,) spread of measured nu, normalises residuals per DOF
    t: np.ndarray | None = None  # (n_grid,) times of the simulation grid (for plots)


def _sim_setup(vessel: VesselSpec, prep: _Prepared, i0: int, i1: int, segment: float, sim_dt: float,
               scale: np.ndarray | None = None) -> _SimSetup | None:
    """Segments of ``segment`` seconds covering samples [i0, i1), on a grid of about ``sim_dt``."""
    if i1 - i0 < 3:
        return None
    stride = max(1, round(sim_dt / prep.dt))
    sel = np.arange(i0, i1, stride)
    t = prep.t[sel]
    d = prep.nu.shape[1]
    x_meas = _state(prep.eta[sel], prep.nu[sel], d)
    L = max(1, min(sel.size - 1, round(segment / (stride * prep.dt))))
    starts = np.arange(0, sel.size - 1, L)
    sim = _Simulator(vessel, t, prep.tau[sel], x_meas, starts, L)
    # tau at the RK4 midpoints from the full-rate log (a logged sample when the stride is even)
    t_mid = 0.5 * (t[sim.idx[:, :-1]] + t[sim.idx[:, 1:]])
    sim.tau_mid = np.stack([np.interp(t_mid, prep.t, prep.tau[:, j]) for j in range(d)], axis=-1)
    psi = np.unwrap(prep.eta[:, d - 1])  # yaw: last eta entry (3 and 6 DOF)
    sim.psi = psi[sel][sim.idx]
    sim.psi_mid = np.interp(t_mid, prep.t, psi)
    if prep.thrust is not None:
        sim.thrust = prep.thrust[sel][sim.idx]
        sim.thrust_mid = np.stack([np.interp(t_mid, prep.t, prep.thrust[:, j])
                                   for j in range(prep.thrust.shape[1])], axis=-1)
    meas = prep.nu_raw[sel][sim.idx]
    mask = sim.valid.copy()
    mask[:, 0] = False
    if scale is None:
        scale = np.maximum(prep.nu_raw[i0:i1].std(axis=0), 1e-9)
    return _SimSetup(sim, meas, mask, scale, t)


def _one(effect: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """Effect terms of one parameter set as the batched simulator takes them (K = 1)."""
    return {k: np.asarray(v, dtype=float)[None] for k, v in (effect or {}).items()}


def _trace(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, run: str,
           effect: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Measured and simulated nu on the simulation grid, every sample once, for the overlay and
    residual plots; ``restarts`` are the segment starts (the simulation restarts there)."""
    x = setup.sim.run(M[None], DL[None], DQ[None], **_one(effect))[0]
    d = setup.meas.shape[-1]
    mask = setup.mask
    assert setup.t is not None
    return {"run": run, "t": setup.t[setup.sim.idx][mask], "y": setup.meas[mask], "yhat": x[..., -d:][mask],
            "restarts": setup.t[setup.sim.idx[:, 0]]}


def _sim_residual(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                  x0: np.ndarray | None = None, **effect: np.ndarray) -> np.ndarray:
    """Normalised nu residuals (K, S, L+1, d); NaN where a simulation diverged."""
    x = setup.sim.run(M, DL, DQ, x0, **effect)
    d = setup.meas.shape[-1]
    return (x[..., -d:] - setup.meas[None]) / setup.scale


def _nrmse_per_dof(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                   effect: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-DOF NRMSE ‖y − ŷ‖/‖y − ȳ‖ of simulated nu, and the flat normalised residual."""
    r = _sim_residual(setup, M[None], DL[None], DQ[None], **_one(effect))[0]
    mask = setup.mask
    y = setup.meas[mask]
    res = r[mask] * setup.scale
    out = np.array([fitting.nrmse(y[:, j], y[:, j] - res[:, j]) if np.all(np.isfinite(res[:, j]))
                    else math.inf for j in range(y.shape[1])])
    return out, r[mask]
