"""Real-time pacing: hold a fixed-step loop to the wall clock, and measure how well it was held.

A loop that talks to a real vessel must not run ahead of the vessel: step k may start only when
the wall clock reaches ``t0 + k * step``. ``time.sleep`` alone overshoots by the scheduler's
wake-up latency (typically 50-100 µs, several ms on a loaded 2-core machine), so the pacer sleeps
until ``spin`` seconds before the target and busy-waits the rest; the spin costs at most ``spin``
of CPU per step (2 % at 1 ms per 50 ms step) and takes the timer slack out of the jitter.

The schedule is absolute: a late step does not shift the following ones (the loop catches up), so
the real-time factor over a long run stays 1 however the single steps wobble. Statistics:

- lateness of each wake-up (wall time at which step k started minus its target): p50, p99, max;
- real-time factor over consecutive wall-clock windows (simulated time / wall time in each);
- overruns: steps that started more than one step late.
"""

from __future__ import annotations

import itertools
import os
import time
from dataclasses import dataclass, field

import numpy as np

DEFAULT_SPIN = 0.001  # s: busy-wait after the coarse sleep (covers the usual wake-up latency)


@dataclass
class PacingStats:
    """How closely a paced run followed the wall clock (times in seconds)."""

    steps: int
    step: float
    wall_time: float
    sim_time: float
    realtime_factor: float  # over the whole run
    window: float
    window_factors: list[float] = field(default_factory=list)  # per wall-clock window
    jitter_p50: float = 0.0
    jitter_p99: float = 0.0
    jitter_max: float = 0.0
    overruns: int = 0
    waited: float = 0.0  # the loop's time in the waits, s: not work (a step's own cost excludes it)

    def summary(self) -> str:
        w = self.window_factors
        wtxt = f", windows of {self.window:g} s: {min(w):.4f}..{max(w):.4f}" if w else ""
        return (
            f"real-time factor {self.realtime_factor:.4f}{wtxt}; step jitter p50 "
            f"{1e3 * self.jitter_p50:.3f} ms, p99 {1e3 * self.jitter_p99:.3f} ms, max "
            f"{1e3 * self.jitter_max:.3f} ms; {self.overruns} overruns in {self.steps} steps"
        )

    def as_dict(self) -> dict[str, float | int | list[float]]:
        return {
            "steps": self.steps,
            "step": self.step,
            "wall_time": self.wall_time,
            "sim_time": self.sim_time,
            "realtime_factor": self.realtime_factor,
            "window": self.window,
            "window_factors": list(self.window_factors),
            "jitter_p50": self.jitter_p50,
            "jitter_p99": self.jitter_p99,
            "jitter_max": self.jitter_max,
            "overruns": self.overruns,
            "waited": self.waited,
        }


class Pacer:
    """Sleep a fixed-step loop to the wall clock: ``pacer.wait_until(k)`` returns at ``t0 + k*step``.

    The clock starts at the first wait (or ``start``): the first ``wait_until(k)`` returns at once
    and anchors step k to now. ``stats()`` summarises the run.
    """

    def __init__(self, step: float, spin: float = DEFAULT_SPIN, window: float = 10.0) -> None:
        if not step > 0:
            raise ValueError(f"pacer step must be > 0, got {step!r}")
        self.step = float(step)
        self.spin = float(spin)
        self.window = float(window)
        self.t0: float | None = None
        self._late: list[float] = []  # lateness of each wake-up
        self._wall: list[float] = []  # wall time of each wake-up, relative to t0
        self._sim: list[float] = []  # loop time each wake-up was due at
        self.waited = 0.0  # s spent in the waits (sleep and spin)

    @staticmethod
    def elevate(priority: int) -> bool:
        """Ask for SCHED_FIFO at ``priority`` (1-99) for this thread: wake-ups then beat the other
        processes on a loaded machine. Needs root or CAP_SYS_NICE; False (and nothing changed) if not."""
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError, ValueError):
            return False
        return True

    def start(self, now: float | None = None) -> None:
        """Anchor the schedule: loop time 0 is ``now`` (perf_counter; default: this instant)."""
        self.t0 = time.perf_counter() if now is None else now

    def wait_until(self, k: int) -> float:
        """Block until step ``k`` is due; return the lateness (s, >= 0 unless the clock jumped)."""
        return self.wait_for(k * self.step)

    def wait_for(self, t: float) -> float:
        """Block until loop time ``t`` (s since the anchor, which the first call sets) is due."""
        if self.t0 is None:
            self.start(now=time.perf_counter() - t)
        target = self.t0 + t  # type: ignore[operator]
        perf = time.perf_counter
        entered = perf()
        coarse = target - self.spin - entered
        if coarse > 0:
            time.sleep(coarse)
        now = perf()
        while now < target:
            now = perf()
        self.waited += now - entered
        late = now - target
        self._late.append(late)
        self._wall.append(now - self.t0)  # type: ignore[operator]
        self._sim.append(t)
        return late

    def now(self) -> float:
        """Loop time now: wall seconds since the anchor (0 before the clock starts)."""
        return 0.0 if self.t0 is None else time.perf_counter() - self.t0

    def stats(self) -> PacingStats:
        late = np.asarray(self._late)
        n = len(late)
        if n < 2:
            return PacingStats(n, self.step, 0.0, 0.0, float("nan"), self.window, waited=self.waited)
        wall = np.asarray(self._wall)
        sim = np.asarray(self._sim)
        wall_span = wall[-1] - wall[0]
        sim_span = sim[-1] - sim[0]
        factors = []
        edges = np.arange(wall[0], wall[-1] + self.step / 2, self.window)  # last edge may fall a hair late
        idx = np.searchsorted(wall, edges)
        for a, b_raw in itertools.pairwise(idx):
            b = min(b_raw, n - 1)
            if b > a and wall[b] > wall[a]:
                factors.append(float((sim[b] - sim[a]) / (wall[b] - wall[a])))
        return PacingStats(
            steps=n,
            step=self.step,
            wall_time=float(wall_span),
            sim_time=float(sim_span),
            realtime_factor=float(sim_span / wall_span) if wall_span > 0 else float("nan"),
            window=self.window,
            window_factors=factors,
            jitter_p50=float(np.percentile(late, 50)),
            jitter_p99=float(np.percentile(late, 99)),
            jitter_max=float(late.max()),
            overruns=int(np.count_nonzero(late > self.step)),
            waited=self.waited,
        )
