"""Thrust allocation: the thesis's pseudo-inverse numbers, exactness, saturation, heading priority."""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
import pytest

from seafmu.components.allocation import (
    AllocatorBlock,
    drop_thruster,
    priority_allocation,
    pseudo_inverse_allocation,
    thrust_capability,
)
from seafmu.components.block import full_params
from seafmu.components.thrusters import max_thrust, speed_to_thrust, thruster_matrix
from seafmu.components.vessel_spec import VesselSpec


def block(vessel: VesselSpec, **params: object) -> AllocatorBlock:
    return AllocatorBlock(vessel, full_params(AllocatorBlock.interface(vessel), params))


class Out(NamedTuple):
    n: np.ndarray  # n_cmd
    T: np.ndarray  # thrust_cmd
    tau: np.ndarray  # tau_alloc
    err: float  # alloc_error


def split(vessel: VesselSpec, y: np.ndarray) -> Out:
    m, d = vessel.thrusters.count, vessel.dof
    return Out(y[:m], y[m : 2 * m], y[2 * m : 2 * m + d], float(y[2 * m + d]))


# Thesis, pseudo-inverse with K = 1 (thrust in N per unit of the thruster command).
REFERENCE = [
    ([100, 0, 0, 0, 0, 0], [34.29, 34.29, 34.29, 34.29, 11.60, -6.47, -6.47]),
    ([0, 100, 0, 0, 0, 0], [42.57, -42.57, -38.58, 38.58, 0.0, 14.77, -14.77]),
    ([0, 0, 0, 0, 0, 10], [2.455, -2.455, 2.455, -2.455, 0.0, 0.0, 0.0]),
]


@pytest.mark.parametrize(("tau", "expected"), REFERENCE)
def test_minerva_pseudo_inverse_reproduces_thesis(minerva: VesselSpec, tau: list, expected: list) -> None:
    B = thruster_matrix(minerva.thrusters, 6)
    T = pseudo_inverse_allocation(B, tau)
    np.testing.assert_allclose(T, expected, atol=0.01)
    np.testing.assert_allclose(B @ T, tau, atol=1e-9)


def test_minerva_drop_thruster_1_sway(minerva: VesselSpec) -> None:
    B = thruster_matrix(minerva.thrusters, 6)
    expected = [0.0, -85.15, 3.99, 81.16, 0.0, 14.77, -14.77]
    T = pseudo_inverse_allocation(B, [0, 100, 0, 0, 0, 0], drop=[0])
    np.testing.assert_allclose(T, expected, atol=0.01)
    # The 6 x 6 system of the remaining thrusters is square: its inverse gives the same thrusts.
    T6 = np.linalg.solve(drop_thruster(B, 0), [0, 100, 0, 0, 0, 0])
    np.testing.assert_allclose(T6, expected[1:], atol=0.01)
    # Same through the block (thruster 1 disabled), converted to speed and back.
    y = block(minerva, enable_1=0).step(0.0, 0.05, np.array([0, 100.0, 0, 0, 0, 0]))
    out = split(minerva, y)
    np.testing.assert_allclose(out.T, expected, atol=0.01)
    np.testing.assert_allclose(speed_to_thrust(minerva.thrusters, out.n), expected, atol=0.01)
    assert out.err < 1e-9


def test_feasible_demands_are_met_exactly(minerva: VesselSpec) -> None:
    """Random tau inside the capability: B T = tau, alloc_error = 0, speeds give back the thrusts."""
    rng = np.random.default_rng(1)
    alloc = block(minerva)
    B = thruster_matrix(minerva.thrusters, 6)
    T_min, T_max = max_thrust(minerva.thrusters)
    for _ in range(50):
        tau = rng.normal(size=6) * [200, 200, 200, 50, 50, 100]
        T = pseudo_inverse_allocation(B, tau)
        room = np.where(T > 0, T_max / np.maximum(T, 1e-12), T_min / np.minimum(T, -1e-12))
        tau *= 0.95 * min(1.0, room.min())
        out = split(minerva, alloc.step(0.0, 0.05, tau))
        np.testing.assert_allclose(out.tau, tau, atol=1e-8)
        assert out.err < 1e-8
        np.testing.assert_allclose(speed_to_thrust(minerva.thrusters, out.n), out.T, rtol=1e-9, atol=1e-9)


def test_saturation_keeps_limits_and_reports_error(minerva: VesselSpec) -> None:
    rng = np.random.default_rng(2)
    alloc = block(minerva)
    T_min, T_max = max_thrust(minerva.thrusters)
    for _ in range(50):
        tau = rng.normal(size=6) * [3000, 3000, 3000, 800, 800, 1500]
        out = split(minerva, alloc.step(0.0, 0.05, tau))
        assert np.all(out.T >= T_min - 1e-9) and np.all(out.T <= T_max + 1e-9)
        assert np.all(np.abs(out.n) <= minerva.thrusters.n_max + 1e-12)
        assert out.err > 1.0
        assert out.err == pytest.approx(np.linalg.norm(out.tau - tau))


def test_capability_is_where_saturation_starts(minerva: VesselSpec) -> None:
    cap = thrust_capability(minerva)
    alloc = block(minerva)
    for j in range(6):
        for sign in (1.0, -1.0):
            e = np.zeros(6)
            e[j] = sign * cap[j]
            assert split(minerva, alloc.step(0.0, 0.05, 0.999 * e)).err < 1e-6
        # Beyond it in the weaker direction the allocator must saturate.
        errs = [split(minerva, alloc.step(0.0, 0.05, s * 1.05 * cap[j] * np.eye(6)[j])).err for s in (1, -1)]
        assert max(errs) > 1e-3


