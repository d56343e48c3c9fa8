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
NO_SAMPLE = -(2**62)  # last served sample instant before the first update
N_FAULT = 7  # mag_fault, outlier rate, outlier size, dropout start, dropout length, outliers, in dropout


def mag_heading_error(psi: float, amplitude: float) -> float:
    """Heading error of the magnetometer calibration fault at true heading psi: A sin(psi)."""
    return amplitude * math.sin(psi)


class SensorSuite:
    """All sensor groups of a vessel; outputs [meas..., count] per group, in file order.

    The whole state lives in a few flat arrays (channels of all groups side by side, group g's in
    ``off[g]:off[g + 1]``), so the plant's compiled step (``kernels/plant.py``,
    ``sensors_update``) samples every group in the same call as the integration. ``update`` and
    ``_take`` below are the plain-Python reference form of that kernel (same operations in the same
    order; ``tests/test_kernels.py`` holds them bit-identical); the plant uses them on land.

    Packed arrays (names as in the kernel):
    - ``s_int`` (int64): G, C, off (G + 1), state index (C), angle channel (C), yaw channel of each
      group (G, flat index or -1), the state index of that yaw (G), and the position-fix group with
      its north and east channels (3 values, -1 when the vessel has none);
    - ``s_conf`` (float): rate (G), std (C), bias (C), both already times ``noise_scale``;
    - ``s_int_mut`` (int64): next noise row of each group (G), next uniform row of the fault
      stream, index of each group's last served sample instant (G; ``NO_SAMPLE`` before the first
      update);
    - ``s_float_mut`` (float): held values (C), counts (G), then ``mag_fault``, outlier rate,
      outlier size, dropout start, dropout length, outliers so far, in dropout (0/1);
    - ``noise`` (CHUNK, C): each group's standard normals drawn ahead in its own columns, refilled
      from the group's generator as soon as its last row is used; ``uniform`` (CHUNK, 2) the same
      for the fault stream.
    """

    def __init__(
        self, sensors: list[SensorSpec], state_names: list[str], seed: int, noise_scale: float
    ) -> None:
        children = np.random.SeedSequence(seed).spawn(len(sensors))
        pos = {n: i for i, n in enumerate(state_names)}
        G = len(sensors)
        off = [0]
        for s in sensors:
            off.append(off[-1] + len(s.channels))
        C = off[-1]
        self.G, self.C = G, C
        self.rngs = [np.random.default_rng(ss) for ss in children]
        idx = [pos[c] for s in sensors for c in s.channels]
        angle = [int(c in ANGLE_NAMES) for s in sensors for c in s.channels]
        yaw, yaw_state = [], []
        pos_fix = [-1, -1, -1]
        for g, s in enumerate(sensors):
            ch = list(s.channels)
            yaw.append(off[g] + ch.index("yaw") if "yaw" in ch else -1)
            yaw_state.append(pos["yaw"] if "yaw" in ch else -1)
            if pos_fix[0] < 0 and "north" in ch and "east" in ch:
                pos_fix = [g, off[g] + ch.index("north"), off[g] + ch.index("east")]
        self.s_int = np.array([G, C, *off, *idx, *angle, *yaw, *yaw_state, *pos_fix], dtype=np.int64)
        self.s_conf = np.concatenate([
            [float(s.rate_hz) for s in sensors],
            *[noise_scale * np.asarray(s.noise_std, dtype=float) for s in sensors],
            *[noise_scale * np.asarray(s.bias, dtype=float) for s in sensors],
        ]).astype(float) if G else np.zeros(0)
        self.s_int_mut = np.array([0] * G + [0] + [NO_SAMPLE] * G, dtype=np.int64)
        self.s_float_mut = np.zeros(C + G + N_FAULT)
        self.noise = np.zeros((CHUNK, C))
        self.uniform = np.zeros((CHUNK, 2))
        self.fault_rng = (np.random.default_rng(np.random.SeedSequence([seed, FAULT_STREAM]))
                          if pos_fix[0] >= 0 else None)
        for g in range(G):
            self._refill(g)
        if self.fault_rng is not None:
            self.uniform = self.fault_rng.uniform(size=(CHUNK, 2))

    # -- layout helpers (Python side; the kernel reads the same positions) -------------------------
    @property
    def _off(self) -> np.ndarray:
        return self.s_int[2 : 3 + self.G]

    def _refill(self, g: int) -> None:
        """CHUNK new standard-normal rows of group g's stream into its columns of ``noise``."""
        a, b = int(self.s_int[2 + g]), int(self.s_int[3 + g])
        self.noise[:, a:b] = self.rngs[g].standard_normal((CHUNK, b - a))
        self.s_int_mut[g] = 0

    def refill(self) -> None:
        """Draw ahead for every stream whose rows are all used (the kernel says when)."""
        G = self.G
        for g in range(G):
            if self.s_int_mut[g] >= CHUNK:
                self._refill(g)
        if self.fault_rng is not None and self.s_int_mut[G] >= CHUNK:
            self.uniform = self.fault_rng.uniform(size=(CHUNK, 2))
            self.s_int_mut[G] = 0

    # -- faults --------------------------------------------------------------------------------
    @property
    def mag_fault(self) -> float:
        return float(self.s_float_mut[self.C + self.G])

    def set_mag_fault(self, amplitude: float) -> None:
        """Magnetometer calibration error amplitude A (rad) on every heading channel."""
        self.s_float_mut[self.C + self.G] = float(amplitude)

    def set_pos_faults(self, rate: float, size: float, dropout_start: float, dropout_length: float) -> None:
        """Outliers and dropout of the position-fix sensor (no effect if the vessel has none)."""
        if self.fault_rng is not None:
            k = self.C + self.G
            self.s_float_mut[k + 1 : k + 5] = [float(rate), float(size), float(dropout_start),
                                               float(dropout_length)]

    @property
    def outliers(self) -> float:
        """Position-fix outliers injected so far."""
        return float(self.s_float_mut[self.C + self.G + 5])

    @property
    def in_dropout(self) -> bool:
        """True while the position-fix sensor is in its dropout (set at each sample instant)."""
        return bool(self.s_float_mut[self.C + self.G + 6])

    @staticmethod
    def output_names(sensors: list[SensorSpec]) -> list[str]:
        names: list[str] = []
        for s in sensors:
            names += [f"meas_{c}" for c in s.channels] + [f"{s.name}_count"]
        return names

    # -- the reference form of kernels/plant.sensors_update ----------------------------------------
    def _take(self, g: int, state: np.ndarray) -> None:
        """Group g samples ``state``: bias + noise, the faults, angles wrapped; count + 1."""
        G, C = self.G, self.C
        si, fm = self.s_int, self.s_float_mut
        a, b = int(si[2 + g]), int(si[3 + g])
        idx = si[3 + G + a : 3 + G + b]
        row = self.noise[int(self.s_int_mut[g]), a:b]
        self.s_int_mut[g] += 1
        std, bias = self.s_conf[G + a : G + b], self.s_conf[G + C + a : G + C + b]
        vals = state[idx] + bias + std * row
        k = C + G
        yaw, yaw_state = int(si[3 + G + 2 * C + g]), int(si[3 + 2 * G + 2 * C + g])
        if fm[k] != 0.0 and yaw >= 0:
            vals[yaw - a] += mag_heading_error(float(state[yaw_state]), float(fm[k]))
        pg, pn, pe = (int(v) for v in si[3 + 3 * G + 2 * C : 6 + 3 * G + 2 * C])
        if g == pg:
            j = int(self.s_int_mut[G])
            x, ang = self.uniform[j].tolist()  # drawn for every fix: stream aligned
            self.s_int_mut[G] += 1
            if x < fm[k + 1]:
                vals[pn - a] += fm[k + 2] * math.cos(2.0 * math.pi * ang)
                vals[pe - a] += fm[k + 2] * math.sin(2.0 * math.pi * ang)
                fm[k + 5] += 1.0
        for i in range(a, b):
            # wrap only what left (-pi, pi]: wrap_angle's mod arithmetic perturbs in-range values
            if si[3 + G + C + i]:
                v = vals[i - a]
                if v > math.pi or v <= -math.pi:
                    vals[i - a] = wrap_angle(v)
        fm[a:b] = vals
        fm[C + g] += 1.0

    def initialise(self, state: np.ndarray) -> None:
        for g in range(self.G):
            self._take(g, state)
        self.refill()

    def update(self, t: float, h: float, state: np.ndarray) -> bool:
        """Sample every group with a sample instant in (t, t + h] (``state`` is the state at t + h);
        True if any took a new sample."""
        G, C = self.G, self.C
        changed = False
        last = self.s_int_mut[G + 1 :]
        fm = self.s_float_mut
        pg = int(self.s_int[3 + 3 * G + 2 * C])
        for g in range(G):
            rate = float(self.s_conf[g])
            if last[g] == NO_SAMPLE:
                # the initial sample served the instant at (or just before) the start time t
                last[g] = math.floor(t * rate + _EPS)
            k = math.floor((t + h) * rate + _EPS)
            if k > last[g]:
                last[g] = k
                if g == pg:
                    start, length = float(fm[C + G + 3]), float(fm[C + G + 4])
                    ts = k / rate
                    dropout = length > 0.0 and start - _EPS <= ts < start + length - _EPS
                    fm[C + G + 6] = 1.0 if dropout else 0.0
                    if dropout:
                        continue
                self._take(g, state)
                changed = True
        self.refill()
        return changed

    def output(self) -> list[float]:
        out: list[float] = []
        off = self._off.tolist()
        for g in range(self.G):
            out += self.s_float_mut[off[g] : off[g + 1]].tolist()
            out.append(float(self.s_float_mut[self.C + g]))
        return out
