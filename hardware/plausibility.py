"""Physical plausibility limits of every value the link decodes: one table, used by the codecs.

A well-formed sentence (valid checksum) or frame can still carry nonsense: latitude 200 deg, a
depth that overflows to inf when the offset is added, a DVL speed of 1e30 m/s, a shaft speed of
300 rev/s on a 20 rev/s thruster. A value outside its limits (or not finite) makes the whole
sentence or frame a drop of class ``implausible`` (NMEA, counted in ``lines_dropped``) or
``implausible_feedback`` (CAN, counted in ``frames_dropped``); it never reaches the observer.

The limits catch garbage, overflow and unit errors, not sensor inaccuracy: they are generous
bounds for the vessels seafmu ships (ROV Minerva 2, a 1 m/s vehicle rated for a few hundred
metres; the AMV OSF, 2 m/s), each with its reason in ``source``. docs/hardware.md shows the same
table (a test keeps the two equal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    """Closed interval [lo, hi] of a value in ``unit``; ``relative``: in units of the thruster's n_max."""

    lo: float
    hi: float
    unit: str
    source: str
    relative: bool = False

    def holds(self, value: float, scale: float = 1.0) -> bool:
        # A value sent at the bound comes back a little past it after the wire's rounding (20 m/s
        # as 38.877 kn decodes to 20.00016 m/s): the bounds get a slack of 1e-4 of their size.
        lo, hi = self.lo * scale, self.hi * scale
        slack = 1e-4 * max(abs(lo), abs(hi))
        return math.isfinite(value) and lo - slack <= value <= hi + slack


# Wire fields (as sent, before conversion) and channels (SI, after conversion): one table.
LIMITS: dict[str, Limit] = {
    # -- wire fields ---------------------------------------------------------------------------
    "latitude": Limit(-90.0, 90.0, "deg", "definition of latitude (GGA, RMC)"),
    "longitude": Limit(-180.0, 180.0, "deg", "definition of longitude (GGA, RMC)"),
    "heading": Limit(
        0.0, 360.0, "deg", "true heading / course over ground on the wire is 0-360 (HDT, THS, RMC, VTG)"
    ),
    # -- channels (SI) ---------------------------------------------------------------------------
    "north": Limit(
        -20e3, 20e3, "m",
        "distance from the profile origin: beyond 20 km the flat-earth NED frame is off by > 0.5 % "
        "(125 m east at 63 deg N), so the fix or the origin is wrong",
    ),
    "east": Limit(-20e3, 20e3, "m", "as north"),
    "down": Limit(
        -5.0, 11000.0, "m",
        "5 m above the surface (pressure-depth offset, waves) to the deepest ocean (Challenger "
        "Deep, 10 935 m); catches overflow (DPT depth + offset, DBT fathoms x 1.8288) and sentinels",
    ),
    "roll": Limit(-math.pi, math.pi, "rad", "Euler angle range (ZYX): roll in [-180, 180] deg"),
    "pitch": Limit(-math.pi / 2, math.pi / 2, "rad", "Euler angle range (ZYX): pitch in [-90, 90] deg"),
    "yaw": Limit(-math.pi, math.pi, "rad", "heading, wrapped (the wire field is checked as heading)"),
    "course": Limit(-math.pi, math.pi, "rad", "course over ground, wrapped (wire: heading)"),
    "u": Limit(
        -20.0, 20.0, "m/s",
        "about 39 kn: ten times the fastest vessel here (AMV OSF max_forward_speed 2 m/s; Minerva 2 "
        "CFD data up to 1 m/s); catches overflow and mm/s or cm/s read as m/s",
    ),
    "v": Limit(-20.0, 20.0, "m/s", "as u"),
    "w": Limit(-20.0, 20.0, "m/s", "as u"),
    "sog": Limit(0.0, 20.0, "m/s", "as u; speed over ground is not negative"),
    "p": Limit(
        -math.pi, math.pi, "rad/s",
        "180 deg/s: a turn in 2 s, far beyond both vessels (Minerva 2 CFD rates 0.01-0.2 rad/s) and "
        "within the range of common MEMS/FOG gyros (250 deg/s and up)",
    ),
    "q": Limit(-math.pi, math.pi, "rad/s", "as p"),
    "r": Limit(-math.pi, math.pi, "rad/s", "as p (XDR_RATES and ROT)"),
    # -- CAN feedback ----------------------------------------------------------------------------
    "speed_measured": Limit(
        -1.5, 1.5, "n_max",
        "a drive's measured shaft speed: drives limit their speed to n_max (vessel file), so 50 % "
        "more is a decoding or drive error; the DBC's int16 x 0.01 rev/s would allow +-327",
        relative=True,
    ),
}


def violation(name: str, value: float, scale: float = 1.0) -> str | None:
    """None if ``value`` is within LIMITS[name] (times ``scale`` if relative), else why not."""
    lim = LIMITS[name]
    s = scale if lim.relative else 1.0
    if lim.holds(value, s):
        return None
    unit = f"rev/s ({lim.lo:g}..{lim.hi:g} x n_max)" if lim.relative else lim.unit
    return f"{name} = {value:.6g} outside [{lim.lo * s:g}, {lim.hi * s:g}] {unit}"


def check_channels(values: dict[str, float]) -> str | None:
    """The first channel of a decoded sample outside its limits (reason), or None."""
    for name, value in values.items():
        if name in LIMITS:
            why = violation(name, value)
            if why:
                return why
        elif not math.isfinite(value):
            return f"{name} = {value} is not finite"
    return None


def limits_markdown() -> str:
    """LIMITS as the Markdown table in docs/hardware.md (a test keeps the two equal)."""

    def num(x: float) -> str:
        for k, name in ((1, "π"), (0.5, "π/2")):
            if abs(abs(x) - k * math.pi) < 1e-12:
                return ("−" if x < 0 else "") + name
        return f"{x:g}".replace("-", "−")

    rows = ["| value | limits | unit | why |", "|---|---|---|---|"]
    for name, lim in LIMITS.items():
        rows.append(f"| `{name}` | {num(lim.lo)} … {num(lim.hi)} | {lim.unit} | {lim.source} |")
    return "\n".join(rows)
