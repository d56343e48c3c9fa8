"""Thrusters: configuration matrix, thrust law, speed limits and shaft dynamics.

The plant integrates the shaft speeds inside its own RK4 (see ``vessel_model``), using the same
coefficients as these helpers; the allocator uses the inverse law (``thrust_to_speed``) and the
thrust limits (``max_thrust``) so that both sides agree on one definition of the thruster.
"""

from __future__ import annotations

import numpy as np

from .vessel_spec import ThrusterSpec


def configuration_matrix(positions: np.ndarray, directions: np.ndarray, dof: int = 6) -> np.ndarray:
    """B with column i = [d_i; r_i x d_i] (6 x m); for dof = 3 the rows X, Y, N."""
    positions = np.asarray(positions, dtype=float)
    directions = np.asarray(directions, dtype=float)
    B = np.vstack([directions.T, np.cross(positions, directions).T])
    if dof == 3:
        return B[[0, 1, 5], :]
    return B


def thruster_matrix(spec: ThrusterSpec, dof: int) -> np.ndarray:
    """B of a vessel's thrusters (tau = B T)."""
    return configuration_matrix(spec.positions, spec.directions, dof)


def clip_speed(spec: ThrusterSpec, n_cmd: np.ndarray) -> np.ndarray:
    """Speed command limited to |n| <= n_max (what the motor drive does)."""
    return np.clip(np.asarray(n_cmd, dtype=float), -spec.n_max, spec.n_max)


def speed_to_thrust(spec: ThrusterSpec, n: np.ndarray) -> np.ndarray:
    """T = k n (linear) or k n|n| (quadratic), k = k_forward for n >= 0, k_reverse otherwise."""
    n = np.asarray(n, dtype=float)
    k = np.where(n >= 0.0, spec.k_forward, spec.k_reverse)
    if spec.law == "linear":
        return k * n
    return k * n * np.abs(n)


def thrust_to_speed(spec: ThrusterSpec, T: np.ndarray, clip: bool = True) -> np.ndarray:
    """Inverse law: the shaft speed that gives thrust T (clipped to +-n_max unless ``clip=False``)."""
    T = np.asarray(T, dtype=float)
    k = np.where(T >= 0.0, spec.k_forward, spec.k_reverse)
    if spec.law == "linear":
        n = T / k
    else:
        n = np.sign(T) * np.sqrt(np.abs(T) / k)
    return np.clip(n, -spec.n_max, spec.n_max) if clip else n


def max_thrust(spec: ThrusterSpec) -> tuple[np.ndarray, np.ndarray]:
    """(T_min, T_max) per thruster at -n_max and +n_max; T_min is negative (reverse coefficient)."""
    return speed_to_thrust(spec, -spec.n_max), speed_to_thrust(spec, spec.n_max)


def speed_rate(spec: ThrusterSpec, n: np.ndarray, n_cmd: np.ndarray) -> np.ndarray:
    """First-order shaft lag n_dot = (clip(n_cmd) - n) / T."""
    return (clip_speed(spec, n_cmd) - np.asarray(n, dtype=float)) / spec.time_constant
