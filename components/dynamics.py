"""Rigid-body and hydrodynamic building blocks in Fossen's (SNAME) notation, written once.

Every model in seafmu uses these: the plant (``vessel_model``), the observer (EKF model and its
Jacobian), the controller's feed-forward, and (later) identification. Names follow Fossen's MSS
toolbox (Fossen 2021, *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed., ch. 2,
3, 4 and App. A):

- rotations: ``rzyx`` = R(Θ) (body -> NED, zyx convention), ``tzyx`` = T(Θ), ``tzyx_inv`` = T(Θ)⁻¹,
  ``rpsi`` = R(ψ) of the 3-DOF horizontal model, ``J`` = J(η) for 3 or 6 DOF, ``smtrx`` = S(a);
- Coriolis and centripetal forces: ``m2c`` = C(ν) of a mass matrix (C_RB from M_RB, C_A from M_A),
  ``coriolis_force`` = C(ν)ν as cross products, ``coriolis_tensor`` (its Jacobian, for the EKF),
  ``coriolis_kron`` (C(ν)ν = T (ν ⊗ ν), for least squares);
- restoring forces: ``gvect`` = g(η) of weight and buoyancy, ``restoring_coefficients`` and
  ``restoring_force`` (the same with the constants folded, vectorised over samples).

The hot paths (``kernels/rigid_body.py``: ``rhs3``, ``rhs6``; ``kernels/ekf.py``: ``kin3``, ``kin6``)
are compiled scalar code for speed; ``tests/test_dynamics.py`` holds each equal to the matrix form here.

Symmetry: ``m2c`` and ``coriolis_force`` use the symmetric part of M, so C(ν) is skew-symmetric
(C + Cᵀ = 0) and does no work: with an asymmetric inertia matrix there is no conserved mechanical
energy to check a model against (docs/vessels.md, "mass matrices").
"""

from __future__ import annotations

import math

import numpy as np

# -- angles and rotations -----------------------------------------------------------------------


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Map to (-pi, pi]; angles already in range come back bit-identical."""
    arr = np.asarray(a, dtype=float)
    inside = (arr > -np.pi) & (arr <= np.pi)
    w = np.mod(arr + np.pi, 2.0 * np.pi) - np.pi
    w = np.where(w == -np.pi, np.pi, w)
    w = np.where(inside, arr, w)
    return float(w) if np.ndim(w) == 0 else w


def smtrx(a: np.ndarray) -> np.ndarray:
    """S(a) with S(a) b = a x b (Fossen's Smtrx)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def rzyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R(Θ): body-to-NED rotation, zyx convention (Fossen's Rzyx)."""
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
    """T(Θ): Euler-angle rates from body rates; singular at theta = +-90 deg (never reached here)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    return np.array(
        [[1.0, sphi * sth / cth, cphi * sth / cth], [0.0, cphi, -sphi], [0.0, sphi / cth, cphi / cth]]
    )


def tzyx_inv(phi: float, theta: float) -> np.ndarray:
    """T(Θ)⁻¹: body rates from Euler-angle rates (no singularity)."""
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    return np.array([[1.0, 0.0, -sth], [0.0, cphi, cth * sphi], [0.0, -sphi, cth * cphi]])


def rpsi(psi: float) -> np.ndarray:
    """R(ψ): the 3-DOF (north, east, yaw) rotation, η̇ = R(ψ) ν for ν = (u, v, r)."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot2(psi: float) -> np.ndarray:
    """The horizontal 2 x 2 rotation (north, east) from (u, v)."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s], [s, c]])


def J(eta: np.ndarray) -> np.ndarray:
    """η̇ = J(η) ν: R(ψ) for a 3-DOF η = (north, east, yaw), diag(R(Θ), T(Θ)) for 6 DOF (eulerang)."""
    if len(eta) == 3:
        return rpsi(eta[2])
    out = np.zeros((6, 6))
    out[:3, :3] = rzyx(eta[3], eta[4], eta[5])
    out[3:, 3:] = tzyx(eta[3], eta[4])
    return out


# -- Coriolis and centripetal forces ------------------------------------------------------------


def _sym(M: np.ndarray) -> np.ndarray:
    M = np.asarray(M, dtype=float)
    return 0.5 * (M + M.T)


