"""Compiled allocation steps (``components/allocation.py``): the pseudo-inverse with clipping,
the inverse thrust law, the allocator's outputs, and the QP's per-call bounds.

``pinv_clip``: T = P (tau - tau_fixed) + T_fixed, clipped into [lo, hi], saturation flags
(``AllocatorBlock.pseudo_inverse`` without the camera re-weighting, which stays in Python: it
needs other allocation matrices). ``speed_from_thrust``: ``thrusters.thrust_to_speed``.
``outputs``: n, T, tau_alloc = B T, ||B T - tau||, sat, T^T T as ``AllocatorBlock.step`` lays
them out. ``qp_bounds``: the bounds DAQP gets per call (thrust box, equality rows = tau).
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel
from .thrust_law import speed_of


@kernel
def pinv_clip(
    P: np.ndarray,
    tau: np.ndarray,
    tau_fixed: np.ndarray,
    T_fixed: np.ndarray,
    any_off: bool,
    lo: np.ndarray,
    hi: np.ndarray,
    T: np.ndarray,
    Tc: np.ndarray,
    sat: np.ndarray,
) -> None:
    """Unclipped T, clipped Tc and sat = (Tc != T) (a bool array) into the given arrays."""
    m, d = P.shape
    tt = np.empty(d)
    for j in range(d):
        tt[j] = tau[j] - tau_fixed[j] if any_off else tau[j]
    for i in range(m):
        s = 0.0
        for j in range(d):
            s += P[i, j] * tt[j]
        if any_off:
            s = s + T_fixed[i]
        T[i] = s
        c = min(max(s, lo[i]), hi[i])
        Tc[i] = c
        sat[i] = c != s


@kernel
def speed_from_thrust(
    T: np.ndarray, th: np.ndarray, law: int, n_max: np.ndarray, out: np.ndarray
) -> None:
    """The inverse thrust law (``thrust_law.speed_of``), k by the sign of T, clipped to +-n_max."""
    for i in range(T.shape[0]):
        t = T[i]
        n = speed_of(th[0, i] if t >= 0.0 else th[1, i], t, law)
        out[i] = min(max(n, -n_max[i]), n_max[i])


@kernel
def outputs(
    T: np.ndarray,
    tau: np.ndarray,
    B: np.ndarray,
    th: np.ndarray,
    law: int,
    n_max: np.ndarray,
    off: np.ndarray,
    any_off: bool,
    sat: np.ndarray,
    y: np.ndarray,
    pos: np.ndarray,
) -> None:
    """The allocator's outputs into y at the positions ``pos`` = (first n_cmd, first thrust_cmd,
    first tau_alloc, alloc_error, first sat, thrust_energy): n (0 for a thruster that is off), T,
    tau_alloc = B T, ||tau_alloc - tau||, sat, T^T T (``AllocatorBlock.step``)."""
    d, m = B.shape
    n = np.empty(m)
    speed_from_thrust(T, th, law, n_max, n)
    n0, t0, a0, e0, s0, w0 = pos[0], pos[1], pos[2], pos[3], pos[4], pos[5]
    for i in range(m):
        y[n0 + i] = 0.0 if (any_off and off[i]) else n[i]
        y[t0 + i] = T[i]
        y[s0 + i] = 1.0 if sat[i] else 0.0
    ss = 0.0
    for j in range(d):
        s = 0.0
        for i in range(m):
            s += B[j, i] * T[i]
        y[a0 + j] = s
        e = s - tau[j]
        ss += e * e
    y[e0] = math.sqrt(ss)
    e2 = 0.0
    for i in range(m):
        e2 += T[i] * T[i]
    y[w0] = e2


@kernel
def qp_bounds(
    bu: np.ndarray, bl: np.ndarray, lo: np.ndarray, hi: np.ndarray, tau: np.ndarray, n: int
) -> None:
    """DAQP's bounds for one call: lo <= T <= hi and the equality rows B T - s+ + s- = tau."""
    m = lo.shape[0]
    for i in range(m):
        bu[i] = hi[i]
        bl[i] = lo[i]
    for j in range(tau.shape[0]):
        bu[n + j] = tau[j]
        bl[n + j] = tau[j]


@kernel
def qp_result(
    x: np.ndarray, lo: np.ndarray, hi: np.ndarray, off: np.ndarray, tol: float, T: np.ndarray, sat: np.ndarray
) -> None:
    """T = x[:m] clipped into [lo, hi]; sat (bool) where T is at a bound (within tol) on a working
    thruster."""
    for i in range(T.shape[0]):
        t = min(max(x[i], lo[i]), hi[i])
        T[i] = t
        sat[i] = ((t <= lo[i] + tol) or (t >= hi[i] - tol)) and not off[i]


@kernel
def pinv_step(
    u: np.ndarray,
    tau_idx: np.ndarray,
    P: np.ndarray,
    tau_fixed: np.ndarray,
    T_fixed: np.ndarray,
    any_off: bool,
    lo: np.ndarray,
    hi: np.ndarray,
    B: np.ndarray,
    th: np.ndarray,
    law: int,
    n_max: np.ndarray,
    off: np.ndarray,
    camera: np.ndarray,
    y: np.ndarray,
    pos: np.ndarray,
    front: int,
    iterations: int,
    Tc: np.ndarray,
) -> bool:
    """The whole ``pinv`` allocator step: False (nothing written) if an input is not finite; else
    ``pinv_clip`` of tau = u[tau_idx], ``outputs``, the camera thrusters' negative thrust at y[front]
    (summed in camera order) and 0 QP iterations at y[iterations]; the clipped thrusts into Tc."""
    for i in range(u.shape[0]):
        if not math.isfinite(u[i]):
            return False
    d, m = B.shape
    tau = np.empty(d)
    for j in range(d):
        tau[j] = u[tau_idx[j]]
    T = np.empty(m)
    sat = np.empty(m, dtype=np.bool_)
    pinv_clip(P, tau, tau_fixed, T_fixed, any_off, lo, hi, T, Tc, sat)
    outputs(Tc, tau, B, th, law, n_max, off, any_off, sat, y, pos)
    neg = 0.0
    for k in range(camera.shape[0]):
        t = Tc[camera[k]]
        if t < 0.0:
            neg += -t
    y[front] = neg
    y[iterations] = 0.0
    return True
