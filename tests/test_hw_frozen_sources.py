"""Sources that keep talking but say nothing new: a hung drive whose CAN controller repeats its
last status frame (the alive counter does not advance) and a receiver repeating its last fix (the
same fix time). Neither may pass for a live source: the drive goes stale (``feedback_lost``, its
speed NaN), the sensor's sample count stops (so the observer dead-reckons and the watchdog sees
it); both are counted as dropped input, and both come back as soon as they advance again.

NMEA through a pseudo-terminal pair, CAN through python-can's in-process virtual bus."""

from __future__ import annotations

import itertools
import math
from datetime import UTC, datetime, timedelta

import can
import numpy as np
import pytest
import serial

from seafmu.hardware.canbus import Nmea2000Codec, SeafmuCodec
from seafmu.hardware.link import HardwareLink
from seafmu.hardware.nmea import NmeaCodec, fix_time
from seafmu.hardware.profile import load_profile
from seafmu.hardware.ptybridge import NullModem

VALUES = {
    "north": 1.5, "east": -2.25, "down": 5.0, "roll": 0.01, "pitch": -0.02, "yaw": 1.0,
    "u": 0.1, "v": -0.05, "w": 0.0, "p": 0.001, "q": -0.002, "r": 0.003,
}
SENSORS = {"usbl": ["GGA"], "depth": ["DPT"], "ahrs": ["XDR_ATTITUDE", "HDT"], "dvl": ["PNORBT7"],
           "gyro": ["XDR_RATES"]}
NMEA = NmeaCodec(63.44, 10.40)
T0 = datetime(2026, 1, 1, 12, tzinfo=UTC)
H = 0.05
_chan = itertools.count()


class Vessel:
    """The far end by hand: per step one sample of every sensor (fix time +0.1 s) and one status
    frame per drive (alive counter +1); a frozen drive or receiver repeats its last one instead."""

    def __init__(self, serial_path: str, channel: str, link: HardwareLink) -> None:
        self.ser = serial.serial_for_url(serial_path, timeout=0)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.link = link
        self.k = 0
        self.last_status: dict[int, can.Message] = {}
        self.last_gga = ""

    def step(self, frozen_drives: set[int] = frozenset(), frozen_gps: bool = False,  # type: ignore[assignment]
             position: tuple[float, float] = (1.5, -2.25)) -> None:
        self.k += 1
        values = {**VALUES, "north": position[0], "east": position[1]}
        lines = [NMEA.encode(s, values, T0 + timedelta(seconds=0.1 * self.k))
                 for ss in SENSORS.values() for s in ss]
        if frozen_gps and self.last_gga:
            lines[0] = self.last_gga  # the same sentence again, byte for byte
        self.last_gga = lines[0]
        self.ser.write("".join(ln + "\r\n" for ln in lines).encode())
        for i in range(7):
            if i in frozen_drives and i in self.last_status:
                msg = self.last_status[i]
            else:
                (msg,) = self.link.codec.status(i, 1.0 + i, True, 0, self.k)
                self.last_status[i] = msg
            self.bus.send(msg)
        while self.bus.recv(timeout=0) is not None:
            pass

    def close(self) -> None:
        self.ser.close()
        self.bus.shutdown()


def _run(steps: int, schedule: object, far_end: type[Vessel] = Vessel,
         **over: object) -> tuple[HardwareLink, list[dict]]:
    """Open a link on a fresh pty pair and bus, run ``steps`` steps with ``schedule(k)`` giving the
    vessel's faults of step k; returns the link (closed) and each step's outputs."""
    chan = f"frozen{next(_chan)}"
    with NullModem() as nm:
        prof = load_profile("emulator_pty").with_overrides(**{
            "serial.url": nm.b, "startup_timeout": 2.0, "can.interface": "virtual", "can.channel": chan,
            "can.options": {}, "can.bitrate": None, "watchdog.timeout": 0.3, **over})
        link = HardwareLink(prof)  # paced: each step's data has arrived when it reads
        vessel = far_end(nm.a, chan, link)
        rows = []
        try:
            link.open()
            vessel.step()
            link.initialize(np.zeros(7))
            link.set_inputs(np.full(7, 1.0))
            t = 0.0
            for k in range(steps):
                vessel.step(**schedule(k))  # type: ignore[operator]
                link.do_step(t, H)
                t += H
                rows.append(dict(zip(link.out_names, link.get_outputs().tolist(), strict=True)))
        finally:
            link.close()
            vessel.close()
    return link, rows


