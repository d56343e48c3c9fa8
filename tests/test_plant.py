"""PlantBlock: interface, Block contract, sensors, current, determinism (no FMI)."""

from __future__ import annotations

import copy
import dataclasses
import math
import re

import numpy as np
import pytest

from seafmu.components.block import Block
from seafmu.components.plant import PlantBlock
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel

# Appended by the environment/sensor-fault work (issue 5): new names only, after the old ones.
ENV_PARAMS = [
    "wave_hs", "wave_tp", "wave_direction", "wave_gamma", "wave_components", "current_variation",
    "current_time_constant", "mag_fault_amplitude", "usbl_outlier_rate", "usbl_outlier_size",
    "usbl_dropout_start", "usbl_dropout_length",
]  # fmt: skip
ENV_OUTPUTS_3DOF = [
    "wave_elevation", "tau_wave_X", "tau_wave_Y", "tau_wave_N", "current_north", "current_east",
    "mag_heading_error", "pos_fix_outliers", "pos_fix_dropout",
]  # fmt: skip


def run(block: PlantBlock, inputs: np.ndarray, h: float, t0: float = 0.0) -> np.ndarray:
    """Step once per row of ``inputs``; outputs after each step."""
    out = []
    for k, u in enumerate(inputs):
        out.append(block.step(t0 + k * h, h, u))
    return np.array(out)


# -- interface ------------------------------------------------------------------------------------
def test_interface_amv(amv: VesselSpec) -> None:
    iface = PlantBlock.interface(amv)
    assert PlantBlock.kind == "plant" and issubclass(PlantBlock, Block)
    assert iface.input_names() == ["n_cmd_1", "n_cmd_2"]
    assert iface.inputs[0].min == -2.3 and iface.inputs[0].max == 2.3 and iface.inputs[0].unit == "rev/s"
    assert "screw_port" in iface.inputs[0].description
    assert iface.output_names()[:22] == [
        "north", "east", "yaw", "u", "v", "r", "n_1", "n_2", "thrust_1", "thrust_2",
        "meas_north", "meas_east", "gnss_count", "meas_yaw", "compass_count", "meas_r", "gyro_count",
        "meas_u", "meas_v", "speed_count", "course", "sog",
    ]  # fmt: skip
    assert iface.output_names()[22:] == ENV_OUTPUTS_3DOF
    units = {s.name: s.unit for s in iface.outputs}
    assert units["north"] == "m" and units["yaw"] == "rad" and units["u"] == "m/s" and units["r"] == "rad/s"
    assert units["meas_yaw"] == "rad" and units["thrust_1"] == "N" and units["n_2"] == "rev/s"
    params = {p.name: p for p in iface.parameters}
    assert list(params) == [
        "seed", "noise_scale", "current_speed", "current_direction",
        "north_0", "east_0", "yaw_0", "u_0", "v_0", "r_0", "substep",
        "fail_mode_1", "fail_mode_2", "fail_value_1", "fail_value_2",
        "thruster_efficiency_1", "thruster_efficiency_2", *ENV_PARAMS, "land_mode",
    ]  # fmt: skip
    assert params["seed"].type == "integer" and params["seed"].start == 0
    assert params["noise_scale"].start == 1.0 and params["noise_scale"].min == 0
    assert params["current_speed"].tunable and params["current_direction"].tunable
    assert not params["noise_scale"].tunable and not params["seed"].tunable
    assert params["substep"].start == 0.01 and params["substep"].min > 0


