"""NMEA 0183 sensor sentences <-> plant measurement channels, through pynmea2 (checksums enforced).

One sample of a vessel-file sensor travels as one or more sentences (the profile's ``sensors``
mapping, or ``default_sentences`` by channel). Channels are the plant's state names in SI units;
the wire uses each sentence's own units (degrees, knots, metres, ddmm.mmmm latitude).

| sentence | channels | wire |
|---|---|---|
| GGA | north, east | position fix (quality 1-5 only); lat/lon about the profile's NED origin |
| RMC | north, east (+ course, sog) | position, course and speed over ground (knots); mode as GGA |
| VTG | course, sog | course over ground (deg true), speed (knots and km/h); mode as GGA |
| HDT, THS | yaw | true heading, deg (HDT: reference T required; THS adds a mode; pynmea2 lacks THS) |
| DPT, DBT | down | depth, m (DPT: depth + offset; DBT: the metres field, else feet or fathoms) |
| XDR_ATTITUDE | roll, pitch | XDR transducers ``A,<deg>,D,ROLL`` / ``PITCH`` (the usual AHRS convention) |
| XDR_RATES | p, q, r | XDR transducers ``A,<deg/s>,D,ROLLRATE`` / ``PITCHRATE`` / ``YAWRATE`` |
| ROT | r | rate of turn, deg/min |
| PNORBT7 | u, v, w | Nortek DVL bottom-track velocity X/Y/Z, m/s (-32.768 = invalid) |
| VBW | u, v | longitudinal/transverse ground speed, knots (status V = invalid) |

For an ROV, DPT/DBT carry the vehicle's pressure depth (NMEA 0183 has no vehicle-depth sentence);
body rates have no standard sentence either, so XDR_RATES names them in XDR's generic transducer
syntax (seafmu's convention, documented in docs/hardware.md). The DVL's X/Y/Z are taken as aligned
with the body axes (x forward, y starboard, z down).

Why some of this is hand-written: pynmea2 parses and renders sentences and checks checksums, but
knows nothing of a local NED frame; the flat-earth conversion below (WGS-84 radii of curvature at
the origin) is exact to well under a millimetre over the few hundred metres a DP vessel moves.

Every decoded value is checked against ``hardware/plausibility.py`` (latitude, longitude and
heading on the wire; each channel in SI): a sentence with a value outside its limits, or one that
overflows to inf in the conversion, is dropped as ``implausible``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

import pynmea2
from pynmea2.types.proprietary.nor import NOR

from ..components.vessel_spec import SensorSpec
from .plausibility import check_channels, violation

KNOT = 1852.0 / 3600.0  # m/s
_A = 6378137.0  # WGS-84 semi-major axis, m
_E2 = 6.69437999014e-3  # WGS-84 first eccentricity squared
NORTEK_INVALID = -32.768


class THS(pynmea2.TalkerSentence):
    """True heading and status (IEC 61162-1); missing from pynmea2, registered by subclassing."""

    fields = (("Heading", "heading", float), ("Mode indicator", "mode"))


class NmeaError(ValueError):
    """A line that cannot be used; ``kind`` is its drop class (counted by the link): ``checksum``,
    ``malformed``, ``invalid`` (the sender says so), ``implausible`` (well-formed, physically
    impossible: hardware/plausibility.py), ``unsupported`` (valid, nothing of ours)."""

    def __init__(self, kind: str, msg: str) -> None:
        super().__init__(msg)
        self.kind = kind


@dataclass(frozen=True)
class LocalFrame:
    """Flat-earth NED frame about an origin (deg): north/east metres <-> latitude/longitude."""

    lat0: float
    lon0: float

    def _radii(self) -> tuple[float, float]:
        s2 = math.sin(math.radians(self.lat0)) ** 2
        r_n = _A / math.sqrt(1.0 - _E2 * s2)  # prime vertical
        r_m = _A * (1.0 - _E2) / (1.0 - _E2 * s2) ** 1.5  # meridian
        return r_m, r_n * math.cos(math.radians(self.lat0))

    def to_latlon(self, north: float, east: float) -> tuple[float, float]:
        r_m, r_e = self._radii()
        return self.lat0 + math.degrees(north / r_m), self.lon0 + math.degrees(east / r_e)

    def to_ned(self, lat: float, lon: float) -> tuple[float, float]:
        r_m, r_e = self._radii()
        dlon = (lon - self.lon0 + 180.0) % 360.0 - 180.0
        return math.radians(lat - self.lat0) * r_m, math.radians(dlon) * r_e


# -- field helpers -----------------------------------------------------------------------------


# A number: sign, digits, decimal point (NMEA 0183), and an exponent, which some devices write and
# which reads as the same value. Python's float() also takes "1_0" (= 10: a corrupted field read
# as a wrong value), " 5", "infinity" and "nan": all refused here.
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")


def _num(text: str, what: str) -> float:
    if not isinstance(text, str) or _NUMBER.fullmatch(text) is None:
        raise NmeaError("malformed", f"{what}: not a number ({text!r})")
    v = float(text)
    if not math.isfinite(v):
        raise NmeaError("malformed", f"{what}: not finite ({text!r})")
    return v


def _field(msg: pynmea2.NMEASentence, i: int, what: str) -> str:
    if i >= len(msg.data):
        raise NmeaError("malformed", f"{what}: missing (truncated sentence)")
    return msg.data[i]


def _wrap(a: float) -> float:
    a = math.remainder(a, 2.0 * math.pi)
    return math.pi if a == -math.pi else a


def _deg(v: float) -> str:
    return f"{v:.5f}"


def _heading_deg(yaw: float) -> str:
    return f"{math.degrees(yaw) % 360.0:.5f}"


def _lat_str(lat: float) -> tuple[str, str]:
    a = abs(lat)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:02d}{m:010.7f}", "N" if lat >= 0 else "S"


def _lon_str(lon: float) -> tuple[str, str]:
    a = abs(lon)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:03d}{m:010.7f}", "E" if lon >= 0 else "W"


_COORD = re.compile(r"^(\d*)(\d\d(?:\.\d*)?)$")  # (degrees)(mm[.mmmm]): minutes = 2 digits before the point


def _parse_latlon(value: str, hemi: str, deg_digits: int, what: str) -> float:
    """ddmm.mmmm / dddmm.mmmm: the minutes are the two digits before the decimal point, the
    degrees all digits before them (leading zeros may be missing; a third latitude digit is read,
    not cut off, so 20000.0,N is 200 deg and dropped as implausible rather than misread as 20)."""
    hemis = ("N", "S") if deg_digits == 2 else ("E", "W")
    match = _COORD.match(value)
    if match is None or hemi not in hemis:
        raise NmeaError("malformed", f"{what}: bad coordinate {value!r} {hemi!r}")
    d = float(match.group(1) or 0)
    m = float(match.group(2))
    if not 0.0 <= m < 60.0:
        raise NmeaError("malformed", f"{what}: minutes out of range ({value!r})")
    v = d + m / 60.0
    v = -v if hemi in ("S", "W") else v
    why = violation("latitude" if deg_digits == 2 else "longitude", v)
    if why:
        raise NmeaError("implausible", f"{what}: {why}")
    return v


def _heading_field(text: str, what: str) -> float:
    """A true heading or course on the wire (deg, 0-360) as radians in (-pi, pi]."""
    deg = _num(text, what)
    why = violation("heading", deg)
    if why:
        raise NmeaError("implausible", f"{what}: {why}")
    return _wrap(math.radians(deg))


def _utc(t: datetime) -> str:
    return t.strftime("%H%M%S.") + f"{t.microsecond // 10000:02d}"


# -- the codecs --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Ctx:
    frame: LocalFrame
    talkers: dict[str, str]


@dataclass(frozen=True)
class Sentence:
    """One supported sentence: the channels it carries and how to write and read them."""

    name: str
    channels: tuple[str, ...]  # sensor channels (vessel-file state names)
    talker: str
    flexible: bool  # may carry any non-empty subset of its channels (XDR)
    encode: Callable[[dict[str, float], datetime, Ctx], pynmea2.NMEASentence]
    decode: Callable[[pynmea2.NMEASentence, Ctx], dict[str, float]]
    extras: tuple[str, ...] = ()  # course/sog: link outputs, but no sensor channel
    # its first field is the time of its measurement (see fix_time): "day" a UTC time of day
    # (hhmmss.ss, wrapping at midnight), "unix" Unix time; "" none
    clock: str = ""


def _t(name: str, ctx: Ctx, default: str) -> str:
    return ctx.talkers.get(name, default)


def _enc_gga(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    lat, lon = ctx.frame.to_latlon(v["north"], v["east"])
    la, lo = _lat_str(lat), _lon_str(lon)
    return pynmea2.GGA(
        _t("GGA", ctx, "GP"),
        "GGA",
        (_utc(t), la[0], la[1], lo[0], lo[1], "1", "08", "1.0", "0.0", "M", "0.0", "M", "", ""),
    )


# GGA fix quality (NMEA 0183): only 1-5 (and 9, SBAS, which some receivers send) are measured
# positions; 0 and 6-8 are the receiver saying
# it has none (a dead-reckoned, typed-in or simulated position must not reach the observer as a fix)
_GGA_MEASURED = {"1": "GPS", "2": "DGPS", "3": "PPS", "4": "RTK fixed", "5": "RTK float",
                 "9": "SBAS (WAAS/EGNOS: some receivers' differential fix)"}
_GGA_NOT_MEASURED = {"0": "no fix", "6": "estimated/dead reckoning", "7": "manual input", "8": "simulation"}


def _dec_gga(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    quality = _field(m, 5, "GGA fix quality")
    if quality == "":
        raise NmeaError("invalid", "GGA: fix quality empty (no fix)")
    if quality in _GGA_NOT_MEASURED:
        raise NmeaError(
            "invalid", f"GGA: fix quality {quality} ({_GGA_NOT_MEASURED[quality]}), not a measured position"
        )
    if quality not in _GGA_MEASURED:
        raise NmeaError("malformed",
                        f"GGA: fix quality {quality!r} is not one of NMEA 0183's 0-8 (or 9, SBAS)")
    lat = _parse_latlon(_field(m, 1, "GGA latitude"), _field(m, 2, "GGA N/S"), 2, "GGA latitude")
    lon = _parse_latlon(_field(m, 3, "GGA longitude"), _field(m, 4, "GGA E/W"), 3, "GGA longitude")
    n, e = ctx.frame.to_ned(lat, lon)
    return {"north": n, "east": e}


# RMC/VTG mode indicator (NMEA 0183 2.3+; absent before): the same rule as GGA's quality
_MODE_MEASURED = {"A", "D", "F", "P", "R"}  # autonomous, differential, float RTK, precise, RTK
_MODE_NOT_MEASURED = {"E": "estimated/dead reckoning", "M": "manual input", "S": "simulation", "N": "no fix"}


def _check_mode(m: pynmea2.NMEASentence, i: int, kind: str) -> None:
    mode = m.data[i] if len(m.data) > i else ""
    if mode in _MODE_NOT_MEASURED:
        raise NmeaError("invalid", f"{kind}: mode {mode} ({_MODE_NOT_MEASURED[mode]}), not a measurement")
    if mode and mode not in _MODE_MEASURED:
        raise NmeaError("malformed", f"{kind}: mode indicator {mode!r} is not NMEA 0183's")


def _enc_rmc(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    lat, lon = ctx.frame.to_latlon(v["north"], v["east"])
    la, lo = _lat_str(lat), _lon_str(lon)
    sog, course = v.get("sog", 0.0), v.get("course", 0.0)
    return pynmea2.RMC(
        _t("RMC", ctx, "GP"),
        "RMC",
        (
            _utc(t),
            "A",
            la[0],
            la[1],
            lo[0],
            lo[1],
            f"{sog / KNOT:.4f}",
            _heading_deg(course),
            t.strftime("%d%m%y"),
            "",
            "",
            "D",
        ),
    )


def _dec_rmc(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    if _field(m, 1, "RMC status") != "A":
        raise NmeaError("invalid", "RMC: status not A (no valid fix)")
    _check_mode(m, 11, "RMC")
    lat = _parse_latlon(_field(m, 2, "RMC latitude"), _field(m, 3, "RMC N/S"), 2, "RMC latitude")
    lon = _parse_latlon(_field(m, 4, "RMC longitude"), _field(m, 5, "RMC E/W"), 3, "RMC longitude")
    n, e = ctx.frame.to_ned(lat, lon)
    out = {"north": n, "east": e}
    if _field(m, 6, "RMC speed"):
        out["sog"] = _num(m.data[6], "RMC speed") * KNOT
    if _field(m, 7, "RMC course"):
        out["course"] = _heading_field(m.data[7], "RMC course")
    return out


def _enc_vtg(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    sog = v["sog"]
    return pynmea2.VTG(
        _t("VTG", ctx, "GP"),
        "VTG",
        (_heading_deg(v["course"]), "T", "", "M", f"{sog / KNOT:.4f}", "N", f"{sog * 3.6:.4f}", "K", "D"),
    )


def _dec_vtg(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    _check_mode(m, 8, "VTG")
    if _field(m, 4, "VTG speed (kn)"):
        sog = _num(m.data[4], "VTG speed (kn)") * KNOT
    else:
        sog = _num(_field(m, 6, "VTG speed (km/h)"), "VTG speed (km/h)") / 3.6
    out = {"sog": sog}
    if _field(m, 0, "VTG course"):  # empty when the receiver has no course (standing still), as in RMC
        out["course"] = _heading_field(m.data[0], "VTG course")
    return out


def _enc_hdt(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    return pynmea2.HDT(_t("HDT", ctx, "HE"), "HDT", (_heading_deg(v["yaw"]), "T"))


def _enc_ths(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    return THS(_t("THS", ctx, "HE"), "THS", (_heading_deg(v["yaw"]), "A"))


def _dec_heading(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    kind = type(m).__name__
    if kind == "THS" and _field(m, 1, "THS mode") == "V":
        raise NmeaError("invalid", "THS: mode V (data not valid)")
    if kind == "HDT":  # without its T, nothing says the heading is true rather than magnetic
        ref = m.data[1] if len(m.data) > 1 else None
        if ref != "T":
            got = "missing" if ref is None else repr(ref)
            raise NmeaError("malformed", f"HDT: heading reference {got}, expected T (true)")
    return {"yaw": _heading_field(_field(m, 0, f"{kind} heading"), f"{kind} heading")}


def _enc_dpt(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    return pynmea2.DPT(_t("DPT", ctx, "SD"), "DPT", (f"{v['down']:.4f}", "0.0", ""))


def _dec_dpt(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    depth = _num(_field(m, 0, "DPT depth"), "DPT depth")
    off = _num(m.data[1], "DPT offset") if len(m.data) > 1 and m.data[1] else 0.0
    return {"down": depth + off}


def _enc_dbt(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    d = v["down"]
    return pynmea2.DBT(
        _t("DBT", ctx, "SD"), "DBT", (f"{d / 0.3048:.4f}", "f", f"{d:.4f}", "M", f"{d / 1.8288:.4f}", "F")
    )


def _dec_dbt(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    for i, scale in ((2, 1.0), (0, 0.3048), (4, 1.8288)):
        if len(m.data) > i and m.data[i]:
            return {"down": _num(m.data[i], "DBT depth") * scale}
    raise NmeaError("malformed", "DBT: no depth field")


_XDR_IDS = {"roll": "ROLL", "pitch": "PITCH", "p": "ROLLRATE", "q": "PITCHRATE", "r": "YAWRATE"}
_XDR_CHANNEL = {v: k for k, v in _XDR_IDS.items()}


def _enc_xdr(
    v: dict[str, float], t: datetime, ctx: Ctx, name: str, chans: tuple[str, ...]
) -> pynmea2.NMEASentence:
    data: list[str] = []
    for c in chans:
        if c in v:
            data += ["A", _deg(math.degrees(v[c])), "D", _XDR_IDS[c]]
    return pynmea2.XDR(_t(name, ctx, "II"), "XDR", tuple(data))


def _dec_xdr(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    if len(m.data) % 4 or not m.data:
        raise NmeaError("malformed", "XDR: transducer fields come in fours")
    out: dict[str, float] = {}
    seen: set[str] = set()
    for i in range(0, len(m.data), 4):
        kind, value, unit, ident = m.data[i : i + 4]
        ch = _XDR_CHANNEL.get(ident.upper())
        if ch is not None:  # two values for one transducer: which is the measurement is unknowable
            if ch in seen:
                raise NmeaError("malformed", f"XDR: transducer {ident} appears twice (ambiguous)")
            seen.add(ch)
        if ch is None or kind != "A":
            continue  # other transducers (temperature, pressure, ...) are not plant channels
        if unit != "D":
            raise NmeaError("malformed", f"XDR {ident}: unit {unit!r}, expected D (degrees)")
        out[ch] = math.radians(_num(value, f"XDR {ident}"))
    if not out:
        raise NmeaError("unsupported", "XDR: no roll/pitch/rate transducer")
    return out


def _enc_rot(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    return pynmea2.ROT(_t("ROT", ctx, "HE"), "ROT", (f"{math.degrees(v['r']) * 60.0:.4f}", "A"))


def _dec_rot(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    if len(m.data) > 1 and m.data[1] == "V":
        raise NmeaError("invalid", "ROT: status V (data not valid)")
    return {"r": math.radians(_num(_field(m, 0, "ROT rate"), "ROT rate") / 60.0)}


def _enc_norbt7(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    ts = f"{t.timestamp():.4f}"
    return NOR(
        "NOR",
        [
            "BT7",
            ts,
            "0.0000",
            "0.0000",
            f"{v['u']:.5f}",
            f"{v['v']:.5f}",
            f"{v['w']:.5f}",
            "0.0050",
            "10.00",
            "10.00",
            "10.00",
            "10.00",
        ],
    )


def _dec_norbt7(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    vals = [
        _num(_field(m, i, f"PNORBT7 velocity {a}"), f"PNORBT7 velocity {a}")
        for i, a in ((3, "X"), (4, "Y"), (5, "Z"))
    ]
    if any(abs(x - NORTEK_INVALID) < 1e-9 for x in vals):
        raise NmeaError("invalid", "PNORBT7: invalid velocity (-32.768: no bottom lock)")
    return dict(zip(("u", "v", "w"), vals, strict=True))


def _enc_vbw(v: dict[str, float], t: datetime, ctx: Ctx) -> pynmea2.NMEASentence:
    return pynmea2.VBW(
        _t("VBW", ctx, "VD"), "VBW", ("", "", "V", f"{v['u'] / KNOT:.5f}", f"{v['v'] / KNOT:.5f}", "A")
    )


def _dec_vbw(m: pynmea2.NMEASentence, ctx: Ctx) -> dict[str, float]:
    if _field(m, 5, "VBW ground status") != "A":
        raise NmeaError("invalid", "VBW: ground speed not valid (status V)")
    return {
        "u": _num(m.data[3], "VBW longitudinal speed") * KNOT,
        "v": _num(m.data[4], "VBW transverse speed") * KNOT,
    }


SENTENCES: dict[str, Sentence] = {
    s.name: s
    for s in (
        Sentence("GGA", ("north", "east"), "GP", False, _enc_gga, _dec_gga, clock="day"),
        Sentence("RMC", ("north", "east"), "GP", False, _enc_rmc, _dec_rmc, ("course", "sog"), "day"),
        Sentence("VTG", (), "GP", False, _enc_vtg, _dec_vtg, ("course", "sog")),
        Sentence("HDT", ("yaw",), "HE", False, _enc_hdt, _dec_heading),
        Sentence("THS", ("yaw",), "HE", False, _enc_ths, _dec_heading),
        Sentence("DPT", ("down",), "SD", False, _enc_dpt, _dec_dpt),
        Sentence("DBT", ("down",), "SD", False, _enc_dbt, _dec_dbt),
        Sentence(
            "XDR_ATTITUDE",
            ("roll", "pitch"),
            "II",
            True,
            lambda v, t, c: _enc_xdr(v, t, c, "XDR_ATTITUDE", ("roll", "pitch")),
            _dec_xdr,
        ),
        Sentence(
            "XDR_RATES",
            ("p", "q", "r"),
            "II",
            True,
            lambda v, t, c: _enc_xdr(v, t, c, "XDR_RATES", ("p", "q", "r")),
            _dec_xdr,
        ),
        Sentence("ROT", ("r",), "HE", False, _enc_rot, _dec_rot),
        Sentence("PNORBT7", ("u", "v", "w"), "", False, _enc_norbt7, _dec_norbt7, clock="unix"),
        Sentence("VBW", ("u", "v"), "VD", False, _enc_vbw, _dec_vbw),
    )
}
EXTRA_CHANNELS = ("course", "sog")  # carried by RMC/VTG, outputs of the link but no sensor channel

# sentence type on the wire -> codecs that may have produced it
_BY_TYPE = {
    "GGA": "GGA",
    "RMC": "RMC",
    "VTG": "VTG",
    "HDT": "HDT",
    "THS": "THS",
    "DPT": "DPT",
    "DBT": "DBT",
    "ROT": "ROT",
    "NORBT7": "PNORBT7",
    "VBW": "VBW",
}

DAY = 86400.0  # s
_HHMMSS = re.compile(r"^([0-9]{2})([0-9]{2})([0-9]{2}(?:\.[0-9]+)?)$")


def fix_time(name: str, line: str) -> float | None:
    """The time of the measurement a sentence carries, s (GGA, RMC: of the UTC day, from hhmmss.ss;
    PNORBT7: Unix time); None for the others or an empty or unreadable field. A sentence whose
    time is not later than the last one's of its kind is no new measurement (``hardware/link.py``)."""
    clock = SENTENCES[name].clock
    if not clock:
        return None
    parts = line.split(",", 2)
    field = parts[1] if len(parts) > 2 else ""
    if clock == "day":
        m = _HHMMSS.match(field)
        return int(m[1]) * 3600.0 + int(m[2]) * 60.0 + float(m[3]) if m else None
    try:
        value = float(field)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


