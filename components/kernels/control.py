"""Compiled pieces of the DP controller (``components/dp_pid.py``, ``controller.py``,
``reference_model.py``): the reference-model step with exact coefficients, the nonlinear PID
force tau = -J^T (K_p e + K_d (J nu - eta_d_dot) + K_i z), and saturation with conditional
integration (anti-windup). Same operations in the same order as the NumPy code; only the
matrix-vector products are summed left to right.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel

_PI = math.pi
_TWO_PI = 2.0 * math.pi


@kernel
def jacobian(eta: np.ndarray, Jm: np.ndarray) -> None:
    """J(eta) into Jm: R(psi) for 3 DOF, diag(R(Theta), T(Theta)) for 6 DOF (``dynamics.J``)."""
    d = eta.shape[0]
    Jm[:, :] = 0.0
    if d == 3:
        c, s = math.cos(eta[2]), math.sin(eta[2])
        Jm[0, 0], Jm[0, 1] = c, -s
        Jm[1, 0], Jm[1, 1] = s, c
        Jm[2, 2] = 1.0
        return
    phi, theta, psi = eta[3], eta[4], eta[5]
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    Jm[0, 0], Jm[0, 1], Jm[0, 2] = (
        cpsi * cth,
        -spsi * cphi + cpsi * sth * sphi,
        spsi * sphi + cpsi * cphi * sth,
    )
    Jm[1, 0], Jm[1, 1], Jm[1, 2] = (
        spsi * cth,
        cpsi * cphi + sphi * sth * spsi,
        -cpsi * sphi + sth * spsi * cphi,
    )
    Jm[2, 0], Jm[2, 1], Jm[2, 2] = -sth, cth * sphi, cth * cphi
    Jm[3, 3], Jm[3, 4], Jm[3, 5] = 1.0, sphi * sth / cth, cphi * sth / cth
    Jm[4, 4], Jm[4, 5] = cphi, -sphi
    Jm[5, 4], Jm[5, 5] = sphi / cth, cphi / cth


@kernel
def eta_rate(eta: np.ndarray, nu: np.ndarray, Jm: np.ndarray, eta_dot: np.ndarray) -> None:
    """J(eta) into Jm and eta_dot = J(eta) nu (summed as in ``pid_force``)."""
    d = eta.shape[0]
    jacobian(eta, Jm)
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += Jm[i, j] * nu[j]
        eta_dot[i] = s


@kernel
def reference_step(
    x: np.ndarray,
    v: np.ndarray,
    x_ref: np.ndarray,
    coef: np.ndarray,
    w2: np.ndarray,
    two_zw: np.ndarray,
    angle: np.ndarray,
    x_out: np.ndarray,
    v_out: np.ndarray,
    a_out: np.ndarray,
) -> None:
    """One exact step of the unlimited second-order reference model (``ReferenceModel.step``).

    coef rows p11, p12, p21, p22: e = p11 e0 + p12 v, v = p21 e0 + p22 v with e0 = x - x_ref
    (angles wrapped); x moves by e - e0 (wrapped again), a = -w^2 e - 2 zeta w v.
    """
    for i in range(x.shape[0]):
        e0 = x[i] - x_ref[i]
        if angle[i]:
            e0 = (e0 + _PI) % _TWO_PI - _PI
        e = coef[0, i] * e0 + coef[1, i] * v[i]
        vn = coef[2, i] * e0 + coef[3, i] * v[i]
        xn = x[i] + (e - e0)
        if angle[i]:
            xn = (xn + _PI) % _TWO_PI - _PI
        x_out[i] = xn
        v_out[i] = vn
        a_out[i] = -w2[i] * e - two_zw[i] * vn


@kernel
def pid_force(
    eta: np.ndarray,
    nu: np.ndarray,
    eta_d: np.ndarray,
    eta_d_dot: np.ndarray,
    z: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    ki: np.ndarray,
    angle: np.ndarray,
    Jm: np.ndarray,
    eta_dot: np.ndarray,
    e: np.ndarray,
    tau: np.ndarray,
) -> None:
    """J(eta), eta_dot = J nu, e = eta - eta_d (angles wrapped) and tau = -J^T (Kp e + Kd edot + Ki z)."""
    d = eta.shape[0]
    eta_rate(eta, nu, Jm, eta_dot)
    pid = np.empty(d)
    for i in range(d):
        ei = eta[i] - eta_d[i]
        if angle[i]:
            ei = (ei + _PI) % _TWO_PI - _PI
        e[i] = ei
        pid[i] = kp[i] * ei + kd[i] * (eta_dot[i] - eta_d_dot[i]) + ki[i] * z[i]
    for j in range(d):
        s = 0.0
        for i in range(d):
            s += Jm[i, j] * pid[i]
        tau[j] = -s


@kernel
def saturate_integrate(
    h: float,
    e: np.ndarray,
    tau_unsat: np.ndarray,
    tau_max: np.ndarray,
    ki: np.ndarray,
    z: np.ndarray,
    z_max: np.ndarray,
    Jm: np.ndarray,
    tau: np.ndarray,
) -> None:
    """tau = clip(tau_unsat, +-tau_max) into ``tau``, the integral z updated in place
    (``ControllerBlock._integrate``: a saturated body DOF blocks the error components coupled
    to it, |J^T| > 0.1, unless the increment unwinds the integral; then z is clamped to z_max)."""
    d = e.shape[0]
    any_over = False
    over = np.empty(d)
    for j in range(d):
        t = min(max(tau_unsat[j], -tau_max[j]), tau_max[j])
        tau[j] = t
        over[j] = tau_unsat[j] - t
        if over[j] != 0.0:
            any_over = True
    dz = np.empty(d)
    for i in range(d):
        dz[i] = h * e[i]
    if any_over:
        blocked = np.zeros(d, dtype=np.bool_)
        for j in range(d):  # body DOF j = row j of J^T = column j of J
            if over[j] == 0.0 or not tau_max[j] > 0.0:
                continue
            sig = 1.0 if over[j] > 0.0 else -1.0
            for i in range(d):
                c = Jm[i, j]
                effect = -(c * (ki[i] * dz[i])) * sig
                current = -(c * (ki[i] * z[i])) * sig
                unwinding = effect < 0.0 and current > 0.0
                if abs(c) > 0.1 and not unwinding:
                    blocked[i] = True
        for i in range(d):
            if blocked[i]:
                dz[i] = 0.0
    for i in range(d):
        zi = z[i] + dz[i]
        z[i] = min(max(zi, -z_max[i]), z_max[i])


@kernel
def dp_step(
    h: float,
    eta: np.ndarray,
    nu: np.ndarray,
    eta_ref: np.ndarray,
    ref_x: np.ndarray,
    ref_v: np.ndarray,
    coef: np.ndarray,
    w2: np.ndarray,
    two_zw: np.ndarray,
    ref_angle: np.ndarray,
    x_out: np.ndarray,
    v_out: np.ndarray,
    a_out: np.ndarray,
    z: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    ki: np.ndarray,
    angle: np.ndarray,
    tau_max: np.ndarray,
    z_max: np.ndarray,
    tau: np.ndarray,
) -> None:
    """One DP step with every DOF held: ``reference_step``, ``pid_force`` on its output, then
    ``saturate_integrate`` (z in place, tau out), in one call (the controller's usual step)."""
    reference_step(ref_x, ref_v, eta_ref, coef, w2, two_zw, ref_angle, x_out, v_out, a_out)
    d = eta.shape[0]
    Jm = np.empty((d, d))
    eta_dot = np.empty(d)
    e = np.empty(d)
    tau_new = np.empty(d)
    pid_force(eta, nu, x_out, v_out, z, kp, kd, ki, angle, Jm, eta_dot, e, tau_new)
    saturate_integrate(h, e, tau_new, tau_max, ki, z, z_max, Jm, tau)


@kernel
def dp_block_step(
    u: np.ndarray,
    in_eta: np.ndarray,
    in_nu: np.ndarray,
    in_ref: np.ndarray,
    h: float,
    ref_x: np.ndarray,
    ref_v: np.ndarray,
    coef: np.ndarray,
    w2: np.ndarray,
    two_zw: np.ndarray,
    ref_angle: np.ndarray,
    x_out: np.ndarray,
    v_out: np.ndarray,
    a_out: np.ndarray,
    z: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    ki: np.ndarray,
    angle: np.ndarray,
    tau_max: np.ndarray,
    z_max: np.ndarray,
    ref_seen: np.ndarray,
    o_tau: np.ndarray,
    o_eta_d: np.ndarray,
    y: np.ndarray,
) -> bool:
    """``dp_step`` from the controller's input vector to its output vector (``DPPidController.step``
    with every DOF held): False, with nothing changed, if an input is not finite; else eta, nu
    and eta_ref gathered from u, the step, eta_ref into ``ref_seen``, tau and eta_d into y."""
    for i in range(u.shape[0]):
        if not math.isfinite(u[i]):
            return False
    d = in_eta.shape[0]
    eta, nu, eta_ref = np.empty(d), np.empty(in_nu.shape[0]), np.empty(d)
    for i in range(d):
        eta[i] = u[in_eta[i]]
        eta_ref[i] = u[in_ref[i]]
        ref_seen[i] = eta_ref[i]
    for i in range(in_nu.shape[0]):
        nu[i] = u[in_nu[i]]
    tau = np.empty(o_tau.shape[0])
    dp_step(h, eta, nu, eta_ref, ref_x, ref_v, coef, w2, two_zw, ref_angle, x_out, v_out, a_out, z, kp, kd,
            ki, angle, tau_max, z_max, tau)
    for i in range(o_tau.shape[0]):
        y[o_tau[i]] = tau[i]
    for i in range(d):
        y[o_eta_d[i]] = x_out[i]
    return True
