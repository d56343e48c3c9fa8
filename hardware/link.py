"""The hardware link: a real (or emulated) vessel in the plant's place in seafmu's master loop.

``HardwareLink`` implements the master's unit protocol (``seafmu.unit.PacedUnit``, structurally: this
layer does not import the one above) with the Plant
FMU's variable names, so the observer, controller and allocator FMUs connect to it unchanged:

- inputs ``n_cmd_1..m`` (rev/s) go out on the CAN bus every step, each clamped to the vessel's
  ``n_max``; NaN/inf become 0; the watchdog can force them to 0 (with enable off);
- outputs ``meas_<channel>`` and ``<sensor>_count`` are decoded from NMEA 0183 sentences; a
  sensor's count rises by one when all the sentences of one sample have arrived (the observer
  updates on a count change, exactly as with the Plant FMU; a GGA, RMC or PNORBT7 whose time is not
  later than the last one taken of its kind is an old measurement again, dropped as ``repeated``
  (``hardware/freshness.py``), so a receiver repeating its last fix does not pass for a live
  sensor, and so is an untimed sentence of its talker meanwhile); the first complete sample of every
  sensor is awaited in ``initialize`` and counts as sample 1, like the plant's initial sample;
- ``n_1..m`` is the thrusters' measured shaft speed from their CAN status frames (NaN before the
  first, and while that thruster's status is stale: none for ``watchdog.timeout``; a status whose
  alive counter did not move forward is not fresh, so a hung drive repeating its last frame goes
  stale); ``course`` and ``sog`` exist when a mapped sentence (RMC, VTG) carries them.
- link status: ``fault_i`` (the thruster's fault bits), ``watchdog_alarm`` (0/1),
  ``lines_dropped``, ``frames_dropped`` (bad input, running totals; physically implausible values
  included, ``hardware/plausibility.py``; command frames the adapter did not take), ``commands_limited``
  (commands clamped or replaced because NaN), ``port_losses``, ``feedback_lost`` (bit i - 1 set
  while thruster i's status is stale).

The true state (``north``, ``u``, ``thrust_i`` ...) of a real vessel is unknown: those plant
outputs are left out, so a scenario that connects or checks them fails validation by name.

Timing: ``do_step(t, h)`` sends the commands, then waits until wall time ``t + h`` (the
``Pacer``), then reads what arrived: its outputs are the vessel "at t + h", as a plant's are. So
the link itself holds the master loop to real time (``pace=False`` leaves that to the caller); it
declares so with ``paces_itself``, and reports how well with ``pacing_stats()``.

Watchdog: the link reads once per step, so it knows only that a datum arrived between two polls;
it takes the earlier one as the arrival time, and trips when a watched source (a sensor, or
``thrusters`` = any CAN status frame) would be older than ``timeout`` by the next poll. So the
zero setpoints are on the bus no later than ``timeout`` after the last datum arrived (between
``timeout - 2h`` and ``timeout - h``, plus the step jitter). Zero frames (enable off) go out at
once, and every step while the alarm lasts. It clears when every watched source has delivered a
new sample and is fresh again; the commands then ramp from 0 over ``resume_ramp``.

Sending never holds the loop: an adapter that does not take a frame costs one short time-out
(``transport.TX_TIMEOUT``) and the rest of that step's round is dropped and counted; the next step
tries again with the then current commands (SLCAN: the frames queued meanwhile are discarded).

Drives: every command frame carries an alive counter (+1 per frame); a drive stops a thruster
whose fresh commands stop for its command timeout (``hardware/drive.py``), which covers what the
link cannot: a killed or hung process. When a drive reports that timeout (fault bit 4), the link
acknowledges it with one enable-0 frame for that thruster and ramps it up from zero again.

Stopping: ``close()`` (also ``terminate()``, and ``close_all_links()`` for every open link, e.g.
from a signal handler, and at interpreter exit) sends zero setpoints with enable 0, closes the
ports and completes the recording; it is idempotent, never raises, and when it interrupts the
link's own I/O (a signal handler running inside ``do_step``) it is carried out as soon as that
I/O ends, before ``do_step`` returns. Any step after it raises ``LinkClosed``.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import math
import threading
import time
import weakref
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from cantools.database.errors import EncodeError

from ..components.block import Interface, Signal
from ..components.thrusters import speed_to_thrust
from ..components.vessel_spec import VesselSpec, load_vessel, state_unit
from .canbus import FAULT_COMMAND_TIMEOUT, CanFrameError, Command, Feedback, ThrusterCodec, make_codec
from .freshness import Freshness, counter_forward, time_forward
from .nmea import (
    DAY,
    EXTRA_CHANNELS,
    SENTENCES,
    NmeaCodec,
    NmeaError,
    check_mapping,
    default_sentences,
    fix_time,
)
from .pacing import Pacer, PacingStats
from .profile import HardwareProfile, load_profile
from .recording import Recorder, trial_meta
from .transport import CanPort, SerialLines

log = logging.getLogger("seafmu.hardware")

THRUSTERS = "thrusters"  # watchdog source name of the CAN status frames
LINE_CLASSES = (
    "checksum", "malformed", "invalid", "implausible", "line_too_long", "incomplete",
    # a timed sentence (GGA, RMC, PNORBT7) whose time is not after the last one taken, and an untimed
    # one of the same talker meanwhile (a VTG beside a repeating RMC)
    "repeated",
)
FRAME_CLASSES = (
    "unknown_id", "wrong_dlc", "decode", "unexpected", "implausible_feedback", "bus_error", "tx_timeout",
    "tx_skipped",  # the rest of a command round after the adapter refused a frame
    "status_repeated",  # a status whose alive counter did not move forward (a hung drive repeating it)
)
LOG_FIRST = 5  # one-line log messages per drop class before they are only counted
CLOSE_ROUNDS = 3  # zero + disable frames per thruster sent by close(), each with a fresh alive counter
# s: how long after an old fix again its talker's VTG is held to be of that old epoch (until its next
# timed sentence): two epochs of a 1 Hz receiver, whose VTG may come at 10 Hz
FROZEN_FIX_HOLD = 2.0
FLUSH_EVERY = 1.0  # s: the raw logs (can.*, nmea.raw) are flushed this often (what a SIGKILL can lose)


class HardwareError(RuntimeError):
    """The link cannot start (port, profile, vessel); one line saying what and where."""


class LinkClosed(HardwareError):
    """A step after ``close()``: the thrusters were stopped and the ports closed."""


_OPEN_LINKS: weakref.WeakSet[HardwareLink] = weakref.WeakSet()


def close_all_links() -> int:
    """``close()`` every open link of this process (zero + disable, ports, recording); the number
    closed now. For signal handlers and exit paths that do not hold the link objects; idempotent."""
    done = 0
    for link in list(_OPEN_LINKS):
        done += bool(link.close())
    return done


atexit.register(close_all_links)  # a run that ends without terminate() still stops the thrusters


def sensor_mapping(profile: HardwareProfile, spec: VesselSpec) -> dict[str, list[str]]:
    """Sensor name -> sentences of one sample: the profile's, else the defaults by channel."""
    names = [s.name for s in spec.sensors]
    given = profile.sensors or {}
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise HardwareError(
            f"{profile.source or profile.name}: sensors: unknown sensor(s) {unknown} "
            f"(vessel '{spec.name}' has {names})"
        )
    out: dict[str, list[str]] = {}
    owner: dict[str, str] = {}
    for s in spec.sensors:
        try:
            sentences = list(given[s.name]) if s.name in given else default_sentences(s)
            check_mapping(s, sentences)
        except ValueError as exc:
            raise HardwareError(f"{profile.source or profile.name}: sensors: {exc}") from None
        for name in sentences:
            if name in owner:
                raise HardwareError(
                    f"{profile.source or profile.name}: sensors: {name} is mapped to both "
                    f"'{owner[name]}' and '{s.name}'"
                )
            owner[name] = s.name
        out[s.name] = sentences
    return out


