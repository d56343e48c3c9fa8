"""The offshore supply vessel (brief section 5b), added as data only (components/vessels/supply.yaml).

The reference model here is written INDEPENDENTLY from the brief's equations (Fossen, Sagatun &
Sorensen 1996; Fossen 2021 App. D) with scipy's solve_ivp, not from components code:

    eta_dot = R(psi) nu,   M nu_dot + D nu = T K (n|n|),   n_dot = (n_cmd - n) / T_n   (n in RPM)
    M = m T^-1 M'' T^-1,   D = m sqrt(g/L) T^-1 D'' T^-1,   T^-1 = diag(1, 1, L)

and the plant block must reproduce it open loop; the DP loop (plant, observer, dp_pid controller,
QP allocator, all named by the vessel file) must hold station in a current and reach setpoint steps.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from seafmu.components.block import full_params
from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.fmus.registry import BLOCKS

# -- the brief, section 5b (typed here on purpose: independent of the vessel file) ---------------
MASS, LENGTH, GRAVITY = 6000e3, 76.2, 9.81
M_BIS = np.array([[1.1274, 0.0, 0.0], [0.0, 1.8902, -0.0744], [0.0, -0.0744, 0.1278]])
D_BIS = np.array([[0.0358, 0.0, 0.0], [0.0, 0.1183, -0.0124], [0.0, -0.0041, 0.0308]])
K_RPM = np.array([3.2, 3.2, 3.2, 3.2, 31.2, 31.2])  # N / RPM^2
N_MAX_RPM = np.array([250.0, 250.0, 250.0, 250.0, 160.0, 160.0])
T_CONF = np.array([[0, 0, 0, 0, 1, 1], [1, 1, 1, 1, 0, 0], [30, 22, -22, -30, -8, 8]], dtype=float)
T_SHAFT = 1.0  # s

TI = np.diag([1.0, 1.0, LENGTH])
M_SI = MASS * TI @ M_BIS @ TI
D_SI = MASS * math.sqrt(GRAVITY / LENGTH) * TI @ D_BIS @ TI

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "supply_dp.yaml"


@pytest.fixture(scope="module")
def supply() -> VesselSpec:
    return load_vessel("supply")


def reference_rhs(t: float, x: np.ndarray, n_cmd_rpm: np.ndarray, current_ned: np.ndarray) -> np.ndarray:
    """The brief's model in relative velocities: x = [north, east, psi, u_r, v_r, r, n_1..n_6 (RPM)],
    M nu_r_dot + D nu_r = tau, and with a current constant in NED eta_dot = R(psi) nu_r + v_c."""
    psi, nu_r, n = x[2], x[3:6], x[6:]
    c, s = math.cos(psi), math.sin(psi)
    vn, ve = current_ned
    eta_dot = [c * nu_r[0] - s * nu_r[1] + vn, s * nu_r[0] + c * nu_r[1] + ve, nu_r[2]]
    tau = T_CONF @ (K_RPM * n * np.abs(n))
    nu_dot = np.linalg.solve(M_SI, tau - D_SI @ nu_r)
    n_dot = (np.clip(n_cmd_rpm, -N_MAX_RPM, N_MAX_RPM) - n) / T_SHAFT
    return np.concatenate([eta_dot, nu_dot, n_dot])


def plant_block(vessel: VesselSpec, **params: object):
    cls = BLOCKS["plant"]
    return cls(vessel, full_params(cls.interface(vessel), {"noise_scale": 0.0, **params}))


# RPM step programme: (start time s, commands n_1..n_6 in RPM). Surge, a turn from the tunnels,
# a sway push while the mains reverse, and a command beyond n_max (clipped by both models).
PROGRAMME = [
    (0.0, [0, 0, 0, 0, 100, 100]),
    (120.0, [150, 150, -150, -150, 100, 100]),
    (200.0, [200, 200, 200, 200, -60, -40]),
    (300.0, [-250, 0, 0, 250, 300, 120]),
    (380.0, [0, 0, 0, 0, 0, 0]),
]
END = 450.0


def test_file_is_the_published_bis_data(supply: VesselSpec) -> None:
    """The SI fields equal the bis formula of the brief's numbers; extra.bis keeps them verbatim."""
    np.testing.assert_allclose(supply.M, M_SI, rtol=1e-13)
    np.testing.assert_allclose(supply.D_L, D_SI, rtol=1e-13)
    assert supply.D_L[1, 2] != supply.D_L[2, 1]  # D'' is not symmetric and stays so
    np.testing.assert_array_equal(supply.D_Q, 0.0)
    assert supply.coriolis == "none" and supply.restoring is None
    bis = supply.extra["bis"]
    assert (bis["mass"], bis["length"], bis["gravity"]) == (MASS, LENGTH, GRAVITY)
    np.testing.assert_array_equal(bis["M_bis"], M_BIS)
    np.testing.assert_array_equal(bis["D_bis"], D_BIS)
    assert all(supply.provenance[k] for k in ("mass_matrix", "linear_damping", "coriolis", "gnc.controller"))
    assert all("Fossen" in supply.provenance[f"thrusters.units[{i}].k_forward"] for i in range(6))