def test_interface_minerva(minerva: VesselSpec) -> None:
    iface = PlantBlock.interface(minerva)
    names = iface.output_names()
    assert iface.input_names() == [f"n_cmd_{i}" for i in range(1, 8)]
    assert names[:12] == ["north", "east", "down", "roll", "pitch", "yaw", "u", "v", "w", "p", "q", "r"]
    assert names[12:26] == [f"n_{i}" for i in range(1, 8)] + [f"thrust_{i}" for i in range(1, 8)]
    assert names[26:45] == [
        "meas_north", "meas_east", "usbl_count", "meas_down", "depth_count",
        "meas_roll", "meas_pitch", "meas_yaw", "ahrs_count", "meas_u", "meas_v", "meas_w", "dvl_count",
        "meas_p", "meas_q", "meas_r", "gyro_count", "course", "sog",
    ]  # fmt: skip
    assert names[45:] == ["wave_elevation"] + [f"tau_wave_{t}" for t in "XYZKMN"] + ENV_OUTPUTS_3DOF[4:]
    block = PlantBlock(minerva, {})
    assert block.output().shape == (len(names),)


def test_initial_outputs_and_thrust_consistency(amv: VesselSpec) -> None:
    block = PlantBlock(amv, {"north_0": 3.0, "yaw_0": 4.0, "u_0": 0.5, "noise_scale": 0.0})
    y = dict(zip(PlantBlock.interface(amv).output_names(), block.output(), strict=True))
    assert y["north"] == 3.0 and y["u"] == 0.5
    assert y["yaw"] == pytest.approx(4.0 - 2 * math.pi)  # wrapped to (-pi, pi]
    assert y["meas_yaw"] == y["yaw"] and y["gnss_count"] == 1.0  # initial state is the first sample
    out = run(block, np.tile([2.0, -1.0], (50, 1)), 0.1)
    y = dict(zip(PlantBlock.interface(amv).output_names(), out[-1], strict=True))
    assert y["thrust_1"] == pytest.approx(12.63 * y["n_1"])
    assert y["thrust_2"] == pytest.approx(12.63 * y["n_2"])
    assert all(-math.pi < o <= math.pi for o in out[:, 2])


# -- contract: errors -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"noise_scale": -1}, "parameter 'noise_scale' must be within [0, 100], got -1"),
        ({"seed": -3}, "parameter 'seed' must be >= 0"),
        ({"seed": 1.5}, "parameter 'seed' must be an integer"),
        ({"substep": 0.0}, "parameter 'substep' must be >= "),
        ({"current_speed": -0.1}, "parameter 'current_speed' must be within [0, 10]"),
        ({"current_speed": 11.0}, "parameter 'current_speed' must be within [0, 10]"),
        ({"current_direction": float("nan")}, "parameter 'current_direction' must be finite"),
        ({"yaw_0": "north"}, "parameter 'yaw_0' must be a number"),
        ({"u_0": float("inf")}, "parameter 'u_0' must be finite"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_parameters_raise_naming_them(amv: VesselSpec, params: dict, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)) as exc:
        PlantBlock(amv, params)
    assert "\n" not in str(exc.value)


def test_bad_inputs_raise_naming_them(minerva: VesselSpec) -> None:
    block = PlantBlock(minerva, {})
    u = np.zeros(7)
    u[2] = np.nan
    with pytest.raises(ValueError, match="n_cmd_3"):
        block.step(0.0, 0.1, u)
    u[2] = 0.0
    u[6] = -np.inf
    with pytest.raises(ValueError, match="n_cmd_7"):
        block.step(0.0, 0.1, u)
    with pytest.raises(ValueError, match="7 inputs"):
        block.step(0.0, 0.1, np.zeros(6))
    with pytest.raises(ValueError, match="step size"):
        block.step(0.0, 0.0, np.zeros(7))
    block.step(0.0, 0.1, np.full(7, 1e300))  # huge but finite: clipped to n_max, not an error
    assert np.all(np.isfinite(block.output()))


def test_set_parameter(amv: VesselSpec) -> None:
    block = PlantBlock(amv, {})
    block.set_parameter("current_speed", 0.3)
    block.set_parameter("current_direction", 1.0)
    with pytest.raises(ValueError, match=r"parameter 'current_speed' must be within \[0, 10\]"):
        block.set_parameter("current_speed", -1.0)
    assert block.params["current_speed"] == 0.3  # a rejected value leaves the old one
    with pytest.raises(ValueError, match="noise_scale"):
        block.set_parameter("noise_scale", 0.0)  # fixed after initialisation
    with pytest.raises(ValueError, match="unknown parameter"):
        block.set_parameter("nope", 0.0)


