"""Thruster setpoints, enables and feedback as CAN frames, defined in DBC files and coded by cantools.

Two mappings, one interface (``ThrusterCodec``):

- ``seafmu`` (``seafmu_thrusters.dbc``): per thruster i (1..8) a command ``THR_CMD_i`` (0x100 + i:
  speed setpoint 0.01 rev/s, enable, alive counter) and a status ``THR_STATUS_i`` (0x180 + i:
  measured speed, enabled, fault bits, alive counter). Standard 11-bit ids, DLC 4. The command's
  4-bit alive counter rises by one per frame; a drive takes a frame whose counter did not advance
  as stale (``hardware/drive.py``), and latches a command timeout until an enable 0 -> 1 edge.
  The status's counter rises by one per frame too: the link takes a status whose counter did not
  move forward as no news (a hung drive repeating its last frame goes stale).
- ``nmea2000`` (``nmea2000_thrusters.dbc``): PGN 128006 Thruster Control Status (direction, power,
  speed in % of n_max) as the demand from seafmu's source address and as each thruster's reported
  state from its own; PGN 128008 Thruster Motor Status for fault bits. Limits: 1 % speed steps,
  no command-timeout fault bit; demands go out as broadcast 128006, not wrapped in PGN 126208
  Command Group Function (a fast-packet message), which some commercial thrusters require. The
  demand's SID is seafmu's alive counter (+1 per frame, mod 252); only the emulated drive checks it.
  A thruster's 128006 whose SID did not move forward is not fresh to the link (SID 252-255, "not
  available", is never checked); a 128006 or 128008 from neither seafmu's nor the drive's source
  address is another device's ("foreign").

Fault bits (``Feedback.faults``): 1 over-current, 2 over-temperature, 4 command timeout, 8 hardware.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
import numpy as np
from cantools.database.errors import DecodeError

from .plausibility import violation

FAULT_OVERCURRENT, FAULT_OVERTEMPERATURE, FAULT_COMMAND_TIMEOUT, FAULT_HARDWARE = 1, 2, 4, 8
_FAULT_SIGNALS = (
    ("fault_overcurrent", FAULT_OVERCURRENT),
    ("fault_overtemperature", FAULT_OVERTEMPERATURE),
    ("fault_command_timeout", FAULT_COMMAND_TIMEOUT),
    ("fault_hardware", FAULT_HARDWARE),
)


class CanFrameError(ValueError):
    """A frame that cannot be used; ``kind`` is its drop class (counted by the link)."""

    def __init__(self, kind: str, msg: str) -> None:
        super().__init__(msg)
        self.kind = kind


@dataclass(frozen=True)
class Command:
    """A setpoint as the vessel side receives it (index 0-based); ``counter``: its alive counter."""

    index: int
    speed: float  # rev/s
    enable: bool
    counter: int | None = None


@dataclass(frozen=True)
class Feedback:
    """A thruster's report as seafmu receives it (index 0-based); None: not in this frame.
    ``counter``: the drive's alive counter (None where the frame has none or says "not available"):
    a status whose counter did not move forward is no news, e.g. a hung drive whose CAN controller
    keeps sending its last frame (the link does not take it as fresh: ``hardware/freshness.py``)."""

    index: int
    speed: float | None  # rev/s
    enabled: bool | None
    faults: int | None
    counter: int | None = None


def _check(msg: can.Message, m: cantools.database.Message) -> None:
    """Drop what only has ``m``'s id: an error or remote frame, CAN FD where the DBC says classic
    (or the reverse), a wrong length. Data bytes and DLC are reported apart: python-can keeps an
    SLCAN line's DLC digit however few data bytes follow (``t1814``: DLC 4, 0 data bytes)."""
    where, length = f"{m.name} (0x{msg.arbitration_id:X})", m.length
    if msg.is_error_frame:
        raise CanFrameError("unexpected", f"error frame with the id of {where}")
    if msg.is_remote_frame:
        raise CanFrameError("unexpected", f"remote frame {where}")
    if bool(msg.is_fd) != bool(m.is_fd):
        fmt = "CAN FD" if msg.is_fd else "classic CAN"
        raise CanFrameError("unexpected", f"{fmt} frame {where}: the DBC defines the other format")
    n = len(msg.data)
    if msg.dlc != n:
        raise CanFrameError(
            "wrong_dlc", f"{where}: {n} data bytes where its DLC says {msg.dlc} (the message has {length})"
        )
    if n != length:
        raise CanFrameError("wrong_dlc", f"{where}: DLC {n}, expected {length}")


