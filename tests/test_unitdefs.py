"""SI unit definitions: what the FMUs (FMI UnitDefinitions) and SSP exports declare for hosts."""

from __future__ import annotations

import math
import zipfile
from xml.etree import ElementTree as ET

import pytest
from fmpy.validation import validate_fmu

from seafmu.build import fmu_path
from seafmu.unitdefs import UnitParseError, base_unit, parse_unit


@pytest.mark.parametrize(("text", "attrs"), [
    ("N", {"kg": "1", "m": "1", "s": "-2"}),
    ("N.m", {"kg": "1", "m": "2", "s": "-2"}),
    ("N.m/(rad.s)", {"kg": "1", "m": "2", "s": "-3", "rad": "-1"}),
    ("m/s^2", {"m": "1", "s": "-2"}),
    ("1/s", {"s": "-1"}),
    ("rev/s", {"s": "-1", "rad": "1", "factor": repr(2 * math.pi)}),
    ("deg", {"rad": "1", "factor": repr(math.pi / 180)}),
    ("rpm", {"s": "-1", "rad": "1", "factor": repr(2 * math.pi / 60)}),
    ("kn", {"m": "1", "s": "-1", "factor": repr(1852 / 3600)}),
])
def test_base_units(text: str, attrs: dict[str, str]) -> None:
    assert base_unit(text) == attrs


def test_non_integer_exponents_have_no_base_unit() -> None:
    assert parse_unit("m/s^2/sqrt(Hz)").exponents[2] == -1.5
    assert base_unit("m/s^2/sqrt(Hz)") is None


@pytest.mark.parametrize("bad", ["furlong", "m/", "(m", "m^x", "m$"])
def test_bad_units_are_refused(bad: str) -> None:
    with pytest.raises(UnitParseError, match="unit"):
        parse_unit(bad)


def test_fmus_declare_si_base_units_and_validate(built_fmus: dict) -> None:
    path = fmu_path("minerva2", "plant")
    with zipfile.ZipFile(path) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    units = {u.get("name"): u.find("BaseUnit") for u in root.iter("Unit")}
    assert units["rev/s"] is not None and float(units["rev/s"].get("factor")) == pytest.approx(2 * math.pi)
    assert units["N"].attrib == {"kg": "1", "m": "1", "s": "-2"}
    assert validate_fmu(str(path)) == []
