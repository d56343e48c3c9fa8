"""Compiled first-order wave load (``components/waves.py``): the sum over the regular components
of the undisturbed particle acceleration, rotated into the body and times the load matrix W.
The component sums run left to right (NumPy's dot may group them otherwise).
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel


@kernel
def elevation(
    t: float,
    north: float,
    east: float,
    omega: np.ndarray,
    k: np.ndarray,
    phase: np.ndarray,
    amp: np.ndarray,
    cd: float,
    sd: float,
) -> float:
    """Surface elevation at (north, east) and time t (``WaveField.elevation``)."""
    s = 0.0
    xh = north * cd + east * sd
    for i in range(omega.shape[0]):
        s += amp[i] * math.cos(omega[i] * t - k[i] * xh + phase[i])
    return s


@kernel
def force(
    t: float,
    eta: np.ndarray,
    dof: int,
    omega: np.ndarray,
    k: np.ndarray,
    phase: np.ndarray,
    acc_amp: np.ndarray,
    cd: float,
    sd: float,
    W: np.ndarray,
    out: np.ndarray,
) -> None:
    """Body-frame wave force W a_b at time t for eta (first ``dof`` entries used; ``WaveLoad.force``)."""
    north, east = eta[0], eta[1]
    down = eta[2] if dof == 6 else 0.0
    xh = north * cd + east * sd
    dk = max(down, 0.0)
    ss = 0.0
    sc = 0.0
    for i in range(omega.shape[0]):
        th = omega[i] * t - k[i] * xh + phase[i]
        att = acc_amp[i] * math.exp(-k[i] * dk)
        ss += att * math.sin(th)
        sc += att * math.cos(th)
    ah = -ss
    an, ae, ad = ah * cd, ah * sd, sc
    if dof == 6:
        phi, theta, psi = eta[3], eta[4], eta[5]
        cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
        cp, sp = math.cos(psi), math.sin(psi)
        a0 = cp * ct * an + sp * ct * ae - st * ad
        a1 = (-sp * cf + cp * st * sf) * an + (cp * cf + sf * st * sp) * ae + ct * sf * ad
        a2 = (sp * sf + cp * cf * st) * an + (-cp * sf + st * sp * cf) * ae + ct * cf * ad
        for i in range(6):
            out[i] = W[i, 0] * a0 + W[i, 1] * a1 + W[i, 2] * a2
    else:
        c, s = math.cos(eta[2]), math.sin(eta[2])
        a0 = c * an + s * ae
        a1 = -s * an + c * ae
        for i in range(3):
            out[i] = W[i, 0] * a0 + W[i, 1] * a1
