"""Vessel dynamics: rigid body, added mass, Coriolis, damping, restoring, and the thruster shafts.

    eta_dot = J(eta) nu
    M nu_dot + C_RB(nu) nu + C_A(nu_r) nu_r + D_L nu_r + D_Q (|nu_r| * nu_r) + g(eta) = B T(n)
    n_dot   = (clip(n_cmd) - n) / T_n,        nu_r = nu - nu_c(eta)

D_L and D_Q are full matrices (not necessarily symmetric). A vessel file with ``coriolis: none``
drops both Coriolis terms (linear low-speed DP models such as the offshore supply vessel's);
``current_inertia: relative`` makes the inertia act on the relative acceleration, M nu_r_dot
(Fossen's DP model M nu_r_dot + D nu_r = tau): with a current constant in NED,
nu_c_dot = -omega x nu_c in the body, so M nu_dot gets the extra force -M [omega x nu_c1; 0].
``restoring`` is only read for 6 DOF.

The state integrated by RK4 is x = [eta, nu, n] (2 dof + m values): the shaft lag lives in the
same integrator so a thruster spinning up inside one co-simulation step is resolved.

Two implementations of the same right-hand side exist on purpose:
- ``rhs`` is the hot path (every RK4 stage of every co-simulation step): Python floats for the
  trigonometry and the cross products, and ONE precomputed 6 x (m + 18) matrix product
  K = M^-1 [B, -I, -D_L, -D_Q] for everything linear, because on vectors this short the cost is
  the number of NumPy calls, not the arithmetic;
- ``derivative`` is the textbook matrix form (``m2c``, ``J``) used by the tests to check ``rhs``.

Mass matrices: the symmetric parts of M_RB and M_A are used everywhere (inertia and Coriolis).
Potential-flow added mass is symmetric in theory; the published Minerva 2 matrix is slightly
asymmetric (panel-code error), and with an asymmetric inertia matrix the Coriolis terms would do
work, so the model would have no conserved mechanical energy to check against.
"""

from __future__ import annotations

import math

import numpy as np

from .dynamics import J, gvect, m2c, restoring_coefficients, rzyx, wrap_angle
from .environment import current_body
from .thrusters import speed_to_thrust, thruster_matrix
from .vessel_spec import ANGLE_NAMES, VesselSpec

_PI = math.pi
_TWO_PI = 2.0 * math.pi


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)


