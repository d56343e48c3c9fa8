"""``seafmu export``: SSP 1.0 and OSP files that validate and run in libcosim and ecos.

Engines run in child processes: libcosim aborts its host on some FMU errors, and each child
starts with a clean interpreter like a user's host would.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
import xmlschema

from seafmu.cli import main
from seafmu.export import ExportError, events_document, export_osp, export_ssp
from seafmu.scenario import load_scenario

RECORD = [("plant", "north"), ("plant", "east"), ("plant", "down"), ("plant", "yaw"),
          ("controller", "north_ref"), ("allocator", "n_cmd_1")]


def _xsd(name: str) -> xmlschema.XMLSchema:
    import pyssp_standard

    return xmlschema.XMLSchema(str(Path(pyssp_standard.__file__).parent / "resources" / name))


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory, built_fmus: object) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("export")
    sc = load_scenario("minerva2_dp")
    export_ssp(sc, out / "minerva2_dp.ssp")
    export_osp(sc, out / "osp")
    return {"ssp": out / "minerva2_dp.ssp", "events": out / "minerva2_dp.events.json",
            "checks": out / "minerva2_dp.checks.yaml", "osp": out / "osp"}


def test_ssd_and_ssv_validate_against_the_ssp_1_0_schema(exported: dict[str, Path]) -> None:
    with zipfile.ZipFile(exported["ssp"]) as z:
        names = z.namelist()
        ssd = z.read("SystemStructure.ssd").decode()
        ssvs = {n: z.read(n).decode() for n in names if n.endswith(".ssv")}
    assert list(_xsd("SystemStructureDescription.xsd").iter_errors(ssd)) == []
    schema = _xsd("SystemStructureParameterValues.xsd")
    assert set(ssvs) == {"resources/plant.ssv", "resources/controller.ssv"}
    for text in ssvs.values():
        assert list(schema.iter_errors(text)) == []
    assert {n for n in names if n.endswith(".fmu")} == {
        f"resources/Minerva2{k}.fmu" for k in ("Plant", "Observer", "Controller", "Allocator")}
    # connectors carry types and units, units carry SI exponents
    assert 'name="north" kind="output"' in ssd and 'unit="m"' in ssd
    assert '<ssc:Unit name="rev/s">' in ssd


def test_connector_names_are_unique_in_each_component(exported: dict[str, Path]) -> None:
    """controller.down_ref is an input with a start value: one input connector, its value in the
    parameter set (a second connector of the same name breaks SSP hosts that key by name: fmpy.ssp)."""
    with zipfile.ZipFile(exported["ssp"]) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
        controller_ssv = z.read("resources/controller.ssv").decode()
    ns = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription"}
    for comp in root.iterfind(".//ssd:Component", ns):
        names = [c.get("name") for c in comp.iterfind("ssd:Connectors/ssd:Connector", ns)]
        assert len(names) == len(set(names)), comp.get("name")
    ctrl = root.find(".//ssd:Component[@name='controller']", ns)
    assert [c.get("kind") for c in ctrl.iterfind("ssd:Connectors/ssd:Connector[@name='down_ref']", ns)] == [
        "input"]
    assert 'name="down_ref"' in controller_ssv


def test_parameters_are_bound_in_si(exported: dict[str, Path]) -> None:
    with zipfile.ZipFile(exported["ssp"]) as z:
        plant = z.read("resources/plant.ssv").decode()
    # scenario: current_direction: 45 deg, seed: 1 (integer)
    assert 'name="current_direction"' in plant and repr(np.pi / 4) in plant
    assert '<ssv:Integer value="1"' in plant


def test_events_and_checks_are_written_beside(exported: dict[str, Path]) -> None:
    doc = json.loads(exported["events"].read_text())
    assert [(e["time"], e["model"], e["variable"]) for e in doc["events"]] == [
        (40.0, "controller", "north_ref"), (100.0, "controller", "east_ref"),
        (160.0, "controller", "down_ref"), (220.0, "controller", "yaw_ref")]
    assert doc["events"][3]["value"] == pytest.approx(np.pi / 2)
    assert "heading setpoint reached" in exported["checks"].read_text()
    assert (exported["osp"] / "scenario.json").is_file() and (exported["osp"] / "checks.yaml").is_file()


def test_hardware_scenarios_are_refused_in_one_line(tmp_path: Path) -> None:
    sc = load_scenario(Path("scenarios/hil/minerva2_dp_emulator.yaml"))
    with pytest.raises(ExportError, match="hardware link cannot be exported") as err:
        export_ssp(sc, tmp_path / "x.ssp")
    assert "\n" not in str(err.value)
    with pytest.raises(ExportError, match=r"ends in \.ssp"):
        export_ssp(load_scenario("minerva2_dp"), tmp_path / "x.zip")


def test_events_document_keeps_types() -> None:
    sc = load_scenario("minerva2_dp")
    assert all(isinstance(e["value"], float) for e in events_document(sc)["events"])


_CHILD = """
import sys, numpy as np
from pathlib import Path
from seafmu import hosts
kind, path, events, out = sys.argv[1], Path(sys.argv[2]), sys.argv[3], sys.argv[4]
rec = [tuple(x.split('.')) for x in sys.argv[5].split(',')]
duration = float(sys.argv[6])
events = Path(events) if events != '-' else None
if kind == 'osp':
    r = hosts.run_osp_libcosim(path, rec, duration, 0.05)
