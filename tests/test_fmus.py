"""The FMUs: valid modelDescription, all four in one process, state round trip, readable errors,
and the same trajectory as the components composed in-process without FMI."""

from __future__ import annotations

import dataclasses
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from seafmu.build import KINDS, VESSELS, build_fmu
from seafmu.master import FmuUnit, SimulationError, run
from seafmu.scenario import Instance, interface_variables, load_scenario


@pytest.mark.parametrize("vessel", VESSELS)
@pytest.mark.parametrize("kind", KINDS)
def test_model_description_validates_clean(built_fmus: dict, vessel: str, kind: str) -> None:
    path = built_fmus[(vessel, kind)]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.coSimulation.canGetAndSetFMUstate
    real = {v.name: v for v in md.modelVariables if v.type == "Real"}
    # units and ranges reach the modelDescription
    if kind == "plant":
        assert real["north"].unit == "m"
        assert real["n_cmd_1"].unit == "rev/s" and real["n_cmd_1"].max is not None
    assert len(md.outputs) == len(md.initialUnknowns) > 0


def test_interfaces_are_exact_for_each_vessel(built_fmus: dict) -> None:
    for vessel, n_thr in (("minerva2", 7), ("amv_osf", 2)):
        md = read_model_description(str(built_fmus[(vessel, "plant")]))
        inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        assert inputs == [f"n_cmd_{i}" for i in range(1, n_thr + 1)]
        md = read_model_description(str(built_fmus[(vessel, "allocator")]))
        outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        assert [f"n_cmd_{i}" for i in range(1, n_thr + 1)] == [o for o in outputs if o.startswith("n_cmd_")]


def test_build_is_incremental(built_fmus: dict) -> None:
    assert not build_fmu("minerva2", "plant").rebuilt  # nothing changed since the session build


def test_fmu_bundles_components(built_fmus: dict) -> None:
    names = zipfile.ZipFile(built_fmus[("minerva2", "plant")]).namelist()
    bundles = {n.split("/")[1] for n in names if n.startswith("resources/seafmu_fmu_")}
    assert len(bundles) == 1  # one package name, unique to this build
    (bundle,) = bundles
    assert f"resources/{bundle}/components/plant.py" in names
    assert f"resources/{bundle}/components/vessels/minerva2.yaml" in names
    assert f"resources/{bundle}/fmus/_slave.py" in names
    assert not any(n.startswith(("resources/components/", "resources/fmus/")) for n in names)
    assert [n for n in names if n.startswith("resources/minerva2_plant_fmu_")]
    assert "resources/requirements.txt" in names


def test_fmu_bytecode_is_checked_hash_of_its_own_sources(built_fmus: dict) -> None:
    """Every Python file in an FMU has this interpreter's pyc beside it, validated by the source's
    hash (flags 0b11), so a fresh unpack does not compile the FMU again and a pyc can never be stale;
    there is no other bytecode (no time-stamped pyc of some earlier source)."""
    import importlib.util

    with zipfile.ZipFile(built_fmus[("minerva2", "plant")]) as z:
        names = set(z.namelist())
        sources = sorted(n for n in names if n.startswith("resources/") and n.endswith(".py"))
        assert len(sources) > 20
        expected = set()
        for src in sources:
            folder, stem = src.rsplit("/", 1)
            pyc = f"{folder}/__pycache__/{stem[:-3]}.{sys.implementation.cache_tag}.pyc"
            expected.add(pyc)
            assert pyc in names, pyc
            head = z.read(pyc)[:16]
            assert head[:4] == importlib.util.MAGIC_NUMBER
            assert int.from_bytes(head[4:8], "little") == 0b11
            assert head[8:16] == importlib.util.source_hash(z.read(src))
        assert {n for n in names if "__pycache__" in n} == expected


def _instance(vessel: str, kind: str, params: dict | None = None) -> Instance:
    return Instance(kind, kind, None, 1, params or {}, interface_variables(vessel, kind))


def test_state_round_trip_plant(built_fmus: dict) -> None:
    log: list[str] = []
    unit = FmuUnit(_instance("minerva2", "plant", {"seed": 3}), built_fmus[("minerva2", "plant")], [], log)
    fmu = unit.fmu
    md = read_model_description(str(built_fmus[("minerva2", "plant")]))
    vr_in = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    unit.initialize(np.zeros(0))
    fmu.setReal(vr_in, [10.0, 10.0, 10.0, 10.0, 5.0, -3.0, 3.0])
    h = 0.05
    for k in range(40):
        unit.do_step(k * h, h)
    state = fmu.getFMUstate()
    blob = fmu.serializeFMUstate(state)
    first = []
    for k in range(40, 80):
        unit.do_step(k * h, h)
        first.append(unit.get_outputs().copy())
    fmu.setFMUstate(state)
    again = []
    for k in range(40, 80):
        unit.do_step(k * h, h)
        again.append(unit.get_outputs().copy())
    np.testing.assert_array_equal(np.array(first), np.array(again))  # noise stream included
    fmu.setFMUstate(fmu.deSerializeFMUstate(blob))
    unit.do_step(40 * h, h)
    np.testing.assert_array_equal(unit.get_outputs(), first[0])
    assert np.ptp(np.array(first)[:, 0]) > 0  # the vessel moved: the test compares a real trajectory
    unit.terminate()