def m2c(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(ν) of a mass matrix M (Fossen 2021, eq. 3.46 / 6.43; MSS m2c): C_RB = m2c(M_RB, ν),
    C_A = m2c(M_A, ν_r).

    Uses the symmetric part of M so the result is skew-symmetric (C + Cᵀ = 0): the property that
    makes C do no work, which the energy tests rely on. 3 DOF (u, v, r) is the surge/sway/yaw
    sub-block of the 6-DOF formula with all of M's u and v rows, so off-diagonal surge couplings
    are not silently dropped (Fossen's 3-DOF shortcut drops M12, M13, M21).
    """
    M = _sym(M)
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
    u, v, r = nu
    c13 = -(M[1, 0] * u + M[1, 1] * v + M[1, 2] * r)
    c23 = M[0, 0] * u + M[0, 1] * v + M[0, 2] * r
    return np.array([[0.0, 0.0, c13], [0.0, 0.0, c23], [-c13, -c23, 0.0]])


def coriolis_force(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(ν)ν = m2c(M, ν) ν as cross products, vectorised over leading axes of ``nu``.

    6 DOF: [ν₂ × a; ν₁ × a + ν₂ × b] with [a; b] = M ν. 3 DOF: [-r a_y, r a_x, u a_y - v a_x] with
    (a_x, a_y) the first two entries of M ν. Several times fewer NumPy calls than the matrix form.
    """
    nu = np.asarray(nu, dtype=float)
    a = np.einsum("...ij,...j->...i", _sym(M), nu)
    if nu.shape[-1] == 6:
        u, v, w, p, q, r = (nu[..., i] for i in range(6))
        a1, a2, a3, b1, b2, b3 = (a[..., i] for i in range(6))
        return np.stack([
            q * a3 - r * a2, r * a1 - p * a3, p * a2 - q * a1,
            v * a3 - w * a2 + q * b3 - r * b2,
            w * a1 - u * a3 + r * b1 - p * b3,
            u * a2 - v * a1 + p * b2 - q * b1,
        ], axis=-1)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    ax, ay = a[..., 0], a[..., 1]
    return np.stack([-r * ay, r * ax, u * ay - v * ax], axis=-1)


def coriolis_tensor(M: np.ndarray) -> np.ndarray:
    """G with G @ ν = ∂(C(ν)ν)/∂ν and C(ν)ν = (G @ ν) @ ν / 2, for C = m2c(M, ·) (EKF Jacobian).

    C(ν)ν = Σ_jk T_ijk ν_j ν_k with T_ijk = C(e_j)_ik (m2c is linear in ν), so the Jacobian is
    Σ_k (T_ilk + T_ikl) ν_k.
    """
    d = M.shape[0]
    T = np.stack([m2c(M, np.eye(d)[j]) for j in range(d)], axis=1)  # T[i, j, k] = C(e_j)[i, k]
    return T + T.transpose(0, 2, 1)


def coriolis_kron(M: np.ndarray) -> np.ndarray:
    """T (d, d²) with C(ν)ν = T (ν ⊗ ν), symmetric in the pair (j, k): for linear least squares."""
    d = M.shape[0]
    G = coriolis_tensor(M)  # G[i, j, k] = T_ijk + T_ikj
    return (0.5 * G).reshape(d, d * d)


# -- restoring forces ---------------------------------------------------------------------------


def gvect(W: float, B: float, theta: float, phi: float, r_g: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """g(η) of weight W and buoyancy B acting at r_g and r_b (Fossen 2021, eq. 4.6; MSS gvect).

    The generalised restoring force on the left-hand side, M ν̇ + ... + g(η) = τ: a heavy vessel
    (W > B) gets g_Z = -(W - B) cos θ cos φ < 0, i.e. it sinks (z down).
    """
    xg, yg, zg = (float(c) for c in r_g)
    xb, yb, zb = (float(c) for c in r_b)
    sth, cth = math.sin(theta), math.cos(theta)
    sphi, cphi = math.sin(phi), math.cos(phi)
    return np.array([
        (W - B) * sth,
        -(W - B) * cth * sphi,
        -(W - B) * cth * cphi,
        -(yg * W - yb * B) * cth * cphi + (zg * W - zb * B) * cth * sphi,
        (zg * W - zb * B) * sth + (xg * W - xb * B) * cth * cphi,
        -(xg * W - xb * B) * cth * sphi - (yg * W - yb * B) * sth,
    ])


def restoring_coefficients(W: float, B: float, r_g: np.ndarray, r_b: np.ndarray) -> tuple[float, ...]:
    """(W - B, g_x, g_y, g_z) with (g_x, g_y, g_z) = W r_g - B r_b: all ``gvect`` needs besides the angles."""
    gx, gy, gz = (W * np.asarray(r_g, dtype=float) - B * np.asarray(r_b, dtype=float)).tolist()
    return (float(W - B), gx, gy, gz)


def restoring_force(coeffs: tuple[float, ...], phi: np.ndarray | float,
                    theta: np.ndarray | float) -> np.ndarray:
    """g(η) from ``restoring_coefficients``, vectorised over samples of (phi, theta)."""
    wb, gx, gy, gz = coeffs
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    return np.stack([
        wb * st, -wb * ct * sp, -wb * ct * cp,
        -gy * ct * cp + gz * ct * sp, gz * st + gx * ct * cp, -gx * ct * sp - gy * st,
    ], axis=-1)


def restoring_stiffness(coeffs: tuple[float, ...] | None, eta_names: list[str]) -> np.ndarray:
    """Diagonal of ∂g/∂η at η = 0 (hydrostatic stiffness): g_z in roll and pitch, 0 elsewhere.

    ``coeffs`` None (no restoring section: a surface vessel in the horizontal plane) gives zeros.
    """
    out = np.zeros(len(eta_names))
    if coeffs is not None:
        for j, name in enumerate(eta_names):
            if name in ("roll", "pitch"):
                out[j] = coeffs[3]
    return out
