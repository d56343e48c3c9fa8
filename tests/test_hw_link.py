"""The hardware link against a scripted vessel: decoding, limits, malformed input, port loss, watchdog,
recording. Serial through a pseudo-terminal pair, CAN through python-can's in-process virtual bus
(and SLCAN on a pty for adapter garbage); the test writes what a vessel would and reads the bus."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
import serial

from seafmu.hardware.canbus import Command
from seafmu.hardware.link import HardwareLink
from seafmu.hardware.nmea import NmeaCodec
from seafmu.hardware.profile import load_profile
from seafmu.hardware.ptybridge import NullModem
from seafmu.identification.trial import load_trial

JITTER = 0.01  # s: poll-to-send processing and scheduling on a loaded 2-core machine
VALUES = {
    "north": 1.5,
    "east": -2.25,
    "down": 5.0,
    "roll": 0.01,
    "pitch": -0.02,
    "yaw": 1.0,
    "u": 0.1,
    "v": -0.05,
    "w": 0.0,
    "p": 0.001,
    "q": -0.002,
    "r": 0.003,
}
SENSORS = {
    "usbl": ["GGA"],
    "depth": ["DPT"],
    "ahrs": ["XDR_ATTITUDE", "HDT"],
    "dvl": ["PNORBT7"],
    "gyro": ["XDR_RATES"],
}
_chan = itertools.count()


class Vessel:
    """The far end: writes NMEA on the serial pty, reads commands and answers on the CAN bus."""

    def __init__(self, serial_path: str, can_channel: str) -> None:
        self.ser = serial.serial_for_url(serial_path, timeout=0)
        self.bus = can.Bus(interface="virtual", channel=can_channel)
        self.link_codec = None
        self.nmea = NmeaCodec(63.44, 10.40)
        self.alive = 0
        t0 = datetime(2026, 1, 1, tzinfo=UTC)
        self.fix_times = (t0 + timedelta(seconds=0.1 * k) for k in itertools.count())

    def sample(
        self, values: dict[str, float] | None = None, sensors: tuple[str, ...] = tuple(SENSORS)
    ) -> float:
        v = values or VALUES
        utc = next(self.fix_times)  # a live receiver's fix times advance
        lines = [self.nmea.encode(s, v, utc) for name in sensors for s in SENSORS[name]]
        self.ser.write("".join(ln + "\r\n" for ln in lines).encode())
        self.ser.flush()
        return time.time()

    def raw(self, data: bytes) -> None:
        self.ser.write(data)
        self.ser.flush()

    def frames(self) -> list[can.Message]:
        out = []
        while (m := self.bus.recv(timeout=0)) is not None:
            out.append(m)
        return out

    def status(self, link: HardwareLink, speeds: list[float], faults: int = 0) -> None:
        self.alive += 1  # a live drive's status counter advances with every frame
        for i, n in enumerate(speeds):
            for msg in link.codec.status(i, n, True, faults, self.alive):
                self.bus.send(msg)

    def close(self) -> None:
        self.ser.close()
        self.bus.shutdown()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[NullModem, str, Path]]:
    link_path = tmp_path / "nmea"
    nm = NullModem(link_b=link_path)
    yield nm, f"hwtest{next(_chan)}", link_path
    nm.close()


def _link(
    rig: tuple[NullModem, str, Path], record: Path | None = None, **over: object
) -> tuple[HardwareLink, Vessel]:
    nm, chan, link_path = rig
    prof = load_profile("emulator_pty").with_overrides(
        **{
            "serial.url": str(link_path),
            "can.interface": "virtual",
            "can.channel": chan,
            "can.options": {},
            "startup_timeout": 2.0,
            "reconnect_interval": 0.1,
            **over,
        }
    )
    vessel = Vessel(nm.a, chan)
    link = HardwareLink(prof, record_dir=record)
    return link, vessel


def _start(link: HardwareLink, vessel: Vessel) -> np.ndarray:
    link.open()  # opening a port flushes what came before, as on a real line
    vessel.sample()
    y = link.initialize(np.zeros(len(link.in_names))).copy()
    vessel.frames()
    return y


def out(link: HardwareLink, name: str) -> float:
    return float(link.get_outputs()[link.out_names.index(name)])


def test_starts_on_the_first_samples_and_decodes_them(rig: tuple) -> None:
    link, vessel = _link(rig)
    try:
        y = _start(link, vessel)
        for c, v in VALUES.items():
            assert y[link.out_names.index(f"meas_{c}")] == pytest.approx(v, abs=1e-4), c
        assert all(y[link.out_names.index(f"{s}_count")] == 1.0 for s in SENSORS)
        assert math.isnan(y[link.out_names.index("n_1")])  # no thruster feedback yet
        # the true state of a real vessel is unknown: not an output
        assert "north" not in link.out_names and "thrust_1" not in link.out_names
        link.set_inputs(np.arange(7, dtype=float))
        vessel.status(link, [0.5] * 7, faults=2)
        vessel.sample({**VALUES, "down": 6.0}, ("depth",))
        link.do_step(0.0, 0.05)
        cmds = [link.codec.decode(m) for m in vessel.frames()]
        assert [c.speed for c in cmds if isinstance(c, Command)] == pytest.approx(list(range(7)))
        assert out(link, "meas_down") == pytest.approx(6.0) and out(link, "depth_count") == 2.0
        assert out(link, "ahrs_count") == 1.0  # nothing new from the others
        assert out(link, "n_3") == pytest.approx(0.5) and out(link, "fault_3") == 2.0
    finally:
        link.terminate()
        vessel.close()


def test_commands_are_clamped_and_nan_never_reaches_the_bus(rig: tuple) -> None:
    link, vessel = _link(rig)
    try:
        _start(link, vessel)
        link.set_inputs(np.array([np.nan, 1e6, -1e6, np.inf, 5.0, -np.inf, 19.99]))
        vessel.sample()
        link.do_step(0.0, 0.05)
        sent = [link.codec.decode(m) for m in vessel.frames()]
        assert [c.speed for c in sent] == pytest.approx([0.0, 20.0, -20.0, 0.0, 5.0, 0.0, 19.99])
        assert all(c.enable for c in sent)
        assert out(link, "commands_limited") == 5.0
        assert sum("sent 0" in ln for ln in link.log_lines) == 3
    finally:
        link.terminate()
        vessel.close()


def test_a_sample_missing_a_channel_is_dropped_never_completed_with_an_old_value(rig: tuple) -> None:
    """An XDR may carry any of its transducers: an AHRS round whose XDR has roll but no pitch is
    dropped (counted, logged), not completed with the pitch of the sample before."""
    link, vessel = _link(rig)
    try:
        _start(link, vessel)
        enc = vessel.nmea.encode
        t, h = 0.0, 0.05
        for k, xdr in enumerate((enc("XDR_ATTITUDE", {"roll": 0.2}), enc("XDR_RATES", {"r": 0.05}))):
            other = enc("HDT", {"yaw": 0.5}) if k == 0 else ""
            vessel.raw(f"{xdr}\r\n{other}\r\n".encode())
            time.sleep(0.02)
            link.do_step(t, h)
            t += h
            assert link.counters["incomplete"] == k + 1
        assert out(link, "ahrs_count") == 1.0 and out(link, "gyro_count") == 1.0
        assert out(link, "meas_roll") == pytest.approx(VALUES["roll"], abs=1e-6)  # the last full sample
        assert out(link, "lines_dropped") == 2.0
        assert any("ahrs: its sentences carried no pitch; sample dropped" in ln for ln in link.log_lines)
        vessel.sample({**VALUES, "roll": 0.3}, sensors=("ahrs",))  # a whole sample completes again
        time.sleep(0.02)
        link.do_step(t, h)
        assert out(link, "ahrs_count") == 2.0 and out(link, "meas_roll") == pytest.approx(0.3, abs=1e-6)
        assert out(link, "meas_pitch") == pytest.approx(VALUES["pitch"], abs=1e-6)
    finally:
        link.terminate()
        vessel.close()


def test_malformed_input_is_counted_and_dropped_without_blocking(rig: tuple, tmp_path: Path) -> None:
    link, vessel = _link(rig, record=tmp_path / "rec")
    good = vessel.nmea.encode("DPT", {"down": 7.0})
    bad_inputs = [
        ("checksum", (good[:-2] + ("00" if good[-2:] != "00" else "11") + "\r\n").encode()),
        ("checksum", (good.split("*")[0] + "\r\n").encode()),  # no checksum at all
        ("checksum", (good[:9] + "\r\n").encode()),  # truncated: its checksum is gone
        ("malformed", b"\x00\xff\xfe\x80garbage\r\n"),  # garbage, not even ASCII
        ("malformed", b"$GPGGA,,,,,,,,*\r\n"),
        ("line_too_long", b"$" + b"A" * 400),  # a stream without line ends
    ]
    try:
        _start(link, vessel)
        t = 0.0
        h = 0.05
        durations = []
        for kind, data in bad_inputs:
            before = link.counters[kind]
            vessel.raw(b"\r\n" + data + b"\r\n")
            vessel.sample()
            vessel.status(link, [1.0] * 7)
            t0 = time.perf_counter()
            link.do_step(t, h)
            durations.append(time.perf_counter() - t0)
            t += h
            assert link.counters[kind] == before + 1, kind
            assert out(link, "watchdog_alarm") == 0.0
        # CAN: unknown id, wrong DLC, undecodable, remote and error frames
        cmd_id = link.codec.command(0, 0.0, True, 0).arbitration_id
        status_id = link.codec.status(0, 0.0, True, 0, 0)[0].arbitration_id
        for msg in (
            can.Message(arbitration_id=0x555, data=b"\x01\x02", is_extended_id=False),
            can.Message(arbitration_id=status_id, data=b"\x01\x02\x03", is_extended_id=False),
            can.Message(arbitration_id=status_id, is_remote_frame=True, dlc=4, is_extended_id=False),
            can.Message(arbitration_id=0, is_error_frame=True),
        ):
            vessel.bus.send(msg)
        vessel.bus.send(
            can.Message(arbitration_id=cmd_id, data=bytes(4), is_extended_id=False)
        )  # a command: ignored
        vessel.sample()
        vessel.status(link, [1.0] * 7)
        link.do_step(t, h)
        assert link.counters["unknown_id"] == 1 and link.counters["wrong_dlc"] == 1
        assert link.counters["unexpected"] == 1 and link.counters["bus_error"] == 1
        assert out(link, "frames_dropped") == 4.0
        assert out(link, "lines_dropped") == len(bad_inputs)
        # good data kept flowing, and no step waited for anything
        assert out(link, "depth_count") == len(bad_inputs) + 2
        assert max(durations) < h + 0.05
        assert sum("dropped (" in ln for ln in link.log_lines) == len(bad_inputs) + 4
    finally:
        link.terminate()
        vessel.close()
    # the recording has the raw traffic, bad lines included, and reads back as a maneuver trial
    rec = tmp_path / "rec"
    assert b"garbage" in (rec / "nmea.raw").read_bytes()
    frames = list(can.LogReader(str(rec / "can.asc")))
    assert any(f.arbitration_id == 0x555 for f in frames) and any(not f.is_rx for f in frames)
    trial = load_trial(rec / "trial.yaml")  # seafmu.identification reads it as a maneuver trial
    assert trial.kind == "maneuver" and trial.vessel == "minerva2"
    assert trial.columns["north"] == "meas_north" and trial.columns["thrust_7"] == "thrust_7"
    data = np.genfromtxt(rec / "signals.csv", delimiter=",", names=True, skip_header=1)
    assert len(data) == len(bad_inputs) + 1 and np.all(np.diff(data["time"]) > 0)
    assert data["watchdog_alarm"].max() == 0.0 and data["n_cmd_1"][0] == 0.0


def _slcan_rig(tmp_path: Path, body: Callable[[HardwareLink, Any, Callable[[float], bytes]], None]) -> None:
    """A link on SLCAN over a pty whose adapter side the test writes by hand (``frame(v)``: thruster
    3's status frame with shaft speed v), with every sensor's first sample sent."""
    with NullModem() as nm_ser, NullModem() as nm_can:
        prof = load_profile("emulator_pty").with_overrides(
            **{"serial.url": nm_ser.b, "can.channel": nm_can.b, "startup_timeout": 2.0}
        )
        ser = serial.serial_for_url(nm_ser.a, timeout=0)
        adapter = serial.serial_for_url(nm_can.a, timeout=0)  # the adapter's side, written by hand
        link = HardwareLink(prof)
        nmea = NmeaCodec(63.44, 10.40)

        alive = itertools.count(1)  # the drive's status counter: +1 per frame

        def frame(v: float) -> bytes:
            good = link.codec.status(2, v, True, 0, next(alive))[0]
            return f"t{good.arbitration_id:03X}{good.dlc}{good.data.hex().upper()}\r".encode()

        try:
            link.open()
            ser.write(
                "".join(nmea.encode(s, VALUES) + "\r\n" for ss in SENSORS.values() for s in ss).encode()
            )
            link.initialize(np.zeros(7))
            body(link, adapter, frame)
        finally:
            link.terminate()
            ser.close()
            adapter.close()


def test_slcan_adapter_garbage_is_counted_and_frames_keep_coming(tmp_path: Path) -> None:
    """python-can's slcan reader raises on garbage lines, and sticks on non-ASCII ones (their bytes
    stay in its buffer): each is counted and named, and the frames after it are read, every step."""

    def body(link: HardwareLink, adapter: Any, frame: Callable[[float], bytes]) -> None:
        t = 0.0
        for k, junk in enumerate((b"tZZZ8\r", b"t1\r", b"\xff\xfe\r", b"\x80junk\r")):
            adapter.write(junk + frame(3.0 + k))
            time.sleep(0.02)
            link.do_step(t, 0.05)
            t += 0.05
            assert out(link, "n_3") == pytest.approx(3.0 + k)  # the frame right after the junk
        assert link.counters["bus_error"] == 4
        assert any("not ASCII: b'\\xff\\xfe" in ln for ln in link.log_lines), link.log_lines
        for k in range(3):  # and nothing sticks: every later step reads its own frame
            adapter.write(frame(10.0 + k))
            time.sleep(0.02)
            link.do_step(t, 0.05)
            t += 0.05
            assert out(link, "n_3") == pytest.approx(10.0 + k)
        assert link.counters["bus_error"] == 4

    _slcan_rig(tmp_path, body)


@pytest.mark.parametrize("line", [b"z\r", b"Z\r", b"\r", b"\x07"], ids=["ack", "ack-ext", "empty", "bell"])
def test_slcan_lines_that_are_not_frames_do_not_end_the_poll(tmp_path: Path, line: bytes) -> None:
    """Lawicel adapters answer each transmitted frame with ``z`` (python-can returns no frame for it):
    the frames after such a line are read in the same step, so feedback never falls behind."""

    def body(link: HardwareLink, adapter: Any, frame: Callable[[float], bytes]) -> None:
        t = 0.0
        for k in range(6):
            adapter.write(line * 3 + frame(1.0 + k) + line + frame(2.0 + k) + line)
            time.sleep(0.02)
            link.do_step(t, 0.05)
            t += 0.05
            assert out(link, "n_3") == pytest.approx(2.0 + k)  # the newest frame of this step
        assert link.counters["bus_error"] == 0

    _slcan_rig(tmp_path, body)


def test_lost_serial_port_is_reopened_and_the_loop_never_stalls(rig: tuple) -> None:
    nm, _, link_path = rig
    link, vessel = _link(rig)
    try:
        _start(link, vessel)
        h, t = 0.05, 0.0
        nm.close()  # the USB adapter is unplugged
        vessel.ser.close()
        steps = []
        for _ in range(4):
            t0 = time.perf_counter()
            link.do_step(t, h)
            steps.append(time.perf_counter() - t0)
            t += h
        assert out(link, "port_losses") >= 1 and max(steps) < h + 0.05
        nm2 = NullModem(link_b=link_path)  # plugged in again (same device name)
        try:
            vessel.ser = serial.serial_for_url(nm2.a, timeout=0)
            for _ in range(6):
                vessel.sample({**VALUES, "down": 8.0})
                link.do_step(t, h)
                t += h
            assert out(link, "meas_down") == pytest.approx(8.0)
            assert link.serial.is_open
        finally:
            nm2.close()
    finally:
        link.terminate()
        vessel.close()


def test_watchdog_zeroes_thrusters_within_the_timeout_and_recovers(rig: tuple) -> None:
    link, vessel = _link(rig, **{"watchdog.resume_ramp": 0.3})
    timeout = link.profile.watchdog.timeout
    h, t = 0.05, 0.0
    try:
        _start(link, vessel)
        link.set_inputs(np.full(7, 10.0))
        for _ in range(10):  # data flowing: commands go out as given
            last = vessel.sample()
            vessel.status(link, [10.0] * 7)
            link.do_step(t, h)
            t += h
        assert all(
            c.speed == pytest.approx(10.0) and c.enable for c in map(link.codec.decode, vessel.frames())
        )
        zero_at = None
        for _ in range(round(2 * timeout / h)):  # sensors fall silent (the CAN feedback goes on)
            vessel.status(link, [10.0] * 7)
            link.do_step(t, h)
            t += h
            for m in vessel.frames():
                c = link.codec.decode(m)
                if zero_at is None and not c.enable:
                    assert c.speed == 0.0
                    zero_at = m.timestamp
        assert zero_at is not None and out(link, "watchdog_alarm") == 1.0
        reaction = zero_at - last
        # The link stamps a datum at its previous poll (before `last`) and trips at the first poll
        # whose age could pass the timeout by the next one, so a loop on schedule zeroes within the
        # timeout; JITTER covers the poll-to-send processing and a late wake-up on a loaded machine
        # (a trip one step late, +50 ms, still fails).
        assert timeout - 2 * h - 0.01 < reaction <= timeout + JITTER, reaction
        assert any("WATCHDOG ALARM" in ln for ln in link.log_lines)
        speeds = []
        for _ in range(12):  # data returns: the alarm clears, commands ramp back
            vessel.sample()
            vessel.status(link, [10.0] * 7)
            link.do_step(t, h)
            t += h
            speeds.append(max(c.speed for c in map(link.codec.decode, vessel.frames())))
        assert out(link, "watchdog_alarm") == 0.0
        assert any("watchdog cleared" in ln for ln in link.log_lines)
        rising = [s for s in speeds if s > 0]
        assert 0 < rising[0] < 10.0 and rising[-1] == pytest.approx(10.0)
        assert np.all(np.diff(rising) >= -1e-9)
        assert len(link.alarms) == 1 and link.alarms[0][1] is not None
        print(
            f"watchdog reaction {1e3 * reaction:.1f} ms (timeout {1e3 * timeout:.0f} ms, "
            f"step {1e3 * h:.0f} ms)"
        )
    finally:
        link.terminate()
        vessel.close()


def test_startup_fails_in_one_line_without_data(rig: tuple) -> None:
    link, vessel = _link(rig, startup_timeout=0.3)
    try:
        link.open()
        vessel.sample(sensors=("depth", "ahrs"))
        with pytest.raises(RuntimeError, match=r"no complete sample from usbl, dvl, gyro within 0.3 s"):
            link.initialize(np.zeros(7))
    finally:
        vessel.close()


def test_run_with_an_unreachable_vessel_ends_in_one_line(tmp_path: Path) -> None:
    """`seafmu run` against a profile whose port does not exist: exit 2, one error line, no traceback."""
    import subprocess
    import sys

    from seafmu.hardware.profile import profile_path

    prof = tmp_path / "bad.yaml"
    text = profile_path("emulator_pty").read_text()
    prof.write_text(text.replace("/tmp/seafmu-emulator/nmea", "/dev/ttyNOPE0"))
    sc = tmp_path / "s.yaml"
    sc.write_text(
        "name: badport\nvessel: minerva2\nduration: 2\nstep: 0.05\n"
        f"fmus:\n  plant: {{hardware: {prof}}}\n  observer: {{kind: observer}}\n"
        "  controller: {kind: controller}\n  allocator: {kind: allocator}\n"
    )
    cmd = [sys.executable, "-m", "seafmu.cli", "run", str(sc), "-q", "-o", str(tmp_path / "o")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("seafmu: error:")]
    assert len(errors) == 1 and "/dev/ttyNOPE0" in errors[0]
