"""Kinematics in Fossen's (SNAME) notation: rotations, J(eta), skew matrices, Coriolis from mass.

Written by hand on purpose: these are a dozen lines of textbook formulas (Fossen 2011, ch. 2 and 3)
and the hot path of every RK4 stage; a dependency would add call overhead and nothing else.
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Map to (-pi, pi]; angles already in range come back bit-identical."""
    arr = np.asarray(a, dtype=float)
    inside = (arr > -np.pi) & (arr <= np.pi)
    w = np.mod(arr + np.pi, 2.0 * np.pi) - np.pi
    w = np.where(w == -np.pi, np.pi, w)
    w = np.where(inside, arr, w)
    return float(w) if np.ndim(w) == 0 else w


def smtrx(a: np.ndarray) -> np.ndarray:
    """S(a) with S(a) b = a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def rzyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body-to-NED rotation (zyx convention)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth],
            [spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi],
            [-sth, cth * sphi, cth * cphi],
        ]
    )


def tzyx(phi: float, theta: float) -> np.ndarray:
    """Angular velocity transformation; singular at theta = +-90 deg (never reached by these vessels)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    return np.array(
        [[1.0, sphi * sth / cth, cphi * sth / cth], [0.0, cphi, -sphi], [0.0, sphi / cth, cphi / cth]]
    )


def rot2(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s], [s, c]])


def J(eta: np.ndarray) -> np.ndarray:
    """eta_dot = J(eta) nu, for 3-DOF (north, east, yaw) or 6-DOF eta."""
    if len(eta) == 3:
        c, s = math.cos(eta[2]), math.sin(eta[2])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = np.zeros((6, 6))
    out[:3, :3] = rzyx(eta[3], eta[4], eta[5])
    out[3:, 3:] = tzyx(eta[3], eta[4])
    return out


def m2c(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Coriolis-centripetal matrix C(nu) of a mass matrix M (Fossen 2011, eq. 3.46 / m2c.m).

    Uses the symmetric part of M so the result is skew-symmetric (C + C^T = 0): the property that
    makes C do no work, which the energy tests rely on.
    """
    M = 0.5 * (M + M.T)
    if len(nu) == 6:
        M11, M12, M21, M22 = M[:3, :3], M[:3, 3:], M[3:, :3], M[3:, 3:]
        nu1, nu2 = nu[:3], nu[3:]
        a = M11 @ nu1 + M12 @ nu2
        b = M21 @ nu1 + M22 @ nu2
        C = np.zeros((6, 6))
        Sa = smtrx(a)
        C[:3, 3:] = -Sa
        C[3:, :3] = -Sa
        C[3:, 3:] = -smtrx(b)
        return C
    # 3 DOF (u, v, r): the surge/sway/yaw sub-block of the 6-DOF formula (all of M's u, v rows,
    # so off-diagonal surge couplings are not silently dropped).
    u, v, r = nu
    c13 = -(M[1, 0] * u + M[1, 1] * v + M[1, 2] * r)
    c23 = M[0, 0] * u + M[0, 1] * v + M[0, 2] * r
    return np.array([[0.0, 0.0, c13], [0.0, 0.0, c23], [-c13, -c23, 0.0]])