def test_thrusters_in_rpm_become_the_model_units(supply: VesselSpec) -> None:
    from seafmu.components.thrusters import max_thrust, thruster_matrix

    th = supply.thrusters
    np.testing.assert_allclose(th.n_max * 60.0, N_MAX_RPM, rtol=1e-15)
    np.testing.assert_allclose(th.k_forward, K_RPM * 3600.0)  # K per (rev/s)^2 = K per RPM^2 x 3600
    np.testing.assert_allclose(th.time_constant, T_SHAFT)
    _, T_max = max_thrust(th)
    np.testing.assert_allclose(T_max, [200e3] * 4 + [798720.0] * 2, rtol=1e-12)  # 200 kN, 799 kN
    np.testing.assert_allclose(thruster_matrix(th, 3), T_CONF, atol=1e-12)


@pytest.mark.parametrize("current", [0.0, 0.5])
def test_open_loop_rpm_steps_match_an_independent_model(supply: VesselSpec, current: float) -> None:
    """Plant block vs solve_ivp of the brief's equations: position within 0.1 % of the distance run,
    without and with a current (0.5 m/s towards 30 deg: the model's M nu_r_dot, not M nu_dot)."""
    h = 0.5
    beta = math.radians(30.0)
    current_ned = current * np.array([math.cos(beta), math.sin(beta)])
    plant = plant_block(supply, current_speed=current, current_direction=beta)
    x = np.zeros(12)
    x[3:5] = -current_ned  # at rest over ground at psi = 0: nu_r = -nu_c
    t_plant, pos_plant, pos_ref, yaw_err = 0.0, [], [], []
    times = [p[0] for p in PROGRAMME] + [END]
    for (t0, cmd), t1 in zip(PROGRAMME, times[1:], strict=True):
        cmd = np.array(cmd, dtype=float)
        sol = solve_ivp(reference_rhs, (t0, t1), x, args=(cmd, current_ned), method="DOP853", rtol=1e-11,
                        atol=1e-9,
                        dense_output=True)
        assert sol.success
        steps = round((t1 - t0) / h)
        for k in range(steps):
            y = plant.step(t_plant, h, cmd / 60.0)  # the plant takes rev/s
            t_plant += h
            xr = sol.sol(t0 + (k + 1) * h)
            pos_plant.append(y[:2])
            pos_ref.append(xr[:2])
            yaw_err.append(abs(y[2] - math.remainder(xr[2], 2 * math.pi)))
        x = sol.y[:, -1]
    pos_plant, pos_ref = np.array(pos_plant), np.array(pos_ref)
    travelled = float(np.sum(np.linalg.norm(np.diff(pos_ref, axis=0), axis=1)))
    err = float(np.max(np.linalg.norm(pos_plant - pos_ref, axis=1)))
    assert travelled > 400.0  # a real manoeuvre, not a drift
    print(f"open loop: max position error {err:.3g} m over {travelled:.1f} m ({err / travelled:.2g})")
    assert err <= 1e-3 * travelled, (err, travelled)
    assert err / travelled < 1e-6  # in fact: RK4 at 0.01 s agrees to integration accuracy
    assert max(yaw_err) < 1e-6
    # the shafts: the plant's n_i (rev/s) follow the same lag to the clipped command
    names = plant.interface(supply).output_names()
    n_plant = np.array([y[names.index(f"n_{i + 1}")] for i in range(6)]) * 60.0
    np.testing.assert_allclose(n_plant, x[6:], atol=1e-6)


def test_steady_surge_speed_is_thrust_over_drag(supply: VesselSpec) -> None:
    """Both mains at 60 RPM: 2 K n^2 = D11 u, no sway or yaw (the mains' moments cancel)."""
    plant = plant_block(supply, substep=0.1)
    cmd = np.array([0, 0, 0, 0, 60.0, 60.0]) / 60.0
    for k in range(2000):  # 2000 s = 23 surge time constants M11 / D11 = 87.8 s
        y = plant.step(k * 1.0, 1.0, cmd)
    u_ss = 2 * 31.2 * 60.0**2 / D_SI[0, 0]
    assert u_ss == pytest.approx(2.914, abs=1e-3)
    assert y[3] == pytest.approx(u_ss, rel=1e-8)
    assert abs(y[4]) < 1e-12 and abs(y[5]) < 1e-12


# -- the DP loop, in process ------------------------------------------------------------------------

