"""Compiled batched RK4 of the identification model (``seafmu.identification.maneuver.simulation``):
K parameter sets x S restarted segments x L steps, one compiled loop instead of L steps of
NumPy calls on (K, S, ...) arrays.

State x = nu (3 DOF) or [roll, pitch, nu] (6 DOF). With z = [tau - g, nu (x) nu, nu, |nu| nu]
(a current: [tau - g, nu (x) nu, nu_r (x) nu_r, nu_r, |nu_r| nu_r], nu_r = nu - nu_c), nu_dot = z W_k
with W_k the parameter set's (nz, d) matrix; roll and pitch follow T(Theta). tau is given per
parameter set (leading axis K) or shared (leading axis 1), at the samples and at the RK4
midpoints. A state reaching |x| >= 1e6 becomes NaN and stays NaN (a diverging model).
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel


@kernel
def _nu_c(d: int, vn: float, ve: float, psi: float, phi: float, th: float, out: np.ndarray) -> None:
    cs, sn = math.cos(psi), math.sin(psi)
    if d == 3:
        out[0] = cs * vn + sn * ve
        out[1] = -sn * vn + cs * ve
        out[2] = 0.0
        return
    cp, sp, ct, st = math.cos(phi), math.sin(phi), math.cos(th), math.sin(th)
    out[0] = cs * ct * vn + sn * ct * ve
    out[1] = (-sn * cp + cs * st * sp) * vn + (cs * cp + sp * st * sn) * ve
    out[2] = (sn * sp + cs * cp * st) * vn + (-cs * sp + st * sn * cp) * ve
    out[3] = 0.0
    out[4] = 0.0
    out[5] = 0.0


@kernel
def _f(
    x: np.ndarray,
    tau: np.ndarray,
    W: np.ndarray,
    d: int,
    g4: np.ndarray,
    cur: bool,
    vn: float,
    ve: float,
    psi: float,
    z: np.ndarray,
    nuc: np.ndarray,
    out: np.ndarray,
) -> None:
    """x_dot of one parameter set and segment into ``out`` (z, nuc: work arrays)."""
    o = 2 if d == 6 else 0
    if d == 6:
        phi, th = x[0], x[1]
        sp, cp, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        wb, gx, gy, gz = g4[0], g4[1], g4[2], g4[3]
        z[0] = tau[0] - wb * st
        z[1] = tau[1] - -wb * ct * sp
        z[2] = tau[2] - -wb * ct * cp
        z[3] = tau[3] - (-gy * ct * cp + gz * ct * sp)
        z[4] = tau[4] - (gz * st + gx * ct * cp)
        z[5] = tau[5] - (-gx * ct * sp - gy * st)
    else:
        phi = th = 0.0
        for i in range(d):
            z[i] = tau[i]
    p = d
    for j in range(d):
        for k in range(d):
            z[p] = x[o + j] * x[o + k]
            p += 1
    if cur:
        _nu_c(d, vn, ve, psi, phi, th, nuc)
        for j in range(d):
            for k in range(d):
                z[p] = (x[o + j] - nuc[j]) * (x[o + k] - nuc[k])
                p += 1
        for j in range(d):
            z[p] = x[o + j] - nuc[j]
            p += 1
        for j in range(d):
            r = x[o + j] - nuc[j]
            z[p] = abs(r) * r
            p += 1
    else:
        for j in range(d):
            z[p] = x[o + j]
            p += 1
        for j in range(d):
            z[p] = abs(x[o + j]) * x[o + j]
            p += 1
    for c in range(d):
        s = 0.0
        for r in range(p):
            s += z[r] * W[r, c]
        out[o + c] = s
    if d == 6:
        p_, q_, r_ = x[5], x[6], x[7]
        out[0] = p_ + (sp * q_ + cp * r_) * math.tan(th)
        out[1] = cp * q_ - sp * r_


@kernel
def simulate(
    x0: np.ndarray,
    tau: np.ndarray,
    tau_mid: np.ndarray,
    W: np.ndarray,
    h: float,
    d: int,
    g4: np.ndarray,
    cur: bool,
    vc: np.ndarray,
    psi: np.ndarray,
    psi_mid: np.ndarray,
    out: np.ndarray,
) -> None:
    """RK4 over the segments for every parameter set into out (K, S, L+1, nx); out[:, :, 0] = x0."""
    K, S, n1, nx = out.shape
    L = n1 - 1
    Kt = tau.shape[0]
    z = np.empty(W.shape[1])
    nuc = np.zeros(6)
    k1, k2, k3, k4 = np.empty(nx), np.empty(nx), np.empty(nx), np.empty(nx)
    x, xs = np.empty(nx), np.empty(nx)
    hh = 0.5 * h
    h6 = h / 6.0
    for kk in range(K):
        kt = kk if Kt > 1 else 0
        vn = vc[kk, 0] if cur else 0.0
        ve = vc[kk, 1] if cur else 0.0
        Wk = W[kk]
        for s in range(S):
            for i in range(nx):
                x[i] = x0[kk, s, i]
                out[kk, s, 0, i] = x[i]
            for step in range(L):
                p0 = psi[s, step] if cur else 0.0
                pm = psi_mid[s, step] if cur else 0.0
                p1 = psi[s, step + 1] if cur else 0.0
                _f(x, tau[kt, s, step], Wk, d, g4, cur, vn, ve, p0, z, nuc, k1)
                for i in range(nx):
                    xs[i] = x[i] + hh * k1[i]
                _f(xs, tau_mid[kt, s, step], Wk, d, g4, cur, vn, ve, pm, z, nuc, k2)
                for i in range(nx):
                    xs[i] = x[i] + hh * k2[i]
                _f(xs, tau_mid[kt, s, step], Wk, d, g4, cur, vn, ve, pm, z, nuc, k3)
                for i in range(nx):
                    xs[i] = x[i] + h * k3[i]
                _f(xs, tau[kt, s, step + 1], Wk, d, g4, cur, vn, ve, p1, z, nuc, k4)
                for i in range(nx):
                    xi = x[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
                    x[i] = xi if abs(xi) < 1e6 else np.nan
                    out[kk, s, step + 1, i] = x[i]
