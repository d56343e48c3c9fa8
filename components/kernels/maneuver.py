"""Compiled batched RK4 of the identification model (``seafmu.identification.maneuver.simulation``):
K parameter sets x S restarted segments x L steps, one compiled loop instead of L steps of
NumPy calls on (K, S, ...) arrays.

State x = nu (3 DOF) or [roll, pitch, nu] (6 DOF). With z = [tau - g, nu (x) nu, nu, |nu| nu]
(a current: [tau - g, nu (x) nu, nu_r (x) nu_r, nu_r, |nu_r| nu_r], nu_r = nu - nu_c), nu_dot = z W_k
with W_k the parameter set's (nz, d) matrix; roll and pitch follow T(Theta). tau is given per
parameter set (leading axis K) or shared (leading axis 1), at the samples and at the RK4
midpoints. A state reaching |x| >= 1e6 becomes NaN and stays NaN (a diverging model).

3 DOF runs on scalars (the state and z in registers), 6 DOF on small work arrays with fixed sizes.
z W is summed over the distinct products only: the weights of nu_j nu_k and nu_k nu_j are added
once per parameter set (``_fold``; 21 instead of 36 products in 6 DOF), and the outputs accumulate
side by side (independent dependency chains). Measured on this machine: about 0.3 us per 6-DOF
RK4 step (0.8 us when z W was one chain per output over all 54 products). The sums are reordered
against NumPy's matmul on one row: equal to about 1e-15 relative per step (``tests/test_kernels.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from . import _jit  # noqa: F401  (first: sets numba's cache folder and its content-keyed cache locator)


def kernel(fn: Any) -> Any:
    """``_jit.kernel`` that also lets the compiler fuse a * b + c into one instruction (numba's
    fastmath "contract" flag alone: no reassociation, NaN and inf kept as they are). z W is about
    two thirds of an RK4 step and fused, it runs about 1.4x faster (measured); the rounding then
    differs from NumPy's matmul by about 1e-16 per product, which ``tests/test_kernels.py`` allows
    (1e-11), where the plant's kernels must equal NumPy bit for bit."""
    return numba.njit(cache=True, nogil=True, fastmath={"contract"})(fn)


@kernel
def _fold(W: np.ndarray, kk: int, d: int, nb: int, Wf: np.ndarray) -> None:
    """W[kk] (nz, d) with each quadratic block's rows of x_j x_k and x_k x_j summed (j < k) into
    Wf's row of the pair: z W on d (d + 1) / 2 products per block instead of d^2 (nb blocks: 1,
    or 2 with a current); the force rows before and the 2 d linear rows after copied."""
    npair = d * (d + 1) // 2
    for i in range(d):
        for c in range(d):
            Wf[i, c] = W[kk, i, c]
    for b in range(nb):
        src = d + d * d * b
        dst = d + npair * b
        p = 0
        for j in range(d):
            for k in range(j, d):
                for c in range(d):
                    w = W[kk, src + d * j + k, c]
                    if k != j:
                        w += W[kk, src + d * k + j, c]
                    Wf[dst + p, c] = w
                p += 1
    s0, d0 = d + d * d * nb, d + npair * nb
    for i in range(2 * d):
        for c in range(d):
            Wf[d0 + i, c] = W[kk, s0 + i, c]


