"""``seafmu export``: a scenario written for other co-simulation engines (SSP 1.0, OSP).

Both formats carry the FMUs, the connections, the parameter values (SI, as the scenario resolved
them) and each FMU's step size (``step × step_multiple``). What they cannot carry is written
beside them and named in one line (``Export.summary``):
* timed events → a libcosim scenario file (JSON; ``CosimExecution.load_scenario``), which OSP's
  ``cosim run`` and libcosimpy read; ecos gets the same events from the JSON via a scenario
  listener (``seafmu.hosts``; see ``load_events``);
* acceptance checks → ``checks.yaml`` (neither format has checks);
* Gauss-Seidel coupling: OSP's fixed-step algorithm, libcosim and ecos step every FMU with the
  inputs of the start of the step (Jacobi coupling: one step of delay per connection). A scenario
  with ``coupling: jacobi`` runs in seafmu as in those engines (equal to 1e-9, tested); one with
  the default ``gauss-seidel`` is said to be left out.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import yaml

from seafmu.outdir import check_output_folder, claim_output_folder
from seafmu.scenario import Instance, Scenario
from seafmu.unitdefs import UnitParseError, base_unit

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP_ANN = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OSP_CFG = "http://opensimulationplatform.com/MSMI/OSPSystemStructure"
PARAMETER_SET = "initialValues"  # one name for every component: ecos applies sets by name
for _prefix, _uri in (("ssd", SSD), ("ssc", SSC), ("ssv", SSV), ("osp", OSP_ANN)):
    ET.register_namespace(_prefix, _uri)

_SSP_TYPE = {"real": "Real", "integer": "Integer", "boolean": "Boolean", "string": "String"}


class ExportError(ValueError):
    """A scenario that cannot be exported; the message is one line."""


@dataclass
class LeftOut:
    """One thing the format cannot hold: what, the files it went to instead (if any), a note."""

    what: str
    files: list[Path] = field(default_factory=list)
    note: str = ""

    def text(self) -> str:
        where = f" -> {', '.join(str(f) for f in self.files)}" if self.files else ""
        return f"{self.what}{where}{f' ({self.note})' if self.note else ''}"


@dataclass
class Export:
    """What was written and what the target format could not hold."""

    files: list[Path] = field(default_factory=list)
    left_out: list[LeftOut] = field(default_factory=list)

    def summary(self) -> str:
        """One line: what was left out of the format and where it went instead."""
        if not self.left_out:
            return "left out: nothing"
        return "left out (not expressible in SSP/OSP): " + "; ".join(x.text() for x in self.left_out)

    @classmethod
    def merged(cls, exports: list[Export]) -> Export:
        """Several exports of one scenario (SSP and OSP) as one: the files, and each thing left
        out once with all the files it went to."""
        out = cls()
        by_what: dict[str, LeftOut] = {}
        for e in exports:
            out.files.extend(e.files)
            for x in e.left_out:
                if x.what in by_what:
                    by_what[x.what].files.extend(f for f in x.files if f not in by_what[x.what].files)
                else:
                    by_what[x.what] = LeftOut(x.what, list(x.files), x.note)
                    out.left_out.append(by_what[x.what])
        return out


def check_exportable(sc: Scenario) -> None:
    """Refuse what no engine can run from a file: hardware links (ExportError, one line)."""
    for inst in sc.instances:
        if inst.hardware:
            raise ExportError(f"{sc.source}: fmus.{inst.name}: a hardware link cannot be exported; build it "
                              f"with 'seafmu build --link {inst.hardware}' and name the FMU with 'fmu:'")


def check_ssp_target(target: Path) -> Path:
    target = Path(target)
    if target.suffix != ".ssp":
        raise ExportError(f"{target}: an SSP file name ends in .ssp")
    if target.exists() and not target.is_file():
        raise ExportError(f"{target}: exists and is not a file")
    _check_parent(target)
    return target


def _check_parent(target: Path) -> None:
    """The folder to write ``target`` in exists (it is not created) and is a folder."""
    if target.parent.exists() and not target.parent.is_dir():
        raise ExportError(f"{target}: {target.parent} is a file, not a folder")
    if not target.parent.is_dir():
        raise ExportError(f"{target}: folder {target.parent} does not exist")


def check_osp_target(target: Path) -> Path:
    """A folder to write the OSP files in: new, empty or an earlier seafmu output folder (not the
    user's own files, which scenario.json and checks.yaml would replace)."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise ExportError(f"{target}: exists and is not a folder")
    _check_parent(target)
    check_output_folder(target)
    return target


def fmu_sources(sc: Scenario) -> dict[str, Path]:
    """Instance name -> FMU file (built seafmu FMUs or the scenario's own)."""
    from seafmu.build import build_fmu

    check_exportable(sc)
    out: dict[str, Path] = {}
    for inst in sc.instances:
        out[inst.name] = inst.fmu_file if inst.fmu_file else build_fmu(sc.vessel, str(inst.kind)).path
    return out


def _value_text(value: Any, vtype: str) -> str:
    if vtype == "boolean":
        return "true" if value else "false"
    if vtype == "integer":
        return str(int(value))
    if vtype == "real":
        return repr(float(value))
    return str(value)


def _parameters(inst: Instance) -> list[tuple[str, str, Any, str]]:
    """(name, type, value, unit) of the instance's parameter values, in the scenario's order."""
    out = []
    for name, value in inst.parameters.items():
        info = inst.variables[name]
        out.append((name, info.type, value, info.unit or ""))
    return out


def _ports(inst: Instance) -> list[tuple[str, str, str, str]]:
    """(name, kind, type, unit) of the connectors: inputs, outputs and the parameters that are set.

    Each name once: an input given a start value (``down_ref: 5 m``) stays an input connector
    (its value is in the parameter set all the same); SSP hosts key connectors by name.
    """
    ports = [(v.name, v.causality, v.type, v.unit or "") for v in inst.variables.values()
             if v.causality in ("input", "output")]
    named = {p[0] for p in ports}
    ports += [(n, "parameter", t, u) for n, t, _, u in _parameters(inst) if n not in named]
    return ports


def _units_element(parent: ET.Element, units: set[str], ns: str) -> None:
    defined = [u for u in sorted(units) if u]
    if not defined:
        return
    el = ET.SubElement(parent, f"{{{ns}}}Units")
    for name in defined:
        unit = ET.SubElement(el, f"{{{SSC}}}Unit", name=name)
        try:
            attrs = base_unit(name)
        except UnitParseError:
            attrs = None
        ET.SubElement(unit, f"{{{SSC}}}BaseUnit", attrs or {})


def _ssv(inst: Instance) -> bytes:
    root = ET.Element(f"{{{SSV}}}ParameterSet", version="1.0", name=PARAMETER_SET)
    params = ET.SubElement(root, f"{{{SSV}}}Parameters")
    units: set[str] = set()
    for name, vtype, value, unit in _parameters(inst):
        p = ET.SubElement(params, f"{{{SSV}}}Parameter", name=name)
        attrs = {"value": _value_text(value, vtype)}
        if vtype == "real" and unit:
            attrs["unit"] = unit
            units.add(unit)
        ET.SubElement(p, f"{{{SSV}}}{_SSP_TYPE[vtype]}", attrs)
    _units_element(root, units, SSV)
    return _xml(root)


def _xml(root: ET.Element) -> bytes:
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def ssd_document(sc: Scenario, sources: dict[str, str]) -> bytes:
    """SystemStructure.ssd (SSP 1.0) for the scenario; ``sources`` maps instance -> path in the SSP."""
    root = ET.Element(f"{{{SSD}}}SystemStructureDescription", version="1.0", name=sc.name)
    system = ET.SubElement(root, f"{{{SSD}}}System", name=sc.name)
    if sc.description:
        system.set("description", " ".join(sc.description.split()))
    elements = ET.SubElement(system, f"{{{SSD}}}Elements")
    units: set[str] = set()
    for inst in sc.instances:
        comp = ET.SubElement(elements, f"{{{SSD}}}Component", name=inst.name,
                             type="application/x-fmu-sharedlibrary", source=sources[inst.name])
        connectors = ET.SubElement(comp, f"{{{SSD}}}Connectors")
        for name, kind, vtype, unit in _ports(inst):
            c = ET.SubElement(connectors, f"{{{SSD}}}Connector", name=name, kind=kind)
            t = ET.SubElement(c, f"{{{SSC}}}{_SSP_TYPE[vtype]}")
            if vtype == "real" and unit:
                t.set("unit", unit)
                units.add(unit)
        if inst.parameters:
            bindings = ET.SubElement(comp, f"{{{SSD}}}ParameterBindings")
            ET.SubElement(bindings, f"{{{SSD}}}ParameterBinding", source=f"resources/{inst.name}.ssv")
        ann = ET.SubElement(ET.SubElement(comp, f"{{{SSD}}}Annotations"), f"{{{SSC}}}Annotation",
                            type="com.opensimulationplatform")
        ET.SubElement(ann, f"{{{OSP_ANN}}}StepSizeHint", value=repr(sc.step * inst.step_multiple))
    if sc.connections:
        conns = ET.SubElement(system, f"{{{SSD}}}Connections")
        for src, svar, dst, dvar in sc.connections:
            ET.SubElement(conns, f"{{{SSD}}}Connection", startElement=src, startConnector=svar,
                          endElement=dst, endConnector=dvar)
    _units_element(root, units, SSD)
    exp = ET.SubElement(root, f"{{{SSD}}}DefaultExperiment", startTime="0.0", stopTime=repr(sc.duration))
    ann = ET.SubElement(ET.SubElement(exp, f"{{{SSD}}}Annotations"), f"{{{SSC}}}Annotation",
                        type="com.opensimulationplatform")
    alg = ET.SubElement(ann, f"{{{OSP_ANN}}}Algorithm")
    ET.SubElement(alg, f"{{{OSP_ANN}}}FixedStepAlgorithm", baseStepSize=repr(sc.step))
    return _xml(root)


def events_document(sc: Scenario) -> dict[str, Any]:
    """The events as a libcosim scenario (JSON): override actions at their times."""
    events = []
    for t, inst, var, value in sc.events:
        vtype = sc.instance(inst).variables[var].type
        events.append({"time": t, "model": inst, "variable": var, "action": "override",
                       "value": value if vtype != "real" else float(value)})
    return {"description": f"events of seafmu scenario '{sc.name}'", "events": events, "end": sc.duration}


def load_events(path: Path) -> list[tuple[float, str, str, Any]]:
    """Events back from a libcosim scenario file, for engines that take them by API (ecos)."""
    doc = json.loads(Path(path).read_text())
    return [(float(e["time"]), e["model"], e["variable"], e["value"]) for e in doc["events"]]


def _checks_document(sc: Scenario) -> list[dict[str, Any]]:
    return [c.model_dump(exclude_none=True) for c in sc.checks]


def _beside(sc: Scenario, out: Export, events_path: Path, checks_path: Path) -> None:
    """The events and checks files beside the export; those of an earlier export to the same place
    are removed when this scenario has none (libcosim would run the old events on the new system)."""
    for path, has in ((events_path, sc.events), (checks_path, sc.checks)):
        if not has:
            path.unlink(missing_ok=True)
    if sc.events:
        events_path.write_text(json.dumps(events_document(sc), indent=2) + "\n")
        out.files.append(events_path)
        out.left_out.append(LeftOut(f"{len(sc.events)} events", [events_path], "libcosim scenario JSON"))
    if sc.checks:
        checks_path.write_text(yaml.safe_dump({"scenario": sc.name, "checks": _checks_document(sc)},
                                              sort_keys=False))
        out.files.append(checks_path)
        out.left_out.append(LeftOut(f"{len(sc.checks)} checks", [checks_path]))
    if sc.coupling != "jacobi":
        out.left_out.append(LeftOut(
            f"{sc.coupling} coupling", [],
            "libcosim and ecos couple as Jacobi, one step of delay per connection; "
            "'seafmu run --coupling jacobi' runs as they do"))


def _file_names(fmus: dict[str, Path]) -> dict[str, str]:
    """Instance -> the FMU's file name in the export, one per distinct file: two different files
    of one name (other/Minerva2Plant.fmu beside Minerva2Plant.fmu) get their instance's name added,
    so that neither replaces the other."""
    by_file: dict[Path, str] = {}
    out: dict[str, str] = {}
    for inst, path in fmus.items():
        key = path.resolve()
        if key not in by_file:
            name = path.name
            if name in by_file.values():
                name = f"{path.stem}_{inst}{path.suffix}"  # instance names are unique
            by_file[key] = name
        out[inst] = by_file[key]
    return out


def export_ssp(sc: Scenario, target: Path) -> Export:
    """Write ``target`` (.ssp: a zip of SystemStructure.ssd, resources/*.fmu, resources/*.ssv)."""
    target = check_ssp_target(target)
    fmus = fmu_sources(sc)
    names = _file_names(fmus)
    sources = {inst: f"resources/{name}" for inst, name in names.items()}
    out = Export()
    with tempfile.NamedTemporaryFile(dir=target.parent, suffix=".ssp.tmp", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    try:
        with zipfile.ZipFile(tmp_path, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("SystemStructure.ssd", ssd_document(sc, sources))
            for inst in sorted(fmus, key=lambda i: names[i]):
                if sources[inst] not in z.namelist():
                    z.write(fmus[inst], sources[inst])
            for inst in sc.instances:
                if inst.parameters:
                    z.writestr(f"resources/{inst.name}.ssv", _ssv(inst))
        tmp_path.replace(target)
    finally:
        tmp_path.unlink(missing_ok=True)
    out.files.append(target)
    stem = target.with_suffix("")
    _beside(sc, out, stem.with_name(stem.name + ".events.json"), stem.with_name(stem.name + ".checks.yaml"))
    return out


def osp_document(sc: Scenario, sources: dict[str, str]) -> bytes:
    """OspSystemStructure.xml: simulators (step sizes, initial values) and connections."""
    ET.register_namespace("", OSP_CFG)
    root = ET.Element(f"{{{OSP_CFG}}}OspSystemStructure", version="0.1")
    ET.SubElement(root, f"{{{OSP_CFG}}}StartTime").text = "0.0"
    ET.SubElement(root, f"{{{OSP_CFG}}}BaseStepSize").text = repr(sc.step)
    ET.SubElement(root, f"{{{OSP_CFG}}}Algorithm").text = "fixedStep"
    sims = ET.SubElement(root, f"{{{OSP_CFG}}}Simulators")
    for inst in sc.instances:
        sim = ET.SubElement(sims, f"{{{OSP_CFG}}}Simulator", name=inst.name, source=sources[inst.name],
                            stepSize=repr(sc.step * inst.step_multiple))
        if inst.parameters:
            ivs = ET.SubElement(sim, f"{{{OSP_CFG}}}InitialValues")
            for name, vtype, value, _unit in _parameters(inst):
                iv = ET.SubElement(ivs, f"{{{OSP_CFG}}}InitialValue", variable=name)
                ET.SubElement(iv, f"{{{OSP_CFG}}}{_SSP_TYPE[vtype]}", value=_value_text(value, vtype))
    conns = ET.SubElement(root, f"{{{OSP_CFG}}}Connections")
    for src, svar, dst, dvar in sc.connections:
        vc = ET.SubElement(conns, f"{{{OSP_CFG}}}VariableConnection")
        ET.SubElement(vc, f"{{{OSP_CFG}}}Variable", simulator=src, name=svar)
        ET.SubElement(vc, f"{{{OSP_CFG}}}Variable", simulator=dst, name=dvar)
    return _xml(root)


def export_osp(sc: Scenario, target: Path) -> Export:
    """Write ``target/``: OspSystemStructure.xml, the FMUs, scenario.json (events), checks.yaml."""
    target = check_osp_target(target)
    claim_output_folder(target)
    fmus = fmu_sources(sc)
    names = _file_names(fmus)
    out = Export()
    for inst in sorted(fmus, key=lambda i: names[i]):
        if target / names[inst] not in out.files:
            shutil.copyfile(fmus[inst], target / names[inst])
            out.files.append(target / names[inst])
    doc = target / "OspSystemStructure.xml"
    doc.write_bytes(osp_document(sc, names))
    out.files.insert(0, doc)
    _beside(sc, out, target / "scenario.json", target / "checks.yaml")
    return out