# -- contract: state and determinism --------------------------------------------------------------
@pytest.mark.parametrize("name", ["amv_osf", "minerva2"])
def test_deepcopy_round_trip_is_bit_identical(name: str) -> None:
    spec = load_vessel(name)
    rng = np.random.default_rng(5)
    m = spec.thrusters.count
    inputs = rng.uniform(-1, 1, (400, m)) * spec.thrusters.n_max
    block = PlantBlock(spec, {"seed": 42, "current_speed": 0.2, "current_direction": 0.7, "substep": 0.02})
    run(block, inputs[:100], 0.05)
    saved = copy.deepcopy(block)  # FMU get state
    a = run(block, inputs[100:], 0.05, t0=5.0)
    restored = copy.deepcopy(saved)  # FMU set state
    b = run(restored, inputs[100:], 0.05, t0=5.0)
    c = run(saved, inputs[100:], 0.05, t0=5.0)  # the snapshot itself was not disturbed
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    assert restored.vessel is block.vessel  # immutable data shared, not copied


def test_same_seed_same_run_different_seed_different(minerva: VesselSpec) -> None:
    inputs = np.tile([5, 5, 5, 5, 2, 0, 0.0], (200, 1))
    a = run(PlantBlock(minerva, {"seed": 1}), inputs, 0.05)
    b = run(PlantBlock(minerva, {"seed": 1}), inputs, 0.05)
    c = run(PlantBlock(minerva, {"seed": 2}), inputs, 0.05)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[:, :26], c[:, :26])  # the true state does not depend on the seed
    meas = [i for i, n in enumerate(PlantBlock.interface(minerva).output_names()) if n.startswith("meas_")]
    assert np.all(a[-1, meas] != c[-1, meas])


def test_adding_a_sensor_leaves_the_others_noise_unchanged(amv: VesselSpec) -> None:
    # Output names must be unique (the block reads and writes them by name): the base vessel's
    # speed log measures u only, the added sensor v.
    speed = amv.sensors[-1]
    base = dataclasses.replace(amv, sensors=[*amv.sensors[:-1], dataclasses.replace(
        speed, channels=["u"], noise_std=speed.noise_std[:1], bias=speed.bias[:1])])
    extra = dataclasses.replace(speed, name="log2", channels=["v"], noise_std=speed.noise_std[1:],
                                bias=speed.bias[1:])
    bigger = dataclasses.replace(base, sensors=[*base.sensors, extra])
    amv = base
    inputs = np.tile([1.0, 0.8], (100, 1))
    a = run(PlantBlock(amv, {"seed": 9}), inputs, 0.1)
    b = run(PlantBlock(bigger, {"seed": 9}), inputs, 0.1)
    k = PlantBlock.interface(amv).output_names().index("course")  # course, sog, env. after the sensors
    np.testing.assert_array_equal(a[:, :k], b[:, :k])
    np.testing.assert_array_equal(a[:, k:], b[:, k - a.shape[1] :])  # what follows the sensors


# -- sensors --------------------------------------------------------------------------------------
@pytest.mark.parametrize("h", [0.01, 0.05, 0.025])
def test_sample_counts_follow_rates(minerva: VesselSpec, h: float) -> None:
    duration = 10.0
    steps = round(duration / h)
    block = PlantBlock(minerva, {})
    out = run(block, np.zeros((steps, 7)), h)
    names = PlantBlock.interface(minerva).output_names()
    for s in minerva.sensors:
        count = out[:, names.index(f"{s.name}_count")]
        expected = min(s.rate_hz, 1.0 / h)  # at most one sample per co-simulation step
        assert count[-1] == 1 + round(duration * expected), s.name
        assert set(np.diff(count)) <= {0.0, 1.0}