# default sentences, in order of preference, for a vessel-file sensor's channels
_PREFERENCE = ("GGA", "DPT", "XDR_ATTITUDE", "HDT", "PNORBT7", "VBW", "XDR_RATES", "ROT")


def default_sentences(sensor: SensorSpec) -> list[str]:
    """Sentences that carry one sample of ``sensor`` (ValueError if a channel has none)."""
    left = list(sensor.channels)
    out = []
    for name in _PREFERENCE:
        s = SENTENCES[name]
        covered = [c for c in s.channels if c in left]
        if (s.flexible and covered) or (covered and len(covered) == len(s.channels)):
            if name == "XDR_RATES" and covered == ["r"]:
                continue  # yaw rate alone: ROT is the standard sentence
            out.append(name)
            left = [c for c in left if c not in covered]
    if left:
        raise ValueError(f"sensor '{sensor.name}': no NMEA sentence carries channel(s) {left}")
    return out


def check_mapping(sensor: SensorSpec, sentences: list[str]) -> None:
    """ValueError unless ``sentences`` carry exactly the sensor's channels (plus course/sog)."""
    carried: list[str] = []
    for name in sentences:
        if name not in SENTENCES:
            raise ValueError(
                f"sensor '{sensor.name}': unknown sentence '{name}' (known: {', '.join(SENTENCES)})"
            )
        s = SENTENCES[name]
        extra = [c for c in s.channels if c not in sensor.channels]
        if extra and not s.flexible:
            raise ValueError(
                f"sensor '{sensor.name}': {name} carries {extra}, which the sensor does not measure"
            )
        carried += [c for c in s.channels if c in sensor.channels]
    missing = [c for c in sensor.channels if c not in carried]
    if missing:
        raise ValueError(f"sensor '{sensor.name}': no sentence in {sentences} carries {missing}")


