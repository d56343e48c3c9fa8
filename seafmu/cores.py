"""The cores this process may use: its CPU affinity, not the machine's count (a container, a
``taskset``, a batch scheduler may allow fewer). Read by the sweep (workers, pinning), the run's
plot workers and the identification simulator's threads."""

from __future__ import annotations

import os


def usable_cores() -> list[int] | None:
    """The cores by number; None where the platform does not say (not Linux)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:
        return None


def core_count() -> int:
    """How many cores this process may use (the machine's count where the platform does not say)."""
    cores = usable_cores()
    return max(1, len(cores) if cores is not None else (os.cpu_count() or 1))