@kernel
def _f3(
    u: float,
    v: float,
    r: float,
    tau: np.ndarray,
    kt: int,
    s: int,
    step: int,
    Wf: np.ndarray,
    cur: bool,
    c0: float,
    c1: float,
) -> tuple[float, float, float]:
    """nu_dot of the 3-DOF model with folded weights (``_fold``); (c0, c1) the body current (its
    yaw rate is 0). The force, quadratic and linear terms are summed apart and then added: three
    short dependency chains instead of one long one."""
    t0, t1, t2 = tau[kt, s, step, 0], tau[kt, s, step, 1], tau[kt, s, step, 2]
    f0 = t0 * Wf[0, 0] + t1 * Wf[1, 0] + t2 * Wf[2, 0]
    f1 = t0 * Wf[0, 1] + t1 * Wf[1, 1] + t2 * Wf[2, 1]
    f2 = t0 * Wf[0, 2] + t1 * Wf[1, 2] + t2 * Wf[2, 2]
    q = (u * u, u * v, u * r, v * v, v * r, r * r)
    q0 = q1 = q2 = 0.0
    for i in range(6):
        qi = q[i]
        q0 += qi * Wf[3 + i, 0]
        q1 += qi * Wf[3 + i, 1]
        q2 += qi * Wf[3 + i, 2]
    if cur:
        ur, vr, rr = u - c0, v - c1, r
        qr = (ur * ur, ur * vr, ur * rr, vr * vr, vr * rr, rr * rr)
        for i in range(6):
            qi = qr[i]
            q0 += qi * Wf[9 + i, 0]
            q1 += qi * Wf[9 + i, 1]
            q2 += qi * Wf[9 + i, 2]
        lin = (ur, vr, rr, abs(ur) * ur, abs(vr) * vr, abs(rr) * rr)
        o = 15
    else:
        lin = (u, v, r, abs(u) * u, abs(v) * v, abs(r) * r)
        o = 9
    l0 = l1 = l2 = 0.0
    for i in range(6):
        li = lin[i]
        l0 += li * Wf[o + i, 0]
        l1 += li * Wf[o + i, 1]
        l2 += li * Wf[o + i, 2]
    return f0 + q0 + l0, f1 + q1 + l1, f2 + q2 + l2


@kernel
def _current3(vn: float, ve: float, psi: float) -> tuple[float, float]:
    cs, sn = math.cos(psi), math.sin(psi)
    return cs * vn + sn * ve, -sn * vn + cs * ve


@kernel
def _run3(
    x0: np.ndarray,
    tau: np.ndarray,
    tau_mid: np.ndarray,
    W: np.ndarray,
    h: float,
    cur: bool,
    vc: np.ndarray,
    psi: np.ndarray,
    psi_mid: np.ndarray,
    out: np.ndarray,
) -> None:
    K, S, n1, _ = out.shape
    Kt = tau.shape[0]
    hh = 0.5 * h
    h6 = h / 6.0
    nan = np.nan
    Wf = np.zeros((21, 3))
    for kk in range(K):
        kt = kk if Kt > 1 else 0
        vn = vc[kk, 0] if cur else 0.0
        ve = vc[kk, 1] if cur else 0.0
        _fold(W, kk, 3, 2 if cur else 1, Wf)
        for s in range(S):
            u, v, r = x0[kk, s, 0], x0[kk, s, 1], x0[kk, s, 2]
            out[kk, s, 0, 0], out[kk, s, 0, 1], out[kk, s, 0, 2] = u, v, r
            c00 = c01 = cm0 = cm1 = c10 = c11 = 0.0
            if cur:
                c10, c11 = _current3(vn, ve, psi[s, 0])
            for k in range(n1 - 1):
                if cur:
                    c00, c01 = c10, c11
                    cm0, cm1 = _current3(vn, ve, psi_mid[s, k])
                    c10, c11 = _current3(vn, ve, psi[s, k + 1])
                a0, a1, a2 = _f3(u, v, r, tau, kt, s, k, Wf, cur, c00, c01)
                b0, b1, b2 = _f3(u + hh * a0, v + hh * a1, r + hh * a2, tau_mid, kt, s, k, Wf, cur, cm0, cm1)
                e0, e1, e2 = _f3(u + hh * b0, v + hh * b1, r + hh * b2, tau_mid, kt, s, k, Wf, cur, cm0, cm1)
                d0, d1, d2 = _f3(u + h * e0, v + h * e1, r + h * e2, tau, kt, s, k + 1, Wf, cur, c10, c11)
                u = u + h6 * (a0 + 2.0 * (b0 + e0) + d0)
                v = v + h6 * (a1 + 2.0 * (b1 + e1) + d1)
                r = r + h6 * (a2 + 2.0 * (b2 + e2) + d2)
                u = u if abs(u) < 1e6 else nan
                v = v if abs(v) < 1e6 else nan
                r = r if abs(r) < 1e6 else nan
                out[kk, s, k + 1, 0], out[kk, s, k + 1, 1], out[kk, s, k + 1, 2] = u, v, r


