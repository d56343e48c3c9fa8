"""Reference model and controllers, closed around small perfect-state models integrated here."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from scipy.linalg import expm

from seafmu.components.block import full_params
from seafmu.components.controller import ControllerBlock, restoring_stiffness
from seafmu.components.kinematics import J, rzyx, wrap_angle
from seafmu.components.reference_model import ReferenceModel, _exact_coefficients
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec


def joystick_at_rest(ctl: ControllerBlock, *parts: object) -> np.ndarray:
    """The inputs ``parts`` (estimates, setpoints, ...) followed by the joystick axes at rest."""
    u = np.concatenate([np.atleast_1d(np.asarray(p, dtype=float)) for p in parts])
    return np.concatenate([u, np.zeros(len(ctl.inp) - len(u))])

def controller(vessel: VesselSpec, **params: object) -> ControllerBlock:
    return ControllerBlock(vessel, full_params(ControllerBlock.interface(vessel), params))


# -- reference model -----------------------------------------------------------------------------


@pytest.mark.parametrize("zeta", [0.4, 1.0, 1.7])
def test_exact_discretisation_is_the_matrix_exponential(zeta: float) -> None:
    w, h = 0.7, 0.3
    Phi = expm(np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]) * h)
    np.testing.assert_allclose(np.reshape(_exact_coefficients(w, zeta, h), (2, 2)), Phi, atol=1e-12)


def test_critically_damped_step_reaches_reference_without_overshoot() -> None:
    w, h = 0.5, 0.05
    ref = ReferenceModel(2, w, 1.0)
    xs = []
    for k in range(1, 801):
        x = ref.step(h, [2.0, -1.0])[0]
        xs.append(x.copy())
        t = k * h
        # Closed-form step response of the critically damped model.
        np.testing.assert_allclose(x, np.array([2.0, -1.0]) * (1 - (1 + w * t) * math.exp(-w * t)), atol=1e-9)
    xs = np.array(xs)
    assert np.all(np.diff(xs[:, 0]) >= 0) and np.all(xs[:, 0] <= 2.0)  # monotone, no overshoot
    assert np.all(np.diff(xs[:, 1]) <= 0) and np.all(xs[:, 1] >= -1.0)
    np.testing.assert_allclose(xs[-1], [2.0, -1.0], atol=1e-5)


def test_yaw_step_across_pi_takes_the_short_way() -> None:
    ref = ReferenceModel(1, 0.5, 1.0, angles=[True])
    ref.reset([3.0])
    path = [ref.step(0.05, [-3.0])[0][0] for _ in range(1000)]
    # From 3.0 rad to -3.0 rad is 0.28 rad through +-pi, not 6 rad through zero.
    assert min(abs(p) for p in path) > 2.9
    assert max(path) <= math.pi and min(path) > -math.pi
    assert path[-1] == pytest.approx(-3.0, abs=1e-4)
    assert ref.v[0] > -1e-12  # it turned positive (3.0 -> pi -> -pi -> -3.0)


def test_velocity_and_acceleration_limits() -> None:
    ref = ReferenceModel(1, 0.5, 1.0, v_max=0.2, a_max=0.05)
    vs, as_ = [], []
    for _ in range(3000):
        x, v, a = ref.step(0.05, [20.0])
        vs.append(v[0])
        as_.append(a[0])
    assert max(np.abs(vs)) <= 0.2 + 1e-12
    assert max(np.abs(as_)) <= 0.05 + 1e-12
    assert x[0] == pytest.approx(20.0, abs=1e-3)
    assert max(vs) == pytest.approx(0.2)  # the limit was active


# -- 6 DOF DP controller (Minerva 2) -------------------------------------------------------------


def simulate_dp(vessel: VesselSpec, ctl: ControllerBlock, eta_ref: np.ndarray, seconds: float,
                force_ned: np.ndarray | None = None, h: float = 0.05) -> np.ndarray:
    """M nu_dot = tau - D nu - G eta + R^T F_ned, eta_dot = J(eta) nu, perfect state to the controller.

    D: the vessel's linear damping plus the quadratic damping linearised at 0.1 m/s (rad/s), G the
    hydrostatic roll/pitch stiffness. Semi-implicit Euler with 5 sub-steps: enough for this model.
    """
    M = 0.5 * (vessel.M + vessel.M.T)
    Minv = np.linalg.inv(M)
    D = vessel.D_L + 0.1 * vessel.D_Q
    G = np.diag(restoring_stiffness(vessel))
    eta, nu = np.zeros(6), np.zeros(6)
    F = np.zeros(6) if force_ned is None else np.asarray(force_ned, float)
    for k in range(round(seconds / h)):
        tau = ctl.step(k * h, h, joystick_at_rest(ctl, eta, nu, eta_ref))[:6]
        dt = h / 5
        for _ in range(5):
            R = rzyx(*eta[3:6])
            f_body = np.concatenate([R.T @ F[:3], F[3:]])
            nu = nu + dt * (Minv @ (tau - D @ nu - G @ eta + f_body))
            eta = eta + dt * (J(eta) @ nu)
            eta[3:] = wrap_angle(eta[3:])
    return eta


def test_dp_reaches_setpoint_and_integral_removes_disturbance(minerva: VesselSpec) -> None:
    eta_ref = np.array([2.0, -1.5, 1.0, 0.0, 0.0, 1.0])
    force = np.array([150.0, -100.0, 40.0, 0.0, 0.0, 20.0])  # constant in NED: current, buoyancy
    eta = simulate_dp(minerva, controller(minerva), eta_ref, 200.0, force)
    err = eta - eta_ref
    assert np.max(np.abs(err[:3])) < 0.01
    assert np.max(np.abs(err[3:])) < 0.002
    # Without integral action the same disturbance leaves an offset of about F / K_p.
    no_i = controller(minerva, **{f"ki_{n}": 0.0 for n in minerva.eta_names})
    eta_p = simulate_dp(minerva, no_i, eta_ref, 200.0, force)
    kp_north = no_i.params["kp_north"]
    assert abs(eta_p[0] - eta_ref[0]) > 0.5 * 150.0 / kp_north
    # The integral force converged to the disturbance (body frame: rotated by the final heading).
    ctl = controller(minerva)
    simulate_dp(minerva, ctl, eta_ref, 200.0, force)
    np.testing.assert_allclose(ctl.ki[:3] * ctl.z[:3], force[:3], rtol=0.05)


def surge_step(ctl: ControllerBlock, vessel: VesselSpec, target: float, seconds: float,
               h: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surge-only perfect-state loop; returns x, tau_X and the integral force K_i z per step."""
    M, D = vessel.M[0, 0], vessel.D_L[0, 0] + 0.1 * vessel.D_Q[0, 0]
    eta, nu, eta_ref = np.zeros(6), np.zeros(6), np.array([target, 0, 0, 0, 0, 0])
    xs, taus, zs = [], [], []
    for k in range(round(seconds / h)):
        y = ctl.step(k * h, h, joystick_at_rest(ctl, eta, nu, eta_ref))
        nu[0] += h * (y[0] - D * nu[0]) / M
        eta[0] += h * nu[0]
        xs.append(eta[0])
        taus.append(y[0])
        zs.append(ctl.ki[0] * ctl.z[0])
    return np.array(xs), np.array(taus), np.array(zs)


