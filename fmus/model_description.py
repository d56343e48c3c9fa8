"""Completion of the modelDescription pythonfmu writes: units with SI base units, min/max and
``InitialUnknowns``, so that ``fmpy.validation.validate_fmu`` reports nothing.

Used by ``seafmu build`` (the four GNC FMUs, which leave this build tool out of their bundle) and
by ``hardware/link_fmu.py`` (the link FMU, whose bundled ``link_fmu`` module imports it).
The SI base units come from the caller (``base_unit``: unit string -> ``<BaseUnit>`` attributes or
None), so this layer imports nothing from the layers above it.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import pythonfmu

BaseUnit = Callable[[str], "dict[str, str] | None"]


def _bounds(sig: Any) -> tuple[float | None, bool, float | None]:
    """(min, whether min itself is excluded, max): the declared range, or that of the allowed values
    (a host then knows the extremes)."""
    if sig.choices is not None:
        values = [float(c) for c in sig.choices]
        return min(values), False, max(values)
    return sig.min, sig.min_open, sig.max


def complete_model_description(fmu: Path, signals: dict, base_unit: BaseUnit,
                               tool: str = "seafmu build") -> None:
    """Add units, min/max and InitialUnknowns to pythonfmu's modelDescription, in place.

    ``signals`` maps variable names to ``components.block.Signal`` (unit, min, max); ``base_unit``
    gives a unit's SI exponents and factor, None (or a ValueError) where it has none.
    """
    with zipfile.ZipFile(fmu) as z:
        members = {n: z.read(n) for n in z.namelist()}
    root = ET.fromstring(members["modelDescription.xml"])

    units = sorted({s.unit for s in signals.values() if s.unit})
    for old in root.findall("UnitDefinitions"):  # idempotent: completing twice changes nothing
        root.remove(old)
    if units:
        ud = ET.Element("UnitDefinitions")
        for u in units:
            unit = ET.SubElement(ud, "Unit", name=u)
            try:  # SI exponents (and factor) so that a host can convert; none for sqrt units
                base = base_unit(u)
            except ValueError:  # seafmu.unitdefs.UnitParseError
                base = None
            if base is not None:
                ET.SubElement(unit, "BaseUnit", base)
        # Schema order: CoSimulation, UnitDefinitions, TypeDefinitions, LogCategories, ...
        root.insert(_first_index(root, ("TypeDefinitions", "LogCategories", "DefaultExperiment",
                                        "VendorAnnotations", "ModelVariables")), ud)

    outputs, initial_unknowns = [], []
    for index, sv in enumerate(root.find("ModelVariables"), start=1):
        sig = signals.get(sv.get("name"))
        real, integer = sv.find("Real"), sv.find("Integer")
        if sig is not None and real is not None:
            if sig.unit:
                real.set("unit", sig.unit)
            lo, lo_open, hi = _bounds(sig)
            if lo is not None:
                # FMI's min is inclusive: an open bound (> 0) is the next number up, which is accepted
                real.set("min", repr(math.nextafter(lo, math.inf) if lo_open else float(lo)))
            if hi is not None:
                real.set("max", repr(float(hi)))
        elif sig is not None and integer is not None:
            lo, lo_open, hi = _bounds(sig)
            if lo is not None:
                integer.set("min", str(math.floor(lo) + 1 if lo_open else math.ceil(lo)))
            if hi is not None:
                integer.set("max", str(math.floor(hi)))
        if sv.get("causality") == "output":
            outputs.append(index)
            initial_unknowns.append(index)
    structure = root.find("ModelStructure")
    for child in list(structure):
        structure.remove(child)
    if outputs:
        o = ET.SubElement(structure, "Outputs")
        for i in outputs:
            ET.SubElement(o, "Unknown", index=str(i))
        iu = ET.SubElement(structure, "InitialUnknowns")
        for i in initial_unknowns:
            ET.SubElement(iu, "Unknown", index=str(i))
    root.set("generationTool", f"{tool} (pythonfmu {pythonfmu.__version__})")
    ET.indent(root)
    members["modelDescription.xml"] = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    tmp = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    tmp.replace(fmu)


def _first_index(root: ET.Element, tags: tuple[str, ...]) -> int:
    for i, child in enumerate(root):
        if child.tag in tags:
            return i
    return len(root)