class ThrusterCodec(ABC):
    """Base: build command and status frames, decode either kind; frame errors raise CanFrameError.

    ``counter_modulus``: the alive counter's range (the link's frame counter is sent modulo it);
    ``command_timeout``: what a drive on this mapping uses (s); ``latching``: whether the drive,
    after a command timeout, needs an enable 0 -> 1 edge (True) or resumes on the next fresh
    command (False: the mapping cannot report the latch)."""

    mapping = ""
    counter_modulus = 16
    latching = True

    def __init__(self, n_max: np.ndarray, dbc: Path, command_timeout: float = 0.5) -> None:
        self.n_max = np.asarray(n_max, dtype=float)
        self.count = len(self.n_max)
        self.db = cantools.database.load_file(str(dbc))
        self.command_timeout = float(command_timeout)

    def _plausible(self, fb: Feedback, name: str) -> Feedback:
        """The feedback, unless its speed is outside hardware/plausibility.py's limit."""
        if fb.speed is not None:
            why = violation("speed_measured", fb.speed, float(self.n_max[fb.index]))
            if why:
                raise CanFrameError("implausible_feedback", f"{name}: thruster {fb.index + 1}: {why}")
        return fb

    @abstractmethod
    def command(self, index: int, speed: float, enable: bool, counter: int) -> can.Message:
        """The setpoint frame of one thruster."""

    @abstractmethod
    def status(self, index: int, speed: float, enabled: bool, faults: int, counter: int) -> list[can.Message]:
        """The feedback frame(s) a drive sends (the emulator plays the drives)."""

    @abstractmethod
    def decode(self, msg: can.Message) -> Command | Feedback:
        """A received frame as a command or feedback; CanFrameError if it is not one of ours."""


class SeafmuCodec(ThrusterCodec):
    """One command and one status message per thruster (``seafmu_thrusters.dbc``)."""

    mapping = "seafmu"

    def __init__(self, n_max: np.ndarray, dbc: Path, command_timeout: float = 0.5) -> None:
        super().__init__(n_max, dbc, command_timeout)
        self._cmd = [self.db.get_message_by_name(f"THR_CMD_{i + 1}") for i in range(self.count)]
        self._sts = [self.db.get_message_by_name(f"THR_STATUS_{i + 1}") for i in range(self.count)]
        self._by_id: dict[int, tuple[str, int]] = {}
        for i in range(self.count):
            self._by_id[self._cmd[i].frame_id] = ("cmd", i)
            self._by_id[self._sts[i].frame_id] = ("status", i)

    def command(self, index: int, speed: float, enable: bool, counter: int) -> can.Message:
        m = self._cmd[index]
        data = m.encode(
            {"speed_setpoint": speed, "enable": int(enable), "counter": counter % 16}, strict=True
        )
        return can.Message(arbitration_id=m.frame_id, data=data, is_extended_id=False)

    def status(self, index: int, speed: float, enabled: bool, faults: int, counter: int) -> list[can.Message]:
        m = self._sts[index]
        sig = {
            "speed_measured": float(np.clip(speed, -300.0, 300.0)),
            "enabled": int(enabled),
            "counter": counter % 16,
        }
        sig.update({name: int(bool(faults & bit)) for name, bit in _FAULT_SIGNALS})
        return [can.Message(arbitration_id=m.frame_id, data=m.encode(sig, strict=True), is_extended_id=False)]

    def decode(self, msg: can.Message) -> Command | Feedback:
        entry = self._by_id.get(msg.arbitration_id) if not msg.is_extended_id else None
        if entry is None:
            raise CanFrameError("unknown_id", f"unknown CAN id 0x{msg.arbitration_id:X}")
        kind, i = entry
        m = self._cmd[i] if kind == "cmd" else self._sts[i]
        _check(msg, m)
        try:
            d = m.decode(bytes(msg.data), decode_choices=False, scaling=True)
        except (DecodeError, ValueError) as exc:
            raise CanFrameError("decode", f"{m.name}: {exc}") from None
        if kind == "cmd":
            return Command(i, float(d["speed_setpoint"]), bool(d["enable"]), int(d["counter"]))
        faults = sum(bit for name, bit in _FAULT_SIGNALS if d[name])
        fb = Feedback(i, float(d["speed_measured"]), bool(d["enabled"]), faults, int(d["counter"]))
        return self._plausible(fb, m.name)