class NmeaCodec:
    """Encode channel values into sentence lines and decode lines back, about one NED origin."""

    def __init__(self, lat0: float, lon0: float, talkers: dict[str, str] | None = None) -> None:
        self.ctx = Ctx(LocalFrame(lat0, lon0), dict(talkers or {}))

    def encode(self, name: str, values: dict[str, float], utc: datetime | None = None) -> str:
        """One line (with checksum, without CR LF) of sentence ``name`` carrying ``values``."""
        t = utc or datetime.now(UTC)
        return str(SENTENCES[name].encode(values, t, self.ctx))

    def decode(self, line: str) -> tuple[str, dict[str, float]]:
        """(sentence name, channel values); NmeaError with a drop class for anything unusable."""
        line = line.strip()
        if not line.startswith(("$", "!")):
            raise NmeaError("malformed", f"not a sentence: {line[:40]!r}")
        # NMEA 0183 is printable ASCII with $ and ! only as the start delimiter: anything else is a
        # corrupted line or two sentences run together, even when the checksum happens to match
        if not (line.isascii() and line.isprintable()):
            raise NmeaError("malformed", f"non-printable or non-ASCII character in {line[:60]!r}")
        if "$" in line[1:] or "!" in line[1:]:
            raise NmeaError("malformed", f"$ or ! inside the sentence (two run together?): {line[:60]!r}")
        try:
            msg = pynmea2.parse(line, check=True)
        except pynmea2.ChecksumError:
            what = "bad checksum" if "*" in line else "no checksum (truncated line?)"
            raise NmeaError("checksum", f"{what}: {line[:60]!r}") from None
        except (pynmea2.ParseError, ValueError, TypeError, AttributeError, IndexError) as exc:
            raise NmeaError("malformed", f"cannot parse {line[:60]!r} ({type(exc).__name__})") from None
        if isinstance(msg, pynmea2.QuerySentence):  # a request for a sentence, carrying no data
            raise NmeaError("unsupported", f"query for {msg.sentence_type} from {msg.talker}: no data")
        kind = getattr(msg, "sentence_type", "")
        if kind == "XDR":
            values = _dec_xdr(msg, self.ctx)
            name = "XDR_ATTITUDE" if ("roll" in values or "pitch" in values) else "XDR_RATES"
            if name == "XDR_ATTITUDE" and any(c in values for c in ("p", "q", "r")):
                raise NmeaError("malformed", "XDR mixes attitude and rate transducers")
        else:
            name = _BY_TYPE.get(kind)
            if name is None:
                raise NmeaError("unsupported", f"sentence {kind or line[:8]!r} carries no plant channel")
            values = SENTENCES[name].decode(msg, self.ctx)
        why = check_channels(values)  # hardware/plausibility.py: the whole sentence or nothing
        if why:
            raise NmeaError("implausible", f"{name}: {why}")
        return name, values
