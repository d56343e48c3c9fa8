"""Compiled right-hand side and RK4 of the vessel model (3 and 6 DOF), the plant's hot path.

The same equations as ``VesselModel._rhs3/_rhs6`` (``components/vessel_model.py``), written in
scalars in the same order, so every product and sum is rounded the same way except the one
matrix product K z = M^-1 [B, -I, -D_L, -D_Q] z, summed left to right here (BLAS may group
the terms otherwise: the results agree to a few units in the last place, ``tests/test_kernels.py``).

Parameters come packed by ``rigid_body_params`` (NumPy, once per vessel):
- ``K`` (dof, m + 3 dof): M^-1 [B, -I, -D_L, -D_Q];
- ``MS``: 6 DOF [M_RB; M_A] (12, 6), Coriolis from [a; b] = M nu; 3 DOF rows u, v of M_RB and M_A (4, 3);
- ``MAL`` (dof, 3): M_A's first three columns (added mass times the linear current), 6 DOF;
- ``ML`` (dof, k): the first k = 3 (6 DOF) or 2 (3 DOF) columns of the matrix the current's
  rotation term acts through: M (omega x nu_c) for ``current_inertia: relative``, M_A (omega x nu_c)
  for ``added`` (zeros, and unused, for ``absolute``);
- ``g6``: (W - B, g_x, g_y, g_z) restoring coefficients (zeros for 3 DOF);
- ``th`` (3, m): rows k_forward, k_reverse, 1 / time constant;
- ``flags``: (dof, thrust law code (``thrust_law.LAWS``), Coriolis on, inertia on the relative
  acceleration: ``current_inertia`` relative or added).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._jit import kernel
from .thrust_law import thrust_of

_PI = math.pi
_TWO_PI = 2.0 * math.pi


class RigidBodyParams(NamedTuple):
    K: np.ndarray
    MS: np.ndarray
    MAL: np.ndarray
    ML: np.ndarray
    g6: np.ndarray
    th: np.ndarray
    flags: np.ndarray
    angle_index: np.ndarray


def _c(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def rigid_body_params(
    M_RB: np.ndarray,
    M_A: np.ndarray,
    D_L: np.ndarray,
    D_Q: np.ndarray,
    B: np.ndarray,
    g6: tuple[float, ...] | None,
    k_forward: np.ndarray,
    k_reverse: np.ndarray,
    time_constant: np.ndarray,
    law: int,
    coriolis: bool,
    current_inertia: str,
    angle_index: list[int],
) -> RigidBodyParams:
    """Pack a vessel's (symmetrised) matrices and thruster data for the kernels."""
    M_RB, M_A = np.asarray(M_RB, float), np.asarray(M_A, float)
    dof = M_RB.shape[0]
    M = M_RB + M_A
    Minv = np.linalg.inv(M)
    K = Minv @ np.hstack(
        [np.asarray(B, float), -np.eye(dof), -np.asarray(D_L, float), -np.asarray(D_Q, float)]
    )
    if dof == 6:
        MS = np.vstack([M_RB, M_A])
        MAL = M_A[:, :3]
    else:
        MS = np.vstack([M_RB[:2], M_A[:2]])
        MAL = np.zeros((3, 3))
    # M nu_r_dot (relative) or M_RB nu_dot + M_A nu_r_dot (added) = M nu_dot + that matrix (omega x nu_c)
    on_current = {"absolute": None, "relative": M, "added": M_A}[current_inertia]
    k = 3 if dof == 6 else 2
    ML = np.zeros((dof, k)) if on_current is None else on_current[:, :k]
    th = np.vstack(
        [np.asarray(k_forward, float), np.asarray(k_reverse, float), 1.0 / np.asarray(time_constant, float)]
    )
    flags = np.array([dof, int(law), int(coriolis), int(on_current is not None)], dtype=np.int64)
    g = np.zeros(4) if g6 is None else np.asarray(g6, float)
    return RigidBodyParams(
        _c(K), _c(MS), _c(MAL), _c(ML), _c(g), _c(th), flags, np.asarray(angle_index, dtype=np.int64)
    )


@kernel
def thrust(n: np.ndarray, th: np.ndarray, law: int, out: np.ndarray) -> None:
    """The thrust law (``thrust_law``), k = k_forward for n >= 0 else k_reverse (``thrust_into``)."""
    for i in range(n.shape[0]):
        ni = n[i]
        out[i] = thrust_of(th[0, i] if ni >= 0.0 else th[1, i], ni, law)


