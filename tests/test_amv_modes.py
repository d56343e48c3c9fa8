"""AMV OSF: backstepping autopilot, land kinematics (components/amv_land.py), the land joystick
through the two-screw allocator, no state reset on unassigned joystick inputs, bumpless switching."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from seafmu.components.allocation import AllocatorBlock
from seafmu.components.amv_land import LandModel, LandParams, land_step, land_velocity
from seafmu.components.block import full_params
from seafmu.components.controller import ControllerBlock
from seafmu.components.vessel_spec import VesselSpec

H = 0.05


def controller(vessel: VesselSpec, **params: object) -> ControllerBlock:
    return ControllerBlock(vessel, full_params(ControllerBlock.interface(vessel), params))


def inputs(yaw: float = 0.0, u: float = 1.0, v: float = 0.0, r: float = 0.0, yaw_ref: float = 0.0,
           surge: float = 50.0, jx: float = 0.0, jy: float = 0.0, slider: float = 0.0,
           buttons: float = 0.0) -> np.ndarray:
    return np.array([0.0, 0.0, yaw, u, v, r, yaw_ref, surge, jx, jy, slider, buttons])


def yaw_loop(vessel: VesselSpec, ctl: ControllerBlock, yaw_ref: float, seconds: float,
             moment: float = 0.0) -> np.ndarray:
    """Yaw only, (I_z + A66) r_dot + D_Q66 |r| r = tau_N + moment, perfect state; rows t, yaw, r, tau_N."""
    m66, dq = vessel.M[2, 2], vessel.D_Q[2, 2]
    yaw = r = 0.0
    out = []
    for k in range(round(seconds / H)):
        y = ctl.step(k * H, H, inputs(yaw=yaw, r=r, yaw_ref=yaw_ref))
        for _ in range(10):
            r += H / 10 * (y[2] - dq * abs(r) * r + moment) / m66
            yaw += H / 10 * r
        out.append((k * H + H, yaw, r, y[2]))
    return np.array(out)


# -- backstepping ----------------------------------------------------------------------------------


def test_backstepping_stabilises_the_heading_step(amv: VesselSpec) -> None:
    ctl = controller(amv, autopilot=1)
    assert (ctl.params["bs_k1"], ctl.params["bs_k2"]) == (8.0, 4.0)  # the thesis's gains
    out = yaw_loop(amv, ctl, 1.0, 60.0)
    assert out[:, 1].max() < 1.01  # (almost) no overshoot
    assert out[-1, 1] == pytest.approx(1.0, abs=0.002)
    assert np.abs(out[:, 3]).max() < ctl.tau_max[0]  # never saturated: the law acted alone
    # The PID (thesis gains) on the same plant overshoots more and settles later.
    pid = yaw_loop(amv, controller(amv), 1.0, 60.0)
    assert out[:, 1].max() < pid[:, 1].max()
    late = out[:, 0] >= 20.0
    assert np.abs(out[late, 1] - 1.0).max() < np.abs(pid[late, 1] - 1.0).max()


def test_backstepping_lyapunov_function_never_increases(amv: VesselSpec) -> None:
    """V = z1^2 / 2 + m66 z2^2 / 2 with the reference model's trajectory: V_dot = -k1 z1^2 - k2 z2^2.

    Holds for the exact model without integral action; it fails for any sign or inertia error in
    the law (e.g. the thesis's I_z - A66).
    """
    ctl = controller(amv, autopilot=1, bs_ki=0.0)
    m66, dq, k1 = amv.M[2, 2], amv.D_Q[2, 2], 8.0
    yaw, r, vs = 0.4, 0.0, []  # start off the reference (0): a real transient
    ctl.start(inputs(yaw=yaw))
    ctl.ref.reset([0.0])
    for k in range(400):
        y = ctl.step(k * H, H, inputs(yaw=yaw, r=r, yaw_ref=0.5))
        z1 = math.remainder(yaw - y[3], 2 * math.pi)
        z2 = r - (y[4] - k1 * z1)
        vs.append(0.5 * z1 * z1 + 0.5 * m66 * z2 * z2)
        for _ in range(20):  # fine sub-steps: the law is held over the step, the reference moves
            r += H / 20 * (y[2] - dq * abs(r) * r) / m66
            yaw += H / 20 * r
    vs = np.array(vs)
    assert vs[0] > 100.0 and vs[-1] < 2e-3 * vs[0]  # slow closed-loop pole 0.16 rad/s: e^-6.5 in 20 s
    assert np.all(np.diff(vs) <= 2e-3 * vs[:-1] + 1e-12)  # non-increasing (up to the zero-order hold)


def test_backstepping_integral_removes_a_constant_moment(amv: VesselSpec) -> None:
    out = yaw_loop(amv, controller(amv, autopilot=1), 0.5, 150.0, moment=-3.0)
    assert out[-1, 1] == pytest.approx(0.5, abs=0.005)
    # Pure backstepping (no integral, as published): offset moment / (1 + k1 k2).
    out = yaw_loop(amv, controller(amv, autopilot=1, bs_ki=0.0), 0.5, 150.0, moment=-3.0)
    assert out[-1, 1] == pytest.approx(0.5 - 3.0 / (1.0 + 8.0 * 4.0), abs=0.003)


# -- land kinematics -------------------------------------------------------------------------------


def test_land_velocity_numbers(amv: VesselSpec) -> None:
    prm = LandParams.from_vessel(amv)
    assert (prm.pitch, prm.diameter, prm.half_track, prm.u_max, prm.v_max) == (0.35, 0.465, 0.22, 2.0, 1.0)
    assert land_velocity(1.0, 1.0, False, prm) == pytest.approx((0.35, 0.0, 0.0))
    # Physical yaw form: r = p (n1 - n2) / (2 l_y); the thesis's printed form lacks the 1 / 0.44.
    assert land_velocity(1.2, 0.8, False, prm) == pytest.approx((0.35, 0.0, 0.35 * 0.4 / 0.44))
    published = LandParams.from_vessel(amv, yaw_form="published")
    assert land_velocity(1.2, 0.8, False, published)[2] == pytest.approx(0.35 * 0.4)
    # Sideways (button held): v = d (n1 + n2) / 2, capped at 1 m/s; no surge, no yaw.
    assert land_velocity(1.0, 1.0, True, prm) == pytest.approx((0.0, 0.465, 0.0))
    assert land_velocity(2.3, 2.3, True, prm) == pytest.approx((0.0, 1.0, 0.0))
    # Forward cap 2 m/s (not reachable with 2.3 rev/s: p n_max = 0.805 m/s).
    assert land_velocity(10.0, 10.0, False, prm)[0] == pytest.approx(2.0)
    # No on-the-spot rotation: screws in opposition do not turn the vessel; at most a pivot about
    # the slower screw (|r| <= |u| / l_y).
    assert land_velocity(1.0, -1.0, False, prm) == pytest.approx((0.0, 0.0, 0.0))
    u, _, r = land_velocity(1.0, 0.0, False, prm)  # pivot about the starboard screw: exactly the limit
    assert r == pytest.approx(u / 0.22) and r == pytest.approx(0.35 / 0.44)
    u, _, r = land_velocity(1.0, -0.5, False, prm)
    assert r == pytest.approx(abs(u) / 0.22) and r < 0.35 * 1.5 / 0.44


def test_land_circle_radius_and_straight_run(amv: VesselSpec) -> None:
    land = LandModel(amv)
    x = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.1, 0.9])  # screws already at speed
    xs = []
    for _ in range(round(60.0 / H)):
        x = land.step(x, [1.1, 0.9], H, substeps=2)
        xs.append(x.copy())
    xs = np.array(xs)[round(20.0 / H):]
    # u = 0.35 m/s, r = 0.35 * 0.2 / 0.44: radius = l_y (n1 + n2) / (n1 - n2) = 2.2 m.
    assert xs[-1, 3] == pytest.approx(0.35, rel=1e-6) and xs[-1, 5] == pytest.approx(0.35 * 0.2 / 0.44)
    assert (xs[:, 0].max() - xs[:, 0].min()) / 2 == pytest.approx(2.2, rel=2e-3)
    x = np.array([0.0, 0.0, math.pi / 2, 0.35, 0.0, 0.0, 1.0, 1.0])
    for _ in range(200):
        x = land.step(x, [1.0, 1.0], H)
    assert x[1] == pytest.approx(0.35 * 10.0, rel=1e-9) and abs(x[0]) < 1e-9  # 10 s east at 0.35 m/s


def test_water_to_land_carries_the_state_over_without_a_jump(amv: VesselSpec) -> None:
    land = LandModel(amv)
    water = np.array([3.0, -2.0, 0.4, 0.8, 0.2, 0.05, 1.5, 1.5])  # a water state, screws at 1.5
    x, prev, jumps = water.copy(), water.copy(), []
    for _ in range(200):
        x = land.step(x, [1.5, 1.5], H)
        jumps.append(np.abs(x[3:6] - prev[3:6]).max())
        prev = x
    # Velocities approach the kinematic values with the 0.5 s slip lag: at most h / T_slip of the
    # difference per step, never a jump; position and heading are continuous by construction.
    assert max(jumps) <= H / 0.5 * 0.55 + 1e-9
    assert x[3:6] == pytest.approx([0.35 * 1.5, 0.0, 0.0], abs=1e-6)
    first = land.step(water, [1.5, 1.5], H)
    assert np.abs(first[:3] - water[:3]).max() < 0.05  # moved by about h * velocity only
    # The pure kinematic model (slip_time 0) jumps: the lag is what makes the transfer bumpless.
    pure = land_step(water, np.array([1.5, 1.5]), H, LandParams.from_vessel(amv, slip_time=0.0),
                     land.shaft_time, land.n_max)
    assert pure[3:6] == pytest.approx([0.525, 0.0, 0.0])
    with pytest.raises(ValueError, match="slip_time"):
        LandParams(slip_time=-1.0)


# -- land joystick, allocator pass-through ---------------------------------------------------------


def test_land_joystick_screw_speeds_reach_the_screws_through_the_allocator(amv: VesselSpec) -> None:
    ctl = controller(amv, land_mode=1)
    alloc = AllocatorBlock(amv, full_params(AllocatorBlock.interface(amv), {}))
    names = ControllerBlock.interface(amv).output_names()
    i1, i2, isw = names.index("n_joy_1"), names.index("n_joy_2"), names.index("sideways")
    for x, yj, s in ((1.0, 0.0, 1.0), (1.0, 0.5, 0.8), (-0.6, -1.0, 0.5), (0.3, 1.0, 1.0)):
        y = ctl.step(0.0, H, inputs(jx=x, jy=yj, slider=s))
        S = 2.3 * s  # land_n_scale defaults to n_max
        n1, n2 = S * x * (0.9 + 0.05 * yj), S * x * (0.9 - 0.05 * yj)
        assert (y[i1], y[i2]) == pytest.approx((n1, n2), abs=1e-12)
        n_cmd = alloc.step(0.0, H, y[:3])[:2]
        np.testing.assert_allclose(n_cmd, [n1, n2], atol=1e-9)  # the allocator inverts tau exactly
    y = ctl.step(0.0, H, inputs(jx=1.0, slider=1.0, buttons=1))
    assert y[isw] == 1.0


# -- no reset on unassigned inputs -----------------------------------------------------------------


def state_of(ctl: ControllerBlock) -> np.ndarray:
    return np.concatenate([ctl.z, ctl.ref.x, ctl.ref.v, ctl._offset, [ctl._joy_heading]])


@pytest.mark.parametrize("land", [0, 1])
def test_unassigned_joystick_inputs_never_reset_a_state(amv: VesselSpec, land: int) -> None:
    """The original's bug: any unassigned button reset all states. Here a twin controller that
    sees the same assigned inputs but wild unassigned ones (buttons 1..7, and in water with the
    joystick off: every joystick axis) must produce the same outputs and keep the same state."""
    a, b = controller(amv, land_mode=land), controller(amv, land_mode=land)
    rng = np.random.default_rng(7)
    for k in range(400):
        yaw, r = 0.3 * math.sin(0.05 * k), 0.015 * math.cos(0.05 * k)
        base = dict(yaw=yaw, r=r, yaw_ref=0.8, jx=0.7, jy=0.2, slider=0.6)
        wild = dict(base, buttons=float(rng.integers(0, 8) * 2))  # bits 1..3: unassigned
        if not land:  # joystick = 0: the axes and slider have no function in water
            wild.update(jx=rng.uniform(-1, 1), jy=rng.uniform(-1, 1), slider=rng.uniform(0, 1))
        ya, yb = a.step(k * H, H, inputs(**base)), b.step(k * H, H, inputs(**wild))
        np.testing.assert_array_equal(ya, yb)
        np.testing.assert_array_equal(state_of(a), state_of(b))
    if not land:
        assert abs(a.z[0]) > 1e-3  # the integral really was active (and not reset)


# -- bumpless switching ----------------------------------------------------------------------------


def run_switches(amv: VesselSpec, blend: float) -> tuple[np.ndarray, list[int]]:
    """Yaw loop with the switches water PID -> backstepping -> land -> water; returns tau rows."""
    ctl = controller(amv, mode_blend_time=blend)
    m66, dq = amv.M[2, 2], amv.D_Q[2, 2]
    yaw = r = 0.0
    taus, switches = [], []
    plan = {200: ("autopilot", 1), 400: ("land_mode", 1), 600: ("land_mode", 0)}
    for k in range(800):
        if k in plan:
            ctl.set_parameter(*plan[k])
            switches.append(k)
        y = ctl.step(k * H, H, inputs(yaw=yaw, r=r, yaw_ref=0.6, jx=1.0, jy=0.4, slider=0.5, surge=20.0))
        taus.append(y[[0, 2]])
        if ctl.land:  # land: the yaw rate the screws impose
            r = land_velocity(*y[6:8], False, LandParams.from_vessel(amv))[2]
        else:
            r += H * (y[2] - dq * abs(r) * r - 2.0) / m66  # a constant moment: the integral is busy
        yaw += H * r
    return np.array(taus), switches


def test_mode_switches_are_bumpless(amv: VesselSpec) -> None:
    taus, switches = run_switches(amv, blend=1.0)
    steps = np.abs(np.diff(taus, axis=0))
    normal = np.delete(steps, [s - 1 for s in switches], axis=0).max(axis=0)
    for s in (switches[0], switches[2]):  # into a closed-loop water law: no step in either force
        np.testing.assert_allclose(taus[s], taus[s - 1], atol=1e-9)
    # Into land mode the screws are the operator's: the force changes (by design, no blending).
    assert np.abs(taus[switches[1]] - taus[switches[1] - 1]).max() > 1.0
    # The same switches without blending jump: the test can fail.
    raw, _ = run_switches(amv, blend=0.0)
    jump = np.abs(raw[switches[2]] - raw[switches[2] - 1])
    assert jump[0] > 5.0 and jump.max() > 5 * normal.max()


def test_back_from_land_holds_the_heading_it_glides_to(amv: VesselSpec) -> None:
    ctl = controller(amv, land_mode=1)
    for k in range(20):
        ctl.step(k * H, H, inputs(yaw=1.0, r=0.05, yaw_ref=0.0))
    ctl.set_parameter("land_mode", 0)
    y = ctl.step(1.0, H, inputs(yaw=1.0, r=0.05, yaw_ref=0.0))
    assert y[3] == pytest.approx(1.0 + 0.05 * H, abs=2e-3)  # the reference starts on the vessel
    assert ctl._latch[0] == pytest.approx(1.0 + 0.05 / 0.5)  # not the stale yaw_ref 0: x0 + r / omega
    ctl2 = copy.deepcopy(ctl)
    y = ctl2.step(1.05, H, inputs(yaw=1.0, r=0.05, yaw_ref=0.3))  # the operator gives a new heading
    assert math.isnan(ctl2._latch[0])
