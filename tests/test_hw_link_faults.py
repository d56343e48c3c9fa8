"""The hardware link under faults of its ports and drives: a CAN adapter that stops taking frames
(F2), one drive whose status frames stop (F3), ports that cannot be opened (F4).

NMEA through a pseudo-terminal pair, CAN through python-can's in-process virtual bus; the blocked
adapter is SLCAN on a raw pty whose adapter end the test does not read (as a stalled USB adapter
or a frozen emulator: the kernel buffer fills, then writes fail)."""

from __future__ import annotations

import itertools
import logging
import math
import os
import threading
import time
import tty
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import can
import numpy as np
import pytest
import serial

from seafmu.hardware.canbus import Command
from seafmu.hardware.emulator import VesselEmulator
from seafmu.hardware.emulator import main as emulate_main
from seafmu.hardware.link import HardwareError, HardwareLink
from seafmu.hardware.nmea import NmeaCodec
from seafmu.hardware.profile import HardwareProfile, load_profile
from seafmu.hardware.ptybridge import NullModem

VALUES = {
    "north": 1.5, "east": -2.25, "down": 5.0, "roll": 0.01, "pitch": -0.02, "yaw": 1.0,
    "u": 0.1, "v": -0.05, "w": 0.0, "p": 0.001, "q": -0.002, "r": 0.003,
}
SENSORS = {"usbl": ["GGA"], "depth": ["DPT"], "ahrs": ["XDR_ATTITUDE", "HDT"], "dvl": ["PNORBT7"],
           "gyro": ["XDR_RATES"]}
NMEA = NmeaCodec(63.44, 10.40)
_FIX_TIMES = (datetime(2026, 1, 1, tzinfo=UTC) + timedelta(seconds=0.1 * k) for k in itertools.count())


def sample() -> bytes:
    """One sample of every sensor, 0.1 s after the last (a live receiver's fix times advance)."""
    utc = next(_FIX_TIMES)
    return "".join(NMEA.encode(s, VALUES, utc) + "\r\n" for ss in SENSORS.values() for s in ss).encode()


_chan = itertools.count()


def _profile(serial_url: str, **over: object) -> HardwareProfile:
    return load_profile("emulator_pty").with_overrides(
        **{"serial.url": serial_url, "startup_timeout": 2.0, **over}
    )


def out(link: HardwareLink, name: str) -> float:
    return float(link.get_outputs()[link.out_names.index(name)])


# -- F2: an adapter that does not take frames ------------------------------------------------------