class VesselModel:
    """Dynamics of one vessel (3 or 6 DOF) with its thrusters, precomputed for fast RK4."""

    def __init__(self, spec: VesselSpec) -> None:
        self.spec = spec
        self.dof = dof = spec.dof
        self.m = m = spec.thrusters.count
        self.n_states = 2 * dof + m
        self.M_RB = _sym(spec.M_RB)
        self.M_A = _sym(spec.M_A)
        self.M = self.M_RB + self.M_A
        self.Minv = np.linalg.inv(self.M)
        self.D_L = np.array(spec.D_L, dtype=float)
        self.D_Q = np.array(spec.D_Q, dtype=float)
        self.B = thruster_matrix(spec.thrusters, dof)
        self.angle_index = [i for i, name in enumerate(spec.eta_names) if name in ANGLE_NAMES]
        self.coriolis = spec.coriolis != "none"
        self.relative_inertia = spec.current_inertia == "relative"
        self._M_lin = self.M[:, :3].tolist() if dof == 6 else self.M[:, :2].tolist()  # M times a velocity

        # nu_dot = K @ [T, C+g, nu_r, |nu_r| nu_r]
        self._K = self._k_matrix(self.B)
        self._M_stack = np.vstack([self.M_RB, self.M_A])  # [M_RB nu; M_A nu] in one product
        self._MA_lin = self.M_A[:, :3].tolist()  # M_A times the (linear-only) current
        th = spec.thrusters
        self._kf = th.k_forward.tolist()
        self._kr = th.k_reverse.tolist()
        self._inv_tc = (1.0 / th.time_constant).tolist()
        self._n_max = th.n_max.tolist()
        self._quadratic = th.law == "quadratic"
        if dof == 3:
            # rows u and v of M_RB and M_A: [a_x, a_y] = first two components of M nu
            self._c3 = tuple(self.M_RB[:2].ravel().tolist() + self.M_A[:2].ravel().tolist())
        else:
            rs = spec.restoring
            if rs is None:
                raise ValueError(f"vessel '{spec.name}': 6-DOF model needs a restoring section")
            self.W, self.Bu = rs.weight, rs.buoyancy
            self.r_g, self.r_b = np.asarray(rs.r_g, float), np.asarray(rs.r_b, float)
            self._g6 = restoring_coefficients(self.W, self.Bu, self.r_g, self.r_b)

    def _k_matrix(self, B: np.ndarray) -> np.ndarray:
        return self.Minv @ np.hstack([B, -np.eye(self.dof), -self.D_L, -self.D_Q])

    def k_matrix(self, efficiency: list[float] | np.ndarray) -> np.ndarray:
        """K of ``nu_dot = K [T, C+g, nu_r, |nu_r| nu_r]`` with thruster i delivering ``efficiency[i]``
        x its thrust law (fouling, damage), for ``rhs``/``rk4``'s ``K``. The model itself never
        changes (plants share it), so the efficiency lives with the caller; folded into the thrust
        columns it costs nothing per step, and all ones give the nominal K bit for bit."""
        eff = np.asarray(efficiency, dtype=float)
        if eff.shape != (self.m,):
            raise ValueError(f"efficiency needs {self.m} values, got shape {eff.shape}")
        return self._k_matrix(self.B * eff)

    # -- hot path ------------------------------------------------------------------------------
    def rhs(
        self, x: np.ndarray, n_cmd: list[float], vc_north: float = 0.0, vc_east: float = 0.0,
        tau_ext: list[float] | None = None, K: np.ndarray | None = None,
    ) -> np.ndarray:
        """x_dot for x = [eta, nu, n]; ``n_cmd`` already clipped to +-n_max (a list, see ``clip``).

        ``tau_ext``: extra body-frame generalized force (environment, test rigs), added to B T.
        ``K``: from ``k_matrix`` for thrusters off their nominal efficiency (default nominal).
        """
        K = self._K if K is None else K
        if self.dof == 6:
            return self._rhs6(x, n_cmd, vc_north, vc_east, tau_ext, K)
        return self._rhs3(x, n_cmd, vc_north, vc_east, tau_ext, K)

    def thrust_list(self, n: list[float]) -> list[float]:
        """Thrust law on a list of shaft speeds (same law as ``thrusters.speed_to_thrust``, faster)."""
        kk = zip(n, self._kf, self._kr, strict=True)
        if self._quadratic:
            return [(a if ni >= 0.0 else b) * ni * abs(ni) for ni, a, b in kk]
        return [(a if ni >= 0.0 else b) * ni for ni, a, b in kk]

    def clip(self, n_cmd: list[float] | np.ndarray) -> list[float]:
        """Speed commands limited to +-n_max, as the list ``rhs``/``rk4`` take."""
        return [min(max(float(c), -m), m) for c, m in zip(n_cmd, self._n_max, strict=True)]

    def _thrust_and_lag(self, n: list[float], n_cmd: list[float]) -> tuple[list[float], list[float]]:
        ndot = [(c - ni) * it for ni, c, it in zip(n, n_cmd, self._inv_tc, strict=True)]
        return self.thrust_list(n), ndot

    def _rhs3(self, x: np.ndarray, n_cmd: list[float], vcn: float, vce: float,
              tau_ext: list[float] | None, K: np.ndarray) -> np.ndarray:
        _, _, psi, u, v, r, *n = x.tolist()
        c, s = math.cos(psi), math.sin(psi)
        ur, vr = u - (c * vcn + s * vce), v - (-s * vcn + c * vce)
        m11, m12, m13, m21, m22, m23, a11, a12, a13, a21, a22, a23 = self._c3
        if self.coriolis:
            # C(nu) nu = [-r a_y, r a_x, u a_y - v a_x], [a_x, a_y] from M nu (6-DOF m2c on u, v, r).
            ax, ay = m11 * u + m12 * v + m13 * r, m21 * u + m22 * v + m23 * r
            ex, ey = a11 * ur + a12 * vr + a13 * r, a21 * ur + a22 * vr + a23 * r
            cor = [-r * (ay + ey), r * (ax + ex), u * ay - v * ax + ur * ey - vr * ex]
        else:
            cor = [0.0, 0.0, 0.0]
        if self.relative_inertia and (vcn != 0.0 or vce != 0.0):
            # + M (omega x nu_c), omega x nu_c = (-r v_c, r u_c, 0): M nu_r_dot instead of M nu_dot
            wx, wy = -r * (v - vr), r * (u - ur)
            cor = [cc + ma * wx + mb * wy for cc, (ma, mb) in zip(cor, self._M_lin, strict=True)]
        if tau_ext is not None:
            cor = [c - te for c, te in zip(cor, tau_ext, strict=True)]
        T, ndot = self._thrust_and_lag(n, n_cmd)
        nur = [ur, vr, r]
        nu_dot = K @ np.array([*T, *cor, *nur, abs(ur) * ur, abs(vr) * vr, abs(r) * r])
        return np.array([c * u - s * v, s * u + c * v, r, *nu_dot.tolist(), *ndot])

    def _rhs6(self, x: np.ndarray, n_cmd: list[float], vcn: float, vce: float,
              tau_ext: list[float] | None, K: np.ndarray) -> np.ndarray:
        _, _, _, phi, theta, psi, u, v, w, p, q, r, *n = x.tolist()
        cphi, sphi = math.cos(phi), math.sin(phi)
        cth, sth = math.cos(theta), math.sin(theta)
        cpsi, spsi = math.cos(psi), math.sin(psi)
        R11, R12, R13 = cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth
        R21, R22, R23 = spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi
        R32, R33 = cth * sphi, cth * cphi
        t = (sphi * q + cphi * r) / cth
        eta_dot = [
            R11 * u + R12 * v + R13 * w,
            R21 * u + R22 * v + R23 * w,
            -sth * u + R32 * v + R33 * w,
            p + t * sth,
            cphi * q - sphi * r,
            t,
        ]
        rel = None  # M (omega x nu_c) with current_inertia: relative
        # M_RB nu and M_A nu_r (the current has no angular part); zero without Coriolis terms.
        if self.coriolis:
            a1, a2, a3, b1, b2, b3, e1, e2, e3, f1, f2, f3 = (self._M_stack @ x[6:12]).tolist()
        else:
            a1 = a2 = a3 = b1 = b2 = b3 = e1 = e2 = e3 = f1 = f2 = f3 = 0.0
        if vcn != 0.0 or vce != 0.0:
            uc, vc, wc = R11 * vcn + R21 * vce, R12 * vcn + R22 * vce, R13 * vcn + R23 * vce
            if self.coriolis:
                mc = [ra * uc + rb * vc + rc * wc for ra, rb, rc in self._MA_lin]
                e1, e2, e3 = e1 - mc[0], e2 - mc[1], e3 - mc[2]
                f1, f2, f3 = f1 - mc[3], f2 - mc[4], f3 - mc[5]
            ur, vr, wr = u - uc, v - vc, w - wc
            if self.relative_inertia:  # + M (omega x nu_c): M nu_r_dot instead of M nu_dot
                wx, wy, wz = q * wc - r * vc, r * uc - p * wc, p * vc - q * uc
                rel = [ma * wx + mb * wy + mc_ * wz for ma, mb, mc_ in self._M_lin]
        else:
            ur, vr, wr = u, v, w
        # C(nu) nu = [nu2 x a; nu1 x a + nu2 x b] with [a; b] = M nu (Fossen's m2c, as cross products).
        s1, s2, s3 = a1 + e1, a2 + e2, a3 + e3
        t1, t2, t3 = b1 + f1, b2 + f2, b3 + f3
        wb, gx, gy, gz = self._g6
        force = [
            q * s3 - r * s2 + wb * sth,
            r * s1 - p * s3 - wb * R32,
            p * s2 - q * s1 - wb * R33,
            v * a3 - w * a2 + vr * e3 - wr * e2 + q * t3 - r * t2 - gy * R33 + gz * R32,
            w * a1 - u * a3 + wr * e1 - ur * e3 + r * t1 - p * t3 + gz * sth + gx * R33,
            u * a2 - v * a1 + ur * e2 - vr * e1 + p * t2 - q * t1 - gx * R32 - gy * sth,
        ]
        if rel is not None:
            force = [f + m for f, m in zip(force, rel, strict=True)]
        if tau_ext is not None:
            force = [c - te for c, te in zip(force, tau_ext, strict=True)]
        T, ndot = self._thrust_and_lag(n, n_cmd)
        z = np.array(
            [*T, *force, ur, vr, wr, p, q, r, abs(ur) * ur, abs(vr) * vr, abs(wr) * wr, abs(p) * p,
             abs(q) * q, abs(r) * r]
        )
        return np.array([*eta_dot, *(K @ z).tolist(), *ndot])

    def rk4(self, x: np.ndarray, n_cmd: list[float], dt: float, steps: int = 1,
            vc_north: float = 0.0, vc_east: float = 0.0, tau_ext: list[float] | None = None,
            K: np.ndarray | None = None) -> np.ndarray:
        """``steps`` fixed RK4 steps of size dt with inputs held; angles wrapped after each step."""
        f = self._rhs6 if self.dof == 6 else self._rhs3
        K = self._K if K is None else K
        h2, h6 = 0.5 * dt, dt / 6.0
        for _ in range(steps):
            k1 = f(x, n_cmd, vc_north, vc_east, tau_ext, K)
            k2 = f(x + h2 * k1, n_cmd, vc_north, vc_east, tau_ext, K)
            k3 = f(x + h2 * k2, n_cmd, vc_north, vc_east, tau_ext, K)
            k4 = f(x + dt * k3, n_cmd, vc_north, vc_east, tau_ext, K)
            x = x + h6 * (k1 + k4 + 2.0 * (k2 + k3))
            for i in self.angle_index:
                a = x[i]
                if a > _PI or a <= -_PI:
                    x[i] = wrap_angle(a)
        return x

    # -- readable reference form and energy ----------------------------------------------------
    def initial_state(self, eta: np.ndarray, nu: np.ndarray, n: np.ndarray | None = None) -> np.ndarray:
        n = np.zeros(self.m) if n is None else np.asarray(n, dtype=float)
        return np.concatenate([np.asarray(eta, float), np.asarray(nu, float), n])

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self.dof
        return x[:d], x[d : 2 * d], x[2 * d :]

    def thrust(self, n: np.ndarray) -> np.ndarray:
        return speed_to_thrust(self.spec.thrusters, n)

    def restoring(self, eta: np.ndarray) -> np.ndarray:
        """g(eta) (Fossen's gvect); zero for 3 DOF (surface vessel in the horizontal plane)."""
        if self.dof == 3:
            return np.zeros(3)
        return gvect(self.W, self.Bu, float(eta[4]), float(eta[3]), self.r_g, self.r_b)

    def current_body(self, eta: np.ndarray, vc_north: float, vc_east: float) -> np.ndarray:
        return current_body(eta, vc_north, vc_east)

    def derivative(self, eta: np.ndarray, nu: np.ndarray, tau: np.ndarray,
                   nu_c: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(eta_dot, nu_dot) in plain matrix form; slow, for checking ``rhs`` and for readers."""
        eta, nu = np.asarray(eta, float), np.asarray(nu, float)
        nu_r = nu - (np.zeros(self.dof) if nu_c is None else np.asarray(nu_c, float))
        cor = m2c(self.M_RB, nu) @ nu + m2c(self.M_A, nu_r) @ nu_r if self.coriolis else 0.0
        if self.relative_inertia and nu_c is not None:  # M nu_r_dot: + M [omega x nu_c1; 0]
            k = 3 if self.dof == 6 else 2
            w = np.asarray(nu, float)[3:] if self.dof == 6 else np.array([0.0, 0.0, nu[2]])
            wxc = np.cross(w, np.append(np.asarray(nu_c, float)[:k], [0.0] * (3 - k)))[:k]
            cor = cor + self.M[:, :k] @ wxc
        rest = (
            cor
            + self.D_L @ nu_r
            + self.D_Q @ (np.abs(nu_r) * nu_r)
            + self.restoring(eta)
        )
        return J(eta) @ nu, np.linalg.solve(self.M, np.asarray(tau, float) - rest)

    def kinetic_energy(self, nu: np.ndarray) -> float:
        nu = np.asarray(nu, float)
        return 0.5 * float(nu @ self.M @ nu)

    def potential_energy(self, eta: np.ndarray) -> float:
        """U with dU/dt = g(eta)^T nu: (B - W) down + e_z^T (R - I) (B r_b - W r_g); 0 for 3 DOF.

        Zero when upright at down = 0, so U > 0 measures the energy stored in roll/pitch.
        """
        if self.dof == 3:
            return 0.0
        R = rzyx(eta[3], eta[4], eta[5])
        c = self.Bu * self.r_b - self.W * self.r_g
        return float((self.Bu - self.W) * eta[2] + R[2] @ c - c[2])

    def energy(self, x: np.ndarray) -> float:
        eta, nu, _ = self.split(x)
        return self.kinetic_energy(nu) + self.potential_energy(eta)
