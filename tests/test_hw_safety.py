"""Safety in depth of the vessel link (issue 8): the drives stop the thrusters whatever happens to the
controller, the link stops them cleanly when asked, and physically impossible sensor values are
counted drops.

- the drive-side command check (``hardware/drive.py``): alive counter, command timeout, re-enable
  edge — deterministic (clock passed in) and as properties;
- the emulator's drives in real time over python-can's in-process ``virtual`` bus: commands stop;
  a frozen alive counter (a cyclic transmit task left running);
- across processes over pseudo-terminals (NMEA serial + SLCAN): the controller process running the
  real link is SIGKILLed; the emulated thrusters are at zero within the timeout (measured);
- the link's ``close()``: zero + disable frames, idempotent, deferred when a signal handler
  interrupts its I/O (never interleaved), the recording completed; re-arming after a drive timeout;
- implausible NMEA (latitude 200, depth overflowing to inf, DVL 1e30 m/s, ...) and CAN feedback
  are counted drops, never outputs.

Timing assertions use the emulator's 10 ms tick plus MARGIN for scheduling on a loaded machine.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import can
import numpy as np
import pynmea2
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from seafmu.hardware.canbus import FAULT_COMMAND_TIMEOUT, Command, Feedback
from seafmu.hardware.drive import CommandSupervisor
from seafmu.hardware.emulator import VesselEmulator
from seafmu.hardware.link import CLOSE_ROUNDS, LOG_FIRST, HardwareLink, LinkClosed, close_all_links
from seafmu.hardware.nmea import NORTEK_INVALID, NmeaCodec, NmeaError
from seafmu.hardware.plausibility import LIMITS, check_channels, limits_markdown
from seafmu.hardware.profile import HardwareProfile, load_profile
from seafmu.hardware.ptybridge import NullModem
from seafmu.identification.trial import load_trial

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 0.3  # s: the drives' command timeout in the in-process tests
MARGIN = 0.15  # s: the emulator's 10 ms tick + thread scheduling on a loaded 2-core machine
TAU = 0.2  # s: Minerva 2's shaft lag (vessel file)
N_RUN = -4.35  # rev/s: the command left on the bus in the issue
N_MAX = np.full(7, 20.0)
_chan = itertools.count()


def _nmea(body: str) -> str:
    return f"${body}*{pynmea2.NMEASentence.checksum(body):02X}"


def wait_until(pred: Callable[[], bool], timeout: float, poll: float = 0.005) -> bool:
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        if pred():
            return True
        time.sleep(poll)
    return pred()


# -- the drive-side command check, deterministic ------------------------------------------------


def _cmd(i: int, counter: int | None, speed: float = 5.0, enable: bool = True) -> Command:
    return Command(i, speed, enable, counter)


def test_supervisor_trips_after_the_timeout_and_fresh_frames_keep_it_running() -> None:
    lines: list[str] = []
    sup = CommandSupervisor(N_MAX[:2], timeout=0.3, log=lines.append)
    assert not sup.update(10.0).any()  # in the dock: nothing times out before the first command
    for k in range(10):  # 50 ms frames with an advancing counter
        now = 1.0 + 0.05 * k
        assert sup.receive(_cmd(0, k % 16), now) == "fresh"
        assert sup.receive(_cmd(1, k % 16, -30.0), now) == "fresh"
        assert not sup.update(now + 0.01).any()
    speed, on = sup.output()
    assert speed.tolist() == [5.0, -20.0] and on.all()  # clamped to n_max
    last = 1.0 + 0.05 * 9
    assert not sup.update(last + 0.3 - 1e-9).any()  # at the timeout: still running
    assert sup.update(last + 0.3 + 1e-6).all()  # a hair later: both stopped
    speed, on = sup.output()
    assert speed.tolist() == [0.0, 0.0] and not on.any()
    assert sup.faults().tolist() == [FAULT_COMMAND_TIMEOUT] * 2
    assert len(lines) == 2 and all("COMMAND TIMEOUT" in ln and "no valid command frame" in ln for ln in lines)


def test_supervisor_frozen_counter_is_stale_and_jumps_resynchronise() -> None:
    lines: list[str] = []
    sup = CommandSupervisor(N_MAX[:1], timeout=0.3, max_delta=3, log=lines.append)
    assert sup.receive(_cmd(0, 7), 0.0) == "fresh"
    for k in range(1, 20):  # the same frame again and again: a hung controller's cyclic task
        assert sup.receive(_cmd(0, 7, speed=9.0), 0.05 * k) == "stale"
        sup.update(0.05 * k)
    assert sup.tripped[0] and sup.counters["stale"] == 19
    assert "frozen at 7" in lines[0]
    # two frames lost (delta 3) is fresh; a jump of 4 is not applied but re-synchronises
    sup2 = CommandSupervisor(N_MAX[:1], timeout=0.3, max_delta=3)
    assert sup2.receive(_cmd(0, 14), 0.0) == "fresh"
    assert sup2.receive(_cmd(0, 1, speed=2.0), 0.05) == "fresh"  # 14 -> 1: +3 mod 16
    assert sup2.receive(_cmd(0, 5, speed=9.0), 0.1) == "jump"
    assert sup2.output()[0][0] == 2.0
    assert sup2.receive(_cmd(0, 6, speed=3.0), 0.15) == "fresh"
    assert sup2.output()[0][0] == 3.0


def test_supervisor_a_disabled_thruster_never_times_out_and_runs_on_the_next_enable() -> None:
    """Silence after enable 0 is a clean stop (the link's close), not a fault: no trip, no log line,
    no fault bit; the next fresh enable 1 runs (0 -> 1 is the edge a latched drive asks for)."""
    lines: list[str] = []
    sup = CommandSupervisor(N_MAX[:2], timeout=0.3, log=lines.append)
    sup.receive(_cmd(0, 0), 0.0)
    sup.receive(_cmd(1, 0), 0.0)
    sup.receive(_cmd(0, 1, speed=0.0, enable=False), 0.05)  # thruster 1 stopped cleanly
    assert sup.update(5.0).tolist() == [False, True]  # thruster 2, enabled and silent, trips
    assert sup.faults().tolist() == [0, FAULT_COMMAND_TIMEOUT]
    assert len(lines) == 1 and lines[0].startswith("thruster 2: COMMAND TIMEOUT")
    assert sup.receive(_cmd(0, 2, speed=4.0), 5.1) == "fresh"
    assert sup.output()[0].tolist() == [4.0, 0.0]


def test_supervisor_needs_an_enable_edge_after_a_timeout_unless_not_latching() -> None:
    sup = CommandSupervisor(N_MAX[:1], timeout=0.3, latching=True)
    sup.receive(_cmd(0, 0), 0.0)
    sup.update(0.5)
    assert sup.tripped[0]
    assert sup.receive(_cmd(0, 1, enable=True), 0.6) == "ignored"  # a controller waking from a hang
    assert sup.update(0.65).sum() == 0 and sup.output()[0][0] == 0.0
    assert sup.counters["enable_without_edge"] == 1
    assert sup.receive(_cmd(0, 2, speed=0.0, enable=False), 0.7) == "fresh"  # acknowledged
    assert not sup.tripped[0] and sup.faults()[0] == 0
    assert sup.receive(_cmd(0, 3, speed=4.0), 0.75) == "fresh"
    assert sup.output()[0][0] == 4.0
    assert [e[2] for e in sup.events] == ["timeout", "rearmed"]
    # NMEA 2000 (SID as counter, mod 252; no latch to report): the next fresh frame resumes
    n2k = CommandSupervisor(N_MAX[:1], timeout=0.25, modulus=252, latching=False)
    n2k.receive(_cmd(0, 250), 0.0)
    n2k.update(0.3)
    assert n2k.tripped[0]
    assert n2k.receive(_cmd(0, 251, speed=3.0), 0.35) == "fresh"
    assert n2k.output()[0][0] == 3.0
    assert n2k.receive(_cmd(0, 0, speed=3.5), 0.4) == "fresh"  # 251 -> 0 wraps at 252


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(0.0, 0.25),  # time to the next event
            st.integers(0, 5),  # counter advance (0: repeat)
            st.booleans(),  # enable
            st.floats(-40.0, 40.0),  # speed
            st.booleans(),  # a frame (else only a tick)
        ),
        max_size=60,
    )
)
def test_supervisor_never_runs_a_thruster_without_a_fresh_frame_within_the_timeout(events: list) -> None:
    """Reference model: a thruster may run only if a frame whose counter advanced by 1..max_delta
    arrived within the timeout, and never faster than n_max."""
    timeout, max_delta = 0.3, 3
    sup = CommandSupervisor(N_MAX[:1], timeout=timeout, max_delta=max_delta, latching=True)
    now, counter, last_counter, last_fresh = 0.0, 0, None, -math.inf
    for dt, adv, enable, speed, is_frame in events:
        now += dt
        if is_frame:
            counter = (counter + adv) % 16
            fresh = last_counter is None or 1 <= (counter - last_counter) % 16 <= max_delta
            if last_counter is None or (counter - last_counter) % 16:
                last_counter = counter
            if fresh:
                last_fresh = now
            sup.receive(Command(0, speed, enable, counter), now)
        sup.update(now)
        out, on = sup.output()
        assert abs(out[0]) <= N_MAX[0]
        if out[0] != 0.0 or on[0]:
            assert now - last_fresh <= timeout, (now, last_fresh)


# -- the emulator's drives in real time (in-process, python-can virtual) ------------------------


@contextlib.contextmanager
def running_emulator(profile: HardwareProfile) -> Iterator[VesselEmulator]:
    emu = VesselEmulator(profile, {"seed": 1, "down_0": 5.0})
    emu.open()
    th = threading.Thread(target=emu.run, daemon=True)
    th.start()
    try:
        yield emu
    finally:
        emu.stop_event.set()
        th.join(timeout=5)
        emu.close()


def _virtual_profile(channel: str, serial_url: str = "loop://", **over: object) -> HardwareProfile:
    return load_profile("emulator_pty").with_overrides(
        **{
            "serial.url": serial_url,
            "can.interface": "virtual",
            "can.channel": channel,
            "can.options": {},
            "command_timeout": TIMEOUT,
            **over,
        }
    )


class Controller:
    """A controller on the virtual bus that writes command frames itself (counter under its control)."""

    def __init__(self, emu: VesselEmulator, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.codec = emu.codec
        self.counter = 0
        self.last: list[can.Message] = []

    def round(self, speed: float, enable: bool = True) -> float:
        self.last = [self.codec.command(i, speed, enable, self.counter) for i in range(self.codec.count)]
        for msg in self.last:
            self.bus.send(msg)
        self.counter += 1
        return time.perf_counter()

    def status(self) -> dict[int, Feedback]:
        out: dict[int, Feedback] = {}
        while (m := self.bus.recv(timeout=0)) is not None:
            with contextlib.suppress(Exception):
                fb = self.codec.decode(m)
                if isinstance(fb, Feedback):
                    out[fb.index] = fb
        return out

    def close(self) -> None:
        self.bus.shutdown()


def _trip_times(emu: VesselEmulator, after: int = 0) -> dict[int, float]:
    """perf_counter time of each thruster's first command timeout among the events from ``after``."""
    out: dict[int, float] = {}
    for t, i, kind in emu.drive.events[after:]:
        if kind == "timeout" and i not in out:
            out[i] = emu.perf_time(t)
    return out


def test_emulator_stops_the_thrusters_within_the_timeout_when_commands_stop() -> None:
    chan = f"safety{next(_chan)}"
    with running_emulator(_virtual_profile(chan)) as emu:
        ctl = Controller(emu, chan)
        try:
            for _ in range(20):  # 1 s of commands at 20 Hz
                t_last = ctl.round(N_RUN)
                time.sleep(0.05)
            assert emu.drive.enable.all() and not emu.drive.tripped.any()
            assert np.allclose(emu.n_shaft, N_RUN, atol=0.1)  # the shafts spin
            assert wait_until(lambda: bool(emu.drive.tripped.all()), 3.0)
            trips = _trip_times(emu)
            assert sorted(trips) == list(range(7))
            first, last = min(trips.values()) - t_last, max(trips.values()) - t_last
            assert TIMEOUT - 0.005 <= first and last <= TIMEOUT + MARGIN, (first, last)
            assert wait_until(lambda: float(np.max(np.abs(emu.n_shaft))) < 0.05, 3.0)
            stopped = time.perf_counter() - t_last
            # the demand is zero at the trip; the shaft then coasts down with its lag
            assert stopped <= TIMEOUT + TAU * math.log(abs(N_RUN) / 0.05) + MARGIN
            time.sleep(0.06)  # a status round after the trip
            fb = ctl.status()
            assert all(not fb[i].enabled and fb[i].faults & FAULT_COMMAND_TIMEOUT for i in range(7))
            assert sum("COMMAND TIMEOUT" in ln for ln in emu.log_lines) == 7
            print(
                f"commands stopped: drives zeroed {1e3 * first:.0f}-{1e3 * last:.0f} ms after the last "
                f"frame (timeout {1e3 * TIMEOUT:.0f} ms); shafts < 0.05 rev/s after {1e3 * stopped:.0f} ms"
            )
        finally:
            ctl.close()


def test_emulator_names_bad_command_frames_once_each_kind_then_counts_them() -> None:
    """Wrong-length command frames are counted and the first few logged (then only counted), so a
    drive's later COMMAND TIMEOUT is explained, and a flooding bus does not flood the terminal."""
    chan = f"safety{next(_chan)}"
    with running_emulator(_virtual_profile(chan)) as emu:
        ctl = Controller(emu, chan)
        try:
            for _ in range(12):
                good = ctl.codec.command(0, N_RUN, True, ctl.counter)
                ctl.bus.send(can.Message(arbitration_id=good.arbitration_id, data=bytes(good.data[:3]),
                                         is_extended_id=good.is_extended_id))
                ctl.counter += 1
                time.sleep(0.02)
            assert wait_until(lambda: emu.counters["bad_frame"] == 12, 2.0), emu.counters
            named = [ln for ln in emu.log_lines if ln.startswith("dropped (bad_frame")]
            assert len(named) == LOG_FIRST and "further bad_frame only counted" in named[-1], named
            assert not emu.started and not emu.drive.enable.any()  # nothing was taken as a command
        finally:
            ctl.close()


def test_frozen_alive_counter_is_detected_and_an_enable_edge_restarts() -> None:
    chan = f"safety{next(_chan)}"
    with running_emulator(_virtual_profile(chan)) as emu:
        ctl = Controller(emu, chan)
        tasks: list[can.broadcastmanager.CyclicSendTaskABC] = []
        try:
            for _ in range(10):
                t_fresh = ctl.round(N_RUN)
                time.sleep(0.05)
            # the controller hangs, but a cyclic transmit task keeps sending its last frames
            tasks = [ctl.bus.send_periodic(msg, 0.05) for msg in ctl.last]
            assert wait_until(lambda: bool(emu.drive.tripped.all()), 3.0)
            trips = _trip_times(emu)
            latency = max(trips.values()) - t_fresh
            assert TIMEOUT - 0.005 <= min(trips.values()) - t_fresh and latency <= TIMEOUT + MARGIN
            assert emu.drive.counters["stale"] >= 7 and not emu.drive.output()[1].any()
            assert sum("alive counter frozen" in ln for ln in emu.log_lines) == 7
            for task in tasks:
                task.stop()
            tasks = []
            # the controller is back: enable 1 alone does not restart a latched drive ...
            for _ in range(3):
                ctl.round(N_RUN, enable=True)
                time.sleep(0.05)
            assert emu.drive.tripped.all() and emu.drive.counters["enable_without_edge"] >= 7
            demand, on = emu.drive.output()
            assert not on.any() and not demand.any()  # the shafts coast down, not driven
            # ... enable 0 acknowledges the stop, then enable 1 runs again
            ctl.round(0.0, enable=False)
            assert wait_until(lambda: not emu.drive.tripped.any(), 1.0)
            ctl.round(N_RUN, enable=True)
            assert wait_until(lambda: bool(emu.drive.output()[1].all()), 1.0)
            print(f"frozen counter: drives zeroed {1e3 * latency:.0f} ms after the last fresh frame")
        finally:
            for task in tasks:
                task.stop()
            ctl.close()


# -- across processes: the controller process is SIGKILLed ---------------------------------------

CHILD = r"""
import sys
import numpy as np
from seafmu.hardware.link import HardwareLink
from seafmu.hardware.profile import load_profile

serial_url, can_channel, record, speed = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
prof = load_profile("emulator_pty").with_overrides(
    **{"serial.url": serial_url, "can.channel": can_channel, "startup_timeout": 10.0}
)
link = HardwareLink(prof, record_dir=record)
link.initialize(np.zeros(7))
h, k = 0.05, 0
while True:  # a controller loop: the same command every step, until killed
    link.set_inputs(np.full(7, speed))
    link.do_step(k * h, h)
    k += 1
    if k == 10:
        print("RUNNING", flush=True)
"""


def test_sigkill_of_the_controller_process_stops_the_thrusters_within_the_timeout(tmp_path: Path) -> None:
    base = load_profile("emulator_pty")
    timeout = base.command_timeout  # the bundled profile's, 0.5 s
    with NullModem() as nm_ser, NullModem() as nm_can:
        prof = base.with_overrides(**{"serial.url": nm_ser.a, "can.channel": nm_can.a})
        with running_emulator(prof) as emu:
            err = open(tmp_path / "child.err", "w")
            proc = subprocess.Popen(
                [sys.executable, "-c", CHILD, nm_ser.b, nm_can.b, str(tmp_path / "rec"), str(N_RUN)],
                cwd=REPO,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
            try:
                assert proc.stdout is not None
                ready, _, _ = select.select([proc.stdout], [], [], 30.0)
                line = proc.stdout.readline() if ready else ""
                assert line.strip() == "RUNNING", (tmp_path / "child.err").read_text()[-2000:]
                time.sleep(0.8)  # RUNNING came at 0.5 s of loop time: past the first 1 s flush
                # the thrusters run at the commanded speed, enabled (the situation of issue 8)
                assert wait_until(
                    lambda: bool(np.allclose(emu.n_shaft, N_RUN, atol=0.05) and emu.drive.output()[1].all()),
                    10.0,
                ), (emu.n_shaft, emu.drive.enable, emu.log_lines)
                n_events = len(emu.drive.events)
                t_kill = time.perf_counter()
                os.kill(proc.pid, signal.SIGKILL)
                assert proc.wait(timeout=10) == -signal.SIGKILL
                assert wait_until(lambda: bool(emu.drive.tripped.all()), 3.0), emu.log_lines
                trips = _trip_times(emu, n_events)
                assert sorted(trips) == list(range(7))
                latency = max(trips.values()) - t_kill
                assert latency <= timeout + MARGIN, latency
                # against each drive's own clock: tripped one tick after the timeout
                since = [emu.perf_time(t) - emu.perf_time(emu.drive.last_valid[i])
                         for t, i, kind in emu.drive.events[n_events:] if kind == "timeout"]
                assert timeout - 1e-6 < min(since) and max(since) <= timeout + MARGIN, since
                assert wait_until(lambda: float(np.max(np.abs(emu.n_shaft))) < 0.05, 3.0)
                stopped = time.perf_counter() - t_kill
                assert stopped <= timeout + TAU * math.log(abs(N_RUN) / 0.05) + MARGIN
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(timeout=10)
                err.close()
    timeouts = [ln for ln in emu.log_lines if "COMMAND TIMEOUT" in ln]
    assert len(timeouts) == 7 and all("no valid command frame" in ln for ln in timeouts)
    # the killed process's recording: a loadable trial with every finished row, raw logs flushed
    rec = tmp_path / "rec"
    trial = load_trial(rec / "trial.yaml")
    assert trial.kind == "maneuver" and trial.vessel == "minerva2"
    data = np.genfromtxt(trial.files[0], delimiter=",", names=True, skip_header=1)  # raises on a cut row
    assert len(data) >= 20 and np.all(np.diff(data["time"]) > 0) and np.all(np.isfinite(data["meas_down"]))
    assert sum(1 for f in can.LogReader(str(rec / "can.asc")) if not f.is_rx) >= 7 * 10
    print(
        f"SIGKILL: drives zeroed and disabled {1e3 * latency:.0f} ms after the kill, "
        f"{1e3 * min(since):.0f}-{1e3 * max(since):.0f} ms after their last fresh frame (timeout "
        f"{1e3 * timeout:.0f} ms); shafts < 0.05 rev/s after {1e3 * stopped:.0f} ms"
    )


# -- the link's own stop ---------------------------------------------------------------------------

SENSORS = {
    "usbl": ["GGA"],
    "depth": ["DPT"],
    "ahrs": ["XDR_ATTITUDE", "HDT"],
    "dvl": ["PNORBT7"],
    "gyro": ["XDR_RATES"],
}
VALUES = {
    "north": 1.5, "east": -2.25, "down": 5.0, "roll": 0.01, "pitch": -0.02, "yaw": 1.0,
    "u": 0.1, "v": -0.05, "w": 0.0, "p": 0.001, "q": -0.002, "r": 0.003,
}


class Vessel:
    """The far end written by hand: NMEA on the serial pty, frames on the virtual bus."""

    def __init__(self, serial_path: str, channel: str) -> None:
        self.ser = serial.serial_for_url(serial_path, timeout=0)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.nmea = NmeaCodec(63.44, 10.40)
        self.alive = 0
        t0 = datetime(2026, 1, 1, tzinfo=UTC)
        self.fix_times = (t0 + timedelta(seconds=0.1 * k) for k in itertools.count())

    def sample(self, sensors: tuple[str, ...] = tuple(SENSORS)) -> None:
        utc = next(self.fix_times)  # a live receiver's fix times advance
        lines = [self.nmea.encode(s, VALUES, utc) for name in sensors for s in SENSORS[name]]
        self.raw("".join(ln + "\r\n" for ln in lines).encode())

    def raw(self, data: bytes) -> None:
        self.ser.write(data)
        self.ser.flush()

    def frames(self) -> list[can.Message]:
        out = []
        while (m := self.bus.recv(timeout=0)) is not None:
            out.append(m)
        return out

    def status(self, link: HardwareLink, speed: float) -> None:
        self.alive += 1  # a live drive's status counter advances with every frame
        for i in range(7):
            for msg in link.codec.status(i, speed, True, 0, self.alive):
                self.bus.send(msg)

    def close(self) -> None:
        self.ser.close()
        self.bus.shutdown()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Callable[..., tuple[HardwareLink, Vessel]]]:
    made: list[tuple[NullModem, HardwareLink, Vessel]] = []

    def make(record: Path | None = None, **over: object) -> tuple[HardwareLink, Vessel]:
        path = tmp_path / f"nmea{len(made)}"
        nm = NullModem(link_b=path)
        chan = f"safety{next(_chan)}"
        prof = _virtual_profile(chan, str(path), startup_timeout=2.0, **over)
        link = HardwareLink(prof, record_dir=record)
        vessel = Vessel(nm.a, chan)
        made.append((nm, link, vessel))
        link.open()
        vessel.sample()
        link.initialize(np.zeros(7))
        vessel.frames()
        return link, vessel

    yield make
    for nm, link, vessel in made:
        link.close()
        vessel.close()
        nm.close()


def _decoded(link: HardwareLink, frames: list[can.Message]) -> list[Command]:
    return [c for c in map(link.codec.decode, frames) if isinstance(c, Command)]


def _steps(link: HardwareLink, vessel: Vessel, n: int, t: float = 0.0, h: float = 0.05) -> float:
    for _ in range(n):
        link.set_inputs(np.full(7, N_RUN))
        vessel.sample()
        vessel.status(link, N_RUN)
        link.do_step(t, h)
        t += h
    return t


def test_link_close_sends_zero_and_disable_is_idempotent_and_completes_the_recording(
    rig: Callable[..., tuple[HardwareLink, Vessel]], tmp_path: Path
) -> None:
    link, vessel = rig(record=tmp_path / "rec")
    t = _steps(link, vessel, 5)
    running = _decoded(link, vessel.frames())
    assert running[-1].enable and running[-1].speed == pytest.approx(N_RUN)
    t0 = time.perf_counter()
    assert link.close() is True and link.closed
    took = time.perf_counter() - t0
    assert link.close() is True and close_all_links() == 0  # idempotent
    stop = _decoded(link, vessel.frames())
    assert len(stop) == CLOSE_ROUNDS * 7 and all(c.speed == 0.0 and not c.enable for c in stop)
    # fresh alive counters, so a drive takes them: +1 per round after the last step's
    first = running[-1].counter
    assert [c.counter for c in stop[::7]] == [(first + k) % 16 for k in range(1, CLOSE_ROUNDS + 1)]
    with pytest.raises(LinkClosed):
        link.do_step(t, 0.05)
    assert vessel.frames() == []
    rec = tmp_path / "rec"
    assert (rec / "can.asc").read_text().rstrip().endswith("End TriggerBlock")
    assert (rec / "trial.yaml").is_file()
    assert "closed: zero setpoints, enable 0 sent to 7 thrusters" in (rec / "link.log").read_text()
    frames = list(can.LogReader(str(rec / "can.asc")))
    assert sum(1 for f in frames if not f.is_rx) == 5 * 7 + CLOSE_ROUNDS * 7
    assert took < 0.1
    print(f"close(): {1e3 * took:.1f} ms (zero + disable x {CLOSE_ROUNDS}, ports, recording)")


def test_close_inside_the_link_io_is_deferred_never_interleaved(
    rig: Callable[..., tuple[HardwareLink, Vessel]],
) -> None:
    """A signal handler runs between two bytecodes of the main thread: here it is simulated at the
    worst place, between two frames of one step's command round."""
    link, vessel = rig()
    t = _steps(link, vessel, 2)
    vessel.frames()
    real_send = link.can.send
    calls: list[bool] = []

    def send(msg: can.Message) -> bool:
        ok = real_send(msg)
        if len(calls) == 0 and msg.arbitration_id == 0x103:
            calls.append(link.close())  # as a SIGTERM handler would, mid-round
        return ok

    link.can.send = send  # type: ignore[method-assign]
    link.set_inputs(np.full(7, N_RUN))
    vessel.sample()
    link.do_step(t, 0.05)  # the step ends quietly: the close happened as its send section ended
    assert calls == [False] and link.closed
    cmds = _decoded(link, vessel.frames())
    assert len(cmds) == 7 + CLOSE_ROUNDS * 7
    assert all(c.enable and c.speed == pytest.approx(N_RUN) for c in cmds[:7])  # the whole round
    assert len({c.counter for c in cmds[:7]}) == 1
    assert all(not c.enable and c.speed == 0.0 for c in cmds[7:])
    with pytest.raises(LinkClosed):
        link.do_step(t + 0.05, 0.05)


def test_a_second_interrupt_during_close_is_raised_after_the_close_completes(
    rig: Callable[..., tuple[HardwareLink, Vessel]], tmp_path: Path
) -> None:
    link, vessel = rig(record=tmp_path / "rec")
    _steps(link, vessel, 2)
    vessel.frames()
    real_send = link.can.send
    sent: list[int] = []

    def send(msg: can.Message) -> bool:
        sent.append(msg.arbitration_id)
        if len(sent) == 3:
            raise KeyboardInterrupt  # the user presses Ctrl-C again while the link closes
        return real_send(msg)

    link.can.send = send  # type: ignore[method-assign]
    with pytest.raises(KeyboardInterrupt):
        link.close()
    assert link.closed and not link.can.is_open and not link.serial.is_open
    stop = _decoded(link, vessel.frames())  # the interrupted round is partial, the others complete
    assert len(stop) == 2 + (CLOSE_ROUNDS - 1) * 7 and all(not c.enable and c.speed == 0.0 for c in stop)
    rounds = [c.counter for c in stop[2::7]]  # every round has its own counter: the drives take them
    assert len(set(rounds)) == CLOSE_ROUNDS - 1 and stop[0].counter not in rounds
    assert (tmp_path / "rec" / "can.asc").read_text().rstrip().endswith("End TriggerBlock")
    assert link.close() is True  # and it stays closed


@pytest.mark.parametrize("delay", [0.112, 0.147, 0.171])
def test_close_from_a_real_signal_handler(
    rig: Callable[..., tuple[HardwareLink, Vessel]], delay: float
) -> None:
    link, vessel = rig()
    old = signal.signal(signal.SIGALRM, lambda signum, frame: close_all_links())
    t, h = 0.0, 0.05
    try:
        signal.setitimer(signal.ITIMER_REAL, delay)
        for _ in range(40):
            if link.closed:
                break
            link.set_inputs(np.full(7, N_RUN))
            vessel.sample()
            vessel.status(link, N_RUN)
            try:
                link.do_step(t, h)
            except LinkClosed:
                break
            t += h
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert link.closed
    cmds = _decoded(link, vessel.frames())
    run, stop = cmds[: -CLOSE_ROUNDS * 7], cmds[-CLOSE_ROUNDS * 7 :]
    assert len(run) % 7 == 0 and len(run) >= 7  # only complete rounds before the stop
    for k in range(0, len(run), 7):
        assert len({c.counter for c in run[k : k + 7]}) == 1 and all(c.enable for c in run[k : k + 7])
    assert all(not c.enable and c.speed == 0.0 for c in stop)


def test_link_rearms_a_drive_after_its_command_timeout_and_ramps_from_zero(tmp_path: Path) -> None:
    """The controller hangs for longer than the drives' timeout (a GC pause, SIGSTOP, a blocked
    disk): the drives stop; when it wakes, its stale enable-1 frames do not restart them; the link
    sees the fault bit, sends enable 0, and ramps up from zero."""
    chan = f"safety{next(_chan)}"
    with NullModem() as nm:
        emu_prof = _virtual_profile(chan, nm.a)
        link_prof = _virtual_profile(
            chan, nm.b, **{"watchdog.timeout": 1.0, "watchdog.resume_ramp": 0.5, "startup_timeout": 5.0}
        )
        with running_emulator(emu_prof) as emu:
            link = HardwareLink(link_prof)
            try:
                link.initialize(np.zeros(7))
                h, t = 0.05, 0.0
                link.set_inputs(np.full(7, 10.0))
                for _ in range(10):
                    link.do_step(t, h)
                    t += h
                assert wait_until(lambda: bool(np.allclose(emu.drive.output()[0], 10.0)), 1.0)
                time.sleep(TIMEOUT + 0.2)  # the controller hangs
                applied = []
                for _ in range(40):
                    link.do_step(t, h)
                    t += h
                    applied.append(float(emu.drive.output()[0].max()))
                kinds = [kind for _, _, kind in emu.drive.events]
                assert kinds.count("timeout") == 7 and kinds.count("rearmed") == 7
                assert emu.drive.counters["enable_without_edge"] >= 7  # the stale commands were refused
                assert link.counters["drive_timeout"] == 7
                assert any("re-arming" in ln for ln in link.log_lines)
                after = [a for a in applied if a > 0]
                assert after and after[0] < 10.0 * 0.6  # ramping from zero, not the stale setpoint
                assert after[-1] == pytest.approx(10.0) and np.all(np.diff(after) >= -0.011)
                fault = [link.get_outputs()[link.out_names.index(f"fault_{i}")] for i in range(1, 8)]
                assert fault == [0.0] * 7
            finally:
                link.close()


# -- implausible values ---------------------------------------------------------------------------

IMPLAUSIBLE = [
    ("usbl", "GPGGA,120000.00,20000.0000000,N,01024.0000000,E,1,08,1.0,0.0,M,0.0,M,,"),  # lat 200
    ("usbl", "GPGGA,120000.00,9959.0000000,N,01024.0000000,E,1,08,1.0,0.0,M,0.0,M,,"),  # lat 99.98
    ("usbl", "GPGGA,120000.00,6326.4000000,N,18500.0000000,E,1,08,1.0,0.0,M,0.0,M,,"),  # lon 185
    ("usbl", "GPGGA,120000.00,6426.4000000,N,01024.0000000,E,1,08,1.0,0.0,M,0.0,M,,"),  # 111 km away
    ("depth", "SDDPT,1e308,1e308,"),  # depth + offset overflows to inf
    ("depth", "SDDPT,-50.0,0.0,"),  # 50 m above the surface
    ("dvl", "PNORBT7,1.0,0.0,0.0,1e30,0.0,0.0,0.0050,10.00,10.00,10.00,10.00"),  # 1e30 m/s
    ("dvl", "PNORBT7,1.0,0.0,0.0,0.1,-250.0,0.0,0.0050,10.00,10.00,10.00,10.00"),  # cm/s as m/s
    ("ahrs", "HEHDT,720.0,T"),
    ("ahrs", "IIXDR,A,500.0,D,ROLL,A,0.0,D,PITCH"),
    ("ahrs", "IIXDR,A,0.0,D,ROLL,A,95.0,D,PITCH"),
    ("gyro", "IIXDR,A,1e300,D,ROLLRATE,A,0.0,D,PITCHRATE,A,0.0,D,YAWRATE"),
]


def test_implausible_nmea_and_feedback_are_counted_drops_never_outputs(
    rig: Callable[..., tuple[HardwareLink, Vessel]],
) -> None:
    link, vessel = rig()
    t, h = 0.0, 0.05
    for k, (sensor, body) in enumerate(IMPLAUSIBLE, start=1):
        before = dict(zip(link.out_names, link.get_outputs(), strict=True))
        vessel.raw((_nmea(body) + "\r\n").encode())
        vessel.sample(tuple(s for s in SENSORS if s != sensor))  # the others keep the watchdog quiet
        vessel.status(link, 1.0)
        link.do_step(t, h)
        t += h
        out = dict(zip(link.out_names, link.get_outputs(), strict=True))
        assert link.counters["implausible"] == k, body
        assert out["lines_dropped"] == k
        assert out[f"{sensor}_count"] == before[f"{sensor}_count"], body  # no sample from it
        for c, v in VALUES.items():
            assert out[f"meas_{c}"] == pytest.approx(v, abs=1e-4), (body, c)  # the held values
    # CAN feedback: 300 rev/s from a 20 rev/s thruster
    bad = can.Message(
        arbitration_id=0x183,
        data=link.codec.db.get_message_by_name("THR_STATUS_3").encode(
            {"speed_measured": 300.0, "enabled": 1, "counter": 0, "fault_overcurrent": 0,
             "fault_overtemperature": 0, "fault_command_timeout": 0, "fault_hardware": 0}
        ),
        is_extended_id=False,
    )
    vessel.bus.send(bad)
    vessel.sample()
    link.do_step(t, h)
    out = dict(zip(link.out_names, link.get_outputs(), strict=True))
    assert link.counters["implausible_feedback"] == 1 and out["frames_dropped"] == 1
    assert out["n_3"] == pytest.approx(1.0)
    assert sum("dropped (implausible" in ln for ln in link.log_lines) == 6  # 5 + 1 of each class
    assert out["watchdog_alarm"] == 0.0


def _fmt(x: float, style: int) -> str:
    return (repr(x), f"{x:.3f}", f"{x:e}", f"{x:.1f}")[style]


FIELD_SENTENCES = {  # sentence with one numeric field {x}: any value either decodes in limits or is dropped
    "DPT": "SDDPT,{x},0.0,",
    "DPT offset": "SDDPT,5.0,{x},",
    "DBT fathoms": "SDDBT,,f,,M,{x},F",
    "DBT feet": "SDDBT,{x},f,,M,,F",
    "PNORBT7": "PNORBT7,1.0,0.0,0.0,{x},0.0,0.0,0.0050,10.00,10.00,10.00,10.00",
    "HDT": "HEHDT,{x},T",
    "XDR roll": "IIXDR,A,{x},D,ROLL",
    "XDR pitch": "IIXDR,A,{x},D,PITCH",
    "XDR rate": "IIXDR,A,{x},D,YAWRATE",
    "ROT": "HEROT,{x},A",
    "VBW": "VDVBW,,,V,{x},0.0,A",
    "VTG": "GPVTG,10.0,T,,M,{x},N,,K,D",
    "RMC course": "GPRMC,120000.00,A,6326.4,N,01024.0,E,1.0,{x},010124,,,D",
    "GGA lat": "GPGGA,120000.00,{x},N,01024.0,E,1,08,1.0,0.0,M,0.0,M,,",
    "GGA lon": "GPGGA,120000.00,6326.4,N,{x},E,1,08,1.0,0.0,M,0.0,M,,",
}
CODEC = NmeaCodec(63.44, 10.40)


@settings(max_examples=400, deadline=None)
@given(
    st.sampled_from(sorted(FIELD_SENTENCES)),
    st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e5, 1e5)),
    st.integers(0, 3),
)
def test_whatever_a_sentence_says_the_decoder_returns_only_plausible_values(
    name: str, x: float, style: int
) -> None:
    line = _nmea(FIELD_SENTENCES[name].format(x=_fmt(x, style)))
    try:
        _, values = CODEC.decode(line)
    except NmeaError as exc:
        assert exc.kind in ("malformed", "implausible", "invalid", "unsupported")
        return
    assert check_channels(values) is None and all(math.isfinite(v) for v in values.values())


@settings(max_examples=200, deadline=None)
@given(st.floats(-40.0, 40.0), st.sampled_from(["u", "v", "w"]))
def test_dvl_speeds_are_dropped_exactly_outside_the_limit(speed: float, axis: str) -> None:
    vals = {"u": 0.0, "v": 0.0, "w": 0.0, axis: speed}
    line = CODEC.encode("PNORBT7", vals)
    sent = float(line.split(",")[4 + "uvw".index(axis)])  # what the wire says (5 decimals)
    lim = LIMITS[axis]
    if lim.lo <= sent <= lim.hi:
        assert CODEC.decode(line)[1][axis] == pytest.approx(sent)
    else:
        with pytest.raises(NmeaError) as e:
            CODEC.decode(line)
        # -32.768 is the DVL's own "no bottom lock" marker: invalid by the sensor's word
        assert e.value.kind == ("invalid" if sent == NORTEK_INVALID else "implausible")


def test_the_limits_table_in_the_docs_is_the_one_in_the_code() -> None:
    doc = (REPO / "docs" / "hardware.md").read_text()
    assert limits_markdown() in doc
    assert re.search(r"\| `down` \| −5 … 11000 \| m \|", doc)
