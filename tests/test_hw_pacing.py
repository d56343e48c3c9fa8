"""Real-time pacing: the schedule is held to the wall clock, late steps are caught up, stats are right."""

from __future__ import annotations

import time

import numpy as np
import pytest

from seafmu.hardware.pacing import Pacer


def test_pacer_holds_the_wall_clock_and_catches_up_after_a_late_step() -> None:
    """Checked against the wake-ups' own measured lateness, so a loaded machine's late wake-ups are
    allowed for while a schedule that shifted after the late step (35 ms off) still fails."""
    pacer = Pacer(0.01, window=0.5)
    wall0 = time.perf_counter()
    late = []
    for k in range(201):
        late.append(pacer.wait_until(k))
        if k == 50:
            time.sleep(0.035)  # one step's work overruns by more than three steps
    wall = time.perf_counter() - wall0
    s = pacer.stats()
    assert wall - late[-1] == pytest.approx(2.0, abs=0.005)  # absolute schedule: nothing shifted
    assert late[51] >= 0.025 and late[52] >= 0.015  # the steps after the late one started late
    assert s.steps == 201 and s.sim_time == pytest.approx(2.0)
    assert s.realtime_factor == pytest.approx(2.0 / (2.0 + late[-1] - late[0]), rel=1e-6)
    # a window edge on the late step skews that window and the next one, evenly
    assert len(s.window_factors) == 4 and all(f == pytest.approx(1.0, abs=0.1) for f in s.window_factors)
    assert s.overruns == sum(x > 0.01 for x in late) and s.overruns >= 2
    assert s.jitter_max == max(late) and s.jitter_p50 == pytest.approx(float(np.median(late)))
    assert "real-time factor" in s.summary() and s.as_dict()["overruns"] == s.overruns
    # the waits are the loop's time but for its work (the late step's 35 ms): what a step's cost excludes
    assert 1.85 < s.waited <= wall - 0.035 and s.as_dict()["waited"] == s.waited


def test_pacer_rejects_a_bad_step() -> None:
    with pytest.raises(ValueError, match="step must be > 0"):
        Pacer(0.0)
