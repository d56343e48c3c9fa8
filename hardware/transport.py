"""Serial (pyserial URLs) and CAN (python-can, any interface) ports that never block and never crash.

Both poll without waiting: a control loop calls them once per step. A port that fails (unplugged
adapter, closed pseudo-terminal, vanished device node) is closed, counted and reopened every
``reconnect_interval`` seconds; everything in between is dropped, which is what a loop on a real
vessel must do — the watchdog, not the transport, decides what the thrusters do meanwhile.

Sending never waits long either: an adapter that stops taking frames (a stalled USB adapter, a
frozen SLCAN peer) costs one ``TX_TIMEOUT`` at most per frame, and ``CanPort.tx_blocked`` tells the
caller to drop the rest of its round. SLCAN frames are written here, not by python-can: its send
can leave part of a frame on the line when pyserial's write timeout expires (the next frame is
then glued to it) and ends with a ``tcdrain`` that waits without limit on a stalled USB adapter.
"""

from __future__ import annotations

import errno
import logging
import os
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable
from typing import Any

import can
import serial
from can.interfaces.slcan import slcanBus

log = logging.getLogger("seafmu.hardware")

MAX_LINE = 256  # bytes: NMEA allows 82; the Nortek DVL sentences run to about 110
MAX_FRAMES_PER_POLL = 2000  # a flooding bus must not hold the loop
TX_TIMEOUT = 0.005  # s: the longest one CAN send may wait for an adapter that is not taking frames


def os_reason(exc: BaseException) -> str:
    """The OS's reason behind an open failure, in one line ("No such file or directory"): pyserial
    and python-can wrap it in messages that repeat the port name; their own first line otherwise."""
    seen: BaseException | None = exc
    for _ in range(5):
        if seen is None:
            break
        code = getattr(seen, "errno", None)
        if code is None and len(seen.args) == 2 and isinstance(seen.args[0], int):
            code = seen.args[0]  # termios.error: (errno, text)
        if isinstance(code, int) and code > 0:
            try:
                why = os.strerror(code)
            except ValueError:
                break
            return f"not a serial port ({why})" if code == errno.ENOTTY else why
        seen = seen.__cause__ or seen.__context__
    text = str(exc).splitlines()[0] if str(exc) else ""
    return text or type(exc).__name__


class _Port(ABC):
    """Open/close/reconnect bookkeeping shared by the serial and CAN ports."""

    what = "port"

    def __init__(
        self,
        name: str,
        reconnect_interval: float,
        counters: Counter[str],
        report: Callable[[str, str], None] | None = None,
    ) -> None:
        self.name = name
        self.reconnect_interval = reconnect_interval
        self.counters = counters
        self.report = report or self._log_report
        self.is_open = False
        self.error = ""  # why the last open failed (the OS's words)
        self._next_try = 0.0
        self._lost_logged = False

    def _log_report(self, kind: str, text: str) -> None:
        """Default: count and log; the link passes its own reporter (counts, rate-limited log)."""
        self.counters[kind] += 1
        log.warning(text)

    @abstractmethod
    def _open(self) -> None:
        """Open the device; raise on failure."""

    @abstractmethod
    def _close(self) -> None:
        """Close the device."""

    def open(self, retry: bool = True) -> bool:
        """Try to open now; False if it cannot, with the reason in ``error``. ``retry``: the loop
        will reopen it every ``reconnect_interval`` (logged once per outage); without, the caller
        reports the failure itself (a start that fails ends the run: no "retrying" to promise)."""
        try:
            self._open()
        except Exception as exc:  # pyserial, python-can and the OS raise many kinds: all mean "not now"
            self.error = os_reason(exc)
            self._next_try = time.monotonic() + self.reconnect_interval
            if retry and not self._lost_logged:
                log.warning(
                    "%s %s: cannot open (%s); retrying every %g s",
                    self.what,
                    self.name,
                    self.error,
                    self.reconnect_interval,
                )
                self._lost_logged = True
            return False
        self.error = ""
        if self._lost_logged:
            log.warning("%s %s: open again", self.what, self.name)
        self._lost_logged = False
        self.is_open = True
        return True

    def ensure_open(self) -> bool:
        if not self.is_open and time.monotonic() >= self._next_try:
            self.open()
        return self.is_open

    def lost(self, exc: BaseException) -> None:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        cause = exc.__cause__ or exc.__context__
        if cause is not None:
            why += f": {type(cause).__name__} {str(cause).splitlines()[0] if str(cause) else ''}"
        self.report(
            f"{self.what}_lost", f"{self.what} {self.name} lost ({why}); its data is dropped until it reopens"
        )
        self._lost_logged = True
        self.close()
        self._next_try = time.monotonic() + self.reconnect_interval

    def close(self) -> None:
        if self.is_open:
            try:
                self._close()
            except Exception:  # closing a port that already died raises too; nothing to save
                pass
        self.is_open = False


READ_CHUNK = 65536  # bytes per poll: far above what a 20 Hz loop sees at any baud rate