@kernel
def wrap(a: float) -> float:
    """(-pi, pi] as ``dynamics.wrap_angle`` (in-range angles unchanged)."""
    if a > -_PI and a <= _PI:
        return a
    w = (a + _PI) % _TWO_PI - _PI
    if w == -_PI:
        w = _PI
    return w


@kernel
def _tail(
    x: np.ndarray,
    ncmd: np.ndarray,
    z: np.ndarray,
    K: np.ndarray,
    th: np.ndarray,
    law: int,
    dof: int,
    out: np.ndarray,
) -> None:
    """nu_dot = K z (thrusts written into z[:m] here) and the shaft lag n_dot."""
    m = th.shape[1]
    for i in range(m):
        ni = x[2 * dof + i]
        z[i] = thrust_of(th[0, i] if ni >= 0.0 else th[1, i], ni, law)
    # Each row summed left to right as before; the rows' chains interleaved (one pass over z), so
    # the additions of different rows overlap instead of waiting for each other.
    nz = z.shape[0]
    if dof == 6:
        s0 = s1 = s2 = s3 = s4 = s5 = 0.0
        for j in range(nz):
            zj = z[j]
            s0 += K[0, j] * zj
            s1 += K[1, j] * zj
            s2 += K[2, j] * zj
            s3 += K[3, j] * zj
            s4 += K[4, j] * zj
            s5 += K[5, j] * zj
        out[6], out[7], out[8], out[9], out[10], out[11] = s0, s1, s2, s3, s4, s5
    else:
        s0 = s1 = s2 = 0.0
        for j in range(nz):
            zj = z[j]
            s0 += K[0, j] * zj
            s1 += K[1, j] * zj
            s2 += K[2, j] * zj
        out[3], out[4], out[5] = s0, s1, s2
    for i in range(m):
        out[2 * dof + i] = (ncmd[i] - x[2 * dof + i]) * th[2, i]


@kernel
def _row(MS: np.ndarray, i: int, x: np.ndarray) -> float:
    """Row i of [M_RB; M_A] times nu = x[6:12], summed left to right."""
    s = 0.0
    for j in range(6):
        s += MS[i, j] * x[6 + j]
    return s