def test_one_sample_per_step_when_step_longer_than_period(amv: VesselSpec) -> None:
    block = PlantBlock(amv, {})
    out = run(block, np.zeros((20, 2)), 0.2)  # gyro is 20 Hz, steps are 5 Hz
    count = out[:, PlantBlock.interface(amv).output_names().index("gyro_count")]
    np.testing.assert_array_equal(np.diff(count), 1.0)


def test_perfect_sensors_sample_true_state_and_hold(minerva: VesselSpec) -> None:
    names = PlantBlock.interface(minerva).output_names()
    block = PlantBlock(minerva, {"noise_scale": 0.0, "yaw_0": 3.1, "r_0": 0.3})
    inputs = np.tile([8, 3, -4, 6, 5, 2, -2.0], (300, 1))
    out = run(block, inputs, 0.02)
    for s in minerva.sensors:
        count = out[:, names.index(f"{s.name}_count")]
        for c in s.channels:
            meas, true = out[:, names.index(f"meas_{c}")], out[:, names.index(c)]
            new = np.diff(count, prepend=1.0) > 0
            np.testing.assert_array_equal(meas[new], true[new])
            held = ~new
            np.testing.assert_array_equal(meas[1:][held[1:]], meas[:-1][held[1:]])
    assert np.ptp(out[:, names.index("yaw")]) > math.pi  # yaw crossed +-pi; meas wrapped like truth


def test_noise_statistics(amv: VesselSpec) -> None:
    """At rest the true state is exactly zero, so measurements are pure bias + noise."""
    bias = np.array([0.3, -0.1])
    gnss = dataclasses.replace(amv.sensors[0], bias=bias)
    spec = dataclasses.replace(amv, sensors=[gnss, *amv.sensors[1:]])
    names = PlantBlock.interface(spec).output_names()
    for scale in (1.0, 2.0):
        block = PlantBlock(spec, {"seed": 3, "noise_scale": scale, "substep": 0.2})
        out = run(block, np.zeros((2000, 2)), 0.2)  # 5 Hz gnss: a new sample every step
        assert np.all(out[:, :6] == 0.0)
        for j, c in enumerate(["north", "east"]):
            x = out[:, names.index(f"meas_{c}")]
            n = len(x)
            std = 0.05 * scale
            assert abs(x.mean() - scale * bias[j]) < 4 * std / math.sqrt(n)
            assert abs(x.std(ddof=1) / std - 1) < 4 / math.sqrt(2 * n)  # ~ 4 standard errors
        yaw = out[:, names.index("meas_yaw")]
        assert abs(yaw.std(ddof=1) / (0.01 * scale) - 1) < 4 / math.sqrt(2 * len(yaw))


# -- substeps and current ---------------------------------------------------------------------------
def test_substeps_are_equal_rk4_steps(minerva: VesselSpec) -> None:
    model = VesselModel(minerva)
    u = np.array([8, 3, -4, 6, 5, 2, -2.0])
    for h, substep, steps in [(0.05, 0.01, 5), (0.025, 0.01, 3), (0.03, 0.01, 3), (0.01, 0.02, 1)]:
        block = PlantBlock(minerva, {"substep": substep, "u_0": 0.3, "r_0": 0.1})
        block.step(0.0, h, u)
        x0 = model.initial_state(np.zeros(6), [0.3, 0, 0, 0, 0, 0.1])
        x = model.rk4(x0, model.clip(u), h / steps, steps)
        np.testing.assert_array_equal(block.state, x)


