"""Vessel dynamics: rigid body, added mass, Coriolis, damping, restoring, and the thruster shafts.

    eta_dot = J(eta) nu
    M nu_dot + C_RB(nu) nu + C_A(nu_r) nu_r + D_L nu_r + D_Q (|nu_r| * nu_r) + g(eta) = B T(n)
    n_dot   = (clip(n_cmd) - n) / T_n,        nu_r = nu - nu_c(eta)

D_L and D_Q are full matrices (not necessarily symmetric). A vessel file with ``coriolis: none``
drops both Coriolis terms (linear low-speed DP models such as the offshore supply vessel's);
``current_inertia: relative`` makes the inertia act on the relative acceleration, M nu_r_dot
(Fossen's DP model M nu_r_dot + D nu_r = tau): with a current constant in NED,
nu_c_dot = -omega x nu_c in the body, so M nu_dot gets the extra force -M [omega x nu_c1; 0].
``current_inertia: added``: only the added mass does, M_RB nu_dot + M_A nu_r_dot (Fossen 2021's
model of a hull in an irrotational current), so the extra force is -M_A [omega x nu_c1; 0].
``restoring`` is only read for 6 DOF.

The state integrated by RK4 is x = [eta, nu, n] (2 dof + m values): the shaft lag lives in the
same integrator so a thruster spinning up inside one co-simulation step is resolved.

Two implementations of the same right-hand side exist on purpose:
- ``rhs`` and ``rk4`` are the hot path (every RK4 stage of every co-simulation step), compiled
  (``components/kernels/rigid_body.py``, numba): scalars for the trigonometry and the cross
  products, and ONE precomputed 6 x (m + 18) matrix K = M^-1 [B, -I, -D_L, -D_Q] for everything
  linear; a whole co-simulation step (all RK4 sub-steps) is one call;
- ``derivative`` is the textbook matrix form (``m2c``, ``J``) used by the tests to check ``rhs``.

Mass matrices: the symmetric parts of M_RB and M_A are used everywhere (inertia and Coriolis).
Potential-flow added mass is symmetric in theory; the published Minerva 2 matrix is slightly
asymmetric (panel-code error), and with an asymmetric inertia matrix the Coriolis terms would do
work, so the model would have no conserved mechanical energy to check against. A vessel file with
``inertia: published`` takes M = M_RB + M_A as the file gives them for the inertia (Coriolis still
from the symmetric parts, as Fossen's ``m2c`` does), to compare with a model written that way.
"""

from __future__ import annotations

import math

import numpy as np

