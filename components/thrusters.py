"""Thrusters: configuration matrix, thrust law, speed limits and shaft dynamics."""

from __future__ import annotations

import numpy as np


def configuration_matrix(positions: np.ndarray, directions: np.ndarray, dof: int = 6) -> np.ndarray:
    """B with column i = [d_i; r_i x d_i] (6 x m); for dof = 3 the rows X, Y, N."""
    positions = np.asarray(positions, dtype=float)
    directions = np.asarray(directions, dtype=float)
    B = np.vstack([directions.T, np.cross(positions, directions).T])
    if dof == 3:
        return B[[0, 1, 5], :]
    return B