def test_dp_anti_windup_under_saturation(minerva: VesselSpec) -> None:
    """A 20 m step with a 150 N limit: long saturation; the integral adds no overshoot to PD's."""
    limits = dict(tau_max_X=150.0, tau_max_Y=150.0, ref_omega=1.0)
    x, tau, zf = surge_step(controller(minerva, **limits), minerva, 20.0, 150.0)
    saturated = np.abs(tau) >= 150.0 - 1e-9
    assert saturated.sum() * 0.05 > 30.0  # the scenario really saturates
    assert np.max(np.abs(zf)) <= 150.0 + 1e-9  # clamped to the limit
    # While saturated the integral does not move (no unwinding needed here: it starts at zero).
    both = saturated[1:] & saturated[:-1]
    assert np.all(np.abs(np.diff(zf))[both] <= 1e-9)
    x_pd, _, _ = surge_step(controller(minerva, ki_north=0.0, **limits), minerva, 20.0, 150.0)
    overshoot, overshoot_pd = x.max() - 20.0, x_pd.max() - 20.0
    assert overshoot < overshoot_pd + 0.1  # what is left is the saturated stop, not windup
    assert x[-1] == pytest.approx(20.0, abs=0.02)


def test_dp_wound_integral_can_unwind_in_saturation(minerva: VesselSpec) -> None:
    """An integral that pushes into the saturation must still be able to come down (no deadlock)."""
    ctl = controller(minerva, tau_max_X=150.0)
    ctl.step(0.0, 0.05, np.zeros(22))
    ctl.z[0] = -150.0 / ctl.ki[0]  # integral force +150 N (tau = -K_i z), the clamp level
    u = np.zeros(22)
    u[0], u[6] = 0.1, -0.2  # just past the setpoint, moving back: D term saturates forward
    y = ctl.step(0.05, 0.05, u)
    assert y[0] == pytest.approx(150.0)
    z_before = ctl.z[0]
    ctl.step(0.1, 0.05, u)
    assert ctl.z[0] == pytest.approx(z_before + 0.05 * 0.1)  # unwinding is allowed
    # The same saturation with the error on the other side would wind further: blocked.
    u[0] = -0.1
    z_before = ctl.z[0]
    y = ctl.step(0.15, 0.05, u)
    assert y[0] == pytest.approx(150.0) and ctl.z[0] == z_before


