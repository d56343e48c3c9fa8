"""The vessel side's command check: what a thruster drive must do so that the thrusters stop whatever
happens to the controller (crash, SIGKILL, hang, a frozen sender, a cut cable).

``CommandSupervisor`` is the emulator's drive logic and the specification a real drive must meet
(docs/hardware.md, "Safety"); the clock is passed in, so it is tested without waiting. Per thruster:

- **Fresh frames only.** A command frame is *fresh* if its alive counter advanced by 1 to
  ``max_delta`` (mod the counter's range) since the last frame of that thruster: up to
  ``max_delta - 1`` lost frames in a row are tolerated. A repeated counter (delta 0: a hung
  controller whose adapter keeps sending the last frame, a cyclic transmit task left behind) is
  *stale*; a larger jump (another sender, a restarted controller, a replay) is a *jump*: the
  counter is re-synchronised to it but the frame is not used. Neither is applied, and neither
  refreshes the timeout. The first frame ever received is fresh.
- **Command timeout.** When no fresh frame arrived for ``timeout`` seconds, the thruster is set to
  zero and disabled (``tripped``), with one log line saying why (silence, a frozen counter, jumps)
  and the command-timeout fault bit in its status. Only an *enabled* thruster times out: one the
  controller disabled (enable = 0) is already at zero, and silence after it is a clean stop (seafmu's
  link sends enable 0 as it closes), not a fault to log and latch.
- **Re-enable.** ``latching`` (the seafmu DBC): a tripped drive stays stopped until a fresh frame
  with enable = 0 arrives (the controller acknowledges the stop), then runs on the next fresh
  enable = 1 — an explicit enable edge, so a controller that wakes from a hang cannot restart the
  thrusters with its stale setpoint; seafmu's link sees the fault bit, sends enable 0 and ramps up
  from zero. Not ``latching`` (NMEA 2000, whose PGNs cannot report the latch): the next fresh
  frame resumes the thruster, as PGN 128006's own command timeout does.

Before ``start`` (the vessel "in the dock", no command ever received) every thruster is at zero
and nothing times out.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

import numpy as np

from .canbus import FAULT_COMMAND_TIMEOUT, Command


class CommandSupervisor:
    """Alive-counter check, command timeout and re-enable policy for ``count`` thrusters."""

    def __init__(
        self,
        n_max: np.ndarray,
        timeout: float,
        modulus: int = 16,
        max_delta: int = 3,
        latching: bool = True,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if not timeout > 0:
            raise ValueError(f"command timeout must be > 0, got {timeout!r}")
        if not 1 <= max_delta < modulus:
            raise ValueError(f"max_delta must be in 1..{modulus - 1}, got {max_delta!r}")
        self.n_max = np.asarray(n_max, dtype=float)
        m = len(self.n_max)
        self.timeout = float(timeout)
        self.modulus = int(modulus)
        self.max_delta = int(max_delta)
        self.latching = latching
        self.log = log or (lambda text: None)
        self.started = False
        self.speed = np.zeros(m)  # the last fresh setpoint (clamped to +-n_max)
        self.enable = np.zeros(m, dtype=bool)  # the last fresh enable
        self.tripped = np.zeros(m, dtype=bool)
        self.last_valid = np.full(m, -math.inf)  # time of the last fresh frame
        self.last_counter: list[int | None] = [None] * m
        self._stale = np.zeros(m, dtype=int)  # stale / jump frames since the last fresh one
        self._jumps = np.zeros(m, dtype=int)
        self.counters: Counter[str] = Counter()
        self.events: list[tuple[float, int, str]] = []  # (time, thruster index, "timeout" | "rearmed")

    def start(self, now: float) -> None:
        """Commanding begins: every thruster's timeout counts from ``now``."""
        if not self.started:
            self.started = True
            self.last_valid[:] = now

    def receive(self, cmd: Command, now: float) -> str:
        """Take one command frame; returns its verdict: fresh, stale, jump or ignored (tripped)."""
        i = cmd.index
        self.start(now)
        last = self.last_counter[i]
        if cmd.counter is not None and last is not None:
            delta = (cmd.counter - last) % self.modulus
            if delta == 0:
                self._stale[i] += 1
                self.counters["stale"] += 1
                return "stale"
            self.last_counter[i] = cmd.counter
            if delta > self.max_delta:
                self._jumps[i] += 1
                self.counters["jump"] += 1
                return "jump"
        else:
            self.last_counter[i] = cmd.counter
        self.last_valid[i] = now
        self._stale[i] = self._jumps[i] = 0
        speed = cmd.speed if math.isfinite(cmd.speed) else 0.0
        speed = min(max(speed, -self.n_max[i]), self.n_max[i])
        if self.tripped[i]:
            if self.latching and cmd.enable:
                self.counters["enable_without_edge"] += 1
                return "ignored"
            self.tripped[i] = False
            self.events.append((now, i, "rearmed"))
            self.log(
                f"thruster {i + 1}: command timeout cleared at {now:.3f} s by a fresh "
                f"{'enable 0' if self.latching else 'command'}"
            )
        self.speed[i] = speed
        self.enable[i] = cmd.enable
        return "fresh"

    def update(self, now: float) -> np.ndarray:
        """Trip every enabled thruster without a fresh frame for ``timeout``; True where one tripped now."""
        if not self.started:
            return np.zeros(len(self.n_max), dtype=bool)
        new = ~self.tripped & self.enable & ((now - self.last_valid) > self.timeout)
        for i in np.flatnonzero(new):
            self.tripped[i] = True
            self.speed[i] = 0.0
            self.enable[i] = False
            self.counters["timeout"] += 1
            self.events.append((now, int(i), "timeout"))
            age = now - self.last_valid[i]
            why = "no valid command frame"
            if self._stale[i]:
                why = f"alive counter frozen at {self.last_counter[i]} ({self._stale[i]} repeated frames)"
            elif self._jumps[i]:
                why = f"alive counter jumping ({self._jumps[i]} frames skipped more than {self.max_delta})"
            self.log(
                f"thruster {i + 1}: COMMAND TIMEOUT at {now:.3f} s: {why}, last fresh command "
                f"{age:.3f} s ago (timeout {self.timeout:g} s): zero and disabled"
                + ("; resumes after enable 0 then 1" if self.latching else "; resumes on a fresh command")
            )
        return new

    def output(self) -> tuple[np.ndarray, np.ndarray]:
        """(shaft speed demand, enabled) per thruster: zero unless enabled and not tripped."""
        on = self.enable & ~self.tripped
        return np.where(on, self.speed, 0.0), on

    def faults(self) -> np.ndarray:
        """The command-timeout fault bit per thruster (0 or FAULT_COMMAND_TIMEOUT)."""
        return np.where(self.tripped, FAULT_COMMAND_TIMEOUT, 0).astype(int)