@pytest.mark.parametrize(("name", "duration"), [("amv_osf", 300.0), ("minerva2", 600.0)])
def test_vessel_drifts_with_current_towards_its_direction(name: str, duration: float) -> None:
    """Current of 0.2 m/s flowing TOWARDS east (pi/2): an unpowered vessel ends up moving east at 0.2.

    Damping is purely quadratic in sway (D_L = 0), so the relative speed only decays like
    M_vv / (d_Q,vv t): that, not a fixed number, is the tolerance."""
    spec = load_vessel(name)
    if spec.restoring is not None:  # neutral buoyancy, so the ROV does not also rise
        rs = dataclasses.replace(spec.restoring, buoyancy=spec.restoring.weight)
        spec = dataclasses.replace(spec, restoring=rs)
    h = 0.5
    block = PlantBlock(spec, {"current_speed": 0.2, "current_direction": math.pi / 2, "yaw_0": 0.5,
                              "substep": 0.05})
    out = run(block, np.zeros((round(duration / h), spec.thrusters.count)), h)
    window = round(20.0 / h)
    v_east = (out[-1, 1] - out[-1 - window, 1]) / 20.0
    v_north = (out[-1, 0] - out[-1 - window, 0]) / 20.0
    tol = 2.0 * VesselModel(spec).M[1, 1] / (spec.D_Q[1, 1] * duration)
    assert 0.2 - tol < v_east <= 0.2 + 1e-6 and abs(v_north) < tol
    d = spec.dof
    nu_c = block.model.current_body(out[-1, :d], 0.0, 0.2)
    assert np.max(np.abs(out[-1, d : 2 * d] - nu_c)) < tol  # small relative velocity in the body frame


def test_current_is_tunable_during_run(amv: VesselSpec) -> None:
    block = PlantBlock(amv, {})
    run(block, np.zeros((10, 2)), 0.1)
    assert np.all(block.state == 0.0)
    block.set_parameter("current_speed", 0.5)
    run(block, np.zeros((10, 2)), 0.1, t0=1.0)
    assert block.state[0] > 0.0  # carried north


def test_course_and_speed_over_ground(amv: VesselSpec) -> None:
    """Course = heading + crab angle: with a sway current the two differ by atan2(v, u)."""
    p = PlantBlock(amv, {"noise_scale": 0.0, "current_speed": 0.2, "current_direction": -np.pi / 2})
    y = p.start(np.zeros(2))
    for k in range(600):
        y = p.step(k * 0.05, 0.05, np.array([1.0, 1.0]))
    names = PlantBlock.interface(amv).output_names()
    out = dict(zip(names, y, strict=True))
    vn = out["u"] * np.cos(out["yaw"]) - out["v"] * np.sin(out["yaw"])
    ve = out["u"] * np.sin(out["yaw"]) + out["v"] * np.cos(out["yaw"])
    assert out["sog"] == pytest.approx(np.hypot(vn, ve), rel=1e-12)
    assert out["course"] == pytest.approx(np.arctan2(ve, vn), abs=1e-12)
    assert abs(out["course"] - out["yaw"]) > 0.05  # drifting west: course is not the heading


# -- thruster failures (issue 5) --------------------------------------------------------------------
def test_failure_parameters_are_declared_per_thruster_and_tunable(minerva: VesselSpec) -> None:
    spec = {p.name: p for p in PlantBlock.interface(minerva).parameters}
    for i in range(1, 8):
        assert {f"fail_mode_{i}", f"fail_value_{i}", f"thruster_efficiency_{i}"} <= set(spec)
    mode = spec["fail_mode_3"]
    assert mode.type == "integer" and mode.tunable and mode.min == 0 and mode.max == 2
    assert spec["fail_value_3"].unit == "rev/s" and spec["fail_value_3"].tunable
    assert spec["fail_value_3"].min == -20.0 and spec["fail_value_3"].max == 20.0
    eff = spec["thruster_efficiency_3"]
    assert eff.tunable and (eff.min, eff.max, eff.start) == (0.0, 1.5, 1.0)