@pytest.mark.parametrize("kind", KINDS)
def test_state_round_trip_every_kind_in_the_loop(built_fmus: dict, kind: str) -> None:
    """Each FMU, fed the inputs it sees in the DP scenario, continues bit-identically from a saved
    state: the EKF covariance, integrators, reference model and noise stream are all captured."""
    sc = load_scenario("minerva2_dp")
    sc = dataclasses.replace(sc, duration=60.0, record_every=1, events=[e for e in sc.events if e[0] <= 60])
    rec = run(sc, mode="inprocess", progress=False)
    conns = [(si, sv, dv) for si, sv, di, dv in sc.connections if di == kind]
    log: list[str] = []
    unit = FmuUnit(sc.instance(kind), built_fmus[("minerva2", kind)], [dv for _, _, dv in conns], log)
    inputs = np.column_stack([rec.signals[f"{si}.{sv}"] for si, sv, _ in conns])
    unit.initialize(inputs[0])
    h = sc.step

    def advance(k0: int, k1: int) -> np.ndarray:
        out = []
        for k in range(k0, k1):
            unit.set_inputs(inputs[k])
            unit.do_step(k * h, h)
            out.append(unit.get_outputs().copy())
        return np.array(out)

    advance(0, 800)  # past the 40 s setpoint step: integrators and filters are non-trivial
    state = unit.fmu.getFMUstate()
    first = advance(800, 900)
    unit.fmu.setFMUstate(state)
    again = advance(800, 900)
    np.testing.assert_array_equal(first, again)
    assert np.ptp(first, axis=0).max() > 0  # outputs moved during the compared stretch
    unit.fmu.freeFMUstate(state)
    unit.terminate()


def test_bad_parameter_gives_readable_fmi_error(built_fmus: dict) -> None:
    log: list[str] = []
    # another FMU instantiated later must not steal the plant's log messages
    other = FmuUnit(_instance("minerva2", "controller"), built_fmus[("minerva2", "controller")], [], log)
    unit = FmuUnit(_instance("minerva2", "plant", {"noise_scale": -1.0}), built_fmus[("minerva2", "plant")],
                   [], log)
    with pytest.raises(SimulationError) as err:
        unit.initialize(np.zeros(0))
    unit.terminate()  # freed: no instance of this test outlives it (test_fmu_state counts them)
    assert "exitInitializationMode" in str(err.value) and "noise_scale" in str(err.value)
    assert str(err.value).startswith("FMU 'plant' failed") and "\n" not in str(err.value)
    assert any(m.startswith("plant: ") and "noise_scale" in m for m in log)
    other.terminate()


def test_bad_vessel_file_parameter(built_fmus: dict, tmp_path: Path) -> None:
    log: list[str] = []
    from seafmu.components.vessel_spec import vessel_path

    # a missing file, and a vessel file with another interface (2 screws): refused, not mis-wired
    refused = ((tmp_path / "missing.yaml", r"missing\.yaml"), (vessel_path("amv_osf"), "another interface"))
    for given, why in refused:
        unit = FmuUnit(_instance("minerva2", "plant", {"vessel_file": str(given)}),
                       built_fmus[("minerva2", "plant")], [], log)
        with pytest.raises(SimulationError, match=why):
            unit.initialize(np.zeros(0))
        unit.terminate()


@pytest.mark.parametrize("scenario", ["minerva2_dp", "amv_osf_autopilot"])
def test_fmu_run_equals_inprocess_composition(built_fmus: dict, scenario: str) -> None:
    sc = load_scenario(scenario)
    sc = dataclasses.replace(sc, duration=60.0, events=[e for e in sc.events if e[0] <= 60.0])
    fmu = run(sc, mode="fmu", progress=False)
    ref = run(sc, mode="inprocess", progress=False)
    assert fmu.signals.keys() == ref.signals.keys()
    for k in ref.signals:
        np.testing.assert_allclose(fmu.signals[k], ref.signals[k], rtol=0, atol=1e-9, err_msg=k)
    moved = np.ptp(ref.signals["plant.north"]) + np.ptp(ref.signals["plant.yaw"])
    assert moved > 0.1


def test_all_four_fmus_of_both_vessels_in_one_process(built_fmus: dict) -> None:
    log: list[str] = []
    units = [FmuUnit(_instance(v, k), built_fmus[(v, k)], [], log) for v in VESSELS for k in KINDS]
    for u in units:
        u.initialize(np.zeros(0))
        u.do_step(0.0, 0.05)
        assert np.all(np.isfinite(u.get_outputs()))
    for u in units:
        u.terminate()


def test_same_fmu_instantiated_many_times_in_one_process(built_fmus: dict) -> None:
    """pythonfmu 0.7.0 drops a reference to the slave module's globals per instantiation;
    seafmu's slave compensates. Without it the third instantiate fails or crashes."""
    log: list[str] = []
    for _ in range(8):
        unit = FmuUnit(_instance("amv_osf", "allocator"), built_fmus[("amv_osf", "allocator")], [], log)
        unit.initialize(np.zeros(0))
        unit.do_step(0.0, 0.1)
        unit.terminate()
    assert log == []
