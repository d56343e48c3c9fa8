"""A `seafmu run` log of the default DP scenario (Minerva 2 holding station in a 0.1 m/s current
towards 45 deg, setpoint steps): the diagnosis names the current with its speed and direction.

Station keeping barely excites the hull, so the baseline (damping fitted freely, no current) takes
up the current's force in absurd damping (yaw damping 40 000 times the file's); the current's own
fit, started only from there, stayed in that basin and a lost thruster at 90 % was named instead.
It now also starts from the vessel file's damping with the current fitted alone
(``maneuver.estimation._effect_steps``)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from seafmu.identification.diagnosis import diagnose
from seafmu.identification.trial import csv_trial


def test_the_default_dp_run_s_current_is_named(tmp_path: Path) -> None:
    from seafmu.master import run
    from seafmu.results import write_csv
    from seafmu.scenario import load_scenario

    path = tmp_path / "results.csv"
    write_csv(run(load_scenario("minerva2_dp"), mode="inprocess", progress=False), path)
    d = diagnose(csv_trial(path, "minerva2"))
    doc = d.to_json()
    assert doc["cause"]["effects"] == ["current"], d.evidence
    p = doc["extended"]["params"]
    truth = 0.1 * math.cos(math.radians(45.0))  # north = east
    assert p["v_c_north"] == pytest.approx(truth, rel=0.1) and p["v_c_east"] == pytest.approx(truth, rel=0.1)
