"""Quantities in scenario files: ``"45 deg"``, ``"0.2 kn"``, or a bare number in the variable's SI unit.

A table of the dozen units marine scenarios use, converted to the SI unit each FMU variable
declares. Written by hand on purpose: the FMUs expose a fixed, small set of SI units, and a full
units library would add start-up time and a dependency for no extra safety here.
"""

from __future__ import annotations

import math
import re

# unit -> (SI unit it converts to, factor)
_UNITS: dict[str, tuple[str, float]] = {
    "m": ("m", 1.0), "cm": ("m", 0.01), "mm": ("m", 0.001), "km": ("m", 1000.0), "nmi": ("m", 1852.0),
    "s": ("s", 1.0), "ms": ("s", 0.001), "min": ("s", 60.0), "h": ("s", 3600.0),
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180.0),
    "m/s": ("m/s", 1.0), "kn": ("m/s", 1852.0 / 3600.0), "km/h": ("m/s", 1.0 / 3.6),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180.0),
    "m/s^2": ("m/s^2", 1.0), "rad/s^2": ("rad/s^2", 1.0), "deg/s^2": ("rad/s^2", math.pi / 180.0),
    "N": ("N", 1.0), "kN": ("N", 1000.0),
    "N.m": ("N.m", 1.0), "Nm": ("N.m", 1.0), "kN.m": ("N.m", 1000.0),
    "rev/s": ("rev/s", 1.0), "rps": ("rev/s", 1.0), "rpm": ("rev/s", 1.0 / 60.0),
    "kg": ("kg", 1.0), "Hz": ("Hz", 1.0), "1": ("1", 1.0), "N/s": ("N/s", 1.0), "kN/s": ("N/s", 1000.0),
}

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PLAIN = re.compile(rf"^\s*{_NUMBER}\s*$")
# a unit starts with a letter ("m/s^2", "N.m/(rad.s)"), or is "1/..." after a space ("5 1/s")
_QUANTITY = re.compile(rf"^\s*({_NUMBER})(?:\s*([A-Za-z][A-Za-z0-9/.^()]*)|\s+(1/[A-Za-z0-9/.^()]+))\s*$")
_NON_FINITE = ("inf", "infinity", "nan")


def is_number(text: str) -> bool:
    """A bare number (``"1e2"``, ``" 0.5 "``): no unit, no ``_`` digit separators."""
    return _PLAIN.match(text) is not None


def split_quantity(text: str) -> tuple[float, str] | None:
    """``"<number> <unit>"`` as (number, unit); None for anything else, a bare number included (so
    ``"1e2"`` is 100, never 1 in a unit ``e2``)."""
    if is_number(text):
        return None
    m = _QUANTITY.match(text)
    return None if m is None else (float(m.group(1)), m.group(2) or m.group(3))


class UnitError(ValueError):
    """A value whose unit is unknown or does not fit the variable."""


def _show(value: object, limit: int = 60) -> str:
    """repr of a value for a one-line message, cut to ``limit`` characters."""
    try:
        text = repr(value)
    except ValueError:  # an int of more than 4300 digits has no repr
        text = f"<a {type(value).__name__} too large to show>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def convert(number: float, unit: str, target: str) -> float:
    """``number`` in ``unit`` expressed in ``target`` (both in the table, of one SI unit); UnitError
    if they do not convert."""
    if unit == target:
        return number
    if unit not in _UNITS or target not in _UNITS or _UNITS[unit][0] != _UNITS[target][0]:
        raise UnitError(f"'{unit}' does not convert to '{target}'")
    return number * _UNITS[unit][1] / _UNITS[target][1]


def to_si(value: object, target_unit: str) -> float:
    """Convert a number or a ``"<number> <unit>"`` string to ``target_unit``.

    Never raises anything but ``UnitError``; the result may be inf or NaN (``"1e999 m"``, ``"nan"``):
    callers that need a finite number check it.
    """
    if isinstance(value, bool):
        raise UnitError(f"expected a number, got {value!r}")
    if isinstance(value, int | float):
        try:
            return float(value)
        except OverflowError:
            raise UnitError(f"{_show(value)} is too large for a floating-point number") from None
    if not isinstance(value, str):
        raise UnitError(f"expected a number or '<number> <unit>', got {_show(value)}")
    if is_number(value) or value.strip().lower().lstrip("+-") in _NON_FINITE:
        return float(value)
    q = split_quantity(value)
    if q is None:  # float() would also take "1_0" as 10: refused
        raise UnitError(f"expected a number or '<number> <unit>', got {_show(value)}")
    number, unit = q
    if unit == (target_unit or "1"):  # the variable's own unit, also one the table does not list
        return number
    if unit not in _UNITS:
        raise UnitError(f"unknown unit {_show(unit, 30)} in {_show(value)} "
                        f"(known: {', '.join(sorted(_UNITS))})")
    si, factor = _UNITS[unit]
    if si != (target_unit or "1"):
        shown = target_unit or "1"
        raise UnitError(f"unit '{unit}' in {_show(value)} does not fit this variable's unit '{shown}'")
    return number * factor