def test_dp_outputs_reference_trajectory_and_saturated_force(minerva: VesselSpec) -> None:
    ctl = controller(minerva)
    y = ctl.step(0.0, 0.05, joystick_at_rest(ctl, np.zeros(12), [100.0, 0, 0, 0, 0, 0]))
    names = ControllerBlock.interface(minerva).output_names()
    assert names[:6] == ["tau_X", "tau_Y", "tau_Z", "tau_K", "tau_M", "tau_N"]
    assert names[6:12] == [f"{n}_d" for n in minerva.eta_names]
    assert names[12:] == ["cross_track_error", "corner_error", "leg", "speed_d"]
    assert 0.0 < y[6] < 0.01  # the reference model starts smoothly, not at the setpoint
    y = ctl.step(0.05, 0.05, joystick_at_rest(ctl, [-50.0], np.zeros(11), [100.0, 0, 0, 0, 0, 0]))
    assert y[0] == pytest.approx(ctl.tau_max[0])


# -- 3 DOF heading autopilot (AMV OSF) ------------------------------------------------------------


def simulate_heading(vessel: VesselSpec, ctl: ControllerBlock, yaw_ref: float, seconds: float,
                     u: float = 1.0, v: float = 0.0, moment: float = 0.0, h: float = 0.05) -> list[tuple]:
    """Yaw only: (I_z + A66) r_dot = tau_N - N_r |r| r + moment; surge/sway held (perfect state)."""
    m66, dq = vessel.M[2, 2], vessel.D_Q[2, 2]
    yaw, r, out = 0.0, 0.0, []
    for k in range(round(seconds / h)):
        y = ctl.step(k * h, h, joystick_at_rest(ctl, [0.0, 0.0, yaw, u, v, r, yaw_ref, 50.0]))
        for _ in range(5):
            r += h / 5 * (y[2] - dq * abs(r) * r + moment) / m66
            yaw += h / 5 * r
        out.append((k * h, yaw, r, *y))
    return out


def test_amv_heading_step_without_large_overshoot(amv: VesselSpec) -> None:
    ctl = controller(amv)
    assert (ctl.kp[0], ctl.kd[0], ctl.ki[0]) == (5.0, 50.0, 1.5)  # thesis gains are the defaults
    out = simulate_heading(amv, ctl, 1.0, 80.0)
    yaw = np.array([o[1] for o in out])
    assert yaw.max() < 1.05
    assert yaw[-1] == pytest.approx(1.0, abs=0.01)
    tau = np.array([o[3:6] for o in out])
    assert np.all(tau[:, 0] == 50.0) and np.all(tau[:, 1] == 0.0)  # open-loop surge, no sway
    # Reference model Omega = 0.5, Delta = 1: yaw_d follows the critically damped response.
    t_end = out[-1][0] + 0.05
    assert out[-1][6] == pytest.approx(1 - (1 + 0.5 * t_end) * math.exp(-0.5 * t_end), abs=1e-6)


