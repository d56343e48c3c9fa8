"""The link as an FMU (another FMI tool drives the vessel through it), and the emulator's command line."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from seafmu.components.vessel_spec import load_vessel
from seafmu.hardware.cli import register
from seafmu.hardware.emulator import VesselEmulator, _plant_params, build_parser
from seafmu.hardware.link_fmu import build_link_fmu
from seafmu.hardware.profile import load_profile
from seafmu.hardware.ptybridge import NullModem
from seafmu.unitdefs import base_unit

REPO = Path(__file__).resolve().parents[1]


def test_link_fmu_validates_and_drives_the_emulated_vessel(tmp_path: Path) -> None:
    fmu = build_link_fmu("emulator_pty", tmp_path, base_unit=base_unit)
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    names = {v.name: v for v in md.modelVariables}
    assert names["n_cmd_1"].causality == "input" and names["meas_north"].unit == "m"
    assert names["watchdog_alarm"].causality == "output" and "north" not in names

    with NullModem() as ser, NullModem() as slcan:
        base = load_profile("emulator_pty")
        emu = VesselEmulator(
            base.with_overrides(**{"serial.url": ser.a, "can.channel": slcan.a}), {"seed": 1, "down_0": 5.0}
        )
        emu.open()
        th = threading.Thread(target=emu.run, daemon=True)
        th.start()
        slave = FMU2Slave(
            guid=md.guid,
            unzipDirectory=extract(str(fmu)),
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="link",
        )
        try:
            slave.instantiate()
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            slave.setString(
                [names["serial_url"].valueReference, names["can_channel"].valueReference], [ser.b, slcan.b]
            )
            slave.exitInitializationMode()
            vr_in = [names[f"n_cmd_{i}"].valueReference for i in range(1, 8)]
            vr_out = [names[n].valueReference for n in ("meas_down", "depth_count", "n_5", "watchdog_alarm")]
            slave.setReal(vr_in, [0, 0, 0, 0, 10.0, 0, 0])  # the aft vertical thruster pushes down
            h = 0.05
            for k in range(30):
                slave.doStep(k * h, h)
            down, count, n5, alarm = slave.getReal(vr_out)
            slave.terminate()
        finally:
            slave.freeInstance()
            emu.stop_event.set()
            th.join(timeout=5)
            emu.close()
    assert 4.9 < down < 5.5 and count >= 10 and alarm == 0.0
    assert 9.0 < n5 <= 10.0  # the drive's measured speed came back over CAN


def test_link_fmu_of_a_users_profile_file_and_a_bad_profile(tmp_path: Path, capsys: object) -> None:
    """A profile anywhere on disk builds (the docs: "hardware/profiles/, or any path"); a profile that
    does not load is one line, exit 2, before any FMU is built, and leaves nothing behind."""
    doc = (REPO / "hardware" / "profiles" / "emulator_pty.yaml").read_text()
    mine = tmp_path / "profiles" / "my_rov.yaml"
    mine.parent.mkdir()
    mine.write_text(doc.replace("name: emulator_pty", "name: my_rov", 1))
    assert load_profile(mine).name == "my_rov"
    fmu = build_link_fmu(mine, tmp_path / "out", base_unit=base_unit)
    assert fmu.name == "MyRovLink.fmu" and validate_fmu(str(fmu)) == []
    names = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    assert names["meas_north"].unit == "m" and names["n_cmd_1"].causality == "input"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["MyRovLink.fmu"]

    from seafmu.cli import main

    assert main(["build", "--vessel", "minerva2", "--link", str(tmp_path / "nosuch.yaml")]) == 2
    err = capsys.readouterr()  # type: ignore[attr-defined]
    assert err.out == "" and len(err.err.strip().splitlines()) == 1, err
    assert "nosuch.yaml" in err.err and "no such file" in err.err
    for bad in ("bogus", "../../etc"):  # a vessel name, never a path: it names the build's files
        assert main(["build", "--vessel", bad]) == 2
        err = capsys.readouterr()  # type: ignore[attr-defined]
        assert err.err == (f"seafmu: error: --vessel {bad}: not a vessel with FMUs "
                           "(vessels: amv_osf, minerva2, supply)\n"), err


def test_emulate_subcommand_and_its_ready_line() -> None:
    parser = argparse.ArgumentParser(prog="seafmu")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        ["emulate", "amv_osf", "--serial", "pty", "--can", "slcan:pty", "--set", "seed=3"]
    )
    assert args.vessel == "amv_osf" and args.set == ["seed=3"] and callable(args.fn)

    proc = subprocess.Popen(
        [sys.executable, "-m", "seafmu.hardware.emulator", "amv_osf", "--serial", "pty",
         "--can", "slcan:pty"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("READY serial=/dev/pts/") and " can=slcan:/dev/pts/" in line
        assert Path(line.split()[1].split("=", 1)[1]).exists()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    bad = subprocess.run(
        [sys.executable, "-m", "seafmu.hardware.emulator", "minerva2", "--serial", "pty", "--can", "slcan"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "INTERFACE:CHANNEL" in bad.stderr


def test_emulator_takes_the_whole_can_part_of_a_users_profile(tmp_path: Path) -> None:
    """``seafmu emulate --profile P`` speaks the profile's NMEA 2000 addresses and its own DBC (a
    relative path: beside the profile, as the link finds it): the link's commands reach the drives
    and their feedback comes back. A profile for another vessel's sensors is one line, exit 2."""
    import numpy as np

    from seafmu.hardware.link import HardwareLink

    doc = (REPO / "hardware" / "profiles" / "emulator_pty.yaml").read_text()
    (tmp_path / "my.dbc").write_bytes((REPO / "hardware" / "nmea2000_thrusters.dbc").read_bytes())
    serial_url, slcan_channel = str(tmp_path / "nmea"), str(tmp_path / "slcan")
    doc = doc.replace("name: emulator_pty", "name: n2k_rov", 1)
    doc = doc.replace("mapping: seafmu", "mapping: nmea2000\n  dbc: my.dbc\n  source_address: 17\n"
                      "  thruster_address: 48", 1)
    doc = doc.replace("command_timeout: 0.5", "command_timeout: 0.25", 1)
    path = tmp_path / "n2k_rov.yaml"
    path.write_text(doc)
    prof = load_profile(path).with_overrides(**{"serial.url": serial_url, "can.channel": slcan_channel})
    assert (prof.can.mapping, prof.can.source_address, prof.can.thruster_address) == ("nmea2000", 17, 48)
    path.write_text(yaml.safe_dump(prof.model_dump(exclude={"source"}), sort_keys=False))
    proc = subprocess.Popen(
        [sys.executable, "-m", "seafmu.hardware.emulator", "minerva2", "--serial", f"pty:{serial_url}",
         "--can", f"slcan:pty:{slcan_channel}", "--profile", str(path)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    link = None
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("READY")
        link = HardwareLink(load_profile(path))
        link.initialize(np.full(7, 4.0))
        link.set_inputs(np.full(7, 4.0))
        t, h = 0.0, 0.05
        for _ in range(40):
            link.do_step(t, h)
            t += h
        assert np.allclose(link.get_outputs()[:7], 4.0, atol=0.05) and not link.alarm
    finally:
        if link is not None:
            link.close()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "TIMEOUT" not in err, err
    assert "seafmu emulate: stopped (SIGTERM) at vessel time" in err, err  # one closing line
    other = subprocess.run(
        [sys.executable, "-m", "seafmu.hardware.emulator", "amv_osf", "--serial", "pty", "--can", "slcan:pty",
         "--profile", "emulator_pty"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert other.returncode == 2 and len(other.stderr.strip().splitlines()) == 1, other.stderr
    assert other.stderr.startswith("seafmu emulate: error:") and "sensor" in other.stderr


def test_emulator_set_takes_units_as_run_does() -> None:
    """``seafmu emulate --set`` reads a plant parameter as ``seafmu run --set plant.NAME=VALUE`` does:
    a quantity in its unit, a bare SI number, its type and range; a bad one is one line naming it."""
    import math

    from seafmu.emulate import plant_set_values, scenario_plant_parameters
    from seafmu.hardware.emulator import ScenarioReader

    reader = ScenarioReader(scenario_plant_parameters, plant_set_values)
    spec = load_vessel("minerva2")
    params = _plant_params(None, ["current_speed=0.4kn", "plant.current_direction=90 deg", "seed=3"], reader,
                           spec=spec)  # the plant. of run's --set may be given
    assert params == {"current_speed": pytest.approx(0.4 * 1852 / 3600),
                      "current_direction": pytest.approx(math.pi / 2), "seed": 3}
    for item, why in (("current_speed=30kn", "is above the maximum 10"), ("curent_speed=1", "did you mean"),
                      ("current_speed=2 deg", "current_speed=2 deg"), ("seed=1.5", "expected a whole number"),
                      ("current_speed@3=1", "no timed values"), ("current_speed", "must read NAME=VALUE"),
                      ("vessel_file=x.yaml", "its VESSEL argument"), ("plant.curent_speed=1", "did you mean"),
                      ("current_speed=", "no value after"), ("current_speed=x: y", "the value must be")):
        with pytest.raises(ValueError, match=why) as exc:
            _plant_params(None, [item], reader, spec=spec)
        assert "\n" not in str(exc.value) and str(exc.value).startswith(f"--set {item}")


def test_emulator_carries_a_fouled_thruster() -> None:
    """``--thruster-efficiency 3=0.6`` reaches the emulated plant; bad values are one line naming them."""
    args = build_parser().parse_args(["minerva2", "--serial", "pty", "--can", "slcan:pty", "--set", "seed=2",
                                      "--thruster-efficiency", "3=0.6"])
    params = _plant_params(None, args.set, None, args.thruster_efficiency)
    assert params == {"seed": 2.0, "thruster_efficiency_3": 0.6}
    with NullModem() as ser, NullModem() as slcan:
        profile = load_profile("emulator_pty").with_overrides(**{"serial.url": ser.a, "can.channel": slcan.a})
        emu = VesselEmulator(profile, params)
        try:
            assert emu.plant.efficiency == [1.0, 1.0, 0.6, 1.0, 1.0, 1.0, 1.0]
        finally:
            emu.close()
    for value, why in (("x=0.6", "expected THRUSTER=FRACTION"), ("3=most", "must be a number"),
                       ("3=2", "parameter 'thruster_efficiency_3' must be within [0, 1.5]")):
        bad = subprocess.run(
            [sys.executable, "-m", "seafmu.emulate", "minerva2", "--serial", "pty", "--can", "slcan:pty",
             "--thruster-efficiency", value],
            cwd=REPO, capture_output=True, text=True, timeout=60,
        )
        assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and why in bad.stderr, bad.stderr
