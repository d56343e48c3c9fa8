"""Real-time pacing: the schedule is held to the wall clock, late steps are caught up, stats are right."""

from __future__ import annotations

import time

import pytest

from seafmu.hardware.pacing import Pacer


def test_pacer_holds_the_wall_clock_and_catches_up_after_a_late_step() -> None:
    pacer = Pacer(0.01, window=0.5)
    wall0 = time.perf_counter()
    for k in range(201):
        pacer.wait_until(k)
        if k == 50:
            time.sleep(0.035)  # one step's work overruns by more than three steps
    wall = time.perf_counter() - wall0
    s = pacer.stats()
    assert wall == pytest.approx(2.0, abs=0.01)  # absolute schedule: the late step shifted nothing
    assert s.steps == 201 and s.sim_time == pytest.approx(2.0)
    assert s.realtime_factor == pytest.approx(1.0, abs=0.01)
    # a window edge on the late step skews that window and the next one, evenly
    assert len(s.window_factors) == 4 and all(f == pytest.approx(1.0, abs=0.1) for f in s.window_factors)
    assert s.overruns in (2, 3)  # steps 51, 52 (and 53 if the sleep overshot) started > a step late
    assert s.jitter_max >= 0.025 and s.jitter_p50 < 0.002
    assert "real-time factor" in s.summary() and s.as_dict()["overruns"] == s.overruns


def test_pacer_rejects_a_bad_step() -> None:
    with pytest.raises(ValueError, match="step must be > 0"):
        Pacer(0.0)