elif kind == 'ssp':
    r = hosts.run_ssp_libcosim(path, rec, duration, 0.05, events)
else:
    r = hosts.run_ssp_ecos(path, rec, duration, 0.05, events)
np.savez(out, **r)
"""


def _run_engine(kind: str, path: Path, events: Path | None, out: Path,
                duration: float = 60.0) -> dict[str, np.ndarray]:
    rec = ",".join(f"{i}.{v}" for i, v in RECORD)
    proc = subprocess.run([sys.executable, "-c", _CHILD, kind, str(path), str(events or "-"), str(out), rec,
                           repr(duration)],
                          capture_output=True, text=True, timeout=300, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-2000:]
    with np.load(out) as data:
        return {k: data[k] for k in data.files}


def test_exported_files_run_alike_in_libcosim_and_ecos(exported: dict[str, Path], tmp_path: Path) -> None:
    osp = _run_engine("osp", exported["osp"], None, tmp_path / "osp.npz")
    ssp = _run_engine("ssp", exported["ssp"], exported["events"], tmp_path / "ssp.npz")
    eco = _run_engine("ecos", exported["ssp"], exported["events"], tmp_path / "ecos.npz")
    assert len(osp["plant.north"]) == 1201
    # the event at 40 s reached the controller in every engine, and the vessel moved north
    for res in (osp, ssp, eco):
        assert res["controller.north_ref"][-1] == 3.0
        assert res["plant.north"][-1] > 1.0
    # every row, the one after initialisation (t = 0) included
    assert osp["plant.down"][0] == 5.0  # the initial depth, not the FMU's start value
    for key in osp:
        np.testing.assert_allclose(ssp[key], osp[key], rtol=0, atol=1e-9)
        np.testing.assert_allclose(eco[key], osp[key], rtol=0, atol=1e-9)


def test_integer_events_run_alike_in_libcosim_and_ecos(tmp_path: Path, built_fmus: object) -> None:
    """A thruster failure is Integer events (fail_mode, enable): ecos took every event as Real and
    aborted its host ("Real property not found"); each now goes in as its FMI type."""
    sc = load_scenario("minerva2_thruster_failure")
    assert any(isinstance(v, int) and not isinstance(v, bool) for *_, v in sc.events)
    export_ssp(sc, tmp_path / "tf.ssp")
    export_osp(sc, tmp_path / "osp")
    osp = _run_engine("osp", tmp_path / "osp", None, tmp_path / "osp.npz", 70.0)  # the failure at 60 s
    eco = _run_engine("ecos", tmp_path / "tf.ssp", tmp_path / "tf.events.json", tmp_path / "ecos.npz", 70.0)
    assert osp["allocator.n_cmd_1"].shape == (1401,) and np.ptp(osp["allocator.n_cmd_1"][1200:]) > 0
    for key in osp:
        np.testing.assert_allclose(eco[key], osp[key], rtol=0, atol=1e-9)


# -- the command line: seafmu export -----------------------------------------------------------

def test_cli_export_writes_both_formats_and_one_left_out_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], built_fmus: object) -> None:
    code = main(["export", "minerva2_dp", "--ssp", str(tmp_path / "m.ssp"), "--osp", str(tmp_path / "osp")])
    out = capsys.readouterr().out.splitlines()
    assert code == 0
    wrote = [Path(line.removeprefix("wrote ")) for line in out if line.startswith("wrote ")]
    assert all(p.is_file() for p in wrote)
    fmus = {f"Minerva2{k}.fmu" for k in ("Plant", "Observer", "Controller", "Allocator")}
    assert {p.relative_to(tmp_path).as_posix() for p in wrote} == {
        "m.ssp", "m.events.json", "m.checks.yaml", "osp/OspSystemStructure.xml", "osp/scenario.json",
        "osp/checks.yaml", *(f"osp/{f}" for f in fmus)}
    left = [line for line in out if line.startswith("left out")]
    assert left == [out[-1]]
    assert f"4 events -> {tmp_path / 'm.events.json'}, {tmp_path / 'osp' / 'scenario.json'}" in left[0]
    assert "checks ->" in left[0]
    assert "gauss-seidel coupling (libcosim and ecos couple as Jacobi" in left[0]


def test_two_fmu_files_of_one_name_and_a_second_export_to_the_same_place(
        tmp_path: Path, built_fmus: dict) -> None:
    """Another file named like one of the scenario's FMUs keeps its own name in the export (it
    replaced the other before), and an export of a scenario without events or checks over an
    earlier one leaves none of the earlier events or checks for libcosim to run."""
    import shutil

    import yaml

    doc = yaml.safe_load((Path(__file__).resolve().parents[1] / "scenarios" / "minerva2_dp.yaml").read_text())
    (tmp_path / "other").mkdir()
    shutil.copy(built_fmus[("minerva2", "allocator")], tmp_path / "other" / "Minerva2Plant.fmu")
    doc["fmus"]["allocator"] = {"fmu": "other/Minerva2Plant.fmu"}
    doc["events"], doc["checks"] = [], []
    path = tmp_path / "same_name.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    export_osp(load_scenario("minerva2_dp"), tmp_path / "osp")
    export_ssp(load_scenario("minerva2_dp"), tmp_path / "m.ssp")
    assert (tmp_path / "osp" / "scenario.json").is_file() and (tmp_path / "m.events.json").is_file()
    sc = load_scenario(path)
    export_osp(sc, tmp_path / "osp")
    export_ssp(sc, tmp_path / "m.ssp")
    for stale in ("osp/scenario.json", "osp/checks.yaml", "m.events.json", "m.checks.yaml"):
        assert not (tmp_path / stale).exists(), stale
    root = ET.parse(tmp_path / "osp" / "OspSystemStructure.xml").getroot()
    sources = {s.get("name"): s.get("source") for s in root.iter() if s.tag.endswith("Simulator")}
    assert sources["plant"] == "Minerva2Plant.fmu" and sources["allocator"] == "Minerva2Plant_allocator.fmu"
    for name, kind in (("Minerva2Plant.fmu", "plant"), ("Minerva2Plant_allocator.fmu", "allocator")):
        assert (tmp_path / "osp" / name).read_bytes() == Path(built_fmus[("minerva2", kind)]).read_bytes()
    with zipfile.ZipFile(tmp_path / "m.ssp") as z:
        names = z.namelist()
        assert len(names) == len(set(names))
        assert z.read("resources/Minerva2Plant_allocator.fmu") == (tmp_path / "osp" /
                                                                   "Minerva2Plant_allocator.fmu").read_bytes()


def test_cli_export_of_jacobi_scenarios_leaves_the_coupling_in(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], built_fmus: object) -> None:
    dp = tmp_path / "dp.yaml"
    dp.write_text(Path("scenarios/minerva2_dp.yaml").read_text() + "coupling: jacobi\n")
    assert main(["export", str(dp), "--osp", str(tmp_path / "osp")]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("left out (not expressible in SSP/OSP): 4 events") and "coupling" not in last
    bare = tmp_path / "bare.yaml"
    bare.write_text("name: bare\nvessel: amv_osf\nduration: 1\nstep: 0.05\ncoupling: jacobi\n")
    assert main(["export", str(bare), "--ssp", str(tmp_path / "bare.ssp")]) == 0
    assert capsys.readouterr().out.splitlines() == [f"wrote {tmp_path / 'bare.ssp'}", "left out: nothing"]


@pytest.mark.parametrize(("args", "message"), [
    (["minerva2_dp"], "nothing to write: give --ssp FILE.ssp and/or --osp DIR"),
    (["minerva2_dp", "--ssp", "{tmp}/m.zip"], "m.zip: an SSP file name ends in .ssp"),
    (["minerva2_dp", "--osp", "{tmp}/no/such"], "folder {tmp}/no does not exist"),
    (["minerva2_dp", "--ssp", "{tmp}/ok.ssp", "--osp", "{tmp}/no/such"], "folder {tmp}/no does not exist"),
    (["scenarios/hil/minerva2_dp_emulator.yaml", "--ssp", "{tmp}/h.ssp"], "hardware link cannot be exported"),
    (["no_such_scenario", "--osp", "{tmp}/osp"], "no such file or shipped scenario"),
    (["{tmp}/bad.yaml", "--osp", "{tmp}/osp"], "bad.yaml: coupling:"),
])
def test_cli_export_bad_input_is_one_line_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str) -> None:
    (tmp_path / "bad.yaml").write_text("name: bad\nvessel: amv_osf\nduration: 1\nstep: 0.05\n"
                                       "coupling: parallel\n")
    before = set(tmp_path.iterdir())
    code = main(["export", *(a.format(tmp=tmp_path) for a in args)])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.startswith("seafmu: error: ") and err.count("\n") == 1
    assert message.format(tmp=tmp_path) in err
    assert set(tmp_path.iterdir()) == before  # nothing written
