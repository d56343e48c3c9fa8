"""Recordings of a hardware run: raw traffic, decoded signals, and a trial file for identification.

A recording folder holds

- ``can.<asc|blf|log|csv|trc>`` — every CAN frame sent and received, in python-can's log format
  (readable by ``can.LogReader``, candump tools, Vector and PEAK viewers);
- ``nmea.raw`` — the serial bytes exactly as received, bad lines included (replayable);
- ``signals.csv`` — one row per link step: time, the commands as sent (after limits and the
  watchdog), feedback, every decoded sensor channel and sample counter, link status;
- ``trial.yaml`` — the recording as an identification trial of kind ``maneuver`` in
  ``seafmu.identification``'s schema: the vessel, and which columns hold the measured eta and nu
  and the thrust of each thruster (``seafmu identify`` / ``load_trial`` read it);
- ``link.log`` — the link's one-line messages (watchdog alarms, dropped input, lost ports).

``trial.yaml`` is written when the recording starts and again when it closes; ``signals.csv`` and
``link.log`` are line-buffered and the raw logs flushed every second, so a run that is killed
(SIGKILL, power loss) leaves a loadable trial with every finished row; only ``can.*`` then lacks
its end marker (python-can's readers take such a log as it is).

A file that cannot be written (a full disk, a file-size limit) stops the recording, never the
run: the files are closed, each line-oriented one cut back to its last whole line (``can.asc``
then gets its end marker if there is room), ``link.log`` says why if it can, and one warning
names the file and the reason (``Recorder.stopped``); the link passes it on as its own message
(``warn``), into the run's log.
"""

from __future__ import annotations

import contextlib
import csv
import logging
import os
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import can
import numpy as np
import yaml

TRIAL_FILE = "trial.yaml"
LINE_FORMATS = ("asc", "log", "csv", "trc")  # python-can's text logs: whole lines, a cut one can go
END_MARKERS = {"asc": "End TriggerBlock\n"}  # what the writer's stop() adds last

log = logging.getLogger("seafmu.hardware.recording")  # warnings of a recorder given no ``warn``