def dp_loop(vessel: VesselSpec, duration: float, h: float, params: dict[str, dict],
            events: list[tuple[float, str, float]]) -> dict[str, np.ndarray]:
    """plant -> observer -> controller -> allocator, Gauss-Seidel like seafmu's master: each block reads
    the newest outputs of the others by name; setpoints (``*_ref``) from ``events``; initial outputs
    propagated through ``start`` in the same order."""
    order = ["plant", "observer", "controller", "allocator"]
    blocks, ifaces = {}, {}
    for k in order:
        cls = BLOCKS[k]
        ifaces[k] = cls.interface(vessel)
        blocks[k] = cls(vessel, full_params(ifaces[k], params.get(k, {})))
    outs = {k: dict.fromkeys(ifaces[k].output_names(), 0.0) for k in order}
    refs: dict[str, float] = {}

    def inputs(k: str) -> np.ndarray:
        u = []
        for s in ifaces[k].inputs:
            v = refs.get(s.name, s.start)
            for o in order:
                if o != k and s.name in outs[o]:
                    v = outs[o][s.name]
            u.append(v)
        return np.array(u, dtype=float)

    for k in order:
        outs[k] = dict(zip(ifaces[k].output_names(), blocks[k].start(inputs(k)).tolist(), strict=True))
    log: dict[str, list[float]] = {}
    pending = sorted(events)
    for i in range(round(duration / h)):
        t = i * h
        while pending and pending[0][0] <= t + 1e-9:
            _, name, value = pending.pop(0)
            refs[name] = value
        for k in order:
            y = blocks[k].step(t, h, inputs(k))
            outs[k] = dict(zip(ifaces[k].output_names(), y.tolist(), strict=True))
        log.setdefault("time", []).append(t + h)
        for k in order:
            for name, v in outs[k].items():
                log.setdefault(f"{k}.{name}", []).append(v)
        for name in ("north_ref", "east_ref", "yaw_ref"):
            log.setdefault(name, []).append(refs.get(name, 0.0))
    return {k: np.array(v) for k, v in log.items()}


def test_dp_holds_station_in_current_and_reaches_setpoint_steps(supply: VesselSpec) -> None:
    """The supply_dp case: 0.5 m/s current from the start, 10 m north, 10 m east, 20 deg heading."""
    from seafmu.components.controller import ControllerBlock
    from seafmu.components.dp_pid import DPPidController

    assert isinstance(ControllerBlock(supply, full_params(ControllerBlock.interface(supply), {})),
                      DPPidController)
    log = dp_loop(supply, 900.0, 0.1, {
        "plant": {"seed": 1, "current_speed": 0.5, "current_direction": math.radians(30), "substep": 0.1},
        "observer": {"q_velocity": 0.005, "q_bias": 0.0002},
    }, [(200.0, "north_ref", 10.0), (400.0, "east_ref", 10.0), (600.0, "yaw_ref", math.radians(20))])
    t = log["time"]

    def worst(state: str, a: float, b: float) -> float:
        m = (t >= a) & (t <= b)
        return float(np.max(np.abs(log[f"plant.{state}"][m] - log[f"{state}_ref"][m])))

    assert worst("north", 120, 200) < 0.5 and worst("east", 120, 200) < 0.6  # station in the current
    assert worst("north", 320, 400) < 0.5  # 10 m north reached
    assert worst("east", 520, 600) < 0.5  # 10 m east reached
    assert worst("yaw", 800, 900) < 0.006  # 20 deg heading reached ...
    assert worst("north", 800, 900) < 0.5 and worst("east", 800, 900) < 0.5  # ... on station
    late = t >= 10.0
    assert all(log[f"allocator.sat_{i}"][late].max() == 0.0 for i in range(1, 7))  # inside the limits
    # the integral holds the current: tau = -D nu_c in the body at the final heading (mean over 700-900 s),
    # and the observer's bias force (which knows no current) is the current's drag D nu_c in surge and sway
    psi = math.radians(20)
    vc = 0.5 * np.array([math.cos(math.radians(30) - psi), math.sin(math.radians(30) - psi), 0.0])
    held = t >= 700.0
    tau = np.array([log[f"controller.tau_{x}"][held].mean() for x in "XYN"])
    np.testing.assert_allclose(tau, -D_SI @ vc, rtol=0.15)
    bias = np.array([log[f"observer.bias_{x}_hat"][held].mean() for x in "XY"])
    np.testing.assert_allclose(bias, (D_SI @ vc)[:2], atol=8e3)  # N (the yaw bias is noisy, docs/gnc.md)
    assert float(np.sqrt(np.mean((log["observer.north_hat"] - log["plant.north"])[t >= 20] ** 2))) < 0.2


def test_scenario_runs_through_the_master_when_accepted() -> None:
    """scenarios/supply_dp.yaml through seafmu's master in process."""
    from seafmu.scenario import load_scenario

    sc = load_scenario(SCENARIO)
    from seafmu.master import run
    from seafmu.results import evaluate_checks

    checks = evaluate_checks(run(sc, mode="inprocess", progress=False))
    assert checks and all(c.passed for c in checks), [(c.name, c.value) for c in checks if not c.passed]
