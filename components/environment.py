"""Environment: ocean current (constant in NED). Waves are to come.

The current is kept in NED because that is where it is constant; the body-frame velocity nu_c
depends on the attitude and is therefore evaluated at every RK4 stage by the vessel model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from components.kinematics import rzyx


@dataclass
class Current:
    """Current of ``speed`` (m/s) flowing TOWARDS ``direction`` (rad from north, clockwise)."""

    speed: float = 0.0
    direction: float = 0.0

    def ned(self) -> tuple[float, float]:
        """(north, east) velocity of the water, m/s."""
        return self.speed * math.cos(self.direction), self.speed * math.sin(self.direction)

    def body(self, eta: np.ndarray) -> np.ndarray:
        """nu_c in the body frame for attitude ``eta`` (3 or 6 DOF); angular part zero."""
        return current_body(eta, *self.ned())


def current_body(eta: np.ndarray, vc_north: float, vc_east: float) -> np.ndarray:
    """nu_c = R(Theta)^T [vc_north, vc_east, 0] (6 DOF) or its planar version (3 DOF)."""
    if len(eta) == 3:
        c, s = math.cos(eta[2]), math.sin(eta[2])
        return np.array([c * vc_north + s * vc_east, -s * vc_north + c * vc_east, 0.0])
    R = rzyx(eta[3], eta[4], eta[5])
    lin = R.T @ np.array([vc_north, vc_east, 0.0])
    return np.concatenate([lin, np.zeros(3)])