@kernel
def rhs6(
    x: np.ndarray,
    ncmd: np.ndarray,
    vcn: float,
    vce: float,
    tau_ext: np.ndarray,
    has_ext: bool,
    K: np.ndarray,
    MS: np.ndarray,
    MAL: np.ndarray,
    ML: np.ndarray,
    g6: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> None:
    """x_dot of the 6-DOF model into ``out`` (z: work array of m + 18)."""
    # Long because kinematics, Coriolis, current and restoring are unrolled in scalars into
    # preallocated arrays (no allocation per call on the plant's hot path), as VesselModel._rhs6.
    phi, theta = x[3], x[4]
    psi = x[5]
    u, v, w, p, q, r = x[6], x[7], x[8], x[9], x[10], x[11]
    coriolis = flags[2] != 0
    relative = flags[3] != 0
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    R11, R12, R13 = cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth
    R21, R22, R23 = spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi
    R32, R33 = cth * sphi, cth * cphi
    t = (sphi * q + cphi * r) / cth
    out[0] = R11 * u + R12 * v + R13 * w
    out[1] = R21 * u + R22 * v + R23 * w
    out[2] = -sth * u + R32 * v + R33 * w
    out[3] = p + t * sth
    out[4] = cphi * q - sphi * r
    out[5] = t
    a1 = a2 = a3 = b1 = b2 = b3 = e1 = e2 = e3 = f1 = f2 = f3 = 0.0
    if coriolis:
        a1, a2, a3 = _row(MS, 0, x), _row(MS, 1, x), _row(MS, 2, x)
        b1, b2, b3 = _row(MS, 3, x), _row(MS, 4, x), _row(MS, 5, x)
        e1, e2, e3 = _row(MS, 6, x), _row(MS, 7, x), _row(MS, 8, x)
        f1, f2, f3 = _row(MS, 9, x), _row(MS, 10, x), _row(MS, 11, x)
    rel0 = rel1 = rel2 = rel3 = rel4 = rel5 = 0.0
    has_rel = False
    if vcn != 0.0 or vce != 0.0:
        uc, vc, wc = R11 * vcn + R21 * vce, R12 * vcn + R22 * vce, R13 * vcn + R23 * vce
        if coriolis:
            mc0 = MAL[0, 0] * uc + MAL[0, 1] * vc + MAL[0, 2] * wc
            mc1 = MAL[1, 0] * uc + MAL[1, 1] * vc + MAL[1, 2] * wc
            mc2 = MAL[2, 0] * uc + MAL[2, 1] * vc + MAL[2, 2] * wc
            mc3 = MAL[3, 0] * uc + MAL[3, 1] * vc + MAL[3, 2] * wc
            mc4 = MAL[4, 0] * uc + MAL[4, 1] * vc + MAL[4, 2] * wc
            mc5 = MAL[5, 0] * uc + MAL[5, 1] * vc + MAL[5, 2] * wc
            e1, e2, e3 = e1 - mc0, e2 - mc1, e3 - mc2
            f1, f2, f3 = f1 - mc3, f2 - mc4, f3 - mc5
        ur, vr, wr = u - uc, v - vc, w - wc
        if relative:
            wx, wy, wz = q * wc - r * vc, r * uc - p * wc, p * vc - q * uc
            rel0 = ML[0, 0] * wx + ML[0, 1] * wy + ML[0, 2] * wz
            rel1 = ML[1, 0] * wx + ML[1, 1] * wy + ML[1, 2] * wz
            rel2 = ML[2, 0] * wx + ML[2, 1] * wy + ML[2, 2] * wz
            rel3 = ML[3, 0] * wx + ML[3, 1] * wy + ML[3, 2] * wz
            rel4 = ML[4, 0] * wx + ML[4, 1] * wy + ML[4, 2] * wz
            rel5 = ML[5, 0] * wx + ML[5, 1] * wy + ML[5, 2] * wz
            has_rel = True
    else:
        ur, vr, wr = u, v, w
    s1, s2, s3 = a1 + e1, a2 + e2, a3 + e3
    t1, t2, t3 = b1 + f1, b2 + f2, b3 + f3
    wb, gx, gy, gz = g6[0], g6[1], g6[2], g6[3]
    m = th.shape[1]
    z[m + 0] = q * s3 - r * s2 + wb * sth
    z[m + 1] = r * s1 - p * s3 - wb * R32
    z[m + 2] = p * s2 - q * s1 - wb * R33
    z[m + 3] = v * a3 - w * a2 + vr * e3 - wr * e2 + q * t3 - r * t2 - gy * R33 + gz * R32
    z[m + 4] = w * a1 - u * a3 + wr * e1 - ur * e3 + r * t1 - p * t3 + gz * sth + gx * R33
    z[m + 5] = u * a2 - v * a1 + ur * e2 - vr * e1 + p * t2 - q * t1 - gx * R32 - gy * sth
    if has_rel:
        z[m + 0], z[m + 1], z[m + 2] = z[m + 0] + rel0, z[m + 1] + rel1, z[m + 2] + rel2
        z[m + 3], z[m + 4], z[m + 5] = z[m + 3] + rel3, z[m + 4] + rel4, z[m + 5] + rel5
    if has_ext:
        for i in range(6):
            z[m + i] = z[m + i] - tau_ext[i]
    z[m + 6], z[m + 7], z[m + 8], z[m + 9], z[m + 10], z[m + 11] = ur, vr, wr, p, q, r
    z[m + 12], z[m + 13], z[m + 14] = abs(ur) * ur, abs(vr) * vr, abs(wr) * wr
    z[m + 15], z[m + 16], z[m + 17] = abs(p) * p, abs(q) * q, abs(r) * r
    _tail(x, ncmd, z, K, th, flags[1], 6, out)


@kernel
def rhs3(
    x: np.ndarray,
    ncmd: np.ndarray,
    vcn: float,
    vce: float,
    tau_ext: np.ndarray,
    has_ext: bool,
    K: np.ndarray,
    MS: np.ndarray,
    ML: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> None:
    """x_dot of the 3-DOF model into ``out`` (z: work array of m + 9)."""
    psi, u, v, r = x[2], x[3], x[4], x[5]
    c, s = math.cos(psi), math.sin(psi)
    ur, vr = u - (c * vcn + s * vce), v - (-s * vcn + c * vce)
    m = th.shape[1]
    if flags[2] != 0:
        ax = MS[0, 0] * u + MS[0, 1] * v + MS[0, 2] * r
        ay = MS[1, 0] * u + MS[1, 1] * v + MS[1, 2] * r
        ex = MS[2, 0] * ur + MS[2, 1] * vr + MS[2, 2] * r
        ey = MS[3, 0] * ur + MS[3, 1] * vr + MS[3, 2] * r
        c0, c1, c2 = -r * (ay + ey), r * (ax + ex), u * ay - v * ax + ur * ey - vr * ex
    else:
        c0, c1, c2 = 0.0, 0.0, 0.0
    if flags[3] != 0 and (vcn != 0.0 or vce != 0.0):
        wx, wy = -r * (v - vr), r * (u - ur)
        c0 = c0 + ML[0, 0] * wx + ML[0, 1] * wy
        c1 = c1 + ML[1, 0] * wx + ML[1, 1] * wy
        c2 = c2 + ML[2, 0] * wx + ML[2, 1] * wy
    if has_ext:
        c0, c1, c2 = c0 - tau_ext[0], c1 - tau_ext[1], c2 - tau_ext[2]
    z[m], z[m + 1], z[m + 2] = c0, c1, c2
    z[m + 3], z[m + 4], z[m + 5] = ur, vr, r
    z[m + 6], z[m + 7], z[m + 8] = abs(ur) * ur, abs(vr) * vr, abs(r) * r
    out[0] = c * u - s * v
    out[1] = s * u + c * v
    out[2] = r
    _tail(x, ncmd, z, K, th, flags[1], 3, out)


@kernel
def rhs(
    x: np.ndarray,
    ncmd: np.ndarray,
    vcn: float,
    vce: float,
    tau_ext: np.ndarray,
    has_ext: bool,
    K: np.ndarray,
    MS: np.ndarray,
    MAL: np.ndarray,
    ML: np.ndarray,
    g6: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> None:
    """x_dot for 3 or 6 DOF (``flags[0]``)."""
    if flags[0] == 6:
        rhs6(x, ncmd, vcn, vce, tau_ext, has_ext, K, MS, MAL, ML, g6, th, flags, z, out)
    else:
        rhs3(x, ncmd, vcn, vce, tau_ext, has_ext, K, MS, ML, th, flags, z, out)


@kernel
def rk4(
    x: np.ndarray,
    ncmd: np.ndarray,
    dt: float,
    steps: int,
    vcn: float,
    vce: float,
    tau_ext: np.ndarray,
    has_ext: bool,
    K: np.ndarray,
    MS: np.ndarray,
    MAL: np.ndarray,
    ML: np.ndarray,
    g6: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    angle_index: np.ndarray,
    out: np.ndarray,
) -> None:
    """``steps`` RK4 steps of dt from x with inputs held, angles wrapped after each, into ``out``
    (``VesselModel.rk4``; out may be x itself). Writing into the caller's array, not returning a
    new one: boxing a returned array costs more than a plant step's arithmetic."""
    n = x.shape[0]
    dof = flags[0]
    z = np.zeros(th.shape[1] + 3 * dof)
    k1, k2, k3, k4 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    xs = np.empty(n)
    xc = out
    for i in range(n):
        xc[i] = x[i]
    h2, h6 = 0.5 * dt, dt / 6.0
    for _ in range(steps):
        rhs(xc, ncmd, vcn, vce, tau_ext, has_ext, K, MS, MAL, ML, g6, th, flags, z, k1)
        for i in range(n):
            xs[i] = xc[i] + h2 * k1[i]
        rhs(xs, ncmd, vcn, vce, tau_ext, has_ext, K, MS, MAL, ML, g6, th, flags, z, k2)
        for i in range(n):
            xs[i] = xc[i] + h2 * k2[i]
        rhs(xs, ncmd, vcn, vce, tau_ext, has_ext, K, MS, MAL, ML, g6, th, flags, z, k3)
        for i in range(n):
            xs[i] = xc[i] + dt * k3[i]
        rhs(xs, ncmd, vcn, vce, tau_ext, has_ext, K, MS, MAL, ML, g6, th, flags, z, k4)
        for i in range(n):
            xc[i] = xc[i] + h6 * (k1[i] + k4[i] + 2.0 * (k2[i] + k3[i]))
        for j in range(angle_index.shape[0]):
            i = angle_index[j]
            xc[i] = wrap(xc[i])