class SerialLines(_Port):
    """Lines from a pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/N``, ``loop://``, ``socket://h:p``)."""

    what = "serial"

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        options: dict[str, Any] | None = None,
        reconnect_interval: float = 1.0,
        counters: Counter[str] | None = None,
        on_bytes: Callable[[bytes], None] | None = None,
        report: Callable[[str, str], None] | None = None,
    ) -> None:
        super().__init__(url, reconnect_interval, counters if counters is not None else Counter(), report)
        self.url = url
        self.baudrate = baudrate
        self.options = dict(options or {})
        self.on_bytes = on_bytes
        self._ser: serial.SerialBase | None = None
        self._buf = bytearray()

    def _open(self) -> None:
        self._ser = serial.serial_for_url(
            self.url, baudrate=self.baudrate, timeout=0, write_timeout=0.01, **self.options
        )
        self._buf.clear()

    def _close(self) -> None:
        if self._ser is not None:
            self._ser.close()
        self._ser = None

    def read_lines(self) -> list[bytes]:
        """Complete lines received since the last call (CR/LF stripped); never waits."""
        if not self.ensure_open() or self._ser is None:
            return []
        try:
            # timeout=0: read() returns at once with what is there. Loop: pyserial's socket://
            # handler reports at most 1 waiting byte, and one read per poll starved networked NMEA
            # muxes. Small reads also keep what arrived before a disconnect (a big socket read
            # that meets EOF raises and loses the bytes it had).
            data = b""
            while len(data) < READ_CHUNK:
                chunk = self._ser.read(self._ser.in_waiting or 1)
                if not chunk:
                    break
                data += chunk
        except (serial.SerialException, OSError, TypeError) as exc:  # TypeError: pyserial on a closed fd
            self.lost(exc)
            return []
        if not data:
            return []
        if self.on_bytes is not None:
            self.on_bytes(data)
        self._buf += data
        *lines, rest = self._buf.split(b"\n")
        self._buf = bytearray(rest)
        if len(self._buf) > MAX_LINE:  # garbage without line ends: drop it, keep the loop bounded
            self.report(
                "line_too_long", f"dropped (line_too_long): {len(self._buf)} bytes without a line end"
            )
            self._buf.clear()
        out = []
        for ln in lines:
            ln = ln.strip(b"\r")
            if len(ln) > MAX_LINE:
                self.report("line_too_long", f"dropped (line_too_long): line of {len(ln)} bytes")
            elif ln:
                out.append(bytes(ln))
        return out

    def write(self, data: bytes) -> bool:
        if not self.ensure_open() or self._ser is None:
            return False
        try:
            self._ser.write(data)
        except serial.SerialTimeoutException:  # nobody reads the other end: the bytes are lost
            self.report("serial_write_timeout", f"serial {self.name}: write timed out, bytes dropped")
            return False
        except (serial.SerialException, OSError, TypeError) as exc:
            self.lost(exc)
            return False
        return True


def _undecodable(exc: BaseException) -> UnicodeDecodeError | None:
    """The decoding error behind ``exc`` (python-can wraps it in ``CanOperationError``), if any."""
    seen: BaseException | None = exc
    for _ in range(4):
        if seen is None:
            return None
        if isinstance(seen, UnicodeDecodeError):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


