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
"""

from __future__ import annotations

import csv
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TextIO

import can
import numpy as np
import yaml

TRIAL_FILE = "trial.yaml"


class Recorder:
    """Writes one recording folder while the link runs; every call is cheap and never raises on I/O."""

    def __init__(self, folder: str | Path, can_format: str = "asc") -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.can_file = self.folder / f"can.{can_format}"
        self._can = can.Logger(str(self.can_file))
        self._nmea = open(self.folder / "nmea.raw", "wb")
        self._csv_file: TextIO | None = None
        self._csv: Any = None
        self._log = open(self.folder / "link.log", "w", buffering=1)  # line-buffered: survives a kill
        self.columns: list[str] = []
        self._closed = False

    def start_signals(self, columns: list[str], provenance: str) -> None:
        self.columns = ["time", *columns]
        # line-buffered (one write per step): every finished row survives a SIGKILL of the run
        self._csv_file = open(self.folder / "signals.csv", "w", newline="", buffering=1)
        self._csv_file.write(f"# {provenance}\n")
        self._csv = csv.writer(self._csv_file)
        self._csv.writerow(self.columns)

    def frame(self, msg: can.Message, rx: bool, timestamp: float) -> None:
        msg.timestamp = timestamp
        msg.is_rx = rx
        self._can.on_message_received(msg)

    def serial_bytes(self, data: bytes) -> None:
        self._nmea.write(data)

    def row(self, t: float, values: np.ndarray) -> None:
        if self._csv is not None:
            self._csv.writerow([f"{t:.6f}", *(f"{v:.9g}" for v in values)])

    def line(self, text: str) -> None:
        self._log.write(text + "\n")

    def write_trial(self, meta: dict[str, Any]) -> Path:
        path = self.folder / TRIAL_FILE
        path.write_text(yaml.safe_dump(meta, sort_keys=False))
        return path

    def flush(self) -> None:
        """Push what is buffered to the OS, so a killed process loses at most the last interval."""
        for f in (self._nmea, self._csv_file, self._log, getattr(self._can, "file", None)):
            if f is not None and not getattr(f, "closed", False):
                try:
                    f.flush()
                except (OSError, ValueError):  # a full disk or a closed file: the run goes on
                    pass

    def close(self) -> None:
        """Terminate the CAN log (its writer adds the end marker) and close the files; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._can.stop()
        finally:
            for f in (self._nmea, self._csv_file, self._log):
                if f is not None:
                    f.close()


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