@kernel
def _f6(
    x: np.ndarray,
    tau: np.ndarray,
    kt: int,
    s: int,
    step: int,
    Wf: np.ndarray,
    g4: np.ndarray,
    cur: bool,
    vn: float,
    ve: float,
    psi: float,
    z: np.ndarray,
    out: np.ndarray,
) -> None:
    """x_dot of the 6-DOF model (x = [roll, pitch, nu]) into ``out``, with folded weights
    (``_fold``: 21 products per quadratic block); z: work array. The six outputs accumulate side
    by side (six independent chains, the weights' rows read once)."""
    phi, th = x[0], x[1]
    sp, cp, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
    wb, gx, gy, gz = g4[0], g4[1], g4[2], g4[3]
    z[0] = tau[kt, s, step, 0] - wb * st
    z[1] = tau[kt, s, step, 1] - -wb * ct * sp
    z[2] = tau[kt, s, step, 2] - -wb * ct * cp
    z[3] = tau[kt, s, step, 3] - (-gy * ct * cp + gz * ct * sp)
    z[4] = tau[kt, s, step, 4] - (gz * st + gx * ct * cp)
    z[5] = tau[kt, s, step, 5] - (-gx * ct * sp - gy * st)
    p = 6
    for j in range(6):
        xj = x[2 + j]
        for k in range(j, 6):
            z[p] = xj * x[2 + k]
            p += 1
    if cur:
        cs, sn = math.cos(psi), math.sin(psi)
        rel = (
            x[2] - (cs * ct * vn + sn * ct * ve),
            x[3] - ((-sn * cp + cs * st * sp) * vn + (cs * cp + sp * st * sn) * ve),
            x[4] - ((sn * sp + cs * cp * st) * vn + (-cs * sp + st * sn * cp) * ve),
            x[5],
            x[6],
            x[7],
        )
        for j in range(6):
            for k in range(j, 6):
                z[p] = rel[j] * rel[k]
                p += 1
        for j in range(6):
            z[p + j] = rel[j]
            z[p + 6 + j] = abs(rel[j]) * rel[j]
    else:
        for j in range(6):
            xj = x[2 + j]
            z[p + j] = xj
            z[p + 6 + j] = abs(xj) * xj
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    for i in range(p + 12):
        zi = z[i]
        a0 += zi * Wf[i, 0]
        a1 += zi * Wf[i, 1]
        a2 += zi * Wf[i, 2]
        a3 += zi * Wf[i, 3]
        a4 += zi * Wf[i, 4]
        a5 += zi * Wf[i, 5]
    out[2], out[3], out[4], out[5], out[6], out[7] = a0, a1, a2, a3, a4, a5
    p_, q_, r_ = x[5], x[6], x[7]
    out[0] = p_ + (sp * q_ + cp * r_) * (st / ct)
    out[1] = cp * q_ - sp * r_