class CanPort(_Port):
    """A python-can bus named by interface and channel; recv and send never raise."""

    what = "can"

    def __init__(
        self,
        interface: str,
        channel: str,
        bitrate: int | None = None,
        options: dict[str, Any] | None = None,
        reconnect_interval: float = 1.0,
        counters: Counter[str] | None = None,
        report: Callable[[str, str], None] | None = None,
    ) -> None:
        super().__init__(
            f"{interface}:{channel}",
            reconnect_interval,
            counters if counters is not None else Counter(),
            report,
        )
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.options = dict(options or {})
        self.bus: can.BusABC | None = None
        self.tx_blocked = False  # the adapter did not take the last frame: drop the rest of the round
        self._line_dirty = False  # SLCAN: the line may end inside a frame (a CR goes first)

    def _open(self) -> None:
        kw = dict(self.options)
        if self.bitrate is not None:
            kw["bitrate"] = self.bitrate
        self.bus = can.Bus(interface=self.interface, channel=self.channel, **kw)
        self.tx_blocked = False
        self._line_dirty = False

    def _close(self) -> None:
        bus, self.bus = self.bus, None
        if bus is None:
            return
        port = self._slcan_port(bus)
        try:
            if port is not None:
                # python-can's shutdown writes "C" with the port's (unlimited) write timeout, then
                # tcdrain()s: on an adapter that stopped taking data both would wait for ever
                port.write_timeout = TX_TIMEOUT
                if self.tx_blocked:
                    port.reset_output_buffer()
                    port.close()
        finally:
            bus.shutdown()

    @staticmethod
    def _slcan_port(bus: can.BusABC | None) -> serial.Serial | None:
        """The tty under an SLCAN bus, when it is a local one whose fd this module can write."""
        if not isinstance(bus, slcanBus):
            return None
        port = getattr(bus, "serialPortOrig", None)
        return port if isinstance(port, serial.Serial) and getattr(port, "fd", None) is not None else None

    def _failed(self, exc: BaseException, what: str) -> bool:
        """Count a bus error; True if the port itself is gone (then it is closed for reconnection)."""
        cause = exc.__cause__ or exc.__context__
        if isinstance(cause, serial.SerialTimeoutException):  # adapter not taking data right now
            self.report("tx_timeout", f"dropped (tx_timeout): can {self.name} {what} timed out")
            return False
        if isinstance(exc, OSError | serial.SerialException) or isinstance(
            cause, OSError | serial.SerialException
        ):
            self.lost(exc)
            return True
        bad = _undecodable(exc)
        if bad is not None:
            # python-can's slcan reader keeps the bytes it could not decode in its line buffer, and
            # every later read fails on them again (4.x): the line is dropped here, naming its bytes.
            # Its private buffer is cleared where it has one (what arrived after the bad line is
            # kept); flush() otherwise, which also drops the input waiting.
            self.report("bus_error", f"dropped (bus_error): can {self.name} {what}: adapter line is not "
                        f"ASCII: {bytes(bad.object[:40])!r}")
            buf = getattr(self.bus, "_buffer", None)
            if isinstance(buf, bytearray):
                buf.clear()
                return False
            flush = getattr(self.bus, "flush", None)
            if callable(flush):
                try:
                    flush()
                except Exception as exc2:
                    self.lost(exc2)
                    return True
            return False
        why = str(exc).splitlines()[0] if str(exc) else ""
        self.report("bus_error", f"dropped (bus_error): can {self.name} {what}: {type(exc).__name__} {why}")
        return False

    def _more_waiting(self) -> bool:
        """True if a receive that gave nothing left input unread: python-can's slcan reader returns
        no frame for an adapter line that is not one (a Lawicel transmit acknowledgement ``z``, an
        error BELL, an empty line) though frames may follow it in the same poll."""
        port = getattr(self.bus, "serialPortOrig", None)
        try:
            return bool(port is not None and port.in_waiting)
        except Exception:  # the port is gone: the next receive reports it
            return False

    def recv_all(self) -> list[can.Message]:
        """Every frame waiting now (error frames counted and dropped); never waits."""
        if not self.ensure_open() or self.bus is None:
            return []
        out: list[can.Message] = []
        errors = 0
        for _ in range(MAX_FRAMES_PER_POLL):  # frames, lines that are not frames and errors alike
            if errors >= 20:
                break
            try:
                msg = self.bus.recv(timeout=0)
            except Exception as exc:  # garbage from an adapter surfaces as ValueError, IndexError, ...
                errors += 1
                if self._failed(exc, "receive"):
                    break
                continue
            if msg is None:
                if self._more_waiting():
                    continue
                break
            if msg.is_error_frame:
                self.report("bus_error", f"dropped (bus_error): error frame on can {self.name}")
                continue
            out.append(msg)
        return out

    def send(self, msg: can.Message) -> bool:
        """Send one frame, waiting ``TX_TIMEOUT`` at most; False if it did not go out, and then
        ``tx_blocked`` if the adapter refused it (time-out, bus error), not because the port is closed."""
        if not self.ensure_open() or self.bus is None:
            return False
        port = self._slcan_port(self.bus)
        if port is not None and not (msg.is_fd or msg.is_remote_frame or msg.is_error_frame):
            return self._send_slcan(port, msg)
        try:
            self.bus.send(msg, timeout=TX_TIMEOUT)
        except Exception as exc:  # can.CanOperationError on a full queue or a dead adapter
            self.tx_blocked = not self._failed(exc, "send")
            return False
        self.tx_blocked = False
        return True

    def _send_slcan(self, port: serial.Serial, msg: can.Message) -> bool:
        """One SLCAN line, written without waiting: the adapter takes all of it, or the queued
        frames (stale by now) are discarded and a CR ends whatever part of a frame went out, so
        the next frame starts a clean line and the drives get the current command, not a backlog.
        (A part that lacked only its CR is a whole frame: it arrives late, and its alive counter
        is then behind the next fresh frame's by the frames dropped meanwhile.)"""
        head = f"T{msg.arbitration_id:08X}" if msg.is_extended_id else f"t{msg.arbitration_id:03X}"
        line = f"{head}{msg.dlc:d}{bytes(msg.data).hex().upper()}\r".encode("ascii")
        lead = b"\r" if self._line_dirty else b""
        data = lead + line
        try:
            n = os.write(port.fd, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EINTR):
                n = 0
            else:
                self.lost(exc)
                return False
        if n == len(data):
            self._line_dirty = False
            self.tx_blocked = False
            return True
        try:
            port.reset_output_buffer()  # what still waits behind a full buffer is stale: discard it
        except (serial.SerialException, OSError, TypeError) as exc:
            self.lost(exc)
            return False
        self._line_dirty = True  # the discarded queue may end inside a frame
        self.tx_blocked = True
        self.report("tx_timeout", f"dropped (tx_timeout): can {self.name} adapter not taking frames "
                    f"({n} of {len(data)} bytes written)")
        return False
