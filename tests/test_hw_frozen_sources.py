"""Sources that keep talking but say nothing new: a hung drive whose CAN controller repeats its
last status frame (the alive counter does not advance) and a receiver repeating its last fix (the
same fix time). Neither may pass for a live source: the drive goes stale (``feedback_lost``, its
speed NaN), the sensor's sample count stops (so the observer dead-reckons and the watchdog sees
it); both are counted as dropped input, and both come back as soon as they advance again.

NMEA through a pseudo-terminal pair, CAN through python-can's in-process virtual bus."""

from __future__ import annotations

import functools
import itertools
import math
import operator
from datetime import UTC, datetime, timedelta

import can
import numpy as np
import pytest
import serial

from seafmu.hardware.canbus import CanFrameError, Nmea2000Codec, SeafmuCodec
from seafmu.hardware.freshness import Freshness, counter_forward, time_forward
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
    per drive (alive counter +1). ``drives``/``gps``: thruster index (or True) -> how it fails:
    ``frozen`` repeats its last report, ``toggling`` alternates its last two (a two-slot transmit
    buffer), ``silent`` sends nothing."""

    def __init__(self, serial_path: str, channel: str, link: HardwareLink) -> None:
        self.ser = serial.serial_for_url(serial_path, timeout=0)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.link = link
        self.k = 0
        self.sent: dict[int, list[list[can.Message]]] = {i: [] for i in range(7)}  # each drive's reports
        self.ggas: list[str] = []

    @staticmethod
    def _pick(history: list, mode: str | None, fresh: object) -> object:
        if mode == "frozen" and history:
            return history[-1]
        if mode == "toggling" and len(history) >= 2:
            return history[-2]  # ... then the one before it again: history grows by the one sent
        history.append(fresh)
        return fresh

    def step(self, drives: dict[int, str] | None = None, gps: str | None = None,
             position: tuple[float, float] = (1.5, -2.25)) -> None:
        self.k += 1
        values = {**VALUES, "north": position[0], "east": position[1]}
        lines = [NMEA.encode(s, values, T0 + timedelta(seconds=0.1 * self.k))
                 for ss in SENSORS.values() for s in ss]
        gga = self._pick(self.ggas, gps, lines[0])
        if gps == "toggling" and len(self.ggas) >= 2:
            self.ggas.append(gga)
        self.ser.write("".join(ln + "\r\n" for ln in [gga, *lines[1:]]).encode())
        for i in range(7):
            mode = (drives or {}).get(i)
            if mode == "silent":
                continue
            msgs = self._pick(self.sent[i], mode, self.link.codec.status(i, 1.0 + i, True, 0, self.k))
            if mode == "toggling" and len(self.sent[i]) >= 2:
                self.sent[i].append(msgs)
            for msg in msgs:
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


def _lost(rows: list[dict], bit: float) -> list[int]:
    return [k for k, r in enumerate(rows) if int(r["feedback_lost"]) & int(bit)]


@pytest.mark.parametrize("mode", ["frozen", "toggling"])
def test_a_hung_drive_repeating_itself_goes_stale_and_recovers(mode: str) -> None:
    """Thruster 4's drive hangs from step 5 to step 24: its last status frame repeated every step
    (frozen), or its last two alternating (toggling: the counter goes back and forth, never on).
    Stale once no frame advanced for watchdog.timeout (0.3 s): n_4 NaN, bit 8 in feedback_lost,
    each frame not taken counted in frames_dropped. Fresh again once seen counting (two forward
    steps in a row)."""
    link, rows = _run(40, lambda k: {"drives": {3: mode} if 5 <= k < 25 else {}})
    lost = _lost(rows, 8)
    assert lost, f"a {mode} drive passed for a live one"
    assert all(rows[k]["feedback_lost"] == 8.0 and math.isnan(rows[k]["n_4"]) for k in lost)
    # fresh again at the second forward step: toggling, its last pair's step is the first (A, B, C)
    back = {"frozen": 26, "toggling": 25}[mode]
    assert 9 <= lost[0] <= 12 and lost == list(range(lost[0], back))  # 0.3 s after its last fresh frame
    assert all(r["n_1"] == 1.0 and r["n_7"] == 7.0 for r in rows)  # the other drives stay fresh
    assert rows[-1]["n_4"] == 4.0 and rows[-1]["feedback_lost"] == 0.0
    not_taken = back - 5  # its frames from the hang until it is seen counting
    assert link.counters["status_repeated"] == not_taken and rows[-1]["frames_dropped"] == not_taken
    said = [ln for ln in link.log_lines if "thruster 4:" in ln]
    assert "does not advance" in said[0] and "a repeat, not fresh" in said[0]
    assert any("n_4 is NaN" in ln for ln in said) and any("status frames again" in ln for ln in said)


def test_a_drive_back_from_silence_is_fresh_once_seen_counting() -> None:
    """After a silence (15 steps, 0.75 s > watchdog.timeout) the old counter says nothing: a 4-bit
    counter meets its old value again after 16 frames (here it resumes with exactly the counter
    it had), and a drive may come back hung. Its frames are taken once it counts: the third."""
    link, rows = _run(30, lambda k: {"drives": {2: "silent"} if 5 <= k < 20 else {}})
    resumed = 20  # its first frame after the silence: counter (k + 2) % 16, its last one's (step 4)
    assert (resumed + 2) % 16 == (4 + 2) % 16
    lost = _lost(rows, 4)
    assert lost and lost[-1] == resumed + 1 and rows[resumed + 2]["n_3"] == 3.0
    assert link.counters["status_repeated"] == 2


def test_a_drive_back_from_silence_hung_stays_stale() -> None:
    """Silent from step 5, then from step 20 repeating the last frame it sent before (a drive that
    hung and whose transmit buffer came back): never fresh again."""
    def schedule(k: int) -> dict:
        return {"drives": {2: "silent" if k < 20 else "frozen"} if k >= 5 else {}}

    link, rows = _run(40, schedule)
    lost = _lost(rows, 4)
    assert lost and lost == list(range(lost[0], 40)), lost
    assert all(math.isnan(r["n_3"]) for r in rows[lost[0]:])
    assert link.counters["status_repeated"] == 20


def test_nmea2000_hung_drives_trip_the_watchdog() -> None:
    """NMEA 2000: every drive repeats its last 128006 and 128008 from step 5. The fault-only 128008
    says nothing about the drive being alive, so the thrusters' watchdog source goes silent too:
    the alarm trips (zero setpoints, enable off) and clears once they count again."""
    dbc = load_profile("emulator_pty").dbc_path().parent / "nmea2000_thrusters.dbc"
    link, rows = _run(40, lambda k: {"drives": dict.fromkeys(range(7), "frozen") if 5 <= k < 25 else {}},
                      **{"can.mapping": "nmea2000", "can.dbc": str(dbc)})
    assert link.counters["status_repeated"] > 0
    assert any(r["watchdog_alarm"] == 1.0 for r in rows[10:25])
    assert any(r["feedback_lost"] == 127.0 for r in rows[10:25])
    assert rows[-1]["watchdog_alarm"] == 0.0 and rows[-1]["feedback_lost"] == 0.0


@pytest.mark.parametrize("mode", ["frozen", "toggling"])
def test_a_receiver_repeating_its_last_fixes_is_not_a_new_sample(mode: str) -> None:
    """The GPS repeats its last GGA (frozen) or alternates its last two (toggling) from step 5 to
    step 14: usbl_count stops, the position holds the last real fix, each old one is counted in
    lines_dropped; a watched usbl trips the watchdog; with fixes advancing again the count and the
    position move on."""
    def schedule(k: int) -> dict:
        return {"gps": mode if 5 <= k < 15 else None, "position": (1.5 + 0.1 * k, -2.25)}

    link, rows = _run(25, schedule, **{"watchdog.sources": ["usbl", "thrusters"]})
    counts = [r["usbl_count"] for r in rows]
    assert counts[:5] == [2.0, 3.0, 4.0, 5.0, 6.0]
    assert counts[5:15] == [6.0] * 10  # nothing new while it repeats
    assert counts[15:] == [7.0 + j for j in range(10)]
    assert rows[10]["meas_north"] == pytest.approx(1.5 + 0.1 * 4, abs=1e-3)  # the last real fix
    assert rows[-1]["meas_north"] == pytest.approx(1.5 + 0.1 * 24, abs=1e-3)
    assert link.counters["repeated"] == 10 and rows[-1]["lines_dropped"] == 10.0
    assert any(r["watchdog_alarm"] for r in rows[5:16]) and rows[-1]["watchdog_alarm"] == 0.0
    assert any("GGA with a time not after the last one taken" in ln for ln in link.log_lines)
    assert [r["depth_count"] for r in rows] == [2.0 + k for k in range(25)]  # the others unaffected


class GpsWithVtg(Vessel):
    """The far end with the GPS sending RMC + VTG (``usbl: [RMC, VTG]``) and a foreign sentence
    (a GGA no sensor takes); ``gps="frozen"``: its RMC repeats, its VTG still says a new speed."""

    def __init__(self, serial_path: str, channel: str, link: HardwareLink) -> None:
        super().__init__(serial_path, channel, link)
        self.rmcs: list[str] = []

    def step(self, drives: dict[int, str] | None = None, gps: str | None = None,
             position: tuple[float, float] = (1.5, -2.25)) -> None:
        self.k += 1
        t = T0 + timedelta(seconds=0.1 * self.k)
        values = {**VALUES, "north": position[0], "east": position[1], "sog": 0.01 * self.k, "course": 0.5}
        rmc = self._pick(self.rmcs, gps, NMEA.encode("RMC", values, t))
        vtg = NMEA.encode("VTG", values, t)
        lines = [vtg, rmc, vtg, NMEA.encode("GGA", values, t)]  # VTG before and after: one epoch's
        lines += [NMEA.encode(s, values, t) for name, ss in SENSORS.items() if name != "usbl" for s in ss]
        lines = [_talker(ln, "GP") if "HDT" in ln else ln for ln in lines]  # a GNSS compass's heading
        self.ser.write("".join(ln + "\r\n" for ln in lines).encode())
        for i in range(7):
            for msg in self.link.codec.status(i, 1.0 + i, True, 0, self.k):
                self.bus.send(msg)
        while self.bus.recv(timeout=0) is not None:
            pass


def _talker(line: str, talker: str) -> str:
    body = talker + line[3 : line.index("*")]
    return f"${body}*{functools.reduce(operator.xor, body.encode(), 0):02X}"


def test_a_vtg_beside_a_repeating_rmc_is_of_the_same_old_epoch() -> None:
    """RMC repeats from step 5 to 14: the VTG of its talker after it is dropped as `repeated` too,
    so sog holds the last real value (not the frozen receiver's VTG); both are taken again with the
    fixes. The heading of the same talker ($GPHDT, a GNSS compass) is not held to the fix: ahrs goes
    on. A sentence no sensor of the profile takes (the GGA here) is `unmapped`, never `repeated`."""
    def schedule(k: int) -> dict:
        return {"gps": "frozen" if 5 <= k < 15 else None}

    sensors = {**{k: v for k, v in SENSORS.items() if k != "usbl"}, "usbl": ["RMC", "VTG"]}
    link, rows = _run(25, schedule, far_end=GpsWithVtg, sensors=sensors)
    sog = [r["sog"] for r in rows]
    assert sog[:5] == pytest.approx([0.01 * (k + 2) for k in range(5)], abs=1e-4)
    # the VTG ahead of the first old RMC passes (nothing tells its epoch yet); none after it
    assert sog[5:15] == pytest.approx([0.07] * 10, abs=1e-4)
    assert sog[15:] == pytest.approx([0.01 * (k + 2) for k in range(15, 25)], abs=1e-4)
    assert [r["usbl_count"] for r in rows][5:15] == [6.0] * 10
    assert [r["ahrs_count"] for r in rows] == [2.0 + k for k in range(25)]
    # 10 RMCs; the VTGs after each and ahead of the next (the first fresh RMC's leading one too)
    assert link.counters["repeated"] == 10 + 10 + 10 and link.counters["unmapped"] == 26
    assert any("VTG from GP, whose last fix was an old one again" in ln for ln in link.log_lines)


def test_drives_that_do_not_count_are_checked_for_silence_only() -> None:
    """``can.status_counter: false``: a drive sending one frame forever is not taken as hung."""
    frozen = {"drives": dict.fromkeys(range(7), "frozen")}
    link, rows = _run(20, lambda k: frozen, **{"can.status_counter": False})
    assert all(r["feedback_lost"] == 0.0 and r["n_4"] == 4.0 for r in rows)
    assert link.counters["status_repeated"] == 0
    checked, rows = _run(20, lambda k: frozen)  # the same drives, counter checked: all hung
    assert checked.counters["status_repeated"] > 0
    assert rows[-1]["feedback_lost"] == 127.0 and math.isnan(rows[-1]["n_1"])


def test_freshness_takes_counting_and_rejects_repeats_and_pairs() -> None:
    f = Freshness(counter_forward(16), window=0.3)
    t = iter(0.05 * k for k in itertools.count())
    assert [f.news(c, next(t)) for c in (14, 15, 0, 1, 3)] == [True] * 5  # wraps; a frame lost: fine
    assert [f.news(c, next(t)) for c in (3, 3, 2, 3, 2, 3)] == [False] * 6  # frozen, then toggling
    assert [f.news(c, next(t)) for c in (4, 5)] == [True, True]  # counting again from where it was
    g = Freshness(counter_forward(16), window=0.3)
    assert g.news(7, 0.0) and g.news(8, 0.05)
    assert [g.news(c, 1.0 + 0.05 * k) for k, c in enumerate((8, 9, 10))] == [False, False, True]  # after 1 s
    day = Freshness(time_forward(86400.0))
    assert day.news(86399.9, 0.0) and day.news(0.0, 0.1) and day.news(0.1, 0.2)  # midnight
    assert not day.news(0.1, 0.3) and not day.news(0.0, 0.4)  # the same fix, an older one
    unix = Freshness(time_forward(None))
    assert unix.news(1e9, 0.0) and not unix.news(1e9, 0.1) and unix.news(1e9 + 0.2, 0.2)
    reset = Freshness(time_forward(None))  # a clock set back: taken once seen running (two steps)
    assert reset.news(5000.0, 0.0)
    assert [reset.news(v, 1.0 + k) for k, v in enumerate((100.0, 100.2, 100.4))] == [False, False, True]


def test_fix_times_are_read_from_the_sentences_that_carry_one() -> None:
    utc = T0 + timedelta(seconds=12.34)
    gga = NMEA.encode("GGA", VALUES, utc)
    assert fix_time("GGA", gga) == pytest.approx(12 * 3600 + 12.34)  # s of the UTC day
    assert fix_time("RMC", NMEA.encode("RMC", VALUES, utc)) == pytest.approx(12 * 3600 + 12.34)
    unix = fix_time("PNORBT7", NMEA.encode("PNORBT7", VALUES, utc))
    assert unix == pytest.approx(utc.timestamp(), abs=1e-3)
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


def test_nmea2000_frames_of_other_devices_are_not_a_drive_s_report() -> None:
    """A 128006 is a drive's report only from that drive's source address (thruster_address + i);
    seafmu's own is its demand; another controller's demand, or a 128008 from anyone but the drive,
    is foreign: counted, never taken as feedback (a silent drive stays silent)."""
    n2k = Nmea2000Codec(np.full(7, 10.0), load_profile("emulator_pty").dbc_path().parent
                        / "nmea2000_thrusters.dbc")
    demand = n2k.command(2, 5.0, True, 1)
    state, motor = n2k.status(2, 5.0, True, 0, 1)
    assert n2k.decode(demand).__class__.__name__ == "Command"
    assert n2k.decode(state).speed == pytest.approx(5.0, abs=0.1)
    for msg, sa in ((demand, 0x11), (state, 0x11), (motor, 0x10), (state, 0x21)):
        other = can.Message(arbitration_id=(msg.arbitration_id & ~0xFF) | sa, data=msg.data,
                            is_extended_id=True)
        with pytest.raises(CanFrameError) as exc:
            n2k.decode(other)
        assert exc.value.kind == "foreign" and f"0x{sa:02X}" in str(exc.value), str(exc.value)
    big = n2k._ctrl.encode({**n2k._ctrl.decode(bytes(demand.data), decode_choices=False), "Identifier": 9})
    other = can.Message(arbitration_id=(demand.arbitration_id & ~0xFF) | 0x11, data=big, is_extended_id=True)
    with pytest.raises(CanFrameError) as exc:  # another vessel's thruster 10: foreign, not "unknown"
        n2k.decode(other)
    assert exc.value.kind == "foreign", str(exc.value)

    class OtherController(Vessel):
        def step(self, **kw: object) -> None:
            super().step(drives={2: "silent"})
            for k in range(3):  # another controller's demands for thruster 3, every step
                msg = self.link.codec.command(2, 5.0, True, self.k * 3 + k)
                self.bus.send(can.Message(arbitration_id=(msg.arbitration_id & ~0xFF) | 0x11, data=msg.data,
                                          is_extended_id=True))

    dbc = load_profile("emulator_pty").dbc_path().parent / "nmea2000_thrusters.dbc"
    link, rows = _run(20, lambda k: {}, OtherController, **{"can.mapping": "nmea2000", "can.dbc": str(dbc)})
    assert rows[-1]["feedback_lost"] == 4.0 and math.isnan(rows[-1]["n_3"]) and rows[-1]["n_1"] == 1.0
    assert link.counters["foreign"] > 0 and rows[-1]["frames_dropped"] == 0.0