@kernel
def _run6(
    x0: np.ndarray,
    tau: np.ndarray,
    tau_mid: np.ndarray,
    W: np.ndarray,
    h: float,
    g4: np.ndarray,
    cur: bool,
    vc: np.ndarray,
    psi: np.ndarray,
    psi_mid: np.ndarray,
    out: np.ndarray,
) -> None:
    K, S, n1, _ = out.shape
    Kt = tau.shape[0]
    z = np.zeros(60)
    Wf = np.zeros((60, 6))
    k1, k2, k3, k4 = np.empty(8), np.empty(8), np.empty(8), np.empty(8)
    x, xs = np.empty(8), np.empty(8)
    hh = 0.5 * h
    h6 = h / 6.0
    for kk in range(K):
        kt = kk if Kt > 1 else 0
        vn = vc[kk, 0] if cur else 0.0
        ve = vc[kk, 1] if cur else 0.0
        _fold(W, kk, 6, 2 if cur else 1, Wf)
        for s in range(S):
            for i in range(8):
                x[i] = x0[kk, s, i]
                out[kk, s, 0, i] = x[i]
            for k in range(n1 - 1):
                p0 = psi[s, k] if cur else 0.0
                pm = psi_mid[s, k] if cur else 0.0
                p1 = psi[s, k + 1] if cur else 0.0
                _f6(x, tau, kt, s, k, Wf, g4, cur, vn, ve, p0, z, k1)
                for i in range(8):
                    xs[i] = x[i] + hh * k1[i]
                _f6(xs, tau_mid, kt, s, k, Wf, g4, cur, vn, ve, pm, z, k2)
                for i in range(8):
                    xs[i] = x[i] + hh * k2[i]
                _f6(xs, tau_mid, kt, s, k, Wf, g4, cur, vn, ve, pm, z, k3)
                for i in range(8):
                    xs[i] = x[i] + h * k3[i]
                _f6(xs, tau, kt, s, k + 1, Wf, g4, cur, vn, ve, p1, z, k4)
                for i in range(8):
                    xi = x[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
                    x[i] = xi if abs(xi) < 1e6 else np.nan
                    out[kk, s, k + 1, i] = x[i]


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
    if d == 3:
        _run3(x0, tau, tau_mid, W, h, cur, vc, psi, psi_mid, out)
    else:
        _run6(x0, tau, tau_mid, W, h, g4, cur, vc, psi, psi_mid, out)


def simulate_numpy(x0: np.ndarray, tau: Any, tau_mid: Any, W: Any, h: float, d: int, g4: Any, cur: bool,
                   vc: Any, psi: Any, psi_mid: Any, out: Any) -> None:
    """The NumPy form ``simulate`` is held equal to (``tests/test_kernels.py``) and compared with
    (``benchmarks/bench_maneuver_scaling.py``): the simulator's batched RK4 on (K, S, ...) arrays,
    one step at a time, as it ran before it was compiled; same signature as ``simulate``."""
    K = x0.shape[0]
    L = out.shape[2] - 1
    wb, gx, gy, gz = g4.tolist()

    def f(x: Any, tau_k: Any, p: Any) -> Any:
        o = 2 if d == 6 else 0
        nu = x[..., o:]
        if d == 6:
            phi, th = x[..., 0], x[..., 1]
            sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
            g = np.stack([wb * st, -wb * ct * sp, -wb * ct * cp, -gy * ct * cp + gz * ct * sp,
                          gz * st + gx * ct * cp, -gx * ct * sp - gy * st], axis=-1)
            force = tau_k - g
        else:
            force = np.broadcast_to(tau_k, nu.shape)
        nn = (nu[..., :, None] * nu[..., None, :]).reshape(*nu.shape[:-1], -1)
        if cur:
            cs, sn = np.cos(p), np.sin(p)
            vn, ve = vc[:, 0, None], vc[:, 1, None]
            nuc = np.zeros_like(nu)
            if d == 3:
                nuc[..., 0], nuc[..., 1] = cs * vn + sn * ve, -sn * vn + cs * ve
            else:
                nuc[..., 0] = cs * ct * vn + sn * ct * ve
                nuc[..., 1] = (-sn * cp + cs * st * sp) * vn + (cs * cp + sp * st * sn) * ve
                nuc[..., 2] = (sn * sp + cs * cp * st) * vn + (-cs * sp + st * sn * cp) * ve
            nur = nu - nuc
            nnr = (nur[..., :, None] * nur[..., None, :]).reshape(*nur.shape[:-1], -1)
            z = np.concatenate([np.broadcast_to(force, nu.shape), nn, nnr, nur, np.abs(nur) * nur], axis=-1)
        else:
            z = np.concatenate([force, nn, nu, np.abs(nu) * nu], axis=-1)
        nu_dot = np.matmul(z, W)
        if d == 3:
            return nu_dot
        p_, q_, r_ = nu[..., 3], nu[..., 4], nu[..., 5]
        return np.concatenate([(p_ + (sp * q_ + cp * r_) * np.tan(th))[..., None],
                               (cp * q_ - sp * r_)[..., None], nu_dot], axis=-1)

    x = x0.copy()
    out[:, :, 0] = x
    with np.errstate(all="ignore"):
        for k in range(L):
            p0, pm, p1 = (psi[None, :, k], psi_mid[None, :, k], psi[None, :, k + 1]) if cur else (None,) * 3
            k1 = f(x, tau[:, :, k], p0)
            k2 = f(x + 0.5 * h * k1, tau_mid[:, :, k], pm)
            k3 = f(x + 0.5 * h * k2, tau_mid[:, :, k], pm)
            k4 = f(x + h * k3, tau[:, :, k + 1], p1)
            x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
            x = np.where(np.abs(x) < 1e6, x, np.nan)
            out[:, :, k + 1] = x
    assert K == out.shape[0]
