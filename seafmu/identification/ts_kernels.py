"""Compiled (numba) RK4 loops of the 1st- and 2nd-order time-series models (``timeseries``).

An output-error fit simulates its model a few hundred to a few thousand times; on a 10 000-sample
trial the plain-Python loops took 10 ms per simulation, which made one friction fit 16 s. These
are the same loops, arithmetic in the same order, compiled once (numba's on-disk cache). Only
the named state terms are here: an effect's extra ``state_force`` (a Python callable) takes
``timeseries``' general Python path.
"""

from __future__ import annotations

import math

import numba
import numpy as np

MODE_SMOOTH, MODE_NONE, MODE_EXACT = 0, 1, 2  # friction law of the 1st-order loop


@numba.njit(cache=True, nogil=True)
def _drag(w: float, a: float, b: float, pq: float) -> float:
    """w (a + b |w|^(pq-1)): linear plus (power-law) quadratic damping of the speed w."""
    if pq == 2.0:
        return w * (a + b * abs(w))
    return w * (a + b * abs(w) ** (pq - 1.0))


@numba.njit(cache=True, nogil=True)
def first_rk4(hs: np.ndarray, C1: np.ndarray, C2: np.ndarray, C4: np.ndarray, a: float, b: float,
              pq: float, fm: float, vc: float, ie: float, mode: int, x0: float) -> np.ndarray:
    """M v_dot = tau + F_0 - d_L w - d_Q w|w|^(pq-1) - friction, w = v - v_c, per unit inertia.

    mode: MODE_NONE (no friction), MODE_SMOOTH (f_c tanh(v ie)), MODE_EXACT (sign(v) with stick:
    the body stays stopped while the other forces are below the friction force; test data).
    """
    n = hs.size
    out = np.empty(n + 1)
    x = x0
    out[0] = x
    fs_damp = _drag(vc, a, b, pq)  # damping force at v = 0 (non-zero in a current)
    for i in range(n):
        h, c1, c2, c4 = hs[i], C1[i], C2[i], C4[i]
        if mode == MODE_NONE:
            k1 = c1 - _drag(x - vc, a, b, pq)
            k2 = c2 - _drag(x + 0.5 * h * k1 - vc, a, b, pq)
            k3 = c2 - _drag(x + 0.5 * h * k2 - vc, a, b, pq)
            k4 = c4 - _drag(x + h * k3 - vc, a, b, pq)
            x += h * (k1 + 2.0 * (k2 + k3) + k4) / 6.0
        elif mode == MODE_SMOOTH:
            k1 = c1 - _drag(x - vc, a, b, pq) - fm * math.tanh(x * ie)
            xx = x + 0.5 * h * k1
            k2 = c2 - _drag(xx - vc, a, b, pq) - fm * math.tanh(xx * ie)
            xx = x + 0.5 * h * k2
            k3 = c2 - _drag(xx - vc, a, b, pq) - fm * math.tanh(xx * ie)
            xx = x + h * k3
            k4 = c4 - _drag(xx - vc, a, b, pq) - fm * math.tanh(xx * ie)
            x += h * (k1 + 2.0 * (k2 + k3) + k4) / 6.0
        else:
            k1 = c1 - _drag(x - vc, a, b, pq) - (fm if x > 0 else (-fm if x < 0 else 0.0))
            xx = x + 0.5 * h * k1
            k2 = c2 - _drag(xx - vc, a, b, pq) - (fm if xx > 0 else (-fm if xx < 0 else 0.0))
            xx = x + 0.5 * h * k2
            k3 = c2 - _drag(xx - vc, a, b, pq) - (fm if xx > 0 else (-fm if xx < 0 else 0.0))
            xx = x + h * k3
            k4 = c4 - _drag(xx - vc, a, b, pq) - (fm if xx > 0 else (-fm if xx < 0 else 0.0))
            xn = x + h * (k1 + 2.0 * (k2 + k3) + k4) / 6.0
            if (x == 0.0 or x * xn <= 0.0 or x * (x + h * k1) <= 0.0) and abs(c4 + fs_damp) <= fm:
                xn = 0.0  # stops within this step; friction holds it unless the other forces overcome it
            x = xn
        out[i + 1] = x
    return out


@numba.njit(cache=True, nogil=True)
def _fric(w: float, fm: float, smooth: bool, ie: float) -> float:
    if fm == 0.0:
        return 0.0
    if smooth:
        return fm * math.tanh(w * ie)
    return fm if w > 0 else (-fm if w < 0 else 0.0)


@numba.njit(cache=True, nogil=True)
def second_rk4(hs: np.ndarray, E1: np.ndarray, E2: np.ndarray, E4: np.ndarray, c: float, c3: float,
               a: float, b: float, pq: float, fm: float, sl: bool, smooth: bool, ie: float, x0: float,
               xd0: float) -> np.ndarray:
    """M x_dd = tau + F_0 - c r(x) - c3 x^3 - d_L x_d - d_Q x_d|x_d|^(pq-1) - friction, per unit
    inertia; r = x or sin x. A diverged run gives NaN from there on."""
    n = hs.size
    out = np.empty(n + 1)
    x, xd = x0, xd0
    out[0] = x
    for i in range(n):
        h, e1, e2, e4 = hs[i], E1[i], E2[i], E4[i]
        a1 = e1 - c * (math.sin(x) if sl else x) - c3 * x * x * x - _drag(xd, a, b, pq) - _fric(
            xd, fm, smooth, ie)
        x2, v2 = x + 0.5 * h * xd, xd + 0.5 * h * a1
        a2 = e2 - c * (math.sin(x2) if sl else x2) - c3 * x2 * x2 * x2 - _drag(v2, a, b, pq) - _fric(
            v2, fm, smooth, ie)
        x3, v3 = x + 0.5 * h * v2, xd + 0.5 * h * a2
        a3 = e2 - c * (math.sin(x3) if sl else x3) - c3 * x3 * x3 * x3 - _drag(v3, a, b, pq) - _fric(
            v3, fm, smooth, ie)
        x4, v4 = x + h * v3, xd + h * a3
        a4 = e4 - c * (math.sin(x4) if sl else x4) - c3 * x4 * x4 * x4 - _drag(v4, a, b, pq) - _fric(
            v4, fm, smooth, ie)
        xn = x + h * (xd + 2.0 * (v2 + v3) + v4) / 6.0
        vn = xd + h * (a1 + 2.0 * (a2 + a3) + a4) / 6.0
        if fm > 0.0 and not smooth and (xd == 0.0 or xd * vn <= 0.0 or xd * (xd + h * a1) <= 0.0):
            if abs(e4 - c * (math.sin(xn) if sl else xn) - c3 * xn * xn * xn) <= fm:
                vn = 0.0  # stuck: friction exceeds the restoring force at rest
        x, xd = xn, vn
        out[i + 1] = x
    return out
