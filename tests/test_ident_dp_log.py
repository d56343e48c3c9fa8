"""A `seafmu run` log of the default DP scenario (Minerva 2 holding station in a 0.1 m/s current
towards 45 deg, setpoint steps): the diagnosis names the current with its speed and direction,
and with a lost thruster as well, both.

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


@pytest.mark.parametrize(("scenario", "vessel", "speed", "towards", "lost"), [
    ("minerva2_dp", "minerva2", 0.1, 45.0, None),
    ("minerva2_dp", "minerva2", 0.1, 45.0, 3),
    ("supply_dp", "supply", 0.5, 30.0, None),
])
def test_a_dp_run_s_current_and_a_lost_thruster_are_named(
        tmp_path: Path, scenario: str, vessel: str, speed: float, towards: float, lost: int | None) -> None:
    """The default DP runs (a current), and Minerva 2's with thruster 3 at 60 % as well (``--set
    plant.thruster_efficiency_3=0.6``): the current (the supply vessel's, 0.5 m/s, was `none`),
    and the pair current + thruster_loss, which the pair search also screens from the vessel
    file's damping where the baseline's is far from it (``diagnosis._file_reference``; was
    `none`)."""
    from seafmu.master import run
    from seafmu.results import write_csv
    from seafmu.scenario import load_scenario, parse_override

    sets = [parse_override(f"plant.thruster_efficiency_{lost}=0.6")] if lost else []
    path = tmp_path / "results.csv"
    write_csv(run(load_scenario(scenario, sets), mode="inprocess", progress=False), path)
    d = diagnose(csv_trial(path, vessel))
    doc = d.to_json()
    named = sorted(doc["cause"]["effects"])
    assert named == (["current", "thruster_loss"] if lost else ["current"]), d.evidence
    p = doc["extended"]["params"]
    north, east = speed * math.cos(math.radians(towards)), speed * math.sin(math.radians(towards))
    assert p["v_c_north"] == pytest.approx(north, rel=0.1) and p["v_c_east"] == pytest.approx(east, rel=0.1)
    if lost:
        assert p[f"eta_T[{lost}]"] == pytest.approx(0.6, abs=0.03)