def test_amv_integral_removes_constant_yaw_moment(amv: VesselSpec) -> None:
    out = simulate_heading(amv, controller(amv), 0.5, 120.0, moment=-2.0)
    assert out[-1][1] == pytest.approx(0.5, abs=0.005)
    out = simulate_heading(amv, controller(amv, ki=0.0), 0.5, 120.0, moment=-2.0)
    assert out[-1][1] == pytest.approx(0.5 - 2.0 / 5.0, abs=0.02)  # P-only offset moment / K_p


def test_amv_course_mode_compensates_crab_angle(amv: VesselSpec) -> None:
    out = simulate_heading(amv, controller(amv, course_mode=1), 0.3, 80.0, u=1.0, v=0.2)
    beta = math.atan2(0.2, 1.0)
    assert out[-1][1] == pytest.approx(0.3 - beta, abs=0.01)  # heading = course - crab angle
    # Below the minimum speed the crab angle is not trusted: plain heading.
    out = simulate_heading(amv, controller(amv, course_mode=1), 0.3, 80.0, u=0.05, v=0.02)
    assert out[-1][1] == pytest.approx(0.3, abs=0.01)


def test_amv_yaw_moment_saturates(amv: VesselSpec) -> None:
    ctl = controller(amv, ref_omega=5.0)
    out = simulate_heading(amv, ctl, 3.0, 5.0)
    assert max(abs(o[5]) for o in out) == pytest.approx(ctl.tau_max[0])
    assert abs(ctl.ki[0] * ctl.z[0]) <= ctl.tau_max[0] + 1e-12


def test_errors_name_input_and_parameter(minerva: VesselSpec, amv: VesselSpec) -> None:
    with pytest.raises(ValueError, match="yaw_ref"):
        ctl = controller(amv)
        ctl.step(0.0, 0.05, joystick_at_rest(ctl, [0, 0, 0, 0, 0, 0, np.inf, 0.0]))
    with pytest.raises(ValueError, match="course_mode"):
        controller(amv, course_mode=2)
    with pytest.raises(ValueError, match="kp_north"):
        controller(minerva, kp_north=-1.0)
    with pytest.raises(ValueError, match="ref_omega"):
        controller(minerva).set_parameter("ref_omega", 0.0)


def test_tunable_gain_change_and_deepcopy(minerva: VesselSpec) -> None:
    ctl = controller(minerva)
    u = joystick_at_rest(ctl, np.zeros(12), [1.0, 0, 0, 0, 0, 0])
    for k in range(20):
        ctl.step(k * 0.05, 0.05, u)
    twin = copy.deepcopy(ctl)
    np.testing.assert_array_equal(ctl.step(1.0, 0.05, u), twin.step(1.0, 0.05, u))
    ctl.set_parameter("kp_north", 2.0 * ctl.params["kp_north"])
    twin.set_parameter("kp_north", twin.params["kp_north"])
    assert ctl.step(1.05, 0.05, u)[0] > twin.step(1.05, 0.05, u)[0]


# -- 6 DOF operating modes (Minerva 2): joystick, auto-depth, auto-heading, waypoint ----------------


