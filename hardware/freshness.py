"""Is a report news? A drive's alive counter or a receiver's fix time must move forward.

A hung device often keeps talking: a CAN controller's cyclic transmit buffer repeats the drive's
last status frame, a two-slot buffer alternates its last two, a receiver repeats its last fix.
So a report is news only if its counter (or time) moved forward from the last one taken, and
that one is recent (``window``: after a silence an old counter says nothing — a 4-bit counter
meets any value again — and a hung device may come back repeating its last frame). Otherwise it
takes a source seen counting again: two forward steps in a row among the reports received (an
alternating pair never makes two). The first report ever is news.

Written here because it is a rule of this link, not a protocol a library implements; the drive
side's command check is ``hardware/drive.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


def counter_forward(modulus: int) -> Callable[[int, int], bool]:
    """b is after a on a counter modulo ``modulus``: 1 to less than half the range ahead (frames
    lost between are allowed; half or more is behind)."""
    half = modulus // 2

    def forward(a: int, b: int) -> bool:
        return 1 <= (b - a) % modulus < half

    return forward


def time_forward(period: float | None) -> Callable[[float, float], bool]:
    """b is later than a; on a clock that wraps every ``period`` s (a time of day), up to half a
    period later (23:59:59.9 -> 00:00:00.0 is later)."""
    if period is None:
        return lambda a, b: b > a

    def forward(a: float, b: float) -> bool:
        return 0.0 < (b - a) % period < 0.5 * period

    return forward


class Freshness(Generic[T]):
    """One source's reports: ``news(value, now)`` says whether this one is new (see the module)."""

    def __init__(self, forward: Callable[[T, T], bool], window: float = math.inf) -> None:
        self.forward = forward
        self.window = window
        self._taken: T | None = None
        self._taken_at = -math.inf
        self._seen: T | None = None
        self._seen_at = -math.inf
        self._run = 0  # forward steps in a row among the reports received

    def news(self, value: T, now: float) -> bool:
        seen, taken = self._seen, self._taken
        stepped = seen is not None and now - self._seen_at <= self.window and self.forward(seen, value)
        self._run = self._run + 1 if stepped else 0
        self._seen, self._seen_at = value, now
        recent = taken is not None and now - self._taken_at <= self.window
        ok = taken is None or (recent and self.forward(taken, value)) or self._run >= 2  # type: ignore[arg-type]
        if ok:
            self._taken, self._taken_at = value, now
        return ok