def make_thruster_codec(profile: HardwareProfile, spec: VesselSpec) -> ThrusterCodec:
    if spec.thrusters.count > 8 and profile.can.mapping == "seafmu":
        raise HardwareError(
            f"{profile.name}: the seafmu DBC defines 8 thrusters, vessel has {spec.thrusters.count}"
        )
    return make_codec(
        profile.can.mapping,
        spec.thrusters.n_max,
        profile.dbc_path(),
        profile.can.source_address,
        profile.can.thruster_address,
        profile.command_timeout,
    )


def watched_sources(profile: HardwareProfile, spec: VesselSpec) -> list[str]:
    wd = profile.watchdog
    names = [s.name for s in spec.sensors]
    if wd.sources is not None:
        bad = [s for s in wd.sources if s not in [*names, THRUSTERS]]
        if bad:
            raise HardwareError(
                f"{profile.source or profile.name}: watchdog.sources: unknown {bad} "
                f"(sensors {names} or '{THRUSTERS}')"
            )
        return list(wd.sources)
    return [s.name for s in spec.sensors if 1.0 / s.rate_hz < wd.timeout / 2] + [THRUSTERS]


class _Group:
    """One sensor's decoding state: sentences still missing from the sample being assembled."""

    def __init__(self, name: str, sentences: list[str], out_index: dict[str, int], count_index: int) -> None:
        self.name = name
        self.sentences = set(sentences)
        self.out_index = out_index  # channel -> output slot
        self.count_index = count_index
        self.pending: dict[str, float] = {}
        self.seen: set[str] = set()
        self.last_rx = -math.inf  # loop time of the last complete sample
        self.samples = 0


