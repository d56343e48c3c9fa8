"""Second-order reference model (Fossen 2011, sec. 12.1): a smooth desired trajectory per DOF.

    x_dd + 2 zeta omega x_d_dot + omega^2 x_d = omega^2 x_ref

It turns setpoint steps into a trajectory the vessel can follow (position, velocity and
acceleration for feed-forward), so the controller never sees a step in its error. Critically
damped (zeta = 1) by default: the fastest response without overshoot.

Discretisation: exact (zero-order hold on x_ref, closed-form 2 x 2 matrix exponential per DOF)
when no limits are set, because the model is linear and time-invariant between steps; RK4
sub-steps when velocity/acceleration limits make it nonlinear. Hand-written because it is a few
lines of scalar algebra per DOF and python-control/scipy.signal would cost more per call than the
arithmetic itself.

Angles: the reference error of an angle DOF is wrapped to (-pi, pi] before it drives the model, so a
heading step from 179 deg to -179 deg turns 2 deg the short way; x_d itself is wrapped afterwards.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from . import kernels
from .dynamics import wrap_angle

RK4_DT_MAX = 0.05  # s: largest RK4 sub-step when limits are active
_TWO_PI = 2.0 * math.pi


def _exact_coefficients(omega: float, zeta: float, h: float) -> tuple[float, ...]:
    """Entries of Phi = expm(A h) and Gamma = int expm(A s) ds B for A = [[0,1],[-w^2,-2 z w]].

    With e = x - x_ref (x_ref held) the model is homogeneous: [e, v](h) = Phi [e, v](0), so only
    Phi is needed (Gamma follows as x_ref (1 - Phi11), -x_ref Phi21 applied to e).
    """
    w, z = omega, zeta
    if abs(z - 1.0) < 1e-9:  # critically damped: repeated root -w
        ex = math.exp(-w * h)
        p11 = (1.0 + w * h) * ex
        p12 = h * ex
        p21 = -w * w * h * ex
        p22 = (1.0 - w * h) * ex
        return p11, p12, p21, p22
    # General case through the eigen-decomposition of A (complex roots for z < 1).
    disc = complex(z * z - 1.0) ** 0.5
    l1, l2 = -w * (z - disc), -w * (z + disc)
    e1, e2 = np.exp(l1 * h), np.exp(l2 * h)
    d = l1 - l2
    # Phi = (A - l2 I) e1 / d - (A - l1 I) e2 / d  (Sylvester for distinct eigenvalues)
    a11, a12, a21, a22 = 0.0, 1.0, -w * w, -2.0 * z * w
    p11 = ((a11 - l2) * e1 - (a11 - l1) * e2) / d
    p12 = (a12 * e1 - a12 * e2) / d
    p21 = (a21 * e1 - a21 * e2) / d
    p22 = ((a22 - l2) * e1 - (a22 - l1) * e2) / d
    return p11.real, p12.real, p21.real, p22.real


class ReferenceModel:
    """Vector of independent second-order reference models (one per DOF).

    ``omega`` and ``zeta`` may be scalars or per-DOF sequences; ``angles`` marks the DOFs whose
    reference error is wrapped; ``v_max``/``a_max`` (per DOF or scalar, inf = none) bound the
    desired velocity and acceleration.
    """

    def __init__(
        self,
        n: int,
        omega: float | Sequence[float],
        zeta: float | Sequence[float] = 1.0,
        angles: Sequence[bool] | None = None,
        v_max: float | Sequence[float] = math.inf,
        a_max: float | Sequence[float] = math.inf,
    ) -> None:
        self.n = n
        self.angles = np.zeros(n, dtype=bool) if angles is None else np.asarray(angles, dtype=bool)
        self._angle_idx = np.flatnonzero(self.angles)
        self.x = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self._coef_h = math.nan
        self.set_dynamics(omega, zeta, v_max, a_max)

    def set_dynamics(
        self,
        omega: float | Sequence[float],
        zeta: float | Sequence[float],
        v_max: float | Sequence[float] = math.inf,
        a_max: float | Sequence[float] = math.inf,
    ) -> None:
        """Change bandwidth, damping or limits (state kept: the trajectory continues smoothly)."""
        n = self.n
        self.omega = np.broadcast_to(np.asarray(omega, dtype=float), (n,)).copy()
        self.zeta = np.broadcast_to(np.asarray(zeta, dtype=float), (n,)).copy()
        self.v_max = np.broadcast_to(np.asarray(v_max, dtype=float), (n,)).copy()
        self.a_max = np.broadcast_to(np.asarray(a_max, dtype=float), (n,)).copy()
        if np.any(~(self.omega > 0.0)) or np.any(~np.isfinite(self.omega)):
            raise ValueError(f"reference model: omega must be positive and finite, got {self.omega.tolist()}")
        if np.any(~(self.zeta > 0.0)) or np.any(~np.isfinite(self.zeta)):
            raise ValueError(f"reference model: zeta must be positive and finite, got {self.zeta.tolist()}")
        if np.any(~(self.v_max > 0.0)) or np.any(~(self.a_max > 0.0)):
            raise ValueError("reference model: v_max and a_max must be positive (inf = no limit)")
        self._limited = bool(np.isfinite(self.v_max).any() or np.isfinite(self.a_max).any())
        self._w2 = self.omega**2
        self._2zw = 2.0 * self.zeta * self.omega
        self._coef_h = math.nan

    def reset(self, x: Sequence[float] | np.ndarray, v: Sequence[float] | np.ndarray | None = None) -> None:
        """Start the trajectory at x (and v), e.g. at the current estimate for a bumpless start."""
        self.x = np.array(x, dtype=float)
        self.v = np.zeros(self.n) if v is None else np.array(v, dtype=float)
        self.a = np.zeros(self.n)
        if self._angle_idx.size:
            self.x[self._angle_idx] = wrap_angle(self.x[self._angle_idx])

    def error(self, x_ref: np.ndarray) -> np.ndarray:
        """x_d - x_ref with angle DOFs wrapped (the short way round)."""
        e = self.x - x_ref
        ai = self._angle_idx
        if ai.size:
            e[ai] = (e[ai] + math.pi) % _TWO_PI - math.pi
        return e

    def step(
        self, h: float, x_ref: Sequence[float] | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance by h with x_ref held; returns (x_d, v_d, a_d) at the end of the step.

        The returned arrays are the model's own state: copy them before changing them.
        """
        if not self._limited:
            # the exact discrete step, compiled: e0 = x - x_ref (wrapped), [e, v] = Phi [e0, v],
            # x += e - e0 (wrapped), a = -w^2 e - 2 zeta w v
            x, v, a = np.empty(self.n), np.empty(self.n), np.empty(self.n)
            kernels.control.reference_step(self.x, self.v, np.ascontiguousarray(x_ref, dtype=float),
                                           self.coefficients(h), self._w2, self._2zw, self.angles, x, v, a)
            self.x, self.v, self.a = x, v, a
            return self.x, self.v, self.a
        e0 = self.error(np.asarray(x_ref, dtype=float))
        e, v = self._rk4(e0, self.v, h)
        # Only the (wrapped) error was propagated: moving x_d by its change keeps x_d continuous.
        x = self.x + (e - e0)
        ai = self._angle_idx
        if ai.size:
            x[ai] = (x[ai] + math.pi) % _TWO_PI - math.pi
        self.x, self.v = x, v
        self.a = self._accel(e, v)
        return self.x, self.v, self.a

    @property
    def exact(self) -> bool:
        """True without velocity/acceleration limits: a step is the exact discrete solution."""
        return not self._limited

    def rates(self) -> tuple[np.ndarray, np.ndarray]:
        """(omega^2, 2 zeta omega) per DOF: with ``coefficients`` what a compiled step takes."""
        return self._w2, self._2zw

    def coefficients(self, h: float) -> np.ndarray:
        """Rows p11, p12, p21, p22 of Phi = expm(A h) per DOF (4, n), contiguous; cached per h."""
        if h != self._coef_h:
            coef = [_exact_coefficients(w, z, h) for w, z in zip(self.omega, self.zeta, strict=True)]
            self._coef = np.ascontiguousarray(np.array(coef).T)
            self._coef_h = h
        return self._coef

    def _accel(self, e: np.ndarray, v: np.ndarray) -> np.ndarray:
        a = -self._w2 * e - self._2zw * v
        if self._limited:
            a = np.clip(a, -self.a_max, self.a_max)
            # At the velocity limit, no acceleration pushes further out.
            a = np.where((np.abs(v) >= self.v_max) & (a * v > 0.0), 0.0, a)
        return a

    def _rk4(self, e: np.ndarray, v: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        k = max(1, math.ceil(h / RK4_DT_MAX - 1e-9))
        dt = h / k
        for _ in range(k):
            k1e, k1v = v, self._accel(e, v)
            e2, v2 = e + 0.5 * dt * k1e, v + 0.5 * dt * k1v
            k2e, k2v = v2, self._accel(e2, v2)
            e3, v3 = e + 0.5 * dt * k2e, v + 0.5 * dt * k2v
            k3e, k3v = v3, self._accel(e3, v3)
            e4, v4 = e + dt * k3e, v + dt * k3v
            k4e, k4v = v4, self._accel(e4, v4)
            e = e + dt / 6.0 * (k1e + 2.0 * k2e + 2.0 * k3e + k4e)
            v = np.clip(v + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v), -self.v_max, self.v_max)
        return e, v
