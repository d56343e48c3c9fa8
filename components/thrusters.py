"""Thrusters: configuration matrix, thrust law, speed limits and shaft dynamics.

The plant integrates the shaft speeds inside its own RK4 (see ``vessel_model``), using the same
coefficients as these helpers; the allocator uses the inverse law (``thrust_to_speed``) and the
thrust limits (``max_thrust``) so that both sides agree on one definition of the thruster.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import kernels
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


def _by_element(f: Any, spec: ThrusterSpec, x: np.ndarray) -> np.ndarray:
    """A ``thrust_law`` loop over x of shape (..., m), the coefficients broadcast per thruster."""
    x = np.asarray(x, dtype=float)
    shape = x.shape
    kf = np.ascontiguousarray(np.broadcast_to(np.asarray(spec.k_forward, float), shape)).ravel()
    kr = np.ascontiguousarray(np.broadcast_to(np.asarray(spec.k_reverse, float), shape)).ravel()
    out = np.empty(kf.shape[0])
    f(np.ascontiguousarray(x).ravel(), kf, kr, kernels.thrust_law.code(spec.law), out)
    return out.reshape(shape)


def speed_to_thrust(spec: ThrusterSpec, n: np.ndarray) -> np.ndarray:
    """The vessel's thrust law at shaft speeds n (``kernels/thrust_law.py``: the one definition)."""
    return _by_element(kernels.thrust_law.thrusts, spec, n)


def thrust_to_speed(spec: ThrusterSpec, T: np.ndarray, clip: bool = True) -> np.ndarray:
    """Inverse law: the shaft speed that gives thrust T (clipped to +-n_max unless ``clip=False``)."""
    n = _by_element(kernels.thrust_law.speeds, spec, T)
    return np.clip(n, -spec.n_max, spec.n_max) if clip else n


def max_thrust(spec: ThrusterSpec) -> tuple[np.ndarray, np.ndarray]:
    """(T_min, T_max) per thruster at -n_max and +n_max; T_min is negative (reverse coefficient).

    From the law's plain form (``kernels/laws.py``, what the kernels compile): a scenario's validation
    asks for these limits, and importing numba and its first compiled call in a process cost
    ~0.5 s, for a handful of multiplications."""
    f, law = kernels.laws.thrust_of, kernels.laws.code(spec.law)
    n_max = spec.n_max.tolist()
    return (np.array([f(k, -n, law) for k, n in zip(spec.k_reverse.tolist(), n_max, strict=True)]),
            np.array([f(k, n, law) for k, n in zip(spec.k_forward.tolist(), n_max, strict=True)]))


def speed_rate(spec: ThrusterSpec, n: np.ndarray, n_cmd: np.ndarray) -> np.ndarray:
    """First-order shaft lag n_dot = (clip(n_cmd) - n) / T."""
    return (clip_speed(spec, n_cmd) - np.asarray(n, dtype=float)) / spec.time_constant