class Nmea2000Codec(ThrusterCodec):
    """PGN 128006 (demand and reported state) and 128008 (motor events) (``nmea2000_thrusters.dbc``)."""

    mapping = "nmea2000"
    counter_modulus = 252  # SID 0..251 (252..255 are reserved / not available)
    latching = False  # PGN 128006/128008 have no command-timeout fault to report a latch with
    PRIORITY = 2
    _OFF, _READY, _TO_PORT, _TO_STARBOARD = 0, 1, 2, 3
    _MOTOR_FAULTS = ((1, FAULT_OVERTEMPERATURE), (2, FAULT_OVERCURRENT), (16, FAULT_HARDWARE))

    def __init__(
        self,
        n_max: np.ndarray,
        dbc: Path,
        source_address: int = 0x10,
        thruster_address: int = 0x20,
        command_timeout: float = 0.25,
    ) -> None:
        super().__init__(n_max, dbc, min(command_timeout, 0.253))
        self._ctrl = self.db.get_message_by_name("PGN_128006_ThrusterControlStatus")
        self._motor = self.db.get_message_by_name("PGN_128008_ThrusterMotorStatus")
        self.sa = source_address
        self.thr_sa = thruster_address
        self.timeout = self.command_timeout  # on the wire in every demand (0.001 s, at most 0.253)

    @staticmethod
    def pgn(arbitration_id: int) -> int:
        """PGN of a 29-bit NMEA 2000 id (PDU2 form; both thruster PGNs are PDU2)."""
        return (arbitration_id >> 8) & 0x3FFFF

    def _id(self, message: cantools.database.Message, sa: int) -> int:
        return (self.PRIORITY << 26) | (self.pgn(message.frame_id) << 8) | sa

    def _speed(self, index: int, speed: float, enable: bool) -> dict[str, float]:
        pct = min(100, round(100.0 * abs(speed) / self.n_max[index])) if math.isfinite(speed) else 0
        direction = (
            self._OFF
            if not enable
            else (self._READY if pct == 0 else (self._TO_STARBOARD if speed > 0 else self._TO_PORT))
        )
        return {"Direction_Control": direction, "Power_Enabled": int(enable), "Speed_Control": pct}

    def command(self, index: int, speed: float, enable: bool, counter: int) -> can.Message:
        sig = {
            "SID": counter % 252,
            "Identifier": index,
            "Retract_Control": 0,
            "Control_Events": 0,
            "Command_Timeout": self.timeout,
            "Azimuth_Control": 0.0,
            **self._speed(index, speed, enable),
        }
        data = self._ctrl.encode(sig, strict=True)
        return can.Message(arbitration_id=self._id(self._ctrl, self.sa), data=data, is_extended_id=True)

    def status(self, index: int, speed: float, enabled: bool, faults: int, counter: int) -> list[can.Message]:
        sa = self.thr_sa + index
        state = {
            "SID": counter % 252,
            "Identifier": index,
            "Retract_Control": 0,
            "Control_Events": 0,
            "Command_Timeout": self.timeout,
            "Azimuth_Control": 0.0,
            **self._speed(index, speed, enabled),
        }
        events = sum(n2k for n2k, bit in self._MOTOR_FAULTS if faults & bit)
        motor = {
            "SID": counter % 252,
            "Identifier": index,
            "Motor_Events": events,
            "Current": 0,
            "Temperature": 293.15,
            "Operating_Time": 0,
        }
        return [
            can.Message(
                arbitration_id=self._id(self._ctrl, sa),
                data=self._ctrl.encode(state, strict=True),
                is_extended_id=True,
            ),
            can.Message(
                arbitration_id=self._id(self._motor, sa),
                data=self._motor.encode(motor, strict=True),
                is_extended_id=True,
            ),
        ]

    def decode(self, msg: can.Message) -> Command | Feedback:
        pgn = self.pgn(msg.arbitration_id) if msg.is_extended_id else -1
        if pgn == 128006:
            m = self._ctrl
        elif pgn == 128008:
            m = self._motor
        else:
            raise CanFrameError("unknown_id", f"unknown CAN id 0x{msg.arbitration_id:X} (PGN {pgn})")
        _check(msg, m)
        try:
            d = m.decode(bytes(msg.data), decode_choices=False, scaling=True)
        except (DecodeError, ValueError) as exc:
            raise CanFrameError("decode", f"{m.name}: {exc}") from None
        i = int(d["Identifier"])
        sa = msg.arbitration_id & 0xFF
        if sa != self.thr_sa + i and not (pgn == 128006 and sa == self.sa):
            # another controller's demand, or another device's report: neither seafmu's demand nor
            # the drive's own report (which is all a drive's state may be read from)
            raise CanFrameError("foreign", f"{m.name} for thruster {i + 1} from source address 0x{sa:02X}: "
                                f"neither seafmu's demand (0x{self.sa:02X}) nor the drive's report "
                                f"(0x{self.thr_sa + i:02X})")
        if i >= self.count:
            raise CanFrameError("unknown_id", f"{m.name}: thruster identifier {i}, vessel has {self.count}")
        if pgn == 128008:
            events = int(d["Motor_Events"])
            return Feedback(i, None, None, sum(bit for n2k, bit in self._MOTOR_FAULTS if events & n2k))
        direction, pct = int(d["Direction_Control"]), float(d["Speed_Control"])
        sign = {self._TO_STARBOARD: 1.0, self._TO_PORT: -1.0}.get(direction, 0.0)
        speed = sign * pct / 100.0 * float(self.n_max[i])
        enabled = bool(d["Power_Enabled"] == 1) and direction != self._OFF
        if sa == self.sa:
            return Command(i, speed, enabled, int(d["SID"]))
        sid = int(d["SID"])  # 252..255: reserved / not available (a device that numbers nothing)
        return self._plausible(Feedback(i, speed, enabled, None, sid if sid < 252 else None), m.name)


def make_codec(
    mapping: str,
    n_max: np.ndarray,
    dbc: Path,
    source_address: int = 0x10,
    thruster_address: int = 0x20,
    command_timeout: float = 0.5,
) -> ThrusterCodec:
    if mapping == "seafmu":
        return SeafmuCodec(n_max, dbc, command_timeout)
    if mapping == "nmea2000":
        return Nmea2000Codec(n_max, dbc, source_address, thruster_address, command_timeout)
    raise ValueError(f"unknown CAN mapping {mapping!r} (seafmu, nmea2000)")