def test_weights_shift_effort_and_are_recomputed(minerva: VesselSpec) -> None:
    alloc = block(minerva)
    tau = np.array([0, 100.0, 0, 0, 0, 0])
    T0 = split(minerva, alloc.step(0.0, 0.05, tau)).T
    alloc.set_parameter("w_1", 50.0)
    out = split(minerva, alloc.step(0.0, 0.05, tau))
    assert abs(out.T[0]) < 0.2 * abs(T0[0])
    assert out.err < 1e-8
    with pytest.raises(ValueError, match="w_2"):
        alloc.set_parameter("w_2", -1.0)


def test_front_thrusters_kept_out_of_reverse(minerva: VesselSpec) -> None:
    """Thesis variant: weight 1e8 on thrusters 1 and 2 only when they would go negative."""
    tau = np.array([-100.0, 0, 0, 0, 0, 0])
    plain = split(minerva, block(minerva).step(0.0, 0.05, tau)).T
    assert plain[0] < -30 and plain[1] < -30
    alloc = block(minerva, reverse_weight_1=1e8, reverse_weight_2=1e8)
    out = split(minerva, alloc.step(0.0, 0.05, tau))
    assert out.T[0] > -0.01 and out.T[1] > -0.01
    assert out.err < 1e-6  # the aft pair and the verticals still deliver the demand
    # Forward surge: front thrusters positive anyway, so nothing changes.
    fwd = split(minerva, alloc.step(0.0, 0.05, -tau)).T
    np.testing.assert_allclose(fwd, -plain, atol=1e-9)


def test_amv_two_screw_exact_inside_limits(amv: VesselSpec) -> None:
    kx, ly = 12.63, 0.22
    alloc = block(amv)
    tau = np.array([30.0, 0.0, 2.0])
    n, _, tau_alloc, err = split(amv, alloc.step(0.0, 0.05, tau))
    assert n[0] + n[1] == pytest.approx(tau[0] / kx)
    assert n[0] - n[1] == pytest.approx(tau[2] / (ly * kx))
    np.testing.assert_allclose(tau_alloc[[0, 2]], tau[[0, 2]], atol=1e-9)
    # The screws' side force comes with every yaw moment: tau_Y = k_y (n1 - n2), not demanded.
    assert tau_alloc[1] == pytest.approx(3.97 * (n[0] - n[1]), rel=1e-4)
    assert err == pytest.approx(abs(tau_alloc[1]))


def test_amv_heading_has_priority_over_surge(amv: VesselSpec) -> None:
    alloc = block(amv)
    tau = np.array([100.0, 0.0, 8.0])  # surge beyond 2 x 2.3 rps; yaw alone is feasible
    out = split(amv, alloc.step(0.0, 0.05, tau))
    assert out.tau[2] == pytest.approx(8.0, rel=1e-9)  # yaw moment kept
    assert 0.0 < out.tau[0] < 100.0  # surge reduced
    assert max(abs(out.n)) == pytest.approx(2.3)
    assert np.all(np.abs(out.n) <= 2.3 + 1e-12)
    # Plain clipping of the same demand would have lost yaw moment:
    common, diff = 100 / 12.63, 8 / (0.22 * 12.63)
    n_clip = np.clip([(common + diff) / 2, (common - diff) / 2], -2.3, 2.3)
    assert 0.22 * 12.63 * (n_clip[0] - n_clip[1]) < 7.0
    # Yaw alone beyond capacity: scaled to the limit, no surge left to give.
    out = split(amv, alloc.step(0.0, 0.05, np.array([30.0, 0.0, -20.0])))
    np.testing.assert_allclose(out.n, [-2.3, 2.3])
    assert out.tau[0] == pytest.approx(0.0, abs=1e-9)


def test_priority_allocation_with_asymmetric_limits() -> None:
    """Reverse weaker than forward: yaw kept, surge uses the room left by the asymmetric box."""
    B2 = np.array([[1.0, 1.0], [0.5, -0.5]])
    T_min, T_max = np.array([-70.0, -70.0]), np.array([100.0, 100.0])
    T = priority_allocation(B2, [200.0, 40.0], T_min, T_max)  # yaw needs T1 - T2 = 80
    assert B2[1] @ T == pytest.approx(40.0)
    assert np.all(T <= T_max + 1e-9) and np.all(T >= T_min - 1e-9)
    assert B2[0] @ T == pytest.approx(120.0)  # T = [100, 20]: the most surge with that yaw


def test_bad_input_and_parameter_named(minerva: VesselSpec) -> None:
    alloc = block(minerva)
    with pytest.raises(ValueError, match="tau_Z"):
        alloc.step(0.0, 0.05, np.array([0, 0, np.nan, 0, 0, 0]))
    with pytest.raises(ValueError, match="enable_3"):
        block(minerva, enable_3=2)
    with pytest.raises(ValueError, match="w_1"):
        block(minerva, w_1=0.0)


def test_state_is_deep_copyable(minerva: VesselSpec) -> None:
    alloc = block(minerva, w_3=2.0)
    twin = copy.deepcopy(alloc)
    tau = np.array([50.0, -20, 10, 1, 2, 3])
    np.testing.assert_array_equal(alloc.step(0.0, 0.05, tau), twin.step(0.0, 0.05, tau))