def fly_modes(vessel: VesselSpec, ctl: ControllerBlock, seconds: float, eta_ref: np.ndarray,
              joy: np.ndarray | None = None, plan: dict | None = None, h: float = 0.05,
              eta0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Perfect-state loop around the plant's own 6-DOF physics (``VesselModel``: Coriolis, added
    mass, quadratic damping, restoring) with tau applied directly (no thrusters), the joystick
    inputs and parameter changes ``plan`` = {step: [(name, value)]}; returns eta and outputs."""
    model = VesselModel(vessel)
    x = model.initial_state(np.zeros(6) if eta0 is None else np.array(eta0, float), np.zeros(6))
    joy = np.zeros(4) if joy is None else np.asarray(joy, float)
    off = [0.0] * vessel.thrusters.count
    etas, ys = [], []
    for k in range(round(seconds / h)):
        for name, value in (plan or {}).get(k, []):
            ctl.set_parameter(name, value)
        y = ctl.step(k * h, h, np.concatenate([x[:6], x[6:12], eta_ref, joy]))
        x = model.rk4(x, off, h, 1, tau_ext=y[:6].tolist())
        etas.append(x[:6].copy())
        ys.append(y.copy())
    return np.array(etas), np.array(ys)


def path_length(eta: np.ndarray) -> float:
    return float(np.hypot(*np.diff(eta[:, :2], axis=0).T).sum())


def test_joystick_is_ignored_in_dp_and_drives_the_free_dofs(minerva: VesselSpec) -> None:
    ref = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    _, ya = fly_modes(minerva, controller(minerva), 20.0, ref, eta0=ref)
    _, yb = fly_modes(minerva, controller(minerva), 20.0, ref, joy=[1.0, -1.0, 1.0, 1.0], eta0=ref)
    np.testing.assert_array_equal(ya, yb)  # DP: the sticks have no function, and change nothing
    ctl = controller(minerva, mode=4)
    eta, y = fly_modes(minerva, ctl, 30.0, ref, joy=[0.5, 0.0, 0.0, 0.2], eta0=ref)
    assert y[-1, 0] == pytest.approx(0.5 * ctl.params["joy_max_X"], rel=0.05)  # surge stick -> tau_X
    assert y[-1, 5] == pytest.approx(0.2 * ctl.params["joy_max_N"], rel=0.05)  # yaw stick -> tau_N
    assert np.unwrap(eta[:, 5])[-1] > 0.5 and path_length(eta) > 3.0  # it turns and moves
    assert np.abs(eta[:, 3:5]).max() < 0.02  # roll and pitch are still held (turning at speed: 0.85 deg)


def test_auto_depth_and_auto_heading_hold_their_dof_under_the_joystick(minerva: VesselSpec) -> None:
    ref = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.3])
    eta0 = ref.copy()
    eta, _ = fly_modes(minerva, controller(minerva, mode=2), 60.0, ref, joy=[0.6, 0.3, 1.0, 0.1], eta0=eta0)
    assert np.abs(eta[:, 2] - 5.0).max() < 0.02  # depth held; the heave stick does nothing
    assert path_length(eta) > 5.0 and abs(np.unwrap(eta[:, 5])[-1] - 0.3) > 0.3  # the yaw stick turns it
    eta, _ = fly_modes(minerva, controller(minerva, mode=3), 60.0, ref, joy=[0.0, 0.0, 0.5, 1.0], eta0=eta0)
    assert np.abs(eta[:, 5] - 0.3).max() < 0.005  # heading held; the yaw stick does nothing
    assert eta[-1, 2] > 6.0  # the heave stick dives
    eta, _ = fly_modes(minerva, controller(minerva, mode=5), 60.0, ref, joy=[0.6, 0.0, 1.0, 1.0], eta0=eta0)
    assert np.abs(eta[:, 2] - 5.0).max() < 0.02 and np.abs(eta[:, 5] - 0.3).max() < 0.005
    assert path_length(eta) > 5.0


def test_joystick_to_dp_is_bumpless_and_stops_where_it_glides(minerva: VesselSpec) -> None:
    ref = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    ctl = controller(minerva, mode=4)
    plan = {600: [("mode", 0)]}
    eta, y = fly_modes(minerva, ctl, 90.0, ref, joy=[0.1, 0.0, 0.0, 0.0], plan=plan, eta0=ref)
    # The stick stays pushed, but DP does not use it: at the switch the force is continuous.
    steps = np.abs(np.diff(y[:, :6], axis=0))
    np.testing.assert_allclose(y[600, :6], y[599, :6], atol=1e-9)
    # DP holds where the vessel glides to (x0 + v0 / omega_ref), not at the old setpoint 0.
    x0, v0 = eta[599, 0], (eta[599, 0] - eta[598, 0]) / 0.05
    assert v0 > 0.2 and eta[-1, 0] == pytest.approx(x0 + v0 / 0.2, abs=0.05)
    assert np.all(np.diff(eta[600:, 0]) > -1e-3)  # no reversing
    # Without blending the same switch jumps by the stick force.
    ctl = controller(minerva, mode=4, mode_blend_time=0.0)
    _, y0 = fly_modes(minerva, ctl, 31.0, ref, joy=[0.1, 0.0, 0.0, 0.0], plan=plan, eta0=ref)
    jump = abs(y0[600, 0] - y0[599, 0])
    assert jump > 30.0 and steps[600:].max(axis=0)[0] < 0.5 * jump  # blended: gradual after the switch
    # A new setpoint from the operator releases the latch.
    ctl.set_parameter("mode", 0)
    ctl.step(0.0, 0.05, np.concatenate([eta[-1], np.zeros(6), [1.0, 0, 5.0, 0, 0, 0], np.zeros(4)]))
    assert math.isnan(ctl._latch[0]) and math.isfinite(ctl._latch[1])


def test_waypoint_mode_flies_a_lawnmower_with_small_corner_errors(minerva: VesselSpec) -> None:
    ref = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    ctl = controller(minerva, mode=1, lm_lines=2, lm_spacing=3.0, lm_length=6.0, lm_north=1.0)
    eta, y = fly_modes(minerva, ctl, 110.0, ref, eta0=ref)
    names = ControllerBlock.interface(minerva).output_names()
    leg = y[:, names.index("leg")]
    assert ctl.guidance is not None and ctl.guidance.legs == 4  # approach + 3
    assert leg[-1] == 5  # done
    assert len(ctl.guidance.corner_errors) == 3 and max(ctl.guidance.corner_errors) < 0.05
    assert np.abs(y[:, names.index("cross_track_error")]).max() < 0.05
    assert y[:, names.index("speed_d")].max() == pytest.approx(0.3)
    np.testing.assert_allclose(eta[-1, :2], [1.0, 3.0], atol=0.02)  # holds the last waypoint
    assert np.abs(eta[:, 2] - 5.0).max() < 0.01 and np.abs(eta[:, 3:5]).max() < 0.01
    # Without the model feed-forward the PID alone lags the moving reference much more.
    ctl = controller(minerva, mode=1, lm_lines=2, lm_spacing=3.0, lm_length=6.0, lm_north=1.0, ff_gain=0.0)
    _, y0 = fly_modes(minerva, ctl, 60.0, ref, eta0=ref)
    assert np.abs(y0[:, names.index("cross_track_error")]).max() > 2 * np.abs(
        y[:1200, names.index("cross_track_error")]).max()


def test_mode_and_guidance_parameters_are_checked(minerva: VesselSpec) -> None:
    with pytest.raises(ValueError, match="'mode'"):
        controller(minerva, mode=6)
    with pytest.raises(ValueError, match="waypoints"):
        controller(minerva, waypoints="1, 2; 3")
    with pytest.raises(ValueError, match="guide_speed"):
        controller(minerva).set_parameter("guide_speed", 0.0)
    with pytest.raises(ValueError, match="lm_side"):
        controller(minerva, lm_side=0)
    ctl = controller(minerva, mode=1, waypoints="2, 0; 2, 2")
    ctl.step(0.0, 0.05, np.zeros(22))
    assert ctl.guidance is not None
    np.testing.assert_allclose(ctl.guidance.points, [[0, 0], [2, 0], [2, 2]])


@pytest.mark.parametrize("vessel", ["minerva2", "amv_osf", "supply"])
def test_every_pid_gain_has_the_unit_that_makes_its_term_a_force(vessel: str) -> None:
    """kp * error, kd * error rate and ki * integrated error are each a force (N) or a moment (N.m):
    the modelDescription tells an FMI tool what a gain is, not a bare number."""
    from seafmu.components.dp_pid import DPPidController
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.unitdefs import parse_unit

    params = {s.name: s for s in DPPidController.interface(load_vessel(vessel)).parameters}
    gains = [n for n in params if n.split("_", 1)[0] in ("kp", "kd", "ki")]
    assert len(gains) in (9, 18)  # three gains per controlled DOF, 3 or 6 DOF
    for name in gains:
        g, dof = name.split("_", 1)
        angle = dof in ("roll", "pitch", "yaw")
        error = {"kp": "", "kd": "/s", "ki": ".s"}[g]
        term = parse_unit(f"({params[name].unit}).{'rad' if angle else 'm'}{error}")
        assert term.exponents == parse_unit("N.m" if angle else "N").exponents, (name, params[name].unit)
