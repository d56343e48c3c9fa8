"""The emulator's injected faults (``seafmu emulate --fault``), end to end through a link: what a
user rehearses before a wet run. NMEA through a pseudo-terminal pair, CAN on python-can's virtual bus."""

from __future__ import annotations

import itertools
import math
import threading

import numpy as np
import pytest

from seafmu.hardware.emulator import VesselEmulator
from seafmu.hardware.emulator import main as emulate_main
from seafmu.hardware.faults import Fault, FaultSchedule, check_faults, parse_fault
from seafmu.hardware.link import HardwareLink
from seafmu.hardware.profile import load_profile
from seafmu.hardware.ptybridge import NullModem

SENSORS = ["usbl", "depth", "ahrs", "dvl", "gyro"]
_chan = itertools.count()


def test_fault_specs_are_read_and_bad_ones_named_in_one_line() -> None:
    assert parse_fault("drive-frozen:3@20-30", SENSORS, 7) == Fault("drive-frozen", 2, 20.0, 30.0)
    assert parse_fault("sensor-silent:usbl@5", SENSORS, 7) == Fault("sensor-silent", "usbl", 5.0, math.inf)
    assert parse_fault("drive-silent:7@0.5-1.25", SENSORS, 7).label == "drive-silent:7@0.5-1.25"
    bad = {
        "drive-frozen:3": "expected KIND:TARGET@START[-END]",
        "drive-stuck:3@1": "unknown kind 'drive-stuck' (known: sensor-silent, sensor-frozen, drive-silent",
        "drive-frozen:8@1": "thruster '8': give a number from 1 to 7",
        "drive-frozen:0@1": "thruster '0': give a number from 1 to 7",
        "sensor-frozen:gps@1": "no sensor 'gps' on this vessel (its sensors: usbl, depth, ahrs, dvl, gyro)",
        "sensor-frozen:dvl@x": "'x' is not START or START-END in seconds of vessel time, from 0",
        "sensor-frozen:dvl@5-2": "ends at 2 s, not after its start 5 s",
        "sensor-frozen:dvl@inf": "'inf' is not START or START-END",
        "sensor-frozen:dvl@-1": "'-1' is not START or START-END",
        "sensor-frozen:dvl@1e-3": "'1e-3' is not START or START-END",  # plain decimals only: not 1_0, ...
        "sensor-frozen:dvl@1_0": "'1_0' is not START or START-END",
        "sensor-frozen:dvl@\uff11": "'\uff11' is not START or START-END",  # a full-width digit one
    }
    for spec, why in bad.items():
        with pytest.raises(ValueError) as exc:
            parse_fault(spec, SENSORS, 7)
        assert str(exc.value).startswith(f"--fault {spec}: {why}"), str(exc.value)
        assert "\n" not in str(exc.value)


def test_faults_that_could_never_act_are_refused() -> None:
    """Two faults of one source at once (which would win?), or one starting at --duration or later."""
    def check(specs: list[str], duration: float | None = None) -> None:
        check_faults([parse_fault(f, SENSORS, 7) for f in specs], duration)

    check(["drive-frozen:3@1-2", "drive-silent:3@2-4", "sensor-frozen:dvl@1-3", "drive-frozen:4@1"], 10.0)
    for specs, duration, why in (
        (["drive-frozen:3@1-5", "drive-silent:3@2-4"], None,
         "--fault drive-silent:3@2-4: overlaps --fault drive-frozen:3@1-5 (one fault per source at a time)"),
        (["sensor-silent:dvl@0", "sensor-silent:dvl@0"], None, "--fault sensor-silent:dvl@0: overlaps"),
        (["drive-frozen:3@50"], 2.0, "--fault drive-frozen:3@50: starts at 50 s, not before --duration 2 s"),
    ):
        with pytest.raises(ValueError) as exc:
            check(specs, duration)
        assert str(exc.value).startswith(why), str(exc.value)