from . import kernels
from .dynamics import J, gvect, m2c, restoring_coefficients, rzyx
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
        self.M_RB = _sym(spec.M_RB)  # Coriolis and the current's inertia term act through these
        self.M_A = _sym(spec.M_A)
        self.M = self.M_RB + self.M_A if spec.inertia == "symmetric" else np.asarray(spec.M, float)
        self.Minv = np.linalg.inv(self.M)
        self.D_L = np.array(spec.D_L, dtype=float)
        self.D_Q = np.array(spec.D_Q, dtype=float)
        self.B = thruster_matrix(spec.thrusters, dof)
        self.angle_index = [i for i, name in enumerate(spec.eta_names) if name in ANGLE_NAMES]
        self.coriolis = spec.coriolis != "none"
        # the matrix the current's rotation term acts through (None: M nu_dot, the default)
        self.current_inertia = {"absolute": None, "relative": self.M, "added": self.M_A}[spec.current_inertia]

        # nu_dot = K @ [T, C+g, nu_r, |nu_r| nu_r]
        self._K = self._k_matrix(self.B)
        th = spec.thrusters
        self._n_max = th.n_max.tolist()
        self._law = kernels.thrust_law.code(th.law)
        if dof == 6:
            rs = spec.restoring
            if rs is None:
                raise ValueError(f"vessel '{spec.name}': 6-DOF model needs a restoring section")
            self.W, self.Bu = rs.weight, rs.buoyancy
            self.r_g, self.r_b = np.asarray(rs.r_g, float), np.asarray(rs.r_b, float)
            self._g6 = restoring_coefficients(self.W, self.Bu, self.r_g, self.r_b)
        # the compiled kernels' packed parameters (contiguous float64), K the nominal one
        self.kernel_params = kernels.rigid_body.rigid_body_params(
            self.M_RB, self.M_A, self.D_L, self.D_Q, self.B, self._g6 if dof == 6 else None, th.k_forward,
            th.k_reverse, th.time_constant, self._law, self.coriolis, spec.current_inertia,
            self.angle_index)._replace(K=np.ascontiguousarray(self._K))
        self._no_ext = np.zeros(dof)

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
        p = self.kernel_params
        out = np.empty(self.n_states)
        ext = self._no_ext if tau_ext is None else np.asarray(tau_ext, dtype=float)
        kernels.rigid_body.rhs(
            np.asarray(x, dtype=float), np.asarray(n_cmd, dtype=float), float(vc_north), float(vc_east), ext,
            tau_ext is not None, p.K if K is None else K, p.MS, p.MAL, p.ML, p.g6, p.th, p.flags,
            np.zeros(self.m + 3 * self.dof), out)
        return out

    def thrust_into(self, n: np.ndarray, out: np.ndarray) -> None:
        """The thrust law at shaft speeds n (contiguous float64) into ``out``: one compiled call."""
        kernels.rigid_body.thrust(n, self.kernel_params.th, self._law, out)

    def clip(self, n_cmd: list[float] | np.ndarray) -> list[float]:
        """Speed commands limited to +-n_max, as the list ``rhs``/``rk4`` take."""
        return [min(max(float(c), -m), m) for c, m in zip(n_cmd, self._n_max, strict=True)]

    def rk4(self, x: np.ndarray, n_cmd: list[float], dt: float, steps: int = 1,
            vc_north: float = 0.0, vc_east: float = 0.0, tau_ext: list[float] | None = None,
            K: np.ndarray | None = None) -> np.ndarray:
        """``steps`` fixed RK4 steps of size dt with inputs held; angles wrapped after each step
        (one compiled call; ``x`` is not modified, the new state is returned)."""
        p = self.kernel_params
        ext = self._no_ext if tau_ext is None else np.asarray(tau_ext, dtype=float)
        out = np.empty(self.n_states)
        kernels.rigid_body.rk4(
            np.asarray(x, dtype=float), np.asarray(n_cmd, dtype=float), float(dt), int(steps),
            float(vc_north), float(vc_east), ext, tau_ext is not None, p.K if K is None else K, p.MS, p.MAL,
            p.ML, p.g6, p.th, p.flags, p.angle_index, out)
        return out

    def horizontal_velocity(self, x: np.ndarray) -> tuple[float, float]:
        """(north, east) rates of state x: the first two rows of J(eta) nu, in floats (R(Theta) or
        R(psi)); the plant's course and speed over ground."""
        if self.dof == 6:
            _, _, _, phi, theta, psi, u, v, w = x[:9].tolist()
            cphi, sphi = math.cos(phi), math.sin(phi)
            cth, sth = math.cos(theta), math.sin(theta)
            cpsi, spsi = math.cos(psi), math.sin(psi)
            vn = (cpsi * cth * u + (-spsi * cphi + cpsi * sth * sphi) * v
                  + (spsi * sphi + cpsi * cphi * sth) * w)
            ve = (spsi * cth * u + (cpsi * cphi + sphi * sth * spsi) * v
                  + (-cpsi * sphi + sth * spsi * cphi) * w)
            return vn, ve
        _, _, psi, u, v = x[:5].tolist()
        c, s = math.cos(psi), math.sin(psi)
        return c * u - s * v, s * u + c * v

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
        if self.current_inertia is not None and nu_c is not None:  # + M (or M_A) [omega x nu_c1; 0]
            k = 3 if self.dof == 6 else 2
            w = np.asarray(nu, float)[3:] if self.dof == 6 else np.array([0.0, 0.0, nu[2]])
            wxc = np.cross(w, np.append(np.asarray(nu_c, float)[:k], [0.0] * (3 - k)))[:k]
            cor = cor + self.current_inertia[:, :k] @ wxc
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
