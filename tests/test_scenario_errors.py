"""Malformed scenarios: each fails before the run with one line naming the field."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from seafmu.cli import main
from seafmu.scenario import ScenarioError, load_scenario

BASE = {
    "name": "t",
    "vessel": "minerva2",
    "duration": 10.0,
    "step": 0.05,
    "fmus": {
        "plant": {"kind": "plant", "parameters": {"current_speed": "0.1 m/s"}},
        "observer": {"kind": "observer"},
        "controller": {"kind": "controller"},
        "allocator": {"kind": "allocator"},
    },
    "events": [{"time": 5, "set": "controller.north_ref", "value": "2 m"}],
    "checks": [{"signal": "plant.north", "metric": "max_abs", "max": 10}],
}


def _write(tmp_path: Path, doc: object) -> Path:
    from seafmu.components.vessel_spec import vessel_path

    if isinstance(doc, dict) and doc.get("fmus", {}).get("plant", {}).get("parameters", {}).get(
            "vessel_file") == "AMV":
        doc["fmus"]["plant"]["parameters"]["vessel_file"] = str(vessel_path("amv_osf"))
    p = tmp_path / "scenario.yaml"
    p.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc, sort_keys=False))
    return p


def _mutate(change: dict) -> dict:
    import copy

    doc = copy.deepcopy(BASE)
    for path, value in change.items():
        node = doc
        keys = path.split("/")
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node[k]
        last = keys[-1]
        if value is _DELETE:
            del node[last]
        elif isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return doc


_DELETE = object()

CASES = [
    ("unknown top-level field", {"durration": 5}, "durration: unknown field"),
    ("missing vessel", {"vessel": _DELETE}, "vessel: required field is missing"),
    ("misspelled required field", {"duration": _DELETE, "duraton": 10},
     "duraton: unknown field (did you mean 'duration'? it is missing)"),
    ("unknown vessel", {"vessel": "titanic"}, "vessel: vessel 'titanic'"),
    ("negative duration", {"duration": -1}, "duration: Input should be greater than 0"),
    ("true as a duration", {"duration": True}, "duration: expected a number, not true or false"),
    ("false as a check bound", {"checks/0/max": False}, "checks.0.max: expected a number, not true or false"),
    ("step does not divide duration", {"step": 0.3}, "step: duration 10.0 s is not a whole number"),
    ("unknown FMU in event", {"events/0/set": "ctrl.north_ref"}, "events[0]: unknown FMU 'ctrl'"),
    ("unknown variable", {"events/0/set": "controller.nort_ref"},
     "events[0]: FMU 'controller' has no variable 'nort_ref'"),
    ("wrong type for integer", {"fmus/plant/parameters/seed": 1.5},
     "fmus.plant.parameters.seed: expected a whole number"),
    ("unit of the wrong dimension", {"fmus/plant/parameters/current_speed": "0.1 m"},
     "unit 'm' in '0.1 m' does not fit this variable's unit 'm/s'"),
    ("unknown unit", {"events/0/value": "3 furlongs"}, "events[0].value: unknown unit 'furlongs'"),
    ("event on an output", {"events/0/set": "plant.north"}, "'plant.north' is an output"),
    ("event on a fixed parameter", {"events/0/set": "plant.seed", "events/0/value": 3},
     "plant.seed is a fixed parameter"),
    ("event after the end", {"events/0/time": 11}, "events[0]: time 11.0 is not before the end"),
    ("event at the end has no effect", {"events/0/time": 10}, "events[0]: time 10.0 is not before the end"),
    ("event off the step grid", {"events/0/time": 5.01}, "events[0]: time 5.01 s is not on the step grid"),
    ("empty fmus", {"fmus": {}}, "fmus: lists no FMU"),
    ("FMU name not an identifier", {"fmus": {"p.x": {"kind": "plant"}}}, "fmus.p.x: an FMU name must be"),
    ("scenario name not an identifier", {"name": "../escape"}, "name: String should match pattern"),
    ("integer out of range", {"fmus/plant/parameters/seed": -1}, "fmus.plant.parameters.seed: -1 is below"),
    ("integer wider than 32 bits", {"fmus/plant/parameters/seed": 4294967297},
     "does not fit an FMI Integer (32 bits)"),
    ("unit on a dimensionless variable", {"fmus/plant/parameters/noise_scale": "2 km"},
     "unit 'km' in '2 km' does not fit this variable's unit '1'"),
    ("infinite duration", {"duration": float("inf")}, "duration: Input should be a finite number"),
    ("check window backwards", {"checks/0/after": 5, "checks/0/before": 2}, "'before' (2.0) must be after"),
    ("check min above max", {"checks/0/min": 20}, "min 20.0 is above max 10.0"),
    ("vessel without FMUs", {"vessel": "minerva2_published_damping"},
     "vessel: 'minerva2_published_damping' has no FMUs"),
    ("vessel_file missing", {"fmus/plant/parameters/vessel_file": "nowhere.yaml"},
     "nowhere.yaml (bundled:"),
    ("vessel_file of another interface", {"fmus/plant/parameters/vessel_file": "AMV"},
     "has another interface than vessel 'minerva2'"),
    ("duplicate connection target",
     {"connections": ["plant.north -> controller.north_hat", "plant.east -> controller.north_hat"]},
     "connections[1]: controller.north_hat is already connected"),
    ("record interval does not divide the duration", {"duration": 10.5, "record_interval": 1.0},
     "record_interval: 1.0 s does not divide the duration"),
    ("step multiple does not divide the run", {"fmus/observer/step_multiple": 3},
     "fmus.observer.step_multiple: 3 steps of 0.05 s do not divide"),
    ("connection without arrow", {"connections": ["plant.north observer.north_hat"]},
     "connections[0]: 'plant.north observer.north_hat' must read"),
    ("connection unit mismatch", {"connections": ["plant.north -> controller.yaw_hat"]},
     "connections[0]: unit mismatch"),
    ("a count into a position", {"connections": ["plant.usbl_count -> controller.north_hat"]},
     "connections[0]: unit mismatch: plant.usbl_count is without a unit, controller.north_hat in m"),
    ("check of metres minus radians",
     {"checks": [{"signal": "plant.north", "minus": "plant.yaw", "metric": "max_abs", "max": 1}]},
     "checks[0].minus: unit mismatch: plant.north is in m, plant.yaw in rad"),
    ("connection into an output", {"connections": ["plant.north -> observer.north_hat"]},
     "'observer.north_hat' is an output, expected input"),
    ("step multiple zero", {"fmus/observer/step_multiple": 0}, "fmus.observer.step_multiple"),
    ("allocator that cannot serve the vessel", {"fmus/allocator/parameters": {"allocator": "two_screw"}},
     "fmus.allocator.parameters.allocator: allocator 'two_screw' needs exactly two thrusters"),
    ("lawnmower lines above their maximum", {"fmus/controller/parameters": {"lm_lines": 100000}},
     "fmus.controller.parameters.lm_lines: 100000 is above the maximum 1000"),
    ("record interval not a multiple", {"record_interval": 0.07}, "record_interval: 0.07 s must be"),
    ("check without bound", {"checks/0/max": _DELETE}, "checks.0: a check needs 'max' or 'min'"),
    ("parameter below minimum", {"fmus/plant/parameters/noise_scale": -1},
     "fmus.plant.parameters.noise_scale: -1 is below the minimum 0"),
    ("parameter that does not exist", {"fmus/plant/parameters/gravity": 9.8},
     "fmus.plant.parameters.gravity: no such variable"),
    ("both kind and fmu", {"fmus/observer/fmu": "x.fmu"}, "give exactly one of 'kind', 'fmu' or 'hardware'"),
    ("missing FMU file", {"fmus/observer": {"fmu": "nowhere.fmu"}}, "fmus.observer.fmu: no such FMU file"),
    # issue 8: every number that sizes the run is bounded before anything is allocated
    ("step longer than the run (ran 0 steps)", {"step": 1e308},
     "step: 1e+308 s is longer than the duration 10 s"),
    ("step below the minimum (petabytes)", {"step": 1e-12},
     "step: 1e-12 s is below the smallest step, 1e-06 s"),
    ("duration above the maximum (traceback)", {"duration": 1e308},
     "duration: 1e+308 s is above the limit of 1e+07 s (116 days)"),
    ("too many steps", {"duration": 1e6},
     "step: 1e+06 s in steps of 0.05 s is 2e+07 steps; a run is limited to 1e+07 steps"),
    ("results too large for memory", {"duration": 1e5, "step": 0.01},
     "step: 10000001 samples x 131 columns = 10.5 GB of results in memory; the limit is 1 GB"),
    ("record interval longer than the run", {"record_interval": 20},
     "record_interval: 20 s is longer than the duration 10 s"),
    ("step multiple longer than the run", {"fmus/observer/step_multiple": 400},
     "fmus.observer.step_multiple: 400 is more than the run's 200 steps"),
    ("check window between two samples", {"checks/0/after": 5.01, "checks/0/before": 5.02},
     "checks[0]: the window t >= 5.01 s, t <= 5.02 s contains no recorded sample (samples every 0.05 s)"),
    ("check window before the run", {"checks/0/after": -5, "checks/0/before": -1},
     "checks[0]: the window t >= -5 s, t <= -1 s contains no recorded sample"),
    ("too many FMUs", {"fmus": {f"p{i}": {"kind": "plant"} for i in range(65)}},
     "fmus: 65 FMUs; a scenario is limited to 64"),
    ("number too large for a float", {"fmus/plant/parameters/current_speed": 10**400},
     "fmus.plant.parameters.current_speed: 1000000"),
    ("event far after the run", {"events/0/time": 1e308}, "events[0]: time 1e+308 is not before the end"),
    ("control characters in a name", {"vessel": "a\x1eb"}, "vessel: vessel 'a\x1eb'"),
]


@pytest.mark.parametrize(("label", "change", "expected"), CASES, ids=[c[0] for c in CASES])
def test_malformed_scenario_names_the_field(tmp_path: Path, label: str, change: dict, expected: str) -> None:
    path = _write(tmp_path, _mutate(change))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(str(path))
    assert expected in msg, msg


def test_base_scenario_is_valid(tmp_path: Path) -> None:
    sc = load_scenario(_write(tmp_path, BASE))
    assert [i.name for i in sc.instances] == ["plant", "observer", "controller", "allocator"]
    assert sc.instance("plant").parameters["current_speed"] == pytest.approx(0.1)
    # auto-connection by names closes the loop in all four directions
    pairs = {(s, d) for s, _, d, _ in sc.connections}
    assert {("plant", "observer"), ("observer", "controller"), ("controller", "allocator"),
            ("allocator", "plant"), ("allocator", "observer")} <= pairs
    assert sc.events == [(5.0, "controller", "north_ref", 2.0)]


def test_units_convert_to_si(tmp_path: Path) -> None:
    doc = _mutate({"events/0/set": "controller.yaw_ref", "events/0/value": "90 deg",
                   "fmus/plant/parameters/current_speed": "0.5 kn"})
    sc = load_scenario(_write(tmp_path, doc))
    assert sc.events[0][3] == pytest.approx(3.141592653589793 / 2)
    assert sc.instance("plant").parameters["current_speed"] == pytest.approx(0.5 * 1852 / 3600)


def test_duplicate_keys_and_bad_encoding(tmp_path: Path) -> None:
    text = yaml.safe_dump(BASE, sort_keys=False) + "duration: 20\n"
    with pytest.raises(ScenarioError, match="duplicate key 'duration'"):
        load_scenario(_write(tmp_path, text))
    p = tmp_path / "latin1.yaml"
    p.write_bytes("name: t\nvessel: minerva2\n# \xe9\n".encode("latin-1"))
    with pytest.raises(ScenarioError, match="not UTF-8 text"):
        load_scenario(p)


def test_not_yaml_and_not_a_mapping(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="not valid YAML") as exc:
        load_scenario(_write(tmp_path, "name: [unclosed\n"))
    assert "<unicode string>" not in str(exc.value) and "at line 1, column 7" in str(exc.value)
    with pytest.raises(ScenarioError, match="expected a mapping"):
        load_scenario(_write(tmp_path, "- a\n- b\n"))


def test_cli_prints_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path, _mutate({"step": 0.3}))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("seafmu: error:") and "step" in err[0]


def test_cli_entry_point_no_traceback(tmp_path: Path) -> None:
    path = _write(tmp_path, _mutate({"vessel": "titanic"}))
    cmd = [sys.executable, "-m", "seafmu.cli", "run", str(path)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_hardware_plant_in_a_scenario(tmp_path: Path) -> None:
    """A hardware profile stands in for the plant: validated without opening a port."""
    doc = _mutate({"fmus/plant": {"hardware": "emulator_pty"}, "checks/0/signal": "observer.north_hat"})
    sc = load_scenario(_write(tmp_path, doc))
    assert sc.realtime and sc.instance("plant").hardware == "emulator_pty"
    assert ("plant", "meas_north", "observer", "meas_north") in sc.connections
    # a real vessel reports no true state: checks on it fail by name, before the run
    with pytest.raises(ScenarioError, match="FMU 'plant' has no variable 'north'"):
        load_scenario(_write(tmp_path, _mutate({"fmus/plant": {"hardware": "emulator_pty"}})))
    with pytest.raises(ScenarioError, match=r"fmus\.plant\.hardware: hardware profile 'nowhere'"):
        load_scenario(_write(tmp_path, _mutate({"fmus/plant": {"hardware": "nowhere"}})))


# -- numbers as YAML 1.2 reads them, plausibility maxima, events, folders ---------------------------

def _override(tmp_path: Path, text: str):
    from seafmu.scenario import parse_override

    return load_scenario(_write(tmp_path, BASE), [parse_override(text)])


@pytest.mark.parametrize("text, value", [
    ("controller.north_ref=010", 10.0),  # decimal, not octal 8
    ("controller.north_ref=1e1", 10.0),
    ("controller.north_ref=-.5", -0.5),
    ("plant.seed=010", 10),
])
def test_set_reads_plain_decimal_numbers(tmp_path: Path, text: str, value: float) -> None:
    inst, var = text.split("=")[0].split(".")
    assert _override(tmp_path, text).instance(inst).parameters[var] == value


@pytest.mark.parametrize("text, expected", [
    ("controller.north_ref=1_0", "--set controller.north_ref=1_0: expected a number or '<number> <unit>', "
                                 "got '1_0'"),
    ("controller.north_ref=1:30", "--set controller.north_ref=1:30: expected a number"),
    ("plant.current_speed=0x10", "--set plant.current_speed=0x10: unknown unit"),
    ("plant.seed=0b11", "--set plant.seed=0b11: expected a whole number, got '0b11'"),
    ("plant.seed=0o7", "--set plant.seed=0o7: expected a whole number, got '0o7'"),
])
def test_set_refuses_yaml11_numbers(tmp_path: Path, text: str, expected: str) -> None:
    with pytest.raises(ScenarioError, match=re.escape(expected)):
        _override(tmp_path, text)


def test_scenario_file_numbers_are_decimal(tmp_path: Path) -> None:
    text = yaml.safe_dump(BASE, sort_keys=False).replace("current_speed: 0.1 m/s", "down_0: 010")
    assert load_scenario(_write(tmp_path, text)).instance("plant").parameters["down_0"] == 10.0
    with pytest.raises(ScenarioError, match=r"fmus\.plant\.parameters\.down_0: expected a number"):
        load_scenario(_write(tmp_path, text.replace("down_0: 010", "down_0: 1_0")))
    with pytest.raises(ScenarioError, match=r"fmus\.plant\.parameters\.seed: expected a whole number"):
        load_scenario(_write(tmp_path, text.replace("down_0: 010", "seed: 0x10")))
    with pytest.raises(ScenarioError, match=r"duration: Input should be a valid number"):
        load_scenario(_write(tmp_path, text.replace("duration: 10.0", "duration: 1:30")))


def test_scenario_and_vessel_loaders_read_numbers_alike() -> None:
    """The scenario files' loader and the vessel files' (both made YAML 1.2 by
    components/yaml_numbers.py) read every case the same, and unlike PyYAML's YAML 1.1 SafeLoader."""
    from seafmu.components.vessel_spec import _Loader
    from seafmu.yamlfile import load_value

    cases = {"010": 10, "-7": -7, "+3": 3, "1e30": 1e30, "1.5E-3": 1.5e-3, "2.": 2.0, ".5": 0.5,
             ".inf": float("inf"), "-.Inf": -float("inf"), "1_0": "1_0", "1:30": "1:30", "0x10": "0x10",
             "0b11": "0b11", "0o7": "0o7", "1e": "1e", "inf": "inf", "true": True, "~": None}
    for text, want in cases.items():
        got = (load_value(text), yaml.load(text, Loader=_Loader))
        assert got == (want, want) and all(type(g) is type(want) for g in got), text
    nan = (load_value(".nan"), yaml.load(".NaN", Loader=_Loader))
    assert all(x != x for x in nan)
    assert yaml.safe_load("010") == 8  # PyYAML's own loader is left as it is
    assert issubclass(_Loader, getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml kept


@pytest.mark.parametrize("text, expected", [
    ("plant.current_speed=1e30", "1e+30 m/s is above the maximum 10"),
    ("plant.current_speed=11 m/s", "11 m/s is above the maximum 10"),
    ("plant.noise_scale=1e30", "1e+30 is above the maximum 100"),
    ("plant.current_variation=1e10", "1e+10 m/s is above the maximum 5"),
])
def test_plant_parameters_have_plausible_maxima(tmp_path: Path, text: str, expected: str) -> None:
    with pytest.raises(ScenarioError, match=re.escape(f"--set {text}: {expected}")):
        _override(tmp_path, text)


def test_plant_maxima_themselves_are_accepted(tmp_path: Path) -> None:
    from seafmu.scenario import parse_override

    sets = ["plant.current_speed=10", "plant.noise_scale=100", "plant.current_variation=5"]
    sc = load_scenario(_write(tmp_path, BASE), [parse_override(s) for s in sets])
    p = sc.instance("plant").parameters
    assert (p["current_speed"], p["noise_scale"], p["current_variation"]) == (10.0, 100.0, 5.0)


def test_two_events_setting_one_variable_at_one_time(tmp_path: Path) -> None:
    from seafmu.scenario import parse_override

    same = [{"time": 1, "set": "controller.north_ref", "value": "1 m"},
            {"time": 1.0, "set": "controller.north_ref", "value": "2 m"}]
    with pytest.raises(ScenarioError, match=re.escape(
            "events[1]: sets controller.north_ref at 1 s, as events[0] does")):
        load_scenario(_write(tmp_path, _mutate({"events": same})))
    with pytest.raises(ScenarioError, match=re.escape(
            "--set controller.north_ref@5=3 m: sets controller.north_ref at 5 s, as events[0] does")):
        load_scenario(_write(tmp_path, BASE), [parse_override("controller.north_ref@5=3 m")])
    # another time, or another variable at the same time, is fine
    other = [same[0], {**same[1], "time": 2}, {**same[1], "set": "controller.east_ref"}]
    sc = load_scenario(_write(tmp_path, _mutate({"events": other})))
    assert [(t, v) for t, _, v, _ in sc.events] == [(1.0, "north_ref"), (1.0, "east_ref"), (2.0, "north_ref")]


def test_a_folder_is_neither_an_fmu_nor_a_vessel_file(tmp_path: Path) -> None:
    (tmp_path / "unpacked").mkdir()
    with pytest.raises(ScenarioError, match=re.escape(
            f"fmus.allocator.fmu: {tmp_path / 'unpacked'} is a folder, not an FMU file")):
        load_scenario(_write(tmp_path, _mutate({"fmus/allocator": {"fmu": "unpacked"}})))
    for given in ("unpacked", "unpacked.yaml"):
        if given.endswith(".yaml"):
            (tmp_path / given).mkdir()
        with pytest.raises(ScenarioError, match=re.escape(
                f"fmus.plant.parameters.vessel_file: {tmp_path / given}: is a folder, not a vessel file")):
            load_scenario(_write(tmp_path, _mutate({"fmus/plant/parameters/vessel_file": given})))