def test_a_drive_repeating_its_last_status_frame_goes_stale_and_recovers() -> None:
    """Thruster 4's drive hangs from step 5 to step 24 (its last frame repeated every step, the alive
    counter frozen): stale once no fresh frame came for watchdog.timeout (0.3 s), its n_4 NaN, its
    bit in feedback_lost, every repeat counted in frames_dropped; fresh with its next new frame."""
    link, rows = _run(40, lambda k: {"frozen_drives": {3} if 5 <= k < 25 else set()})
    lost = [k for k, r in enumerate(rows) if r["feedback_lost"]]
    assert lost, "a drive repeating one frame passed for a live one"
    assert all(rows[k]["feedback_lost"] == 8.0 and math.isnan(rows[k]["n_4"]) for k in lost)
    assert 9 <= lost[0] <= 12 and lost[-1] == 24  # 0.3 s after its last fresh frame; back at once
    assert lost == list(range(lost[0], 25))
    assert all(r["n_1"] == 1.0 and r["n_7"] == 7.0 for r in rows)  # the other drives stay fresh
    assert rows[-1]["n_4"] == 4.0 and rows[-1]["feedback_lost"] == 0.0
    assert link.counters["status_repeated"] == 20 and rows[-1]["frames_dropped"] == 20.0
    said = [ln for ln in link.log_lines if "thruster 4:" in ln]
    assert "alive counter of the previous one" in said[0] and "a repeat, not fresh" in said[0]
    assert any("n_4 is NaN" in ln for ln in said) and any("status frames again" in ln for ln in said)


def test_drives_that_do_not_count_are_checked_for_silence_only() -> None:
    """``can.status_counter: false``: a drive sending one counter value forever is not taken as hung."""

    class Uncounted(Vessel):
        def step(self, **kw: object) -> None:
            super().step(frozen_drives=set(range(7)))  # every status the same frame: counter constant

    link, rows = _run(20, lambda k: {}, Uncounted, **{"can.status_counter": False})
    assert all(r["feedback_lost"] == 0.0 and r["n_4"] == 4.0 for r in rows)
    assert link.counters["status_repeated"] == 0
    checked, rows = _run(20, lambda k: {}, Uncounted)  # the same drives, counter checked: all hung
    assert checked.counters["status_repeated"] > 0
    assert rows[-1]["feedback_lost"] == 127.0 and math.isnan(rows[-1]["n_1"])


def test_a_drive_back_from_silence_with_its_old_counter_value_is_fresh_at_once() -> None:
    """A 4-bit counter meets its old value again after 16 frames: a drive silent for 15 steps
    (0.75 s > watchdog.timeout) resumes with the counter it had; that frame is new, not a repeat."""

    def schedule(k: int) -> dict:
        return {"frozen_drives": {2} if 5 <= k < 20 else set()}

    class Silent(Vessel):
        def step(self, frozen_drives: set[int] = frozenset(), **kw: object) -> None:  # type: ignore[assignment]
            self.k += 1
            lines = [NMEA.encode(s, VALUES, T0 + timedelta(seconds=0.1 * self.k))
                     for ss in SENSORS.values() for s in ss]
            self.ser.write("".join(ln + "\r\n" for ln in lines).encode())
            for i in range(7):
                if i not in frozen_drives:  # silent, not repeating
                    (msg,) = self.link.codec.status(i, 1.0 + i, True, 0, self.k)
                    self.bus.send(msg)
            while self.bus.recv(timeout=0) is not None:
                pass

    link, rows = _run(30, schedule, Silent)
    lost = [k for k, r in enumerate(rows) if r["feedback_lost"]]
    resumed = 20  # its first frame after the silence: counter (k + 2) % 16, its last one's (step 4)
    assert (resumed + 2) % 16 == (4 + 2) % 16
    assert lost and lost[-1] == resumed - 1 and rows[resumed]["n_3"] == 3.0
    assert link.counters["status_repeated"] == 0


