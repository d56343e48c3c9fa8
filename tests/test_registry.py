"""Named GNC variants (components/registry.py): vessel files name them, blocks delegate to them, and
nothing infers a vessel kind from its DOF or thruster count."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from seafmu.components import registry
from seafmu.components.allocation import AllocationLaw, AllocatorBlock, thrust_capability
from seafmu.components.block import full_params
from seafmu.components.controller import ControllerBlock
from seafmu.components.dp_pid import DPPidController
from seafmu.components.guidance import PathGuidance
from seafmu.components.heading_autopilot import HeadingAutopilot
from seafmu.components.plant import PlantBlock
from seafmu.components.vessel_spec import VESSEL_DIR, VesselFileError, VesselSpec, load_vessel

COMPONENTS = Path(registry.__file__).parent


def block(cls: type, vessel: VesselSpec, **params: object):
    return cls(vessel, full_params(cls.interface(vessel), params))


def vessel_variant(tmp_path: Path, base: str, edit) -> VesselSpec:
    """A copy of a bundled vessel file with ``edit(doc)`` applied, loaded."""
    doc = yaml.safe_load((VESSEL_DIR / f"{base}.yaml").read_text())
    edit(doc)
    p = tmp_path / f"{base}_variant.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_vessel(p)


def test_every_registered_variant_resolves() -> None:
    for name in registry.CONTROLLERS:
        assert issubclass(registry.controller_class(name), ControllerBlock)
    for name in registry.ALLOCATORS:
        assert isinstance(registry.allocator_law(name), AllocationLaw)
    assert registry.guidance_class("none") is None
    assert registry.guidance_class("reference_point") is PathGuidance
    with pytest.raises(ValueError, match="unknown controller variant 'pid'; known: dp_pid, heading_auto"):
        registry.controller_class("pid")


@pytest.mark.parametrize("name, controller, allocator, guidance, cls", [
    ("minerva2", "dp_pid", "pinv", "reference_point", DPPidController),
    ("minerva2_published_damping", "dp_pid", "pinv", "reference_point", DPPidController),
    ("amv_osf", "heading_autopilot", "two_screw", "none", HeadingAutopilot),
    ("supply", "dp_pid", "qp", "reference_point", DPPidController),
])
def test_bundled_vessels_name_their_variants(name: str, controller: str, allocator: str, guidance: str,
                                             cls: type) -> None:
    vs = load_vessel(name)
    assert (vs.gnc.controller, vs.gnc.allocator, vs.gnc.guidance) == (controller, allocator, guidance)
    assert vs.provenance["gnc.controller"] and vs.provenance["gnc.allocator"]
    ctl = block(ControllerBlock, vs)
    assert type(ctl) is cls and isinstance(ctl, ControllerBlock)
    assert ControllerBlock.interface(vs) == cls.interface(vs)
    assert ctl.params["controller_variant"] == controller
    alloc = block(AllocatorBlock, vs)
    assert alloc.variant == allocator and alloc.params["allocator"] == allocator


def test_a_third_two_thruster_3dof_vessel_gets_what_its_file_names(tmp_path: Path) -> None:
    """The AMV's hull and screws under another name, naming dp_pid + pinv and no land data: the DP
    controller and the pseudo-inverse, not the AMV autopilot or the two-screw method."""
    def edit(doc: dict) -> None:
        doc["name"] = "twin_screw_dp"
        doc["gnc"] = {"controller": "dp_pid", "allocator": "pinv", "guidance": "reference_point"}
        del doc["extra"]

    vs = vessel_variant(tmp_path, "amv_osf", edit)
    assert vs.dof == 3 and vs.thrusters.count == 2
    ctl = block(ControllerBlock, vs)
    assert type(ctl) is DPPidController
    names = ControllerBlock.interface(vs).input_names()
    assert names[6:9] == ["north_ref", "east_ref", "yaw_ref"] and "surge_force_ref" not in names
    alloc = block(AllocatorBlock, vs)
    assert alloc.variant == "pinv"
    T = alloc.thrusts(np.array([10.0, 0.0, 1.0]))
    np.testing.assert_allclose(T, np.linalg.pinv(alloc.B) @ [10.0, 0.0, 1.0], atol=1e-12)
    assert thrust_capability(vs)[1] == 0.0  # pure sway is not producible: the DP saturation says so
    assert "land_mode" not in [p.name for p in PlantBlock.interface(vs).parameters]
    # the same vessel file naming the AMV's variants behaves like the AMV
    amv = load_vessel("amv_osf")
    assert type(block(ControllerBlock, amv)) is HeadingAutopilot
    assert "land_mode" in [p.name for p in PlantBlock.interface(amv).parameters]  # from extra.land


def test_dp_pid_in_3dof_holds_a_position(tmp_path: Path) -> None:
    """dp_pid is not a 6-DOF controller only: on the supply vessel it pushes back towards the setpoint."""
    vs = load_vessel("supply")
    ctl = block(ControllerBlock, vs)
    u = np.zeros(len(ControllerBlock.interface(vs).inputs))
    ctl.start(u)
    u[0], u[1] = 1.0, -2.0  # 1 m north, 2 m west of the setpoint, heading north
    tau = ctl.step(0.0, 0.1, u)[:3]
    assert tau[0] < 0.0 and tau[1] > 0.0


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("gnc"), "field 'gnc': missing"),
    (lambda d: d["gnc"].update(controller="autopilot"), "gnc.controller': unknown controller variant"),
    (lambda d: d["gnc"].update(allocator={"value": "lsq", "source": "x"}), "unknown allocator variant 'lsq'"),
    (lambda d: d["gnc"].update(guidance="los"), "unknown guidance variant 'los'"),
    (lambda d: d["gnc"].update(camera_thrusters=[0, 9]), "thruster numbers 1..7"),
    (lambda d: d["gnc"]["tuning"].update(kp={"value": 1, "source": "x"}), "unknown key(s) kp for controller"),
    (lambda d: d["gnc"].update(observer="ekf"), "unknown field(s) observer"),
    (lambda d: d.update(coriolis="partial"), "field 'coriolis': must be one of full, none"),
    (lambda d: d["thrusters"]["units"][0]["n_max"].update(unit="rad/s"), "unknown unit 'rad/s'"),
])
def test_vessel_file_errors_name_the_field(tmp_path: Path, edit, message: str) -> None:
    with pytest.raises(VesselFileError, match=re.escape(message)):
        vessel_variant(tmp_path, "minerva2", edit)


def test_controller_variant_parameter(tmp_path: Path) -> None:
    minerva = load_vessel("minerva2")
    assert type(block(ControllerBlock, minerva, controller_variant="dp_pid")) is DPPidController
    with pytest.raises(ValueError, match="parameter 'controller_variant': 'heading_autopilot' has another "
                                         "interface"):
        ControllerBlock(minerva, {**full_params(ControllerBlock.interface(minerva), {}),
                                  "controller_variant": "heading_autopilot"})
    with pytest.raises(ValueError, match="parameter 'controller_variant': unknown controller variant 'x'"):
        ControllerBlock(minerva, {**full_params(ControllerBlock.interface(minerva), {}),
                                  "controller_variant": "x"})
    ctl = block(ControllerBlock, minerva)
    with pytest.raises(ValueError, match="fixed after initialisation"):
        ctl.set_parameter("controller_variant", "dp_pid")
    # a vessel without guidance cannot enter waypoint mode
    def no_guidance(doc: dict) -> None:
        doc["gnc"]["guidance"] = "none"

    ctl = block(ControllerBlock, vessel_variant(tmp_path, "minerva2", no_guidance))
    with pytest.raises(ValueError, match="waypoint tracking needs a guidance variant"):
        ctl.set_parameter("mode", 1)


def _run(alloc: AllocatorBlock, taus: np.ndarray) -> np.ndarray:
    return np.array([alloc.step(0.1 * k, 0.1, tau) for k, tau in enumerate(taus)])


def test_allocator_parameter_chooses_the_variant() -> None:
    minerva, amv = load_vessel("minerva2"), load_vessel("amv_osf")
    rng = np.random.default_rng(3)
    taus = rng.normal(scale=[300, 300, 300, 150, 150, 400], size=(40, 6))
    by_name = _run(block(AllocatorBlock, minerva, allocator="qp"), taus)
    by_method = _run(block(AllocatorBlock, minerva, method=1), taus)
    np.testing.assert_array_equal(by_name, by_method)  # the integer selector is the same variant
    overridden = block(AllocatorBlock, minerva, allocator="pinv", method=1)
    assert overridden.variant == "qp"  # a non-zero method wins (existing scenarios)
    # AMV: the two-screw priority keeps the yaw moment in saturation, the pseudo-inverse does not
    tau = np.array([80.0, 0.0, 8.0])
    two = block(AllocatorBlock, amv)
    pinv = block(AllocatorBlock, amv, allocator="pinv")
    assert (two.B @ two.thrusts(tau))[2] == pytest.approx(8.0)
    assert (pinv.B @ pinv.thrusts(tau))[2] < 7.0
    # tunable during the run, checked by name
    two.set_parameter("allocator", "qp")
    assert two.variant == "qp" and two.step(0.0, 0.1, tau)[-1] >= 1  # QP iterations
    with pytest.raises(ValueError, match="parameter 'allocator': unknown allocator variant 'lsq'"):
        two.set_parameter("allocator", "lsq")
    assert two.variant == "qp"
    c = copy.deepcopy(two)
    assert c.variant == "qp"


def test_state_round_trip_keeps_the_variant() -> None:
    amv = load_vessel("amv_osf")
    a = block(AllocatorBlock, amv)
    a.set_parameter("allocator", "pinv")
    state = a.export_state()
    b = block(AllocatorBlock, amv)
    b.set_parameter("allocator", "pinv")
    b.import_state(state)
    tau = np.array([60.0, 0.0, 5.0])
    np.testing.assert_array_equal(a.step(0.0, 0.1, tau), b.step(0.0, 0.1, tau))


def test_no_kind_inference_in_the_gnc_blocks() -> None:
    """The blocks never decide what a vessel is from its thruster count or DOF count (the plant and
    the models still use the DOF count for the shape of their equations: 3-DOF or 6-DOF kinematics)."""
    pattern = re.compile(r"thrusters\.count\s*(==|<=|>=|<|>)|\.count\s*<=|\bdof\s*==|_two_screw\(")
    for name in ("controller.py", "heading_autopilot.py", "allocation.py", "plant.py", "registry.py"):
        text = (COMPONENTS / name).read_text()
        assert not pattern.search(text), (name, pattern.search(text).group(0))


def test_a_vessel_file_rewritten_at_once_is_read_again(tmp_path: Path) -> None:
    """Vessel files are parsed once per distinct text (a sweep validates every case against the same
    file): a rewrite of the same size in the same instant gives the new values, and changing what a
    load returned does not reach the next load."""
    text = (VESSEL_DIR / "minerva2.yaml").read_text()
    old, new = "n_max: {value: 20.0,", "n_max: {value: 21.0,"
    assert old in text
    path = tmp_path / "v.yaml"
    path.write_text(text)
    first = load_vessel(path)
    first.extra["changed by the caller"] = True
    first.M_RB[0, 0] = -1.0
    again = load_vessel(path)
    assert "changed by the caller" not in again.extra and again.M_RB[0, 0] == 2800.0
    assert np.all(again.thrusters.n_max == 20.0)
    path.write_text(text.replace(old, new))  # same size, no time passes
    assert np.all(load_vessel(path).thrusters.n_max == 21.0)
