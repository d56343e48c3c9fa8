"""``seafmu emulate VESSEL --serial PORT --can INTERFACE:CHANNEL``: a vessel behind real protocols.

The plant model (``components.plant.PlantBlock``, the numerics of the Plant FMU) runs in real
time and speaks exactly what the hardware link expects from a vessel:

- NMEA 0183 sensor sentences on the serial port, at each sensor's rate (the plant's own sampled,
  noisy measurements; the profile's sentence mapping);
- thruster command frames are read from the CAN bus (the profile's DBC mapping), applied to the
  shafts, and answered with status frames (measured shaft speed, enable, fault bits) at
  ``--status-rate``. The drives check every frame as a real drive must (``hardware/drive.py``):
  only frames whose alive counter advances count; a thruster without one for ``command_timeout``
  stops, disables, raises its command-timeout fault bit and logs one line (stderr) — whatever
  happened to the controller, SIGKILL included — and, with the seafmu DBC, runs again only after
  an enable 0 -> 1 edge.

The vessel waits "in the dock" until the first command frame arrives: its physics clock starts
then, so an emulator started before seafmu is at t = 0 when seafmu's loop is; until then it sends
its initial sample at the sensors' rates, so the link can start up.

Faults on the wire (``--fault drive-frozen:3@20-30``: silent or frozen sensors and drives over a
window of vessel time) are scheduled by ``hardware/faults.py``.

A fouled or damaged thruster: ``--thruster-efficiency 3=0.6`` (thruster 3 delivers 60 % of its
nominal thrust), the plant parameter ``thruster_efficiency_3`` (also from ``--scenario`` or
``--set``); the status frames still report the shaft speed, as a real drive would.

PORT is a pyserial URL, or ``pty[:PATH]``: a virtual null-modem cable whose other end (printed,
and symlinked at PATH) is the port to give the link. The same for the CAN channel of ``slcan``
(``slcan:pty[:PATH]``). The ready line on stdout names both: ``READY serial=... can=...``.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import can
import numpy as np

from ..components.plant import PlantBlock
from ..components.vessel_spec import VesselSpec, load_vessel
from .canbus import CanFrameError, Command
from .drive import CommandSupervisor
from .faults import Fault, FaultSchedule, check_faults, parse_fault
from .link import LOG_FIRST, HardwareError, make_thruster_codec, sensor_mapping
from .nmea import NmeaCodec
from .pacing import Pacer
from .profile import CanConfig, HardwareProfile, SerialConfig, load_profile
from .ptybridge import NullModem, PortInUse
from .transport import CanPort, SerialLines, os_reason

log = logging.getLogger("seafmu.hardware.emulator")


class VesselEmulator:
    """The plant in real time behind NMEA (serial) and CAN; ``run()`` until stopped."""

    def __init__(
        self,
        profile: HardwareProfile,
        plant_params: dict[str, Any] | None = None,
        step: float = 0.01,
        status_rate: float = 20.0,
        record: str | Path | None = None,
        log_line: Callable[[str], None] | None = None,
        faults: list[Fault] | None = None,
    ) -> None:
        for name, value, (low, high) in (("step", step, STEP_RANGE), ("status_rate", status_rate,
                                                                      STATUS_RATE_RANGE)):
            if not low <= value <= high:  # the command line checks these; a caller in code too
                raise ValueError(f"{name} must be from {low:g} to {high:g}, got {value!r}")
        self.profile = profile
        self.spec = load_vessel(profile.vessel)
        spec = self.spec
        self.plant = PlantBlock(spec, dict(plant_params or {}))
        names = PlantBlock.interface(spec).output_names()
        idx = {n: i for i, n in enumerate(names)}
        self.mapping = sensor_mapping(profile, spec)
        self.groups = [
            (
                s.name,
                [idx[f"meas_{c}"] for c in s.channels],
                list(s.channels),
                idx[f"{s.name}_count"],
                s.rate_hz,
            )
            for s in spec.sensors
        ]
        self._extra_idx = {"course": idx["course"], "sog": idx["sog"]}
        self._n_idx = [idx[f"n_{i + 1}"] for i in range(spec.thrusters.count)]
        self._true_idx = [idx[n] for n in spec.eta_names + spec.nu_names]
        self.nmea = NmeaCodec(profile.origin.lat, profile.origin.lon, profile.talkers)
        self.codec = make_thruster_codec(profile, spec)
        self.counters: Counter[str] = Counter()
        self._logged: Counter[str] = Counter()
        self.serial = SerialLines(
            profile.serial.url,
            profile.serial.baudrate,
            profile.serial.options,
            profile.reconnect_interval,
            self.counters,
            report=self._report,
        )
        c = profile.can
        self.can = CanPort(
            c.interface, c.channel, c.bitrate, c.options, profile.reconnect_interval, self.counters,
            report=self._report,
        )
        self.step = step
        self.status_every = max(1, round(1.0 / (status_rate * step)))
        m = spec.thrusters.count
        self.log_lines: list[str] = []
        self._log_line = log_line or log.warning
        self.drive = CommandSupervisor(
            self.codec.n_max,
            self.codec.command_timeout,
            self.codec.counter_modulus,
            profile.command_counter_max_delta,
            self.codec.latching,
            log=self._say,
        )
        self.faults = np.zeros(m, dtype=int)
        self._status_count = [0] * m  # status frames sent per drive (their alive counter)
        self._last_fix: dict[str, datetime] = {}  # per sensor: the time stamp of its last sample
        self.n_shaft = np.zeros(m)  # the shafts' speed now (rev/s), what the status frames report
        self.started = False
        self.pacer: Pacer | None = None
        self.t = 0.0
        self.injected = FaultSchedule(faults or [])  # --fault: silent or frozen sensors and drives
        self._last_lines: dict[str, list[str]] = {}  # per sensor: its last sample's sentences
        self._last_status: dict[int, list[can.Message]] = {}  # per drive: its last status frames
        self.stop_event = threading.Event()
        self._record = open(record, "w") if record else None
        if self._record:
            self._record.write(
                ",".join(["time", *spec.eta_names, *spec.nu_names, *[f"n_{i + 1}" for i in range(m)]]) + "\n"
            )

    def perf_time(self, t: float) -> float:
        """``time.perf_counter()`` of emulator loop time ``t`` (the drive's event times)."""
        if self.pacer is None or self.pacer.t0 is None:
            raise RuntimeError("the emulator has not run yet")
        return self.pacer.t0 + t

    def _say(self, text: str) -> None:
        self.log_lines.append(text)
        self._log_line(text)

    def _report(self, kind: str, text: str) -> None:
        """Count an event of ``kind``; log the first LOG_FIRST of each kind (as the link does), so an
        adapter sending garbage at 100 Hz does not flood the terminal."""
        self.counters[kind] += 1
        self._logged[kind] += 1
        if self._logged[kind] <= LOG_FIRST:
            more = f" (further {kind} only counted)" if self._logged[kind] == LOG_FIRST else ""
            self._say(f"{text}{more}")

    def open(self, labels: dict[str, str] | None = None) -> None:
        """Open both ports; an OSError naming the one that failed (``labels``: what the user gave
        for it, e.g. ``--serial /dev/ttyUSB0``) and the OS's reason, in one line."""
        for port in (self.serial, self.can):
            if not port.open(retry=False):  # the emulator exits: nothing is retried
                label = (labels or {}).get(port.what, f"{port.what} port")
                where = "" if port.name in label else f" {port.name}"
                raise OSError(f"{label}: cannot open{where}: {port.error}")

    def _fix_time(self, sensor: str, now: datetime) -> datetime:
        """Wall time to the hundredth of a second GGA and RMC carry, 10 ms past the sensor's previous
        sample at least: a sample whose time is not later than the last is an old one to the link."""
        now = now.replace(microsecond=now.microsecond // 10000 * 10000)
        last = self._last_fix.get(sensor)
        if last is not None and now <= last:
            now = last + timedelta(milliseconds=10)
        self._last_fix[sensor] = now
        return now

    def _sentences(self, y: np.ndarray, only: list[int] | None = None) -> bytes:
        lines = []
        now = datetime.now(UTC)
        extras = {k: float(y[i]) for k, i in self._extra_idx.items()}
        for gi, (name, meas, chans, _, _) in enumerate(self.groups):
            if (only is not None and gi not in only) or self.injected.on("sensor-silent", name):
                continue
            if self.injected.on("sensor-frozen", name) and name in self._last_lines:
                lines += self._last_lines[name]  # a hung receiver: the same sentences again
                continue
            values = dict(zip(chans, (float(y[i]) for i in meas), strict=True)) | extras
            stamp = self._fix_time(name, now)
            sample = [self.nmea.encode(sen, values, stamp) for sen in self.mapping[name]]
            self._last_lines[name] = sample
            lines += sample
        return "".join(f"{ln}\r\n" for ln in lines).encode("ascii")

    def _read_commands(self, now: float) -> None:
        for msg in self.can.recv_all():
            try:
                item = self.codec.decode(msg)
            except CanFrameError as exc:
                if exc.kind == "foreign":  # another device's frame (NMEA 2000): not for these drives
                    self.counters["foreign"] += 1
                else:
                    self._report("bad_frame", f"dropped (bad_frame, {exc.kind}): {exc}")
                continue
            if not isinstance(item, Command):
                continue
            self.drive.receive(item, now)  # the first one starts every drive's timeout
            self.started = True

    def run(self, duration: float | None = None) -> None:
        """Run until ``duration`` s of vessel time (after the first command) or ``stop_event``."""
        # sleep only, no busy-wait: the null-modem threads need the GIL, and a vessel keeps its own time
        pacer = Pacer(self.step, spin=0.0)
        self.pacer = pacer
        h = self.step
        y = self.plant.output()
        next_idle = [0.0] * len(self.groups)
        counts = [y[g[3]] for g in self.groups]
        k = 0
        k0 = 0
        while not self.stop_event.is_set():
            pacer.wait_until(k)
            wall = pacer.now()
            self.serial.read_lines()  # nothing is expected from seafmu on the serial line: drain
            was_started = self.started
            self._read_commands(wall)
            if not self.started:  # in the dock: initial sample at the sensors' rates
                due = [gi for gi, g in enumerate(self.groups) if wall >= next_idle[gi]]
                for gi in due:
                    next_idle[gi] = wall + 1.0 / self.groups[gi][4]
                if due:
                    self.serial.write(self._sentences(y, due))
                k += 1
                continue
            if not was_started:
                k0 = k
                self._write_true(y)
            self.t = (k - k0) * h
            if duration is not None and self.t >= duration - 1e-9:
                break
            for line in self.injected.update(self.t):
                self._say(line)
            tripped = self.drive.update(wall)
            u, on = self.drive.output()
            self.faults = self.drive.faults()
            y = self.plant.step(self.t, h, u)
            self.n_shaft = y[self._n_idx]
            new = [gi for gi, g in enumerate(self.groups) if y[g[3]] != counts[gi]]
            if new:
                for gi in new:
                    counts[gi] = y[self.groups[gi][3]]
                self.serial.write(self._sentences(y, new))
            due = (k - k0) % self.status_every == 0
            for i in range(len(u)):
                if (due or tripped[i]) and not self.injected.on("drive-silent", i):  # a trip at once
                    self._send_status(i, float(y[self._n_idx[i]]), bool(on[i]))
            self._write_true(y, self.t + h)
            k += 1

    def _send_status(self, i: int, n_i: float, on: bool) -> None:
        if self.injected.on("drive-frozen", i) and i in self._last_status:
            msgs = self._last_status[i]  # a hung drive: its last frames again, alive counter frozen
        else:
            self._status_count[i] += 1  # the DBC's alive counter: +1 per frame of this drive
            msgs = self.codec.status(i, n_i, on, int(self.faults[i]), self._status_count[i])
            self._last_status[i] = msgs
        for msg in msgs:
            self.can.send(msg)

    def _write_true(self, y: np.ndarray, t: float = 0.0) -> None:
        if self._record is not None:
            vals = [y[i] for i in self._true_idx] + [y[i] for i in self._n_idx]
            self._record.write(f"{t:.4f}," + ",".join(f"{v:.9g}" for v in vals) + "\n")

    def close(self) -> None:
        self.serial.close()
        self.can.close()
        if self._record is not None:
            self._record.close()
            self._record = None


def _port(spec: str, bridges: list[NullModem], option: str = "--serial") -> tuple[str, str]:
    """(the emulator's end, the end to give the link) of a port spec: a URL, or pty[:PATH]. A pty
    that cannot be made is one line naming the option (the OS's message named only a folder)."""
    if spec == "pty" or spec.startswith("pty:"):
        link = spec[4:] or None
        try:
            nm = NullModem(link_b=link)
        except PortInUse:
            raise
        except OSError as exc:
            what = f"cannot make the pty link {link}" if link else "cannot make a pty"
            name = getattr(exc, "filename", None)
            at = f" ({name})" if name and str(name) != link else ""
            raise OSError(f"{option}: {what}: {os_reason(exc)}{at}") from None
        bridges.append(nm)
        return nm.a, (link or nm.b)
    return spec, spec


@dataclass(frozen=True)
class ScenarioReader:
    """What the layer that reads scenarios (``seafmu.emulate``) lends the emulator, which never
    imports it: a scenario's plant parameters by name (``--scenario``), and ``--set`` values read as
    ``seafmu run --set`` reads them, units and ranges (the vessel, loaded; items -> values)."""

    plant_parameters: Callable[[str], dict[str, Any]]
    set_values: Callable[[VesselSpec, list[str]], dict[str, Any]]


def _plant_params(scenario: str | None, sets: list[str], reader: ScenarioReader | None = None,
                  efficiencies: list[str] | None = None, spec: VesselSpec | None = None) -> dict[str, Any]:
    """The plant's parameters: the scenario's, then ``--set NAME=VALUE`` (with units where the
    scenario reader is lent, else SI numbers), then ``--thruster-efficiency I=FRACTION`` (a fouled
    or damaged thruster, 1-based I); the plant checks names and ranges."""
    params: dict[str, Any] = {}
    if scenario:
        if reader is None:
            raise ValueError("--scenario needs seafmu's scenario reader: use `seafmu emulate` "
                             "or `python -m seafmu.emulate`")
        params.update(reader.plant_parameters(scenario))
        own = params.pop("vessel_file", None)
        if own is not None and spec is not None and (theirs := load_vessel(own).name) != spec.name:
            raise ValueError(f"--scenario {scenario}: a scenario of vessel '{theirs}', not '{spec.name}'")
    if reader is not None and spec is not None:
        params.update(reader.set_values(spec, sets))
    else:
        for item in sets:
            key, _, value = item.partition("=")
            params[key.strip()] = _number("--set", item, value)
    for item in efficiencies or []:
        index, _, value = item.partition("=")
        count = spec.thrusters.count if spec is not None else None
        if not index.strip().isdigit() or int(index) < 1 or (count is not None and int(index) > count):
            span = f"from 1 to {count}" if count is not None else "from 1"
            raise ValueError(f"--thruster-efficiency {item!r}: expected THRUSTER=FRACTION with THRUSTER "
                             f"a thruster number {span}, e.g. 3=0.6")
        params[f"thruster_efficiency_{int(index)}"] = _number("--thruster-efficiency", item, value)
    return params


def _number(option: str, item: str, value: str) -> float:
    try:
        return float(value)
    except ValueError:
        raise ValueError(f"{option} {item!r}: the value after '=' must be a number") from None


# The bounds of the emulator's numbers, checked by the parser: a value outside them used to be
# taken and the emulator printed READY and then never ran (or a traceback). --step: below 0.1 ms the
# sleep-only pacer and one plant step with its serial and CAN I/O cannot keep real time; above 1 s a
# vessel's motion (time constants of seconds), 20 Hz sensors and the drives' 0.5 s command timeout
# are sampled far coarser than they run. --status-rate: slower than one frame per 10 s is no
# feedback at all; 1000 per s for each of 8 thrusters already fills a 1 Mbit/s bus (some 8000
# frames/s); and at most one frame per step goes out (checked with --step, _check_args).
STEP_RANGE = (1e-4, 1.0)  # s
STATUS_RATE_RANGE = (0.1, 1000.0)  # frames per second and thruster
BITRATE_RANGE = (10_000, 1_000_000)  # bit/s: classic CAN, 10 kbit/s to 1 Mbit/s


def _number_in(low: float, high: float, unit: str) -> Callable[[str], float]:
    """An argparse type: a number from ``low`` to ``high``; NaN and text are refused with the range."""
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        if not low <= x <= high:  # False for NaN
            raise argparse.ArgumentTypeError(f"must be a number from {low:g} to {high:g} {unit}, got {text}")
        return x
    return parse


def _positive_seconds(text: str) -> float:
    """An argparse type: a finite duration > 0 s (--duration, --command-timeout)."""
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not (x > 0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds > 0, got {text}")
    return x


def _bitrate(text: str) -> int:
    """An argparse type: a whole number of bit/s in BITRATE_RANGE (0 used to be blamed on the port)."""
    low, high = BITRATE_RANGE
    try:
        b = int(text)
    except ValueError:
        b = 0
    if not low <= b <= high:
        raise argparse.ArgumentTypeError(f"must be a whole number of bit/s from {low} to {high} "
                                         f"(classic CAN), got {text}")
    return b


def _nonempty(text: str) -> str:
    """An argparse type: an empty name or path would silently mean 'not given'."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty; give a value or leave the flag out")
    return text


def _check_args(args: argparse.Namespace, iface: str) -> None:
    """What the parser cannot check alone (ValueError, one line): the arguments together, the
    adapter's bitrates, the --record folder. Before a port is opened or READY printed."""
    if args.status_rate * args.step > 1.0 + 1e-9:
        raise ValueError(f"--status-rate {args.status_rate:g}: at most one status frame per step goes out; "
                         f"with --step {args.step:g} s at most {1.0 / args.step:g} per s")
    if iface == "slcan":
        from can.interfaces.slcan import slcanBus

        known = sorted(getattr(slcanBus, "_BITRATES", {}))  # python-can's table of the S0..S9 commands
        if known and args.bitrate not in known:
            raise ValueError(f"--bitrate {args.bitrate}: an slcan adapter takes one of "
                             f"{', '.join(str(b) for b in known)}")
    if args.record is not None:
        folder = Path(args.record).parent
        if not folder.is_dir():
            what = "is a file, not a folder" if folder.exists() else "does not exist"
            raise ValueError(f"--record {args.record}: {folder} {what}")


def build_parser(p: argparse.ArgumentParser | None = None,
                 scenarios: bool = False) -> argparse.ArgumentParser:
    """The emulator's options; ``--scenario`` only where the caller can read scenarios."""
    p = p or argparse.ArgumentParser(prog="seafmu emulate", description=__doc__.splitlines()[0])
    p.add_argument("vessel", help="vessel file name (minerva2, amv_osf) or path")
    p.add_argument(
        "--serial", required=True, help="NMEA port: pyserial URL, or pty[:PATH] for a virtual cable"
    )
    p.add_argument(
        "--can", required=True, help="INTERFACE:CHANNEL, e.g. slcan:pty, slcan:/dev/ttyACM0, socketcan:can0"
    )
    p.add_argument("--bitrate", type=_bitrate, default=500000, help="CAN bitrate (default 500000)")
    p.add_argument(
        "--profile", type=_nonempty,
        help="hardware profile for the sentence and DBC mapping (default: by channel, seafmu DBC)",
    )
    if scenarios:
        p.add_argument(
            "--scenario", type=_nonempty,
            help="take the plant parameters (seed, current, initial state) from this scenario",
        )
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a plant parameter, as `seafmu run --set plant.NAME=VALUE` takes it "
                        "(e.g. current_speed=0.4kn; SI numbers when run without seafmu's scenario layer)")
    p.add_argument("--thruster-efficiency", action="append", default=[], metavar="I=FRACTION",
                   help="thruster I (from 1) delivers FRACTION of its nominal thrust (fouled or damaged, "
                   "0..1.5; the plant parameter thruster_efficiency_I), e.g. 3=0.6")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:TARGET@START[-END]",
                   help="inject a fault on the wire from START to END s of vessel time: sensor-silent:"
                   "SENSOR, sensor-frozen:SENSOR (its last sentences repeated), drive-silent:I, "
                   "drive-frozen:I (its last status frame repeated), e.g. drive-frozen:3@20-30")
    p.add_argument("--step", type=_number_in(*STEP_RANGE, "s"), default=0.01,
                   help="physics step, s (default 0.01)")
    p.add_argument("--status-rate", type=_number_in(*STATUS_RATE_RANGE, "per s"), default=20.0,
                   help="thruster status frames per second (default 20)")
    p.add_argument(
        "--command-timeout",
        type=_positive_seconds,
        help="s: a drive without a fresh command (alive counter advancing) for this long stops "
        "(default: the profile's command_timeout, 0.5)",
    )
    p.add_argument(
        "--duration", type=_positive_seconds,
        help="stop after this much vessel time, s; the vessel's clock starts at the first thruster "
             "command (default: until Ctrl-C)",
    )
    p.add_argument("--record", type=_nonempty,
                   help="CSV file for the true state (what a real vessel cannot tell)")
    return p


def main(argv: list[str] | None = None, reader: ScenarioReader | None = None) -> int:
    """The command line; with ``reader`` (``seafmu.emulate``) it takes ``--scenario``, and units in
    ``--set``."""
    args = build_parser(scenarios=reader is not None).parse_args(argv)
    return run_args(args, reader)


def _checked(args: argparse.Namespace, iface: str, channel: str, reader: ScenarioReader | None
             ) -> tuple[HardwareProfile, dict[str, Any], list[Fault]]:
    """Every argument checked, nothing opened: the profile (its ports still the specs as given,
    ``pty:...``), the plant's parameters and the faults to inject. The vessel, the plant
    parameters' ranges, the profile's sentence and CAN mappings and the faults are tried here as
    the emulator will use them, so a bad one is one line before any port exists or READY is
    printed."""
    _check_args(args, iface)
    base = load_profile(args.profile) if args.profile else None
    options = {"sleep_after_open": 0} if iface == "slcan" else {}
    profile = HardwareProfile(
        name=base.name if base else f"{Path(args.vessel).stem}_emulated",
        vessel=args.vessel,
        serial=SerialConfig(url=args.serial),
        can=CanConfig(
            interface=iface,
            channel=channel,
            bitrate=args.bitrate,
            options=options,
            mapping=base.can.mapping if base else "seafmu",
            # the profile's DBC found as the link finds it (beside the profile file)
            dbc=str(base.dbc_path()) if base and base.can.dbc else None,
            **(
                {"source_address": base.can.source_address, "thruster_address": base.can.thruster_address}
                if base
                else {}
            ),
        ),
        **(
            {
                "origin": base.origin,
                "sensors": base.sensors,
                "talkers": base.talkers,
                "command_timeout": base.command_timeout,
                "command_counter_max_delta": base.command_counter_max_delta,
            }
            if base
            else {}
        ),
    )
    if args.command_timeout is not None:
        profile = profile.model_copy(update={"command_timeout": args.command_timeout})
    spec = load_vessel(profile.vessel)
    params = _plant_params(getattr(args, "scenario", None), args.set, reader, args.thruster_efficiency, spec)
    try:
        PlantBlock(spec, dict(params))
    except ValueError as exc:  # a range the plant checks: named by the option that gave the value
        given = next((f"--thruster-efficiency {item}: " for item in args.thruster_efficiency
                      if f"'thruster_efficiency_{item.partition('=')[0].strip()}'" in str(exc)), "")
        raise ValueError(f"{given}{exc}") from None
    sensor_mapping(profile, spec)
    make_thruster_codec(profile, spec)
    faults = [parse_fault(f, [s.name for s in spec.sensors], spec.thrusters.count) for f in args.fault]
    check_faults(faults, args.duration)
    return profile, params, faults


def run_args(args: argparse.Namespace, reader: ScenarioReader | None = None) -> int:
    bridges: list[NullModem] = []
    emu: VesselEmulator | None = None
    try:
        iface, _, channel = args.can.partition(":")
        if not channel:
            print(f"seafmu emulate: error: --can {args.can!r}: must be INTERFACE:CHANNEL (e.g. slcan:pty, "
                  "socketcan:can0)", file=sys.stderr)
            return 2
        profile, params, faults = _checked(args, iface, channel, reader)
        ser_emu, ser_link = _port(args.serial, bridges, f"--serial {args.serial}")
        can_emu, can_link = (_port(channel, bridges, f"--can {args.can}") if iface == "slcan"
                             else (channel, channel))
        profile = profile.model_copy(update={"serial": profile.serial.model_copy(update={"url": ser_emu}),
                                             "can": profile.can.model_copy(update={"channel": can_emu})})
        emu = VesselEmulator(
            profile,
            params,
            args.step,
            args.status_rate,
            args.record,
            log_line=lambda text: print(f"seafmu emulate: {text}", file=sys.stderr, flush=True),
            faults=faults,
        )
        emu.open({"serial": f"--serial {args.serial}", "can": f"--can {args.can}"})
        stop = emu.stop_event
        stopped_by: list[str] = []

        def on_signal(signum: int, _frame: object) -> None:
            stopped_by.append(signal.Signals(signum).name)
            stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, on_signal)
        print(f"READY serial={ser_link} can={iface}:{can_link}", flush=True)
        print(
            f"seafmu emulate: {emu.spec.name} waiting for the first thruster command "
            f"(NMEA on {ser_link}, CAN {iface}:{can_link})",
            file=sys.stderr,
            flush=True,
        )
        emu.run(args.duration)
        why = stopped_by[0] if stopped_by else f"--duration {args.duration:g} s"
        when = f"at vessel time {emu.t:.2f} s" if emu.started else "before the first thruster command"
        counted = ", ".join(f"{k} {v}" for k, v in sorted(emu.counters.items()))
        print(f"seafmu emulate: stopped ({why}) {when}" + (f"; counted: {counted}" if counted else ""),
              file=sys.stderr, flush=True)  # one line: what ended it, and what went wrong meanwhile
        return 0
    except (OSError, ValueError, HardwareError) as exc:  # ProfileError is a ValueError
        print(f"seafmu emulate: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    finally:
        if emu is not None:
            emu.close()
        for b in bridges:
            b.close()


if __name__ == "__main__":
    sys.exit(main())
