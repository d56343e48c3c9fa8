"""Compiled EKF of the observer (``components/observer.py``): model and Jacobian, prediction,
measurement updates without an explicit inverse.

Model, Jacobian and prediction are ``ObserverBlock._model/_kin3/_kin6/predict`` in scalars and
loops (same order of operations; matrix products through BLAS). The update solves with the
Cholesky factor of the innovation covariance S = H P H^T + R (tiny: one sensor's 1-6 channels)
instead of forming S^-1: the gain K = P H^T S^-1 from triangular solves, the NIS y^T S^-1 y as
|L^-1 y|^2. Joseph form kept: P = (I - KH) P (I - KH)^T + K R K^T, symmetrised. An S that is not
positive definite (it cannot be unless P went bad) falls back to an LU solve.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel
from .rigid_body import wrap

_PI = math.pi
_TWO_PI = 2.0 * math.pi


@kernel
def kin3(x: np.ndarray, A: np.ndarray, f: np.ndarray) -> None:
    """eta_dot into f[:3]; d(eta_dot)/d eta and J into A (``ObserverBlock._kin3``)."""
    psi, u, v, r = x[2], x[3], x[4], x[5]
    c, s = math.cos(psi), math.sin(psi)
    A[0, 2], A[0, 3], A[0, 4], A[0, 5] = -s * u - c * v, c, -s, 0.0
    A[1, 2], A[1, 3], A[1, 4], A[1, 5] = c * u - s * v, s, c, 0.0
    A[2, 2], A[2, 3], A[2, 4], A[2, 5] = 0.0, 0.0, 0.0, 1.0
    f[0], f[1], f[2] = c * u - s * v, s * u + c * v, r


@kernel
def kin6(
    x: np.ndarray, A: np.ndarray, f: np.ndarray, g6: np.ndarray, Minv: np.ndarray, g: np.ndarray
) -> None:
    """eta_dot into f[:6], restoring g; d(eta_dot)/d Theta, J and -M^-1 dg/d(phi, theta) into A."""
    phi, th, psi = x[3], x[4], x[5]
    u, v, w, p, q, r = x[6], x[7], x[8], x[9], x[10], x[11]
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(th), math.sin(th)
    cp, sp = math.cos(psi), math.sin(psi)
    tt = st / ct
    R11, R12, R13 = cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st
    R21, R22, R23 = sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf
    R31, R32, R33 = -st, ct * sf, ct * cf
    pn = R11 * u + R12 * v + R13 * w
    pe = R21 * u + R22 * v + R23 * w
    pd = R31 * u + R32 * v + R33 * w
    qs = q * sf + r * cf
    qc = q * cf - r * sf
    c3 = sf * v + cf * w
    a1, a3 = ct * u + st * c3, -st * u + ct * c3
    ct2 = ct * ct
    rows = (
        (-R12 * w + R13 * v, cp * a3, -pe, R11, R12, R13, 0.0, 0.0, 0.0),
        (-R22 * w + R23 * v, sp * a3, pn, R21, R22, R23, 0.0, 0.0, 0.0),
        (-R32 * w + R33 * v, -a1, 0.0, R31, R32, R33, 0.0, 0.0, 0.0),
        (qc * tt, qs / ct2, 0.0, 0.0, 0.0, 0.0, 1.0, sf * tt, cf * tt),
        (-qs, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, cf, -sf),
        (qc / ct, qs * st / ct2, 0.0, 0.0, 0.0, 0.0, 0.0, sf / ct, cf / ct),
    )
    for i in range(6):
        row = rows[i]
        for j in range(9):
            A[i, 3 + j] = row[j]
    wb, gx, gy, gz = g6[0], g6[1], g6[2], g6[3]
    g[0], g[1], g[2] = wb * st, -wb * ct * sf, -wb * ct * cf
    g[3] = -gy * ct * cf + gz * ct * sf
    g[4] = gz * st + gx * ct * cf
    g[5] = -gx * ct * sf - gy * st
    d0 = (0.0, -wb * ct * cf, wb * ct * sf, gy * ct * sf + gz * ct * cf, -gx * ct * sf, -gx * ct * cf)
    d1 = (
        wb * ct,
        wb * st * sf,
        wb * st * cf,
        gy * st * cf - gz * st * sf,
        gz * ct - gx * st * cf,
        gx * st * sf - gy * ct,
    )
    for i in range(6):
        s0 = 0.0
        s1 = 0.0
        for k in range(6):
            s0 += Minv[i, k] * d0[k]
            s1 += Minv[i, k] * d1[k]
        A[6 + i, 3] = -s0
        A[6 + i, 4] = -s1
    f[0], f[1], f[2] = pn, pe, pd
    f[3], f[4], f[5] = p + qs * tt, qc, qs / ct


@kernel
def model(
    x: np.ndarray,
    tau: np.ndarray,
    d: int,
    nw: int,
    inv_tb: float,
    Minv: np.ndarray,
    MinvG: np.ndarray,
    MinvDL: np.ndarray,
    MinvDQ: np.ndarray,
    g6: np.ndarray,
    Aw: np.ndarray,
    A: np.ndarray,
    f: np.ndarray,
) -> None:
    """f(x) into ``f`` and A = df/dx into ``A`` (its constant parts set by the caller): ``_model``.

    S(nu) = M^-1 (G(nu) + D_Q diag(2|nu|)), A_nu,nu = -(S + M^-1 D_L),
    nu_dot = M^-1 (tau + b - g) - (S/2 + M^-1 D_L) nu.
    """
    force = np.empty(d)
    if d == 6:
        g = np.empty(6)
        kin6(x, A, f, g6, Minv, g)
        for i in range(6):
            force[i] = tau[i] + x[12 + i] - g[i]
    else:
        kin3(x, A, f)
        for i in range(3):
            force[i] = tau[i] + x[6 + i]
    for i in range(d):
        fm = 0.0
        for k in range(d):
            fm += Minv[i, k] * force[k]
        acc = 0.0
        for j in range(d):
            s = 0.0
            for k in range(d):
                s += MinvG[i, j, k] * x[d + k]
            s = s + MinvDQ[i, j] * (2.0 * abs(x[d + j]))
            A[d + i, d + j] = -(s + MinvDL[i, j])
            acc += (0.5 * s + MinvDL[i, j]) * x[d + j]
        f[d + i] = fm - acc
    for i in range(d):
        f[2 * d + i] = -inv_tb * x[2 * d + i]
    nn = 2 * nw
    for i in range(nn):
        s = 0.0
        for k in range(nn):
            s += Aw[i, k] * x[3 * d + k]
        f[3 * d + i] = s


@kernel
def predict(
    x: np.ndarray,
    P: np.ndarray,
    tau: np.ndarray,
    k: int,
    dt: float,
    Qc: np.ndarray,
    d: int,
    nw: int,
    inv_tb: float,
    Minv: np.ndarray,
    MinvG: np.ndarray,
    MinvDL: np.ndarray,
    MinvDQ: np.ndarray,
    g6: np.ndarray,
    Aw: np.ndarray,
    A: np.ndarray,
    angle_index: np.ndarray,
) -> None:
    """k prediction sub-steps of dt (x and P in place, A updated; ``ObserverBlock.predict``).

    x+ = x + dt (f + dt A f / 2), Phi = I + dt A + (dt A)^2 / 2, P+ = Phi P Phi^T + Q dt.
    """
    n = x.shape[0]
    f = np.empty(n)
    for _ in range(k):
        model(x, tau, d, nw, inv_tb, Minv, MinvG, MinvDL, MinvDQ, g6, Aw, A, f)
        hA = dt * A
        hAf = hA @ f
        for i in range(n):
            x[i] += dt * (f[i] + 0.5 * hAf[i])
        Phi = hA @ hA
        for i in range(n):
            for j in range(n):
                Phi[i, j] = Phi[i, j] * 0.5 + hA[i, j]
            Phi[i, i] += 1.0
        Pn = (Phi @ P) @ Phi.T
        for i in range(n):
            Pn[i, i] += Qc[i] * dt
        P[:, :] = Pn
    for j in range(angle_index.shape[0]):
        i = angle_index[j]
        x[i] = wrap(x[i])


@kernel
def _cholesky(S: np.ndarray) -> tuple[np.ndarray, bool]:
    """Lower factor L of S = L L^T; False when S is not positive definite."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return L, False
        ljj = math.sqrt(s)
        L[j, j] = ljj
        for i in range(j + 1, m):
            t = S[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / ljj
    return L, True


@kernel
def _gain_and_nis(PHt: np.ndarray, S: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """K = P H^T S^-1 and NIS = y^T S^-1 y by solving with S (Cholesky; LU if not PD)."""
    n, m = PHt.shape
    L, ok = _cholesky(S)
    if not ok:
        K = np.linalg.solve(S, np.ascontiguousarray(PHt.T)).T.copy()  # S symmetric
        sy = np.linalg.solve(S, y)
        nis = 0.0
        for i in range(m):
            nis += y[i] * sy[i]
        return K, nis
    # w = L^-1 y, NIS = |w|^2
    w = np.empty(m)
    for i in range(m):
        t = y[i]
        for k in range(i):
            t -= L[i, k] * w[k]
        w[i] = t / L[i, i]
    nis = 0.0
    for i in range(m):
        nis += w[i] * w[i]
    # rows of K: S k = (P H^T)[r, :] (S symmetric), forward then back substitution
    K = np.empty((n, m))
    b = np.empty(m)
    for r in range(n):
        for i in range(m):
            t = PHt[r, i]
            for k in range(i):
                t -= L[i, k] * b[k]
            b[i] = t / L[i, i]
        for i in range(m - 1, -1, -1):
            t = b[i]
            for k in range(i + 1, m):
                t -= L[k, i] * K[r, k]
            K[r, i] = t / L[i, i]
    return K, nis


@kernel
def innovation(z: np.ndarray, x: np.ndarray, idx: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """y = z - H x for a selection H; angle channels wrapped as (y + pi) mod 2 pi - pi."""
    m = idx.shape[0]
    y = np.empty(m)
    for i in range(m):
        y[i] = z[i] - x[idx[i]]
        if angle[i]:
            y[i] = (y[i] + _PI) % _TWO_PI - _PI
    return y


@kernel
def update_selection(
    x: np.ndarray,
    P: np.ndarray,
    idx: np.ndarray,
    y: np.ndarray,
    var: np.ndarray,
    threshold: float,
    angle_index: np.ndarray,
) -> tuple[bool, float]:
    """Update with channels that measure states ``idx`` directly (H = selection), Joseph form.

    Rejected (no change) when the NIS exceeds ``threshold`` (inf: no gate). Returns
    (accepted, NIS); x and P are updated in place (no array to box on return).
    """
    n = x.shape[0]
    m = idx.shape[0]
    PHt = np.empty((n, m))
    for r in range(n):
        for i in range(m):
            PHt[r, i] = P[r, idx[i]]
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            S[i, j] = PHt[idx[i], j]
        S[i, i] += var[i]
    K, nis = _gain_and_nis(PHt, S, y)
    if nis > threshold:
        return False, nis
    for r in range(n):
        s = 0.0
        for i in range(m):
            s += K[r, i] * y[i]
        x[r] += s
    # (I - KH) P = P - K (H P); Pn = A1 - (A1 H^T) K^T + (K R) K^T, fused (m is 1-6). Each entry's
    # sum over the m channels runs in channel order starting from 0.0; the loops run over a whole
    # row at once (independent entries side by side, which the compiler can vectorise).
    KT = np.empty((m, n))
    for r in range(n):
        for i in range(m):
            KT[i, r] = K[r, i]
    A1 = np.zeros((n, n))
    for r in range(n):
        for i in range(m):
            kri = K[r, i]
            pi = idx[i]
            for c in range(n):
                A1[r, c] += kri * P[pi, c]
        for c in range(n):
            A1[r, c] = P[r, c] - A1[r, c]
    Pn = np.empty((n, n))
    t1 = np.empty(n)
    t2 = np.empty(n)
    for r in range(n):
        for c in range(n):
            t1[c] = 0.0
            t2[c] = 0.0
        for i in range(m):
            a = A1[r, idx[i]]
            kr = K[r, i] * var[i]
            for c in range(n):
                kc = KT[i, c]
                t1[c] += a * kc
                t2[c] += kr * kc
        for c in range(n):
            Pn[r, c] = A1[r, c] - t1[c] + t2[c]
    for i in range(n):
        for j in range(n):
            P[i, j] = (Pn[i, j] + Pn[j, i]) * 0.5
    for j in range(angle_index.shape[0]):
        i = angle_index[j]
        x[i] = wrap(x[i])
    return True, nis


@kernel
def update_general(
    x: np.ndarray,
    P: np.ndarray,
    H: np.ndarray,
    y: np.ndarray,
    var: np.ndarray,
    threshold: float,
    angle_index: np.ndarray,
) -> tuple[bool, float]:
    """Update with a general H (the wave filter's sensors), Joseph form; as ``update_selection``."""
    n = x.shape[0]
    m = H.shape[0]
    PHt = P @ H.T
    S = H @ PHt
    for i in range(m):
        S[i, i] += var[i]
    K, nis = _gain_and_nis(np.ascontiguousarray(PHt), S, y)
    if nis > threshold:
        return False, nis
    x += K @ y
    IKH = -(K @ H)
    for i in range(n):
        IKH[i, i] += 1.0
    Pn = (IKH @ P) @ IKH.T + (K * var) @ K.T
    for i in range(n):
        for j in range(n):
            P[i, j] = (Pn[i, j] + Pn[j, i]) * 0.5
    for j in range(angle_index.shape[0]):
        i = angle_index[j]
        x[i] = wrap(x[i])
    return True, nis


@kernel
def update_measured(
    x: np.ndarray,
    P: np.ndarray,
    idx: np.ndarray,
    z: np.ndarray,
    angle: np.ndarray,
    var0: np.ndarray,
    r_scale: float,
    threshold: float,
    angle_index: np.ndarray,
) -> tuple[bool, float]:
    """``innovation`` and ``update_selection`` in one call, with R = r_scale * var0 (one sensor)."""
    y = innovation(z, x, idx, angle)
    var = var0 * r_scale
    return update_selection(x, P, idx, y, var, threshold, angle_index)


POS_ACCEPTED = 1  # step's flags: a position fix was accepted
REJECTED = 2  # the update of sensor (result >> 2) was rejected by its gate (Python counts it)


@kernel
def step(
    u: np.ndarray,
    x: np.ndarray,
    P: np.ndarray,
    tau_in: np.ndarray,
    k: int,
    dt: float,
    Qc: np.ndarray,
    d: int,
    nw: int,
    inv_tb: float,
    Minv: np.ndarray,
    MinvG: np.ndarray,
    MinvDL: np.ndarray,
    MinvDQ: np.ndarray,
    g6: np.ndarray,
    Aw: np.ndarray,
    A: np.ndarray,
    angle_index: np.ndarray,
    sens: np.ndarray,
    sens_var: np.ndarray,
    thr: np.ndarray,
    r_scale: float,
    last_count: np.ndarray,
    all_initialised: bool,
    layout: np.ndarray,
    y: np.ndarray,
) -> int:
    """The observer's step (``ObserverBlock.step``): input check, ``predict`` with tau = u[tau_in],
    then ``update_measured`` for every sensor whose count input moved, in order, and the outputs
    that depend on x and P into y (``layout``: 3 dof state estimates, position_std, the wave
    displacements).

    ``sens`` row i: count input, channels m, flags (1 position fix, 2 wave-filter sensor, 4 measures
    position/attitude), then the m measurement inputs, the m state indices, the m angle flags (each
    group padded to the widest sensor); ``sens_var`` its noise variances, ``thr`` its gate. Stops
    at a sensor that needs the Python path (a first fix, the wave filter's general H) or that its
    gate rejected, and returns ``(i << 2) | flags`` (i = number of sensors when all were done;
    flags POS_ACCEPTED, REJECTED); -1 for a non-finite input (nothing changed).
    """
    # Long because it is the observer's whole step (check, prediction, the sensors' loop, the
    # outputs) in one call: the point is to leave nothing of it to Python.
    for i in range(u.shape[0]):
        if not math.isfinite(u[i]):
            return -1
    tau = np.empty(tau_in.shape[0])
    for i in range(tau_in.shape[0]):
        tau[i] = u[tau_in[i]]
    predict(x, P, tau, k, dt, Qc, d, nw, inv_tb, Minv, MinvG, MinvDL, MinvDQ, g6, Aw, A, angle_index)
    S = sens.shape[0]
    W = (sens.shape[1] - 3) // 3
    flags = 0
    done = S
    for s in range(S):
        c = u[sens[s, 0]]
        if c == last_count[s]:
            continue
        m, kind = sens[s, 1], sens[s, 2]
        if (kind & 4 and not all_initialised) or (kind & 2 and nw > 0):
            done = s  # Python: first fix, wave filter
            break
        last_count[s] = c
        z = np.empty(m)
        idx = np.empty(m, dtype=np.int64)
        angle = np.empty(m, dtype=np.bool_)
        for j in range(m):
            z[j] = u[sens[s, 3 + j]]
            idx[j] = sens[s, 3 + W + j]
            angle[j] = sens[s, 3 + 2 * W + j] != 0
        ok, _ = update_measured(x, P, idx, z, angle, sens_var[s, :m].copy(), r_scale, thr[s], angle_index)
        if not ok:
            flags |= REJECTED
            done = s
            break
        if kind & 1:
            flags |= POS_ACCEPTED
    n3 = 3 * d
    for i in range(n3):
        y[layout[i]] = x[i]
    y[layout[n3]] = math.sqrt(P[0, 0] + P[1, 1])
    for j in range(layout.shape[0] - n3 - 1):
        y[layout[n3 + 1 + j]] = x[n3 + j] if nw else 0.0
    return (done << 2) | flags
