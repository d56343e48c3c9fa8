"""The link as an FMU (another FMI tool drives the vessel through it), and the emulator's command line."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

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