class BlockedAdapter:
    """A link on SLCAN over a raw pty (``master``: the adapter's end, read only by ``drain``) and
    NMEA over a NullModem; ``fill`` stuffs the pty until the kernel takes nothing more."""

    def __init__(self) -> None:
        self.nm = NullModem()
        self.ser = serial.serial_for_url(self.nm.a, timeout=0)
        self.master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(self.master, False)
        self.slave_path = os.ttyname(slave)
        self._slave = slave
        # no sensor data follows the first sample and the loop runs unpaced: a long watchdog keeps a
        # loaded machine's slow steps from tripping it (these tests are about the adapter, not it)
        overrides = {"can.channel": self.slave_path, "watchdog.timeout": 30.0}
        self.link = HardwareLink(_profile(self.nm.b, **overrides), pace=False)
        self.link.open()
        self.ser.write(sample())
        self.link.initialize(np.zeros(7))
        self.drain()

    def fill(self) -> None:
        """Until the pty takes nothing more (the kernel moves its buffers on asynchronously)."""
        fd = os.open(self.slave_path, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
        try:
            idle = 0
            while idle < 3:
                try:
                    os.write(fd, b"\r" * 64)  # empty SLCAN lines: nothing for a drive
                    idle = 0
                except BlockingIOError:
                    idle += 1
                    time.sleep(0.005)
        finally:
            os.close(fd)

    def drain(self) -> bytes:
        data = b""
        while True:
            try:
                chunk = os.read(self.master, 65536)
            except BlockingIOError:
                return data
            if not chunk:
                return data
            data += chunk

    def close(self) -> None:
        self.link.close()
        self.ser.close()
        self.nm.close()
        os.close(self.master)
        os.close(self._slave)


def _decode(link: HardwareLink, line: bytes) -> object:
    """A standard-id SLCAN data frame line (without its CR) decoded by the link's codec."""
    msg = can.Message(arbitration_id=int(line[1:4], 16), data=bytes.fromhex(line[5:].decode()),
                      is_extended_id=False)
    return link.codec.decode(msg)


@pytest.fixture
def blocked() -> Iterator[BlockedAdapter]:
    rig = BlockedAdapter()
    yield rig
    rig.close()


def test_a_blocked_adapter_costs_one_try_per_step_and_the_line_stays_clean(blocked: BlockedAdapter) -> None:
    """Before: every frame waited out 10 ms (7 x 10 ms > the 50 ms step: the loop fell 2.5 s
    behind) and a half-written frame was glued to the next one on the line."""
    link = blocked.link
    t, h = 0.0, 0.05
    took = []
    for k in range(5):
        blocked.fill()
        blocked.ser.write(sample())
        link.set_inputs(np.full(7, 1.0 + k))
        t0 = time.perf_counter()
        link.do_step(t, h)
        took.append(time.perf_counter() - t0)
        t += h
    assert max(took) < 0.03, took  # one 5 ms try per step; all seven would wait >= 35 ms
    assert link.counters["tx_timeout"] == 5 and link.counters["tx_skipped"] == 30
    assert out(link, "frames_dropped") == 35.0
    assert sum("the adapter is not taking frames" in ln for ln in link.log_lines) == 1
    blocked.drain()  # the adapter takes data again
    link.set_inputs(np.full(7, 9.0))
    link.do_step(t, h)
    lines = [ln for ln in blocked.drain().split(b"\r") if ln]
    cmds = [_decode(link, ln) for ln in lines if len(ln) == 13]
    assert len(cmds) == 7 and all(isinstance(c, Command) and c.speed == 9.0 for c in cmds)
    assert len(lines) == 7  # no part of an old frame glued to them, and no backlog
    assert any("the adapter takes frames again" in ln for ln in link.log_lines)


def test_frames_queued_behind_a_blocked_adapter_are_discarded_not_replayed(blocked: BlockedAdapter) -> None:
    """The adapter stops reading: the link's frames queue in the kernel until it is full; when a
    write fails the queue (stale commands) is discarded, so the drives do not get seconds of old
    setpoints when the adapter takes data again. A pty keeps what its reading side already holds."""
    link = blocked.link
    t, h = 0.0, 0.05
    written = 0
    while link.counters["tx_timeout"] == 0:
        link.set_inputs(np.full(7, 2.0))
        link.do_step(t, h)
        t += h
        written += 7 * 14
        assert written < 200_000
    link.set_inputs(np.full(7, 5.0))
    link.do_step(t, h)
    stale = blocked.drain()
    assert written > 8000 and len(stale) < written / 2, (written, len(stale))
    assert stale.endswith(b"\r")  # the current round on a clean line
    tail = [_decode(link, ln) for ln in stale.split(b"\r")[-8:-1]]
    assert [c.speed for c in tail] == [5.0] * 7


# -- F3: one drive falls silent ---------------------------------------------------------------------


class Vessel:
    """NMEA on the serial pty and status frames on the virtual bus, alive counter +1 per round."""

    def __init__(self, serial_path: str, channel: str) -> None:
        self.ser = serial.serial_for_url(serial_path, timeout=0)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.k = 0

    def step(self, link: HardwareLink, silent: set[int] = frozenset()) -> None:  # type: ignore[assignment]
        self.ser.write(sample())
        self.k += 1
        for i in range(7):
            if i not in silent:
                for msg in link.codec.status(i, 1.0 + i, True, 0, self.k):
                    self.bus.send(msg)
        while self.bus.recv(timeout=0) is not None:
            pass

    def close(self) -> None:
        self.ser.close()
        self.bus.shutdown()


def test_a_silent_drive_is_reported_and_its_speed_is_not_held(tmp_path: Path) -> None:
    chan = f"faults{next(_chan)}"
    with NullModem() as nm:
        vessel = Vessel(nm.a, chan)
        prof = _profile(nm.b, **{"can.interface": "virtual", "can.channel": chan, "can.options": {},
                                 "can.bitrate": None, "watchdog.timeout": 0.3})
        link = HardwareLink(prof, record_dir=tmp_path / "rec")
        try:
            link.open()
            vessel.ser.write(sample())
            link.initialize(np.zeros(7))
            t, h = 0.0, 0.05
            link.set_inputs(np.full(7, 3.0))
            states = []
            for k in range(30):  # thruster 3's drive is silent from step 5 to step 19
                vessel.step(link, {2} if 5 <= k < 20 else set())
                link.do_step(t, h)
                t += h
                states.append((out(link, "feedback_lost"), out(link, "n_3"), out(link, "n_1")))
            lost = [k for k, (bits, _, _) in enumerate(states) if bits]
            assert lost and all(states[k][0] == 4.0 and math.isnan(states[k][1]) for k in lost)
            # stale after 0.3 s; fresh once seen counting again (its third frame: hardware/freshness.py)
            assert 8 <= lost[0] <= 12 and lost[-1] == 21
            assert all(n1 == 1.0 for _, _, n1 in states)  # the others stay fresh
            assert states[-1][:2] == (0.0, 3.0) and out(link, "watchdog_alarm") == 0.0
            said = [ln for ln in link.log_lines if ln.startswith("plant: thruster 3:") and "alive" not in ln]
            assert len(said) == 2 and "no status frame for" in said[0] and "n_3 is NaN" in said[0]
            assert "status frames again" in said[1]
        finally:
            link.close()
            vessel.close()
    data = np.genfromtxt(tmp_path / "rec" / "signals.csv", delimiter=",", names=True, skip_header=1)
    assert np.isnan(data["thrust_3"][lost]).all() and np.isfinite(data["thrust_3"][:lost[0]]).all()
    assert np.isfinite(data["thrust_1"]).all() and (data["feedback_lost"][lost] == 4.0).all()


def test_the_emulated_drives_count_their_status_frames_one_by_one() -> None:
    """The DBC's status alive counter is +1 per frame (it advanced by the emulator's steps per frame)."""
    chan = f"faults{next(_chan)}"
    prof = _profile("loop://", **{"can.interface": "virtual", "can.channel": chan, "can.options": {},
                                  "can.bitrate": None})
    emu = VesselEmulator(prof, {"seed": 1})
    emu.open()
    th = threading.Thread(target=emu.run, daemon=True)
    th.start()
    bus = can.Bus(interface="virtual", channel=chan)
    try:
        bus.send(emu.codec.command(0, 0.0, True, 0))  # the vessel leaves the dock
        got: list[int] = []
        end = time.perf_counter() + 1.0
        while len(got) < 6 and time.perf_counter() < end:
            msg = bus.recv(timeout=0.05)
            if msg is not None and msg.arbitration_id == 0x181:
                got.append(int(emu.codec.db.decode_message(0x181, msg.data)["counter"]))
        assert len(got) == 6 and all((b - a) % 16 == 1 for a, b in itertools.pairwise(got)), got
    finally:
        bus.shutdown()
        emu.stop_event.set()
        th.join(timeout=5)
        emu.close()


# -- F4: a port that cannot be opened ---------------------------------------------------------------


def test_a_missing_port_is_one_error_with_the_reason_and_no_retry_promise(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    missing = tmp_path / "ttyUSB9"
    link = HardwareLink(_profile(str(missing)))
    with caplog.at_level(logging.WARNING, logger="seafmu.hardware"), pytest.raises(HardwareError) as exc:
        link.initialize(np.zeros(7))
    assert str(exc.value) == (f"plant: cannot open serial port {missing}: No such file or directory "
                              "(profile emulator_pty)")
    assert not [r for r in caplog.records if "retrying" in r.getMessage()]


def test_the_emulator_names_the_option_and_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    missing = tmp_path / "ttyUSB9"
    with caplog.at_level(logging.WARNING, logger="seafmu.hardware"):
        assert emulate_main(["minerva2", "--serial", str(missing), "--can", "slcan:pty"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"seafmu emulate: error: --serial {missing}: cannot open: No such file or directory"]
    assert not [r for r in caplog.records if "retrying" in r.getMessage()]
    (tmp_path / "afile").write_text("")
    bad = tmp_path / "afile" / "nmea"
    assert emulate_main(["minerva2", "--serial", "pty", "--can", f"slcan:pty:{bad}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"seafmu emulate: error: --can slcan:pty:{bad}: cannot make the pty link {bad}: "
                   f"File exists ({tmp_path / 'afile'})"]
