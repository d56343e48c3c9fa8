"""Sampled, noisy sensors of the plant state.

Timing rule: a group samples at the instants k / rate_hz. In co-simulation the plant only has
the state at the end of each step, so a sample instant falling in (t, t + h] is served by the
state at t + h; values are held between samples. At most one new sample per co-simulation step
(a step longer than the sample period lowers the effective rate to 1/h). The initial state at
initialisation counts as the first sample (count = 1).

Noise: bias + white Gaussian noise, both scaled by ``noise_scale``. Each group draws from its own
child stream of ``SeedSequence(seed)`` (``spawn``, keyed by the group's position in the vessel
file), so the same seed reproduces a run exactly and appending a sensor leaves the others'
noise unchanged. Noise is drawn even when ``noise_scale`` is 0, so the streams stay aligned.
"""

from __future__ import annotations

import math

import numpy as np

from components.kinematics import wrap_angle
from components.vessel_spec import ANGLE_NAMES, SensorSpec

_EPS = 1e-6  # in units of sample periods: absorbs round-off of t + h at exact sample instants


class SensorGroup:
    """One sensor (several channels, one rate) reading entries ``index`` of the state vector."""

    def __init__(
        self, spec: SensorSpec, index: list[int], rng: np.random.Generator, noise_scale: float
    ) -> None:
        self.spec = spec
        self.index = np.asarray(index, dtype=int)
        self.rate = float(spec.rate_hz)
        self.angle = np.array([c in ANGLE_NAMES for c in spec.channels])
        self.std = noise_scale * np.asarray(spec.noise_std, dtype=float)
        self.bias = noise_scale * np.asarray(spec.bias, dtype=float)
        self.rng = rng
        self.values = np.zeros(len(index))
        self.count = 0.0
        self.last_k: int | None = None  # index of the last sample instant served

    def _take(self, state: np.ndarray) -> None:
        noise = self.std * self.rng.standard_normal(len(self.index))
        vals = state[self.index] + self.bias + noise
        if self.angle.any():
            # wrap only what left (-pi, pi]: wrap_angle's mod arithmetic perturbs in-range values
            out = self.angle & ((vals > math.pi) | (vals <= -math.pi))
            if out.any():
                vals[out] = wrap_angle(vals[out])
        self.values = vals
        self.count += 1.0

    def initialise(self, state: np.ndarray) -> None:
        self._take(state)

    def update(self, t: float, h: float, state: np.ndarray) -> bool:
        """Sample ``state`` (the state at t + h) if a sample instant lies in (t, t + h]."""
        if self.last_k is None:
            # the initial sample served the instant at (or just before) the start time t
            self.last_k = math.floor(t * self.rate + _EPS)
        k = math.floor((t + h) * self.rate + _EPS)
        if k > self.last_k:
            self.last_k = k
            self._take(state)
            return True
        return False


class SensorSuite:
    """All sensor groups of a vessel; outputs [meas..., count] per group, in file order."""

    def __init__(
        self, sensors: list[SensorSpec], state_names: list[str], seed: int, noise_scale: float
    ) -> None:
        children = np.random.SeedSequence(seed).spawn(len(sensors))
        pos = {n: i for i, n in enumerate(state_names)}
        self.groups = [
            SensorGroup(s, [pos[c] for c in s.channels], np.random.default_rng(ss), noise_scale)
            for s, ss in zip(sensors, children, strict=True)
        ]
        self.size = sum(len(g.index) + 1 for g in self.groups)

    @staticmethod
    def output_names(sensors: list[SensorSpec]) -> list[str]:
        names: list[str] = []
        for s in sensors:
            names += [f"meas_{c}" for c in s.channels] + [f"{s.name}_count"]
        return names

    def initialise(self, state: np.ndarray) -> None:
        for g in self.groups:
            g.initialise(state)

    def update(self, t: float, h: float, state: np.ndarray) -> bool:
        """Sample every group that is due; True if any took a new sample."""
        changed = False
        for g in self.groups:
            changed = g.update(t, h, state) or changed
        return changed

    def output(self) -> list[float]:
        out: list[float] = []
        for g in self.groups:
            out += g.values.tolist()
            out.append(g.count)
        return out