class HardwareLink:
    """A vessel behind serial NMEA and CAN, as a master unit with the Plant FMU's names."""

    kind = "hardware"

    def __init__(
        self,
        profile: str | Path | HardwareProfile,
        name: str = "plant",
        in_names: list[str] | None = None,
        log_lines: list[str] | None = None,
        pace: bool = True,
        record_dir: str | Path | None = None,
        vessel: str | None = None,
    ) -> None:
        # Long because it sets the link's whole state in one place (codecs, output slots, ports,
        # pacing, alarms, recorder), one attribute a line; the parts are made by helpers already.
        self.profile = load_profile(profile)
        p = self.profile
        self.name = name
        self.spec = load_vessel(vessel or p.vessel)
        spec = self.spec
        self.log_lines = log_lines if log_lines is not None else []
        self.mapping = sensor_mapping(p, spec)
        self.codec = make_thruster_codec(p, spec)
        self.nmea = NmeaCodec(p.origin.lat, p.origin.lon, p.talkers)
        self.watch = watched_sources(p, spec)
        iface = self.interface(p, spec)
        self.all_inputs = iface.input_names()
        self.in_names = list(in_names) if in_names is not None else list(self.all_inputs)
        bad = [n for n in self.in_names if n not in self.all_inputs]
        if bad:
            raise HardwareError(f"{name}: unknown input(s) {bad}; the link takes {self.all_inputs}")
        self._in_idx = np.array([self.all_inputs.index(n) for n in self.in_names], dtype=int)
        self.out_names = iface.output_names()
        slot = {n: i for i, n in enumerate(self.out_names)}
        self._slot = slot
        m = spec.thrusters.count
        self.n_max = np.asarray(spec.thrusters.n_max, dtype=float)
        self._u = np.zeros(m)  # commands from the allocator
        self._sent = np.zeros(m)  # commands as last sent
        self._y = np.full(len(self.out_names), np.nan)
        for k in ("watchdog_alarm", "lines_dropped", "frames_dropped", "commands_limited", "port_losses",
                  "feedback_lost"):
            self._y[slot[k]] = 0.0
        for i in range(m):
            self._y[slot[f"fault_{i + 1}"]] = 0.0
        self.groups = {
            s.name: _Group(
                s.name,
                self.mapping[s.name],
                {c: slot[f"meas_{c}"] for c in s.channels},
                slot[f"{s.name}_count"],
            )
            for s in spec.sensors
        }
        self._sentence_group = {sen: g for g in self.groups.values() for sen in g.sentences}
        self._fix_clocks: dict[str, Freshness[float]] = {}  # per timed sentence kind: its fix times
        # talkers (GP, GN, ...) whose last timed sentence was an old fix again, and when: the fix's
        # own untimed velocity (a VTG beside a repeating RMC) is of the same old epoch
        self._frozen_talkers: dict[str, float] = {}
        self.counters: Counter[str] = Counter()
        self._logged: Counter[str] = Counter()
        self.serial = SerialLines(
            p.serial.url,
            p.serial.baudrate,
            p.serial.options,
            p.reconnect_interval,
            self.counters,
            report=self._report,
        )
        self.can = CanPort(
            p.can.interface,
            p.can.channel,
            p.can.bitrate,
            p.can.options,
            p.reconnect_interval,
            self.counters,
            report=self._report,
        )
        self.pace = pace
        self.paces_itself = pace  # the unit protocol's pacing capability (seafmu/unit.py)
        self.pacer = Pacer(1.0)  # step set at the first do_step
        self._clock0: float | None = None
        self._last_feedback = -math.inf  # any status frame: the watchdog's `thrusters` source
        self._fb_rx = np.full(m, -math.inf)  # per thruster: loop time of its last status with a speed
        self._fb_seen = np.zeros(m, dtype=bool)  # ever reported its speed
        forward = counter_forward(self.codec.counter_modulus)
        self._fb_fresh = [Freshness(forward, p.watchdog.timeout) for _ in range(m)]  # alive counters
        self._fb_lost = np.zeros(m, dtype=bool)  # status stale (older than watchdog.timeout)
        self._fb_lost_since = np.zeros(m)
        self._fb_losses = np.zeros(m, dtype=int)  # times each went stale (the first LOG_FIRST logged)
        self._tx_blocked_at: float | None = None  # loop time the CAN adapter stopped taking frames
        self._prev_poll = 0.0  # loop time of the previous poll: the earliest a new datum can have come
        self._counter = 0
        self._sent_enable = np.zeros(m, dtype=bool)
        self.alarm = False
        self.alarm_since = 0.0
        self.alarms: list[tuple[float, float | None, str]] = []  # (start, end, reason)
        self._ramp_start = np.full(m, np.nan)  # per thruster: loop time its ramp from 0 began
        self._rearm: set[int] = set()  # thrusters whose drive reported a command timeout
        self._rearm_at = np.full(m, -math.inf)  # loop time of each thruster's last re-arm frame
        self._opened = False
        self._lock = threading.RLock()  # I/O sections and close(): one thread at a time
        self._busy = 0  # > 0 while the link does I/O (a close() from a signal handler then waits)
        self._close_pending = False
        self._closing = False
        self._closed = False
        self._last_flush = 0.0
        self.record_dir = Path(record_dir) if record_dir else (Path(p.record.dir) if p.record.dir else None)
        self.recorder: Recorder | None = None
        self._t = 0.0

    # -- interface -------------------------------------------------------------------------------
    @classmethod
    def interface(cls, profile: str | Path | HardwareProfile, spec: VesselSpec | None = None) -> Interface:
        """The link's variables for a profile (no port is opened): what a scenario connects to."""
        p = load_profile(profile)
        spec = spec or load_vessel(p.vessel)
        mapping = sensor_mapping(p, spec)
        th = spec.thrusters
        inputs = [
            Signal(
                f"n_cmd_{i + 1}",
                "rev/s",
                f"shaft speed command of thruster {i + 1} '{n}' (to CAN)",
                min=-float(th.n_max[i]),
                max=float(th.n_max[i]),
            )
            for i, n in enumerate(th.names)
        ]
        outputs = [
            Signal(f"n_{i + 1}", "rev/s", f"measured shaft speed of thruster {i + 1} '{n}' (CAN feedback)")
            for i, n in enumerate(th.names)
        ]
        for s in spec.sensors:
            outputs += [
                Signal(f"meas_{c}", state_unit(c),
                       f"{c} measured by {s.name} ({'+'.join(mapping[s.name])}), held")
                for c in s.channels
            ]
            outputs.append(
                Signal(f"{s.name}_count", "", f"samples received from {s.name}; +1 per complete sample")
            )
        carried = {c for sentences in mapping.values() for sen in sentences for c in SENTENCES[sen].extras}
        outputs += [
            Signal(c, state_unit(c), f"{c} over ground from the position sensor's sentences")
            for c in EXTRA_CHANNELS
            if c in carried
        ]
        outputs += [
            Signal(
                f"fault_{i + 1}",
                "",
                f"fault bits of thruster {i + 1}: 1 over-current, "
                "2 over-temperature, 4 command timeout, 8 hardware",
            )
            for i in range(th.count)
        ]
        outputs += [
            Signal("watchdog_alarm", "", "1 while the watchdog holds the thrusters at zero"),
            Signal(
                "lines_dropped",
                "",
                "NMEA lines dropped (checksum, malformed, invalid, implausible value, too long), total",
            ),
            Signal(
                "frames_dropped",
                "",
                "CAN frames dropped (unknown id, wrong DLC, undecodable, implausible, bus errors), total",
            ),
            Signal("commands_limited", "", "thruster commands clamped to n_max or replaced (NaN), total"),
            Signal("port_losses", "", "times the serial or CAN port was lost, total"),
            Signal(
                "feedback_lost",
                "",
                "thrusters whose status frames are stale (none for watchdog.timeout), as bits: "
                "1 thruster 1, 2 thruster 2, 4 thruster 3, ...; their n_i is NaN meanwhile",
            ),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=[])

    # -- the master's unit protocol ----------------------------------------------------------------
    def open(self) -> None:
        """Open the ports (and the recording); ``initialize`` does it if not done before."""
        with self._io():
            self._open()

    def _open(self) -> None:
        p = self.profile
        self._opened = True
        _OPEN_LINKS.add(self)
        if self.record_dir is not None and self.recorder is None:
            self.recorder = Recorder(self.record_dir, p.record.can_format, warn=self._say)
            self.serial.on_bytes = self.recorder.serial_bytes
            m = len(self._u)
            self.recorder.start_signals(
                [
                    *[f"n_cmd_{i + 1}" for i in range(m)],
                    *self.out_names,
                    *[f"thrust_{i + 1}" for i in range(m)],
                ],
                f"seafmu hardware link recording, profile {p.name}, vessel {self.spec.name}",
            )
            self.recorder.write_trial(self._trial_meta())  # now too: a killed run still leaves a trial
        for port in (self.serial, self.can):
            if not port.is_open and not port.open(retry=False):  # the run ends: nothing is retried
                self._close_pending = True  # closed as the I/O section ends
                raise HardwareError(
                    f"{self.name}: cannot open {port.what} port {port.name}: {port.error} (profile {p.name})"
                )

    def initial_outputs(self, values: np.ndarray) -> None:
        """None: a vessel's first outputs are its sensors' first samples (``initialize``)."""
        return None

    def initialize(self, values: np.ndarray) -> np.ndarray:
        """Open the ports and wait for a first complete sample of every sensor."""
        p = self.profile
        # the recorder's thrust law once now: its first call imports numba and loads the compiled
        # kernel (~0.3 s), which inside the loop would hold a step past the drives' command timeout
        speed_to_thrust(self.spec.thrusters, np.zeros(len(self._u)))
        self.open()
        self.set_inputs(values)
        t_end = time.perf_counter() + p.startup_timeout
        self._clock0 = time.perf_counter()
        self._prev_poll = 0.0
        while True:
            with self._io():
                self._poll(self._now())
            missing = [g.name for g in self.groups.values() if g.samples == 0]
            if not missing or time.perf_counter() > t_end:
                break
            time.sleep(0.005)
        if missing:
            self.close()
            raise HardwareError(
                f"{self.name}: no complete sample from {', '.join(missing)} within "
                f"{p.startup_timeout:g} s on {p.serial.url} (profile {p.name})"
            )
        for g in self.groups.values():  # the first sample, as the plant's initial one
            g.samples = 1
            g.last_rx = 0.0
            self._y[g.count_index] = 1.0
        self._last_feedback = 0.0 if math.isinf(self._last_feedback) else self._last_feedback
        self._clock0 = None  # the loop clock starts at the first do_step
        self._update_status()
        return self._y.copy()

    def set_inputs(self, values: np.ndarray) -> None:
        self._u[self._in_idx] = values

    def get_outputs(self) -> np.ndarray:
        return self._y

    def do_step(self, t: float, h: float) -> None:
        with self._io():
            self._step_send(t, h)
        if self.pace and not self._closed:
            self.pacer.wait_for(t + h)  # not inside _io: a close() from a signal handler acts at once
        if self._closed:  # closed meanwhile (a signal handler, another thread): this step ends here
            return
        with self._io():
            self._step_read(t, h)

    def _step_send(self, t: float, h: float) -> None:
        if self._clock0 is None:  # first step: loop time t is now
            if self.profile.watchdog.timeout <= 2 * h:
                raise HardwareError(
                    f"{self.name}: watchdog.timeout {self.profile.watchdog.timeout:g} s must "
                    f"exceed two steps ({2 * h:g} s): the link reads once per step"
                )
            self._clock0 = time.perf_counter() - t
            self.pacer = Pacer(h)
            self.pacer.start(self._clock0)
            prio = self.profile.realtime_priority
            if prio is not None and not Pacer.elevate(prio):
                self._say(
                    f"realtime_priority {prio}: not permitted here (needs CAP_SYS_NICE); normal scheduling"
                )
            for g in self.groups.values():
                g.last_rx = t
            self._last_feedback = t
            self._fb_rx[:] = t  # every thruster has one timeout from now to report
            self._prev_poll = t
        self._send(*self._commands(t))

    def _step_read(self, t: float, h: float) -> None:
        now = self._now()
        self._poll(now)
        self._feedback_ages(now)
        self._watchdog(now, h)
        self._t = t + h
        self._update_status()
        if self.recorder is not None:
            n = self._y[: len(self._u)].copy()
            early = ~self._fb_seen & ~self._fb_lost  # no status yet, within its timeout: the command
            n[early] = self._sent[early]
            thrust = speed_to_thrust(self.spec.thrusters, n)  # NaN while a status is stale, not made up
            self.recorder.row(t + h, np.concatenate([self._sent, self._y, thrust]))
            if now - self._last_flush >= FLUSH_EVERY:
                self._last_flush = now
                self.recorder.flush()

    def set_value(self, var: str, value: Any) -> None:
        if var not in self.all_inputs:
            raise ValueError(f"{self.name}: '{var}' is not an input of the hardware link")
        self._u[self.all_inputs.index(var)] = float(value)

    def terminate(self) -> None:
        """The master's end of the run: ``close()``."""
        self.close()

    def collect_log(self) -> None:
        """The link writes its messages to the run's log as they happen; nothing is buffered."""

    def step_error(self, what: str, exc: Exception) -> Exception:
        return exc

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> bool:
        """Stop the thrusters and release everything; True once done (now or before).

        Sends zero setpoints with enable 0 to every thruster (CLOSE_ROUNDS frames each, every one
        with a fresh alive counter, so a drive takes them), closes the serial and CAN ports, and
        completes the recording (link totals in link.log, the CAN log terminated, signals.csv
        flushed, trial.yaml written). Idempotent and never raises: each part that fails is
        logged and the rest still done (a KeyboardInterrupt / SystemExit arriving meanwhile is
        raised after the close is complete). From a signal handler that interrupted the link's own
        I/O inside ``do_step`` it returns False and the close happens as that I/O section ends
        (milliseconds; before ``do_step`` returns or raises) — never interleaved with a frame
        being written. From another thread it waits for the current I/O section, then closes.
        A ``do_step`` during which the link was closed returns without reading; the next one
        raises ``LinkClosed``.
        """
        with self._lock:  # another thread's I/O section ends first; this thread's own re-enters
            if self._closed or self._closing:
                return True
            if self._busy:  # this thread is inside the link's I/O (a signal handler interrupted it)
                self._close_pending = True
                return False
            self._closing = True
            try:
                self._close_now()
            finally:
                self._closed = True
                self._closing = False
                _OPEN_LINKS.discard(self)
            return True

    def _close_now(self) -> None:
        interrupted: list[BaseException] = []

        def guarded(what: str, fn: Any) -> None:
            try:
                fn()
            except Exception as exc:  # a dead port or a full disk must not stop the rest
                with contextlib.suppress(Exception):
                    self._say(f"close: {what} failed ({type(exc).__name__}: {exc})")
            except BaseException as exc:  # a second Ctrl-C: finish closing first, then let it through
                interrupted.append(exc)

        m = len(self._u)

        def zero_round(k: int) -> None:
            if k:
                time.sleep(0.002)  # let a small adapter queue drain between rounds
            self._send(np.zeros(m), np.zeros(m, dtype=bool))

        if self._opened and self.can.is_open:  # never open a port just to close it
            for k in range(CLOSE_ROUNDS):  # each round on its own: an interrupt skips none of the others
                guarded("stopping the thrusters", lambda k=k: zero_round(k))
            said = f"closed: zero setpoints, enable 0 sent to {m} thrusters ({CLOSE_ROUNDS} rounds)"
            guarded("logging", lambda: self._say(said))
        guarded("closing the serial port", self.serial.close)
        guarded("closing the CAN port", self.can.close)
        if self.counters:
            totals = dict(sorted(self.counters.items()))
            guarded("logging the totals", lambda: self._say(f"link totals: {totals}"))
        rec = self.recorder
        if rec is not None:
            self.recorder = None
            self.serial.on_bytes = None
            guarded("writing trial.yaml", lambda: rec.write_trial(self._trial_meta()))
            guarded("closing the recording", rec.close)
        if interrupted:
            raise interrupted[0]

    @contextlib.contextmanager
    def _io(self) -> Iterator[None]:
        """A section of port or recording I/O: a close() arriving meanwhile waits for its end."""
        with self._lock:
            self._busy += 1
            try:
                if self._closed or self._closing:  # checked after busy: a close either ran or waits
                    raise LinkClosed(f"{self.name}: the link is closed (thrusters stopped, ports closed)")
                yield
            finally:
                self._busy -= 1
                if self._close_pending and not self._busy:
                    self._close_pending = False
                    self.close()

    # -- internals -----------------------------------------------------------------------------
    def _now(self) -> float:
        return time.perf_counter() - (self._clock0 or 0.0)

    def _say(self, text: str) -> None:
        line = f"{self.name}: {text}"
        self.log_lines.append(line)
        log.warning(line)
        if self.recorder is not None:
            self.recorder.line(line)

    def _report(self, kind: str, text: str) -> None:
        """Count an event of ``kind``; log the first LOG_FIRST of each kind in one line each."""
        self.counters[kind] += 1
        self._logged[kind] += 1
        if self._logged[kind] <= LOG_FIRST:
            more = f" (further {kind} only counted)" if self._logged[kind] == LOG_FIRST else ""
            self._say(f"{text}{more}")

    def _drop(self, kind: str, detail: str) -> None:
        self._report(kind, f"dropped ({kind}): {detail}")

    def _commands(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Allocator commands made safe: finite, within +-n_max, scaled by the watchdog and the
        ramps; with the enable of each thruster (off during an alarm, and once to re-arm a drive)."""
        u = self._u.copy()
        bad = ~np.isfinite(u)
        if bad.any():
            for i in np.flatnonzero(bad):
                self._drop("command_nan", f"n_cmd_{i + 1} = {u[i]} at t = {t:.2f} s: sent 0")
            u[bad] = 0.0
        over = np.abs(u) > self.n_max
        if over.any():
            self.counters["command_clamped"] += int(over.sum())
            u = np.clip(u, -self.n_max, self.n_max)
        en = np.full(len(u), not self.alarm)
        if self.alarm:
            return np.zeros_like(u), en
        now = self._now()
        if self._rearm:  # acknowledge a drive's command timeout: enable 0 once, then ramp from 0
            idx = sorted(self._rearm)
            self._rearm.clear()
            u[idx] = 0.0
            en[idx] = False
            self._ramp_start[idx] = now
            self._rearm_at[idx] = now
        ramping = np.isfinite(self._ramp_start)
        if ramping.any():
            ramp = self.profile.watchdog.resume_ramp
            f = np.ones(len(u))
            f[ramping] = 1.0 if ramp <= 0 else np.clip((now - self._ramp_start[ramping]) / ramp, 0.0, 1.0)
            self._ramp_start[ramping & (f >= 1.0)] = np.nan
            u *= f
        return u, en

    def _send(self, u: np.ndarray, enable: bool | np.ndarray) -> None:
        """One command frame per thruster, all with the next alive counter. Once the adapter refuses
        a frame (``tx_blocked``) the rest of the round is not tried (counted ``tx_skipped``): each
        would wait out its own time-out, and 7 of them held a 50 ms loop 2.5 s late."""
        en = np.broadcast_to(np.asarray(enable, dtype=bool), (len(u),))
        stamp = time.time()
        counter = self._counter
        self._counter += 1  # first: an interrupted round must not leave its value to the next one
        blocked = False
        sent = 0
        for i, v in enumerate(u):
            if blocked:
                self.counters["tx_skipped"] += 1
                continue
            try:
                msg = self.codec.command(i, float(v), bool(en[i]), counter)
            except (EncodeError, ValueError, OverflowError) as exc:  # never expected after the clamp
                self._drop("command_encode", f"thruster {i + 1}: {exc}")
                continue
            if self.can.send(msg):
                sent += 1
                if self.recorder is not None:
                    self.recorder.frame(msg, rx=False, timestamp=stamp)
            elif self.can.tx_blocked:
                blocked = True
        self._tx_state(blocked, sent)
        self._sent = np.asarray(u, dtype=float).copy()
        self._sent_enable = en.copy()

    def _tx_state(self, blocked: bool, sent: int) -> None:
        """One log line when the adapter stops taking frames, one when it takes them again."""
        if blocked and self._tx_blocked_at is None:
            self._tx_blocked_at = self._now()
            self._say(
                f"CAN {self.can.name}: the adapter is not taking frames at t = {self._tx_blocked_at:.2f} s; "
                "every step tries one frame, the rest of its round is dropped until one goes out"
            )
        elif not blocked and sent and self._tx_blocked_at is not None:
            now = self._now()
            self._say(f"CAN {self.can.name}: the adapter takes frames again at t = {now:.2f} s, "
                      f"after {now - self._tx_blocked_at:.2f} s")
            self._tx_blocked_at = None

    def _poll(self, now: float) -> None:
        since = self._prev_poll  # what arrives now came after the previous poll: stamp it so (safe side)
        for raw in self.serial.read_lines():
            self._line(raw, since)
        for msg in self.can.recv_all():
            if self.recorder is not None:
                self.recorder.frame(msg, rx=True, timestamp=msg.timestamp or time.time())
            self._frame(msg, since)
        self._prev_poll = now

    def _line(self, raw: bytes, now: float) -> None:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            self._drop("malformed", f"non-ASCII bytes {raw[:40]!r}")
            return
        try:
            name, values = self.nmea.decode(text)
        except NmeaError as exc:
            if exc.kind == "unsupported":
                self.counters["unsupported"] += 1  # valid, but nothing of ours (e.g. $GPGSV)
            else:
                self._drop(exc.kind, str(exc))
            return
        g = self._sentence_group.get(name)
        extras = [c for c in EXTRA_CHANNELS if c in values and c in self._slot]
        if g is None and not extras:
            self.counters["unmapped"] += 1  # valid and ours, but no sensor of this profile takes it
            return
        head = text.strip().split(",", 1)[0].lstrip("$!")
        talker = "" if head.startswith("P") else head[:2]  # a proprietary sentence has none
        stamp = fix_time(name, text)
        if stamp is not None:
            clock = self._fix_clocks.get(name)
            if clock is None:
                day = SENTENCES[name].clock == "day"  # a time of day wraps at midnight
                clock = self._fix_clocks[name] = Freshness(time_forward(DAY if day else None))
            if not clock.news(stamp, now):  # a receiver repeating its last fix(es) is no new sample
                if talker:
                    self._frozen_talkers[talker] = now
                self._drop("repeated", f"{name} with a time not after the last one taken ("
                           f"{text.split(',', 2)[1]}): an old measurement again, not a new sample")
                return
            self._frozen_talkers.pop(talker, None)
        elif self._of_frozen_fix(name, talker, now):
            self._drop("repeated", f"{name} from {talker}, whose last fix was an old one again: of the same "
                       "old epoch, not a new sample")
            return
        for c in extras:
            self._y[self._slot[c]] = values[c]
        if g is None:
            return
        g.pending.update({c: v for c, v in values.items() if c in g.out_index})
        g.seen.add(name)
        if g.seen >= g.sentences:
            # an XDR may carry fewer transducers than the sensor measures: a sample is complete
            # only with every channel of this round, never with one held from an earlier sample
            missing = [c for c in g.out_index if c not in g.pending]
            if missing:
                self._drop("incomplete", f"{g.name}: its sentences carried no {', '.join(missing)}; "
                           "sample dropped")
            else:
                for c, v in g.pending.items():
                    self._y[g.out_index[c]] = v
                g.samples += 1
                g.last_rx = now
                self._y[g.count_index] = float(g.samples)
            g.pending.clear()
            g.seen.clear()

    def _of_frozen_fix(self, name: str, talker: str, now: float) -> bool:
        """Is this untimed sentence the velocity of a fix that repeats? Only a sentence that carries
        nothing but a fix's course and speed (VTG), of a talker whose last timed sentence was an old
        fix again within ``FROZEN_FIX_HOLD``: heading, depth or attitude of another device under
        the same talker (a GNSS compass's $GPHDT, a multiplexer's $II) are never held to it, and a
        receiver that stops sending timed sentences is held to its last one for ``FROZEN_FIX_HOLD``
        only."""
        marked = self._frozen_talkers.get(talker)
        sentence = SENTENCES[name]
        return (marked is not None and now - marked <= FROZEN_FIX_HOLD and not sentence.channels
                and bool(sentence.extras))

    def _frame(self, msg: Any, now: float) -> None:
        try:
            item = self.codec.decode(msg)
        except CanFrameError as exc:
            if exc.kind == "foreign":  # valid, but another device's (NMEA 2000): counted, not dropped
                self._report("foreign", f"not ours: {exc}")
            else:
                self._drop(exc.kind, str(exc))
            return
        if isinstance(item, Command):
            return  # seafmu's own demand (an NMEA 2000 broadcast heard back), not feedback
        fb: Feedback = item
        if fb.speed is not None:
            if (fb.counter is not None and self.profile.can.status_counter
                    and not self._fb_fresh[fb.index].news(fb.counter, now)):  # a hung drive repeating itself
                self._report("status_repeated", f"thruster {fb.index + 1}: status whose alive counter "
                             f"({fb.counter}) does not advance at t = {now:.2f} s: a repeat, not fresh (or "
                             "not yet seen counting after a silence)")
                return
            self._y[fb.index] = fb.speed  # n_i are the first outputs
            self._fb_rx[fb.index] = now
            self._fb_seen[fb.index] = True
            self._last_feedback = now  # (a fault-only frame, NMEA 2000's 128008, does not say it is alive)
        if fb.faults is not None:
            old = self._y[self._slot[f"fault_{fb.index + 1}"]]
            if fb.faults != old:
                self._say(f"thruster {fb.index + 1} fault bits {int(old)} -> {fb.faults} at t = {now:.2f} s")
            self._y[self._slot[f"fault_{fb.index + 1}"]] = fb.faults
            i = fb.index
            # a status sent before the drive took the re-arm frame still shows the fault: a new
            # trip cannot be reported sooner than one command timeout after that (fresh) frame
            recent = now - self._rearm_at[i] <= self.profile.command_timeout or i in self._rearm
            if fb.faults & FAULT_COMMAND_TIMEOUT and self._sent_enable[i] and not recent:
                self._rearm.add(i)
                self._report(
                    "drive_timeout",
                    f"thruster {i + 1}: the drive reports a command timeout at t = {now:.2f} s: "
                    f"re-arming (enable 0, then a ramp from 0 over {self.profile.watchdog.resume_ramp:g} s)",
                )

    def _feedback_ages(self, now: float) -> None:
        """Per thruster: a status older than ``watchdog.timeout`` is stale, so its n_i is NaN (a
        silent drive's speed was held, and the recording's thrust made from it) and its bit is set
        in ``feedback_lost``; one log line when it goes stale, one when it reports again. The
        watchdog's ``thrusters`` source is any status frame: one silent drive does not stop all."""
        limit = self.profile.watchdog.timeout
        lost = (now - self._fb_rx) > limit
        for i in np.flatnonzero(lost != self._fb_lost):
            if lost[i]:
                self._fb_lost_since[i] = now
                self._fb_losses[i] += 1
                self.counters["feedback_lost"] += 1
            logged = self._fb_losses[i] <= LOG_FIRST
            if lost[i] and logged:
                more = " (further losses only counted)" if self._fb_losses[i] == LOG_FIRST else ""
                self._say(
                    f"thruster {i + 1}: no status frame for {now - self._fb_rx[i]:.2f} s at t = {now:.2f} s "
                    f"(watchdog.timeout {limit:g} s): n_{i + 1} is NaN until it reports again{more}"
                )
            elif not lost[i] and logged:
                self._say(f"thruster {i + 1}: status frames again at t = {now:.2f} s (stale for "
                          f"{now - self._fb_lost_since[i]:.2f} s)")
        self._fb_lost = lost
        self._y[: len(lost)][lost] = np.nan

    def _ages(self, now: float) -> dict[str, float]:
        return {
            s: now - (self._last_feedback if s == THRUSTERS else self.groups[s].last_rx) for s in self.watch
        }

    def _watchdog(self, now: float, h: float) -> None:
        limit = self.profile.watchdog.timeout - h  # ages are upper bounds; the next poll is h away
        ages = self._ages(now)
        stale = {s: a for s, a in ages.items() if a > limit}
        if not self.alarm and stale:
            self.alarm = True
            self.alarm_since = now
            self._ramp_start[:] = np.nan
            self._send(np.zeros(len(self._u)), enable=False)
            why = ", ".join(f"{s} silent {a:.2f} s" for s, a in stale.items())
            self.alarms.append((now, None, why))
            self._say(f"WATCHDOG ALARM at t = {now:.2f} s: {why}; thrusters zeroed")
        elif self.alarm and not stale:
            fresh_since_alarm = all(a <= now - self.alarm_since for a in ages.values())
            if fresh_since_alarm:
                self.alarm = False
                self._ramp_start[:] = now
                start, _, why = self.alarms[-1]
                self.alarms[-1] = (start, now, why)
                self._say(
                    f"watchdog cleared at t = {now:.2f} s after {now - start:.2f} s; "
                    f"commands ramp back over {self.profile.watchdog.resume_ramp:g} s"
                )

    def _update_status(self) -> None:
        c = self.counters
        y, s = self._y, self._slot
        y[s["watchdog_alarm"]] = 1.0 if self.alarm else 0.0
        y[s["lines_dropped"]] = sum(c[k] for k in LINE_CLASSES)
        y[s["frames_dropped"]] = sum(c[k] for k in FRAME_CLASSES)
        y[s["commands_limited"]] = c["command_nan"] + c["command_clamped"]
        y[s["port_losses"]] = c["serial_lost"] + c["can_lost"]
        y[s["feedback_lost"]] = float(sum(1 << int(i) for i in np.flatnonzero(self._fb_lost)))

    def _trial_meta(self) -> dict[str, Any]:
        spec = self.spec
        columns = {c: f"meas_{c}" for c in spec.eta_names + spec.nu_names}
        columns |= {f"thrust_{i + 1}": f"thrust_{i + 1}" for i in range(spec.thrusters.count)}
        name = self.record_dir.name if self.record_dir else self.profile.name
        return trial_meta(name, spec.name, self.profile.name, columns)

    # -- reporting -------------------------------------------------------------------------------
    def pacing_stats(self) -> PacingStats:
        return self.pacer.stats()