def test_the_schedule_says_when_each_fault_starts_and_ends() -> None:
    sched = FaultSchedule([Fault("drive-silent", 2, 1.0, 2.0), Fault("sensor-frozen", "dvl", 1.5)])
    assert sched.update(0.5) == [] and not sched.on("drive-silent", 2)
    assert sched.update(1.0) == ["fault drive-silent:3@1-2 on at t = 1.00 s"]
    assert sched.on("drive-silent", 2) and not sched.on("drive-silent", 3)
    assert sched.update(1.5) == ["fault sensor-frozen:dvl@1.5 on at t = 1.50 s"]
    assert sched.update(2.0) == ["fault drive-silent:3@1-2 off at t = 2.00 s"]
    assert sched.on("sensor-frozen", "dvl") and not sched.on("drive-silent", 2)


def test_a_bad_fault_stops_the_emulator_before_any_port_opens(capsys: pytest.CaptureFixture[str]) -> None:
    assert emulate_main(["minerva2", "--serial", "loop://", "--can", "virtual:x", "--fault",
                         "drive-frozen:9@1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["seafmu emulate: error: --fault drive-frozen:9@1: thruster '9': give a number from 1 to 7"]


def test_injected_faults_reach_the_link_as_the_faults_they_stand_for() -> None:
    """From 1 s to 2 s of vessel time: drive 3 repeats its last status frame, drive 5 is silent,
    the DVL repeats its last PNORBT7, the gyro is silent. The link takes both drives as stale
    (feedback_lost = 4 + 16, their n_i NaN), counts no new DVL or gyro sample, and its watchdog
    (which watches both) trips; after 2 s everything is fresh again and the alarm clears."""
    chan = f"emufaults{next(_chan)}"
    faults = [parse_fault(f, SENSORS, 7) for f in
              ("drive-frozen:3@1-2", "drive-silent:5@1-2", "sensor-frozen:dvl@1-2", "sensor-silent:gyro@1-2")]
    with NullModem() as nm:
        over = {"startup_timeout": 3.0, "can.interface": "virtual", "can.channel": chan, "can.options": {},
                "can.bitrate": None, "watchdog.timeout": 0.5}
        emu = VesselEmulator(load_profile("emulator_pty").with_overrides(**{"serial.url": nm.a, **over}),
                             {"seed": 1}, faults=faults)
        link = HardwareLink(load_profile("emulator_pty").with_overrides(**{"serial.url": nm.b, **over}))
        emu.open()
        th = threading.Thread(target=emu.run, daemon=True)
        th.start()
        rows, t, h = [], 0.0, 0.05
        try:
            link.open()
            link.initialize(np.zeros(7))
            link.set_inputs(np.full(7, 1.0))
            while t < 3.6:
                link.do_step(t, h)
                t += h
                rows.append((t, dict(zip(link.out_names, link.get_outputs().tolist(), strict=True))))
        finally:
            link.close()
            emu.stop_event.set()
            th.join(timeout=5)
            emu.close()
    during = [r for tt, r in rows if 1.7 <= tt <= 1.9]  # stale by then: 0.5 s after the last fresh datum
    assert during and all(r["feedback_lost"] == 20.0 for r in during)
    assert all(math.isnan(r["n_3"]) and math.isnan(r["n_5"]) and r["n_1"] == r["n_1"] for r in during)
    window = [r for tt, r in rows if 1.15 <= tt <= 1.9]
    assert len({r["dvl_count"] for r in window}) == 1 and len({r["gyro_count"] for r in window}) == 1
    assert any(r["watchdog_alarm"] for r in during)
    end = rows[-1][1]
    assert end["feedback_lost"] == 0.0 and end["watchdog_alarm"] == 0.0
    assert end["dvl_count"] > window[0]["dvl_count"] and end["gyro_count"] > window[0]["gyro_count"]
    assert link.counters["status_repeated"] > 0 and link.counters["repeated"] > 0
    assert "fault drive-frozen:3@1-2 on at t = 1.00 s" in emu.log_lines
    assert "fault sensor-silent:gyro@1-2 off at t = 2.00 s" in emu.log_lines