class Recorder:
    """Writes one recording folder while the link runs; every call is cheap and never raises on I/O.

    Only creating the folder and opening its files may raise (the run has not started then). After
    that, the first write, flush or close that fails stops the recording (module docstring): one
    warning through ``warn`` (default: this module's logger), kept in ``stopped``; every later call
    does nothing.
    """

    def __init__(self, folder: str | Path, can_format: str = "asc",
                 warn: Callable[[str], None] | None = None) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.can_format = can_format
        self.can_file = self.folder / f"can.{can_format}"
        self.nmea_file = self.folder / "nmea.raw"
        self.signals_file = self.folder / "signals.csv"
        self.log_file = self.folder / "link.log"
        self.columns: list[str] = []
        self.stopped = ""  # the warning when a file could not be written, else ""
        self._warn = warn or log.warning
        self._csv_file: IO[str] | None = None
        self._csv: Any = None
        self._closed = False
        with contextlib.ExitStack() as undo:  # a file that cannot be opened closes those opened before
            self._can = can.Logger(str(self.can_file))
            undo.callback(self._can.stop)
            self._nmea = undo.enter_context(open(self.nmea_file, "wb"))
            # line-buffered: survives a kill
            self._log = undo.enter_context(open(self.log_file, "w", buffering=1))
            undo.pop_all()

    def start_signals(self, columns: list[str], provenance: str) -> None:
        if self._closed:
            return
        self.columns = ["time", *columns]
        try:
            # line-buffered (one write per step): every finished row survives a SIGKILL of the run
            self._csv_file = open(self.signals_file, "w", newline="", buffering=1)
            self._csv_file.write(f"# {provenance}\n")
            self._csv = csv.writer(self._csv_file)
            self._csv.writerow(self.columns)
        except OSError as exc:
            self._stop(self.signals_file, exc)

    def frame(self, msg: can.Message, rx: bool, timestamp: float) -> None:
        if self._closed:
            return
        msg.timestamp = timestamp
        msg.is_rx = rx
        try:
            self._can.on_message_received(msg)
        except OSError as exc:
            self._stop(self.can_file, exc)

    def serial_bytes(self, data: bytes) -> None:
        if self._closed:
            return
        try:
            self._nmea.write(data)
        except OSError as exc:
            self._stop(self.nmea_file, exc)

    def row(self, t: float, values: np.ndarray) -> None:
        if self._csv is None or self._closed:
            return
        try:
            self._csv.writerow([f"{t:.6f}", *(f"{v:.9g}" for v in values)])
        except OSError as exc:
            self._stop(self.signals_file, exc)

    def line(self, text: str) -> None:
        if self._closed:
            return
        try:
            self._log.write(text + "\n")
        except OSError as exc:
            self._stop(self.log_file, exc)

    def write_trial(self, meta: dict[str, Any]) -> Path:
        """trial.yaml, replaced whole (a failed write keeps the one before); nothing once stopped."""
        path = self.folder / TRIAL_FILE
        if not self._closed:
            try:
                _replace_text(path, yaml.safe_dump(meta, sort_keys=False))
            except OSError as exc:
                self._stop(path, exc)
        return path

    def flush(self) -> None:
        """Push what is buffered to the OS, so a killed process loses at most the last interval."""
        if self._closed:
            return
        for path, f in self._files():
            try:
                f.flush()
            except OSError as exc:
                self._stop(path, exc)
                return

    def close(self) -> None:
        """Terminate the CAN log (its writer adds the end marker) and close the files; idempotent."""
        if self._closed:
            return
        self._closed = True
        failed = self._close_files()
        if failed is not None:
            self._finish_stopped(*failed, "when it was closed")

    # -- a write that failed -------------------------------------------------------------------
    def _files(self) -> list[tuple[Path, IO[Any]]]:
        files: list[tuple[Path, Any]] = [(self.nmea_file, self._nmea), (self.signals_file, self._csv_file),
                                         (self.log_file, self._log),
                                         (self.can_file, getattr(self._can, "file", None))]
        return [(path, f) for path, f in files if f is not None and not getattr(f, "closed", False)]

    def _close_files(self) -> tuple[Path, OSError] | None:
        """Close every file (the CAN log through its writer's stop); the first failure, if any."""
        failed: tuple[Path, OSError] | None = None
        closers = [(self.can_file, self._can.stop), *((path, f.close) for path, f in self._files()
                                                       if path != self.can_file)]
        for path, close in closers:
            try:  # a file whose last flush fails is closed all the same (io's close)
                close()
            except OSError as exc:
                failed = failed or (path, exc)
        return failed

    def _stop(self, path: Path, exc: OSError) -> None:
        """``path`` could not be written: close everything, leave the files readable, warn once."""
        if self._closed:
            return
        self._closed = True
        self._close_files()
        self._finish_stopped(path, exc, "the run goes on without it")

    def _finish_stopped(self, path: Path, exc: OSError, outcome: str) -> None:
        reason = exc.strerror or str(exc) or type(exc).__name__
        self.stopped = f"recording stopped: {path}: {reason}; {outcome}"
        with contextlib.suppress(OSError):  # the folder itself says it is incomplete, if there is room
            with open(self.log_file, "a") as f:
                f.write(self.stopped + "\n")
        for cut in (self.signals_file, self.log_file, *([self.can_file] if self.can_format in LINE_FORMATS
                                                         else [])):
            _cut_to_whole_lines(cut)
        end = END_MARKERS.get(self.can_format)
        if end is not None and not _ends_with(self.can_file, end):
            try:
                with open(self.can_file, "a") as f:
                    f.write(end)
            except OSError:  # no room: the log ends at its last whole frame line
                _cut_to_whole_lines(self.can_file)
        with contextlib.suppress(Exception):  # a warning that cannot be shown must not end the run
            self._warn(self.stopped)


def _replace_text(path: Path, text: str) -> None:
    """Write beside ``path``, then rename over it (not seafmu.outdir's: the link FMU bundles only
    the hardware, components and fmus packages)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def _ends_with(path: Path, text: str) -> bool:
    data = text.encode()
    with contextlib.suppress(OSError), open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        if size >= len(data):
            f.seek(size - len(data))
            return f.read() == data
    return False


def _cut_to_whole_lines(path: Path) -> None:
    """Drop the half line a failed write left at the end, so readers see only whole lines."""
    with contextlib.suppress(OSError), open(path, "rb+") as f:
        end = f.seek(0, os.SEEK_END)
        pos = end
        while pos > 0:
            start = max(0, pos - 4096)
            f.seek(start)
            chunk = f.read(pos - start)
            i = chunk.rfind(b"\n")
            if i >= 0:
                if start + i + 1 < end:
                    f.truncate(start + i + 1)
                return
            pos = start
        f.truncate(0)


def trial_meta(name: str, vessel: str, profile: str, columns: dict[str, str]) -> dict[str, Any]:
    """``trial.yaml``: a ``maneuver`` trial over ``signals.csv`` in seafmu.identification's schema."""
    started = datetime.now(UTC).isoformat(timespec="seconds")
    return {
        "name": name,
        "description": "seafmu hardware link recording: thruster commands as sent (n_cmd_i, after limits and "
        "the watchdog), decoded sensor channels (meas_*, held between samples; a sample is new "
        "where <sensor>_count changes), thrust_i from the measured shaft speed n_i through the "
        "vessel file's thrust law (from the command before the first feedback)",
        "provenance": f"recorded by the seafmu hardware link, profile {profile}, started {started}",
        "kind": "maneuver",
        "vessel": vessel,
        "files": ["signals.csv"],
        "columns": columns,
    }
