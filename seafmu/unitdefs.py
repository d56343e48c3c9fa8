"""SI base-unit exponents and factors of the unit strings seafmu's FMUs declare.

FMI 2.0 (``<UnitDefinitions>``/``<BaseUnit>``) and SSP 1.0 (``<ssc:Unit>``/``<ssc:BaseUnit>``) both
describe a unit as ``factor · kg^a m^b s^c A^d K^e mol^f cd^g rad^h + offset``, so that a host can
convert between connected variables. The unit strings here are small expressions such as
``N.m/(rad.s)`` or ``m/s^2``; a ~60-line parser is all they need (pint would bring a large
registry for six base symbols, and its output would still have to be mapped onto FMI's eight
exponents). A unit whose exponents are not integers (``m/s^2/sqrt(Hz)``) has no FMI base unit:
``base_unit`` returns None and the unit is declared by name only.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

EXPONENTS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

# symbol -> (factor to SI, exponents in EXPONENTS order)
_SYMBOLS: dict[str, tuple[float, tuple[float, ...]]] = {
    "1": (1.0, (0, 0, 0, 0, 0, 0, 0, 0)),
    "kg": (1.0, (1, 0, 0, 0, 0, 0, 0, 0)),
    "g": (1e-3, (1, 0, 0, 0, 0, 0, 0, 0)),
    "m": (1.0, (0, 1, 0, 0, 0, 0, 0, 0)),
    "s": (1.0, (0, 0, 1, 0, 0, 0, 0, 0)),
    "min": (60.0, (0, 0, 1, 0, 0, 0, 0, 0)),
    "h": (3600.0, (0, 0, 1, 0, 0, 0, 0, 0)),
    "Hz": (1.0, (0, 0, -1, 0, 0, 0, 0, 0)),
    "N": (1.0, (1, 1, -2, 0, 0, 0, 0, 0)),
    "W": (1.0, (1, 2, -3, 0, 0, 0, 0, 0)),
    "J": (1.0, (1, 2, -2, 0, 0, 0, 0, 0)),
    "Pa": (1.0, (1, -1, -2, 0, 0, 0, 0, 0)),
    "A": (1.0, (0, 0, 0, 1, 0, 0, 0, 0)),
    "V": (1.0, (1, 2, -3, -1, 0, 0, 0, 0)),
    "K": (1.0, (0, 0, 0, 0, 1, 0, 0, 0)),
    "rad": (1.0, (0, 0, 0, 0, 0, 0, 0, 1)),
    "deg": (math.pi / 180.0, (0, 0, 0, 0, 0, 0, 0, 1)),
    "rev": (2.0 * math.pi, (0, 0, 0, 0, 0, 0, 0, 1)),
    "rpm": (2.0 * math.pi / 60.0, (0, 0, -1, 0, 0, 0, 0, 1)),
    "kn": (1852.0 / 3600.0, (0, 1, -1, 0, 0, 0, 0, 0)),
}

_TOKEN = re.compile(r"\s*(sqrt\(|[A-Za-z]+|\d+(?:\.\d+)?|[./()^*-])")


class UnitParseError(ValueError):
    """A unit string outside the small grammar above."""


@dataclass(frozen=True)
class SIUnit:
    factor: float
    exponents: tuple[float, ...]  # in EXPONENTS order


def _mul(a: SIUnit, b: SIUnit, sign: float = 1.0) -> SIUnit:
    return SIUnit(a.factor * b.factor**sign, tuple(x + sign * y for x, y in zip(a.exponents, b.exponents,
                                                                                strict=True)))


def _pow(a: SIUnit, p: float) -> SIUnit:
    return SIUnit(a.factor**p, tuple(x * p for x in a.exponents))


class _Parser:
    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = _TOKEN.findall(text)
        if "".join(self.tokens) != re.sub(r"\s+", "", text):
            raise UnitParseError(f"unit '{text}': unexpected characters")
        self.i = 0

    def peek(self) -> str | None:
        return self.tokens[self.i] if self.i < len(self.tokens) else None

    def take(self) -> str:
        tok = self.peek()
        if tok is None:
            raise UnitParseError(f"unit '{self.text}': ends too early")
        self.i += 1
        return tok

    def product(self) -> SIUnit:
        unit = self.power()
        while self.peek() in (".", "*", "/"):
            op = self.take()
            unit = _mul(unit, self.power(), -1.0 if op == "/" else 1.0)
        return unit

    def power(self) -> SIUnit:
        unit = self.atom()
        if self.peek() == "^":
            self.take()
            sign = -1.0 if self.peek() == "-" and self.take() else 1.0
            exponent = self.take()
            if not re.fullmatch(r"\d+(?:\.\d+)?", exponent):
                raise UnitParseError(f"unit '{self.text}': exponent '{exponent}' is not a number")
            unit = _pow(unit, sign * float(exponent))
        return unit

    def atom(self) -> SIUnit:
        tok = self.take()
        if tok in ("(", "sqrt("):
            inner = self.product()
            if self.take() != ")":
                raise UnitParseError(f"unit '{self.text}': unbalanced parentheses")
            return _pow(inner, 0.5) if tok == "sqrt(" else inner
        if tok in _SYMBOLS:
            factor, exps = _SYMBOLS[tok]
            return SIUnit(factor, tuple(float(e) for e in exps))
        raise UnitParseError(f"unit '{self.text}': unknown symbol '{tok}'")


def parse_unit(text: str) -> SIUnit:
    """The SI factor and base exponents of a unit string (``'N.m/(rad.s)'``, ``'kn'``)."""
    p = _Parser(text)
    unit = p.product()
    if p.peek() is not None:
        raise UnitParseError(f"unit '{text}': unexpected '{p.peek()}'")
    return unit


def base_unit(text: str) -> dict[str, str] | None:
    """Attributes of an FMI/SSP ``BaseUnit`` element, or None when the exponents are not integers."""
    unit = parse_unit(text)
    if any(e != int(e) for e in unit.exponents):
        return None
    attrs = {name: str(int(e)) for name, e in zip(EXPONENTS, unit.exponents, strict=True) if e}
    if unit.factor != 1.0:
        attrs["factor"] = repr(unit.factor)
    return attrs