def test_failed_thruster_ignores_its_command(minerva: VesselSpec) -> None:
    """Stuck at zero, stuck at a value, repaired: the shaft follows the lag to what the drive does."""
    block = PlantBlock(minerva, {"noise_scale": 0.0})
    names = PlantBlock.interface(minerva).output_names()
    i_n, i_T = names.index("n_1"), names.index("thrust_1")
    cmd = np.full(7, 10.0)
    y = run(block, np.tile(cmd, (40, 1)), 0.05)[-1]  # 2 s = 10 shaft time constants
    np.testing.assert_allclose(y[i_n : i_n + 7], 10.0, atol=1e-3)
    block.set_parameter("fail_mode_3", 1)  # stuck at zero
    assert block.failed == [2]
    y = run(block, np.tile(cmd, (40, 1)), 0.05, t0=2.0)[-1]
    assert abs(y[i_n + 2]) < 1e-3 and abs(y[i_T + 2]) < 1e-3
    np.testing.assert_allclose(np.delete(y[i_n : i_n + 7], 2), 10.0, atol=1e-3)
    block.set_parameter("fail_value_3", -5.0)
    block.set_parameter("fail_mode_3", 2)  # stuck at -5 rev/s: reverse thrust 0.7 * 25 N
    y = run(block, np.tile(cmd, (40, 1)), 0.05, t0=4.0)[-1]
    assert y[i_n + 2] == pytest.approx(-5.0, abs=1e-3)
    assert y[i_T + 2] == pytest.approx(-0.7 * 25.0, abs=0.01)
    block.set_parameter("fail_mode_3", 0)  # repaired
    assert block.failed == []
    y = run(block, np.tile(cmd, (40, 1)), 0.05, t0=6.0)[-1]
    assert y[i_n + 2] == pytest.approx(10.0, abs=1e-2)


def test_failure_at_start_and_copied_with_the_state(minerva: VesselSpec) -> None:
    block = PlantBlock(minerva, {"noise_scale": 0.0, "fail_mode_1": 2, "fail_value_1": 15.0})
    run(block, np.zeros((20, 7)), 0.05)
    twin = copy.deepcopy(block)
    a = run(block, np.zeros((20, 7)), 0.05, t0=1.0)
    b = run(twin, np.zeros((20, 7)), 0.05, t0=1.0)
    np.testing.assert_array_equal(a, b)
    assert block.state[12] == pytest.approx(15.0, abs=1e-3)  # n_1 runs at the stuck speed, command 0
    assert abs(block.state[0]) + abs(block.state[1]) > 0.0  # and pushes the ROV


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [("fail_mode_2", 3, "parameter 'fail_mode_2' must be one of 0, 1, 2"),
     ("fail_mode_2", 0.5, "parameter 'fail_mode_2' must be one of"),
     ("fail_value_2", 25.0, "parameter 'fail_value_2' must be within"),
     ("fail_value_2", "x", "parameter 'fail_value_2' must be a number")],
)
def test_bad_failure_parameters_raise_naming_them(minerva: VesselSpec, name: str, value: object,
                                                  message: str) -> None:
    with pytest.raises(ValueError, match=message):
        PlantBlock(minerva, {name: value})
    block = PlantBlock(minerva, {})
    with pytest.raises(ValueError, match=message):
        block.set_parameter(name, value)
    assert block.failed == []


def test_amv_land_mode_follows_the_screw_kinematics(amv: VesselSpec) -> None:
    """On land the screws roll: u = p (n1 + n2) / 2 = 0.35 m/s at n = [1, 1]; back to water without a jump."""
    p = PlantBlock(amv, {"noise_scale": 0.0, "u_0": 0.8})
    names = PlantBlock.interface(amv).output_names()
    iu = names.index("u")
    p.set_parameter("land_mode", 1)
    y = p.output()
    for k in range(200):
        y = p.step(k * 0.05, 0.05, np.array([1.0, 1.0]))
    assert y[iu] == pytest.approx(0.35, abs=1e-3)
    assert abs(y[names.index("v")]) < 1e-9
    p.set_parameter("land_mode", 0)
    y2 = p.step(10.0, 0.05, np.array([1.0, 1.0]))
    # no jump at the water line: u changes by what the 25 N of thrust does in one step (0.5 m/s^2)
    assert abs(y2[iu] - y[iu]) < 0.03
    with pytest.raises(ValueError, match="parameter 'land_mode' must be one of 0, 1, 2"):
        p.set_parameter("land_mode", 3)
    assert "land_mode" not in [s.name for s in PlantBlock.interface(load_vessel("minerva2")).parameters]


