"""Faults the vessel emulator injects on its own wire, to rehearse how a controller and the link
take them before they happen at sea: ``seafmu emulate ... --fault KIND:TARGET@START[-END]``.

| kind | target | on the wire |
|---|---|---|
| ``sensor-silent`` | a sensor of the vessel file (``usbl``) | its sentences are not sent |
| ``sensor-frozen`` | a sensor | its last sentences are sent again, byte for byte (a hung receiver) |
| ``drive-silent`` | a thruster number from 1 | its drive sends no status frame |
| ``drive-frozen`` | a thruster number | its last status frames are sent again (alive counter frozen) |

START and END are vessel time in seconds (from the first thruster command, as the emulator's
clock); without END the fault lasts to the end. A frozen source needs something to repeat: it
repeats what it sent last before START. The physics is untouched: a silent or frozen drive still
turns its shaft as commanded (only its report is lost); a failed thruster is the plant's business
(``--set`` / the scenario's events).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

KINDS = ("sensor-silent", "sensor-frozen", "drive-silent", "drive-frozen")
_SPEC = re.compile(r"^(?P<kind>[a-z-]+):(?P<target>[A-Za-z0-9_]+)@(?P<window>.*)$", re.ASCII)
_T = r"(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)"  # a time as a plain decimal: float() would take 1_0, 1e1, nan
_WINDOW = re.compile(rf"^({_T})(?:-({_T}))?$", re.ASCII)


@dataclass(frozen=True)
class Fault:
    """One injected fault; ``target`` a sensor name or a 0-based thruster index."""

    kind: str
    target: str | int
    start: float
    end: float = math.inf

    def active(self, t: float) -> bool:
        return self.start <= t < self.end

    @property
    def label(self) -> str:
        target = self.target + 1 if isinstance(self.target, int) else self.target
        end = "" if math.isinf(self.end) else f"-{self.end:g}"
        return f"{self.kind}:{target}@{self.start:g}{end}"


def parse_fault(spec: str, sensors: list[str], thrusters: int) -> Fault:
    """A ``--fault`` value checked against the vessel (its sensor names, its thruster count);
    ValueError with one line naming the value and what is wrong."""
    m = _SPEC.match(spec.strip())
    if m is None:
        raise ValueError(f"--fault {spec}: expected KIND:TARGET@START[-END], e.g. drive-frozen:3@20-30")
    kind, target = m["kind"], m["target"]
    if kind not in KINDS:
        raise ValueError(f"--fault {spec}: unknown kind '{kind}' (known: {', '.join(KINDS)})")
    w = _WINDOW.match(m["window"])
    if w is None:
        raise ValueError(f"--fault {spec}: '{m['window']}' is not START or START-END in seconds of vessel "
                         "time, from 0 (e.g. 20 or 20-30.5)")
    start, end = float(w[1]), float(w[2]) if w[2] is not None else math.inf
    if end <= start:
        raise ValueError(f"--fault {spec}: ends at {end:g} s, not after its start {start:g} s")
    if kind.startswith("sensor-"):
        if target not in sensors:
            raise ValueError(f"--fault {spec}: no sensor '{target}' on this vessel (its sensors: "
                             f"{', '.join(sensors)})")
        return Fault(kind, target, start, end)
    if not target.isdigit() or not 1 <= int(target) <= thrusters:
        raise ValueError(f"--fault {spec}: thruster '{target}': give a number from 1 to {thrusters}")
    return Fault(kind, int(target) - 1, start, end)


def check_faults(faults: list[Fault], duration: float | None) -> None:
    """ValueError (one line) for a fault that would never act: one starting at or after the
    emulator's ``--duration``, or two of one source at once (which would win?)."""
    for k, f in enumerate(faults):
        if duration is not None and f.start >= duration:
            raise ValueError(f"--fault {f.label}: starts at {f.start:g} s, not before --duration "
                             f"{duration:g} s")
        for g in faults[:k]:
            same = g.target == f.target and g.kind.split("-")[0] == f.kind.split("-")[0]
            if same and f.start < g.end and g.start < f.end:
                raise ValueError(f"--fault {f.label}: overlaps --fault {g.label} (one fault per source at a "
                                 "time)")


class FaultSchedule:
    """Which fault is on at vessel time t, and a log line each time one starts or ends."""

    def __init__(self, faults: list[Fault]) -> None:
        self.faults = list(faults)
        self._on = [False] * len(self.faults)

    def update(self, t: float) -> list[str]:
        """Move to vessel time ``t``; what started or ended since the last call, as log lines."""
        said = []
        for k, f in enumerate(self.faults):
            now = f.active(t)
            if now != self._on[k]:
                self._on[k] = now
                said.append(f"fault {f.label} {'on' if now else 'off'} at t = {t:.2f} s")
        return said

    def on(self, kind: str, target: str | int) -> bool:
        return any(on and f.kind == kind and f.target == target
                   for f, on in zip(self.faults, self._on, strict=True))
