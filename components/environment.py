"""Environment: ocean current in NED, constant or slowly varying. Waves: ``components/waves.py``.

The current is kept in NED because that is where it is (nearly) constant; the body-frame velocity
nu_c depends on the attitude and is therefore evaluated at every RK4 stage by the vessel model.

Slow variation (optional): each NED component of the current gets a first-order Gauss-Markov
deviation d_dot = -d / T + w, with stationary standard deviation ``variation`` (m/s) and time
constant ``time_constant`` (s), so speed and direction both wander (the cross-flow deviation has
the same std as the along-flow one: about variation / speed rad of direction). It is advanced
once per co-simulation step with the exact discretisation
d_{k+1} = e^{-h/T} d_k + variation sqrt(1 - e^{-2h/T}) n_k (n_k standard normal, from the
generator the plant seeds), so its statistics do not depend on the step size. It starts at a draw
from the stationary distribution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .dynamics import rzyx


@dataclass
class Current:
    """Current of ``speed`` (m/s) flowing TOWARDS ``direction`` (rad from north, clockwise)."""

    speed: float = 0.0
    direction: float = 0.0

    def ned(self) -> tuple[float, float]:
        """(north, east) velocity of the water, m/s."""
        return self.speed * math.cos(self.direction), self.speed * math.sin(self.direction)

    def step(self, h: float) -> None:
        """Advance slow variations by h (none for a constant current)."""


@dataclass
class GaussMarkovCurrent(Current):
    """Mean current plus first-order Gauss-Markov deviations of its north and east components."""

    variation: float = 0.0  # m/s, stationary std of each component's deviation
    time_constant: float = 300.0  # s
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    dev: list[float] = field(default_factory=lambda: [0.0, 0.0])

    def __post_init__(self) -> None:
        if not (math.isfinite(self.variation) and self.variation >= 0.0):
            raise ValueError(f"current_variation must be >= 0, got {self.variation!r}")
        if not (math.isfinite(self.time_constant) and self.time_constant > 0.0):
            raise ValueError(f"current_time_constant must be > 0, got {self.time_constant!r}")
        self.dev = (self.variation * self.rng.standard_normal(2)).tolist()

    def ned(self) -> tuple[float, float]:
        n, e = super().ned()
        return n + self.dev[0], e + self.dev[1]

    def step(self, h: float) -> None:
        if self.variation == 0.0:  # fixed for the run (not tunable): nothing to draw
            return
        a = math.exp(-h / self.time_constant)
        s = self.variation * math.sqrt(1.0 - a * a)
        w = self.rng.standard_normal(2)
        self.dev = [a * self.dev[0] + s * float(w[0]), a * self.dev[1] + s * float(w[1])]

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