# -- thruster efficiency (a fouled or damaged thruster) --------------------------------------------
def test_thruster_efficiency_scales_that_thrusters_force_only(minerva: VesselSpec) -> None:
    """Efficiency 0.6 on thruster 3: at a fixed shaft speed its force on the hull is 0.6 x B_3 T(n),
    every other thruster's force is unchanged (M nu_dot at rest, level, no current, less the
    zero-thrust restoring force)."""
    model = VesselModel(minerva)
    th, d = minerva.thrusters, minerva.dof
    n_cmd = 0.5 * np.asarray(th.n_max)
    eff = np.ones(th.count)
    eff[2] = 0.6
    K_eff = model.k_matrix(eff)
    rest = model.initial_state(np.zeros(d), np.zeros(d))
    base = model.M @ model.rhs(rest, [0.0] * th.count)[d : 2 * d]
    for k in range(th.count):
        n = np.zeros(th.count)
        n[k] = n_cmd[k]
        x = model.initial_state(np.zeros(d), np.zeros(d), n)  # shaft at its command: steady
        nominal = model.M @ model.rhs(x, n.tolist())[d : 2 * d] - base
        fouled = model.M @ model.rhs(x, n.tolist(), K=K_eff)[d : 2 * d] - base
        law = minerva.thrusters.k_forward[k] * n[k] * abs(n[k])  # quadratic law, forward
        np.testing.assert_allclose(nominal, model.B[:, k] * law, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(fouled, eff[k] * nominal, rtol=1e-9, atol=1e-9)


def test_thruster_efficiency_in_the_plant_is_tunable(amv: VesselSpec) -> None:
    """Through the block (AMV, 3 DOF, no restoring): from rest, the screw at 0.6 gives 0.6 x the
    surge speed and yaw rate (to 0.1 %: quadratic damping and Coriolis are second order at these
    tiny speeds), the other screw exactly what it gave
    before; the thrust outputs (the law at the shaft speed, what a log shows) are unchanged; an
    event gives the same run as the parameter set from the start."""
    h, steps = 0.02, 5
    base = {"noise_scale": 0.0}
    names = PlantBlock.interface(amv).output_names()
    iu, ir = names.index("u"), names.index("r")
    for k, ratio in ((1, 0.6), (0, 1.0)):
        u = np.zeros(2)
        u[k] = 0.5 * amv.thrusters.n_max[k]
        nominal = run(PlantBlock(amv, base), np.tile(u, (steps, 1)), h)
        fouled = run(PlantBlock(amv, {**base, "thruster_efficiency_2": 0.6}), np.tile(u, (steps, 1)), h)
        assert abs(nominal[-1, iu]) > 1e-4 and abs(nominal[-1, ir]) > 1e-5  # the screw does push
        np.testing.assert_allclose(fouled[:, [iu, ir]], ratio * nominal[:, [iu, ir]], rtol=1e-3)
        it = names.index(f"thrust_{k + 1}")
        np.testing.assert_array_equal(fouled[:, it], nominal[:, it])
    u = np.array([0.0, 0.5 * amv.thrusters.n_max[1]])
    event = PlantBlock(amv, base)
    event.set_parameter("thruster_efficiency_2", 0.6)
    assert event.efficiency == [1.0, 0.6]
    np.testing.assert_array_equal(run(event, np.tile(u, (steps, 1)), h),
                                  run(PlantBlock(amv, {**base, "thruster_efficiency_2": 0.6}),
                                      np.tile(u, (steps, 1)), h))
    with pytest.raises(ValueError, match="parameter 'thruster_efficiency_2' must be within"):
        event.set_parameter("thruster_efficiency_2", 2.0)