def test_a_receiver_repeating_its_last_fix_is_not_a_new_sample() -> None:
    """The GPS repeats its last GGA (same fix time) from step 5 to step 14: usbl_count stops, the
    position holds the last real fix, each repeat is counted in lines_dropped; a watched usbl trips
    the watchdog; with fixes advancing again the count and the position move on."""
    def schedule(k: int) -> dict:
        return {"frozen_gps": 5 <= k < 15, "position": (1.5 + 0.1 * k, -2.25)}

    link, rows = _run(25, schedule, **{"watchdog.sources": ["usbl", "thrusters"]})
    counts = [r["usbl_count"] for r in rows]
    assert counts[:5] == [2.0, 3.0, 4.0, 5.0, 6.0]
    assert counts[5:15] == [6.0] * 10  # nothing new while it repeats
    assert counts[15:] == [7.0 + j for j in range(10)]
    assert rows[10]["meas_north"] == pytest.approx(1.5 + 0.1 * 4, abs=1e-3)  # the last real fix
    assert rows[-1]["meas_north"] == pytest.approx(1.5 + 0.1 * 24, abs=1e-3)
    assert link.counters["repeated"] == 10 and rows[-1]["lines_dropped"] == 10.0
    assert any(r["watchdog_alarm"] for r in rows[5:16]) and rows[-1]["watchdog_alarm"] == 0.0
    assert any("GGA with the time of the previous one" in ln for ln in link.log_lines)
    assert [r["depth_count"] for r in rows] == [2.0 + k for k in range(25)]  # the others unaffected


def test_fix_times_are_read_from_the_sentences_that_carry_one() -> None:
    utc = T0 + timedelta(seconds=12.34)
    gga = NMEA.encode("GGA", VALUES, utc)
    assert fix_time("GGA", gga) == "120012.34"
    assert fix_time("RMC", NMEA.encode("RMC", VALUES, utc)) == "120012.34"
    assert float(fix_time("PNORBT7", NMEA.encode("PNORBT7", VALUES, utc)) or "nan") == pytest.approx(
        utc.timestamp(), abs=1e-3)
    assert fix_time("HDT", NMEA.encode("HDT", VALUES, utc)) is None  # no time: cannot tell a repeat
    assert fix_time("GGA", "$GPGGA,,6326.40,N*00") is None  # an empty time field is no time


def test_status_counters_are_decoded_and_not_available_sids_are_none() -> None:
    n_max = np.full(7, 10.0)
    dbc = load_profile("emulator_pty").dbc_path()
    sea = SeafmuCodec(n_max, dbc)
    for k in (0, 5, 15, 16, 17):
        (msg,) = sea.status(2, 1.0, True, 0, k)
        assert sea.decode(msg).counter == k % 16
    n2k = Nmea2000Codec(n_max, dbc.parent / "nmea2000_thrusters.dbc")
    state, motor = n2k.status(1, 5.0, True, 0, 300)
    assert n2k.decode(state).counter == 300 % 252
    assert n2k.decode(motor).counter is None  # faults only: not a speed report
    data = bytearray(state.data)
    data[0] = 0xFF  # SID 255: "not available", a device that does not number its frames
    fb = n2k.decode(can.Message(arbitration_id=state.arbitration_id, data=bytes(data), is_extended_id=True))
    assert fb.counter is None and fb.speed == pytest.approx(5.0, abs=0.1)
