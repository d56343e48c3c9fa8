"""`seafmu run --set/--seed/--format parquet`: overrides validated exactly like the scenario file, the
seed reaching every random source, Parquet beside the CSV."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from seafmu.cli import main
from seafmu.master import run
from seafmu.scenario import ScenarioError, load_scenario, parse_override

SHORT = """name: short_waves
vessel: minerva2
duration: 10
step: 0.05
record_interval: 0.1
fmus:
  plant:
    kind: plant
    parameters: {seed: 1, current_speed: 0.1 m/s, current_direction: 45 deg, down_0: 5 m, substep: 0.05 s,
                 wave_hs: 0.5 m, wave_tp: 5 s, wave_components: 20}
  observer: {kind: observer}
  controller:
    kind: controller
    parameters: {down_ref: 5 m}
  allocator: {kind: allocator}
checks:
  - {name: north error, signal: plant.north, minus: controller.north_ref, metric: max_abs, after: 2, max: 1.0}
"""


@pytest.fixture()
def short(tmp_path: Path) -> Path:
    p = tmp_path / "short.yaml"
    p.write_text(SHORT)
    return p


@pytest.mark.parametrize("given, expected", [
    ("plant.current_speed=0.2 deg", "--set plant.current_speed=0.2 deg: unit 'deg'"),
    ("plant.current_speed=-1m/s", "--set plant.current_speed=-1m/s: -1 m/s is below the minimum 0"),
    ("plant.bogus=1", "--set plant.bogus=1: no such variable in FMU 'plant'\n"),  # nothing close: no hint
    ("pilot.x=1", "--set pilot.x=1: unknown FMU 'pilot' (FMUs: plant, observer"),
    ("plant.curent_speed=0.2m/s", "no such variable in FMU 'plant'; did you mean 'current_speed'?"),
    ("plantt.current_speed=0.2m/s", "unknown FMU 'plantt'; did you mean 'plant'?"),
    ("plant.north=1", "--set plant.north=1: is an output; it cannot be set"),
    ("plant.seed=1.5", "--set plant.seed=1.5: expected a whole number"),
    ("controller.kp_north=fast", "--set controller.kp_north=fast: expected a number"),
    ("plant.current_speed", "must read instance.variable=value"),
    ("plant.fail_mode_3@3.01=1", "--set plant.fail_mode_3@3.01=1: time 3.01 s is not on the step grid"),
    ("plant.wave_tp@2=6", "--set plant.wave_tp@2=6: plant.wave_tp is a fixed parameter"),
    ("plant.current_speed=[1, 2]", "the value must be a number"),
    # text parameters checked as the FMU checks them when it initialises, so a check or a sweep's
    # validation refuses what would fail in the run
    ("allocator.allocator=bogus", "--set allocator.allocator=bogus: unknown allocator variant 'bogus'"),
    ("allocator.allocator@1=bogus", "allocator.allocator@1=bogus: unknown allocator variant 'bogus'; known:"),
    ("controller.controller_variant=bogus", "unknown controller variant 'bogus'; known: dp_pid"),
    ("controller.waypoints=garbage;;", "waypoints: entry 1 'garbage' is not 'north, east'"),
    ("controller.north_hat=5", "controller.north_hat is an input driven by observer.north_hat"),
    ("plant.current_speed=1_0 m/s", "expected a number or '<number> <unit>', got '1_0 m/s'"),
])
def test_set_errors_are_one_line(short: Path, capsys: pytest.CaptureFixture[str], given: str,
                                 expected: str) -> None:
    assert main(["run", str(short), "--set", given, "-o", str(short.parent / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("seafmu: error: ")
    assert expected in err
    assert not (short.parent / "out" / "results.csv").exists()  # nothing ran


def test_numbers_with_an_exponent_and_units_the_table_lacks(short: Path) -> None:
    """'1e-2' is a number (not 1 in a unit 'e-2'); a variable's own unit is accepted even where the
    conversion table has no entry for it (the allocator's N/s)."""
    sc = load_scenario(short, [parse_override("plant.current_speed=1e-2"),
                               parse_override("plant.current_direction=2E2 deg"),
                               parse_override("allocator.thrust_rate_max_1=150 N/s")])
    params = {i.name: i.parameters for i in sc.instances}
    assert params["plant"]["current_speed"] == 0.01
    assert params["plant"]["current_direction"] == pytest.approx(200 * math.pi / 180)
    assert params["allocator"]["thrust_rate_max_1"] == 150.0


def test_bad_seed_is_one_line(short: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(short), "--seed", "-3", "-q", "-o", str(short.parent / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--seed (fmus.plant.seed): -3 is below the minimum 0" in err


def test_seed_without_random_source(tmp_path: Path) -> None:
    p = tmp_path / "noseed.yaml"
    p.write_text("name: x\nvessel: minerva2\nduration: 1\nstep: 0.05\nfmus:\n  observer: {kind: observer}\n")
    with pytest.raises(ScenarioError, match="--seed: no FMU of this scenario has a seed parameter"):
        load_scenario(p, seed=3)


def test_set_is_the_file_value(short: Path) -> None:
    """A --set equal to what the file says changes nothing; a --set converts units as the file does."""
    same = load_scenario(short, [parse_override("plant.current_speed=0.1 m/s")])
    base = load_scenario(short)
    assert same.instance("plant").parameters == base.instance("plant").parameters
    kn = load_scenario(short, [parse_override("plant.current_speed=0.5kn")])
    assert kn.instance("plant").parameters["current_speed"] == pytest.approx(0.5 * 1852 / 3600, rel=1e-15)
    ev = load_scenario(short, [parse_override("controller.north_ref@4=2 m")])
    assert (4.0, "controller", "north_ref", 2.0) in ev.events


def _run(short: Path, seed: int | None, sets: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    sc = load_scenario(short, [parse_override(s) for s in sets], seed)
    return run(sc, progress=False).signals


def test_seed_reaches_every_random_source(short: Path, built_fmus: object) -> None:
    """--seed 1 is the file's seed 1; another seed changes the waves, the sensor noise and what
    follows from them; the same seed twice is bit-identical."""
    base = _run(short, None)
    s1 = _run(short, 1)
    s7 = _run(short, 7)
    s7b = _run(short, 7)
    for k in base:
        np.testing.assert_array_equal(base[k], s1[k], err_msg=k)
        np.testing.assert_array_equal(s7[k], s7b[k], err_msg=k)
    for k in ("plant.wave_elevation", "plant.meas_north", "plant.meas_yaw", "plant.meas_u", "plant.north",
              "observer.north_hat"):
        assert not np.array_equal(base[k], s7[k]), f"{k} does not depend on the seed"


def test_run_cli_set_seed_parquet(short: Path, built_fmus: object) -> None:
    import pandas as pd

    out = short.parent / "out"
    rc = main(["run", str(short), "--set", "plant.current_speed=0.2m/s", "--set", "controller.kp_north=5",
               "--seed", "7", "--format", "parquet", "-o", str(out), "-q"])
    assert rc in (0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["overrides"] == ["plant.current_speed=0.2m/s", "controller.kp_north=5"]
    assert summary["seed"] == 7
    frame = pd.read_parquet(out / "results.parquet")
    csv = np.loadtxt(out / "results.csv", delimiter=",", skiprows=1)
    assert frame.columns[0] == "time" and frame.shape == csv.shape
    np.testing.assert_allclose(frame.to_numpy(), csv, rtol=1e-9, atol=1e-12)  # CSV holds 10 digits
    assert "`--set plant.current_speed=0.2m/s`" in (out / "report.md").read_text()
