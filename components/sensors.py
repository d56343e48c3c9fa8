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

Faults (all off by default; they draw from a separate stream, so switching them on leaves the
noise of every sample unchanged):
- magnetometer calibration error on every ``yaw`` channel: measured heading = psi + A sin(psi)
  (+ noise, bias). A one-cycle (hard-iron-like) deviation: 0 heading north or south, +A heading
  east, -A heading west; what the thesis simulated. ``A`` = ``mag_fault_amplitude`` (rad).
- position-fix sensor (the first group measuring north and east: USBL on Minerva 2, GNSS on the
  AMV): outliers, each sample with probability ``outlier_rate`` displaced by ``outlier_size``
  metres in a uniformly random horizontal direction (acoustic multipath); and a dropout, no
  samples at the sample instants in [dropout_start, dropout_start + dropout_length) (the count
  stops, the last value is held, as a receiver that lost the transponder).
"""

from __future__ import annotations

import math

import numpy as np

from .dynamics import wrap_angle
from .vessel_spec import ANGLE_NAMES, SensorSpec

_EPS = 1e-6  # in units of sample periods: absorbs round-off of t + h at exact sample instants
# Random numbers are drawn CHUNK samples at a time: one Generator call per CHUNK samples instead of
# one per sample (the hot path), and the same numbers (a Generator fills an array in sequence).
CHUNK = 256
FAULT_STREAM = 0x5EAF  # entropy tag of the fault generator: SeedSequence([seed, FAULT_STREAM])


def mag_heading_error(psi: float, amplitude: float) -> float:
    """Heading error of the magnetometer calibration fault at true heading psi: A sin(psi)."""
    return amplitude * math.sin(psi)


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
        self._noise = np.zeros((0, len(index)))  # standard normals drawn ahead (CHUNK rows), next row
        self._next = 0
        self._uniform = np.zeros((0, 2))  # the fault stream's uniforms drawn ahead, next row
        self._next_u = 0
        self._angle_pos = [i for i, a in enumerate(self.angle.tolist()) if a]
        self.values = np.zeros(len(index))
        self.count = 0.0
        self.last_k: int | None = None  # index of the last sample instant served
        ch = list(spec.channels)
        # Fault hooks (SensorSuite configures them): heading channel, position-fix channels.
        self.yaw_pos = ch.index("yaw") if "yaw" in ch else -1
        self.yaw_state = int(self.index[self.yaw_pos]) if self.yaw_pos >= 0 else -1
        self.mag_fault = 0.0
        self.pos_fix = False
        self.north_pos = ch.index("north") if "north" in ch else -1
        self.east_pos = ch.index("east") if "east" in ch else -1
        self.fault_rng: np.random.Generator | None = None
        self.outlier_rate = 0.0
        self.outlier_size = 0.0
        self.dropout = (0.0, 0.0)  # (start, length), s
        self.outliers = 0.0  # outliers injected so far
        self.in_dropout = False

    def _normal(self) -> np.ndarray:
        """The next standard-normal vector of this sensor's stream (len(index) values)."""
        if self._next >= len(self._noise):
            self._noise = self.rng.standard_normal((CHUNK, len(self.index)))
            self._next = 0
        row = self._noise[self._next]
        self._next += 1
        return row

    def _fault_uniforms(self) -> list[float]:
        """The next two uniforms of the fault stream (this group's position fixes draw them)."""
        if self._next_u >= len(self._uniform):
            assert self.fault_rng is not None
            self._uniform = self.fault_rng.uniform(size=(CHUNK, 2))
            self._next_u = 0
        row = self._uniform[self._next_u].tolist()
        self._next_u += 1
        return row

    def _take(self, state: np.ndarray) -> None:
        noise = self.std * self._normal()
        vals = state[self.index] + self.bias + noise
        if self.mag_fault != 0.0 and self.yaw_pos >= 0:
            vals[self.yaw_pos] += mag_heading_error(float(state[self.yaw_state]), self.mag_fault)
        if self.pos_fix and self.fault_rng is not None:
            x, ang = self._fault_uniforms()  # drawn for every fix: stream aligned
            if x < self.outlier_rate:
                vals[self.north_pos] += self.outlier_size * math.cos(2.0 * math.pi * ang)
                vals[self.east_pos] += self.outlier_size * math.sin(2.0 * math.pi * ang)
                self.outliers += 1.0
        for i in self._angle_pos:
            # wrap only what left (-pi, pi]: wrap_angle's mod arithmetic perturbs in-range values
            a = vals[i]
            if a > math.pi or a <= -math.pi:
                vals[i] = wrap_angle(a)
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
            start, length = self.dropout
            ts = k / self.rate
            self.in_dropout = self.pos_fix and length > 0.0 and start - _EPS <= ts < start + length - _EPS
            if self.in_dropout:
                return False
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
        self.mag_fault = 0.0
        fault_rng = np.random.default_rng(np.random.SeedSequence([seed, FAULT_STREAM]))
        self.pos_group: SensorGroup | None = None
        for g in self.groups:
            if g.north_pos >= 0 and g.east_pos >= 0:
                g.pos_fix, g.fault_rng, self.pos_group = True, fault_rng, g
                break

    def set_mag_fault(self, amplitude: float) -> None:
        """Magnetometer calibration error amplitude A (rad) on every heading channel."""
        self.mag_fault = float(amplitude)
        for g in self.groups:
            g.mag_fault = float(amplitude)

    def set_pos_faults(self, rate: float, size: float, dropout_start: float, dropout_length: float) -> None:
        """Outliers and dropout of the position-fix sensor (no effect if the vessel has none)."""
        g = self.pos_group
        if g is not None:
            g.outlier_rate, g.outlier_size = float(rate), float(size)
            g.dropout = (float(dropout_start), float(dropout_length))

    @property
    def outliers(self) -> float:
        """Position-fix outliers injected so far."""
        return self.pos_group.outliers if self.pos_group is not None else 0.0

    @property
    def in_dropout(self) -> bool:
        """True while the position-fix sensor is in its dropout (set at each sample instant)."""
        return self.pos_group is not None and self.pos_group.in_dropout

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
