"""Constrained QP allocation, the camera-jet variants and failure reconfiguration (issue 5)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from seafmu.components.allocation import (
    METHODS,
    AllocatorBlock,
    QPAllocator,
    camera_weighted_allocation,
    default_camera_thrusters,
    negative_front_thrust,
    pseudo_inverse_allocation,
    qp_allocation,
)
from seafmu.components.block import full_params
from seafmu.components.thrusters import max_thrust, speed_to_thrust, thruster_matrix
from seafmu.components.vessel_spec import VesselSpec, load_vessel

H = 0.05


@pytest.fixture(scope="module")
def B(minerva: VesselSpec) -> np.ndarray:
    return thruster_matrix(minerva.thrusters, 6)


@pytest.fixture(scope="module")
def limits(minerva: VesselSpec) -> tuple[np.ndarray, np.ndarray]:
    return max_thrust(minerva.thrusters)


def block(vessel: VesselSpec, **params: object) -> AllocatorBlock:
    return AllocatorBlock(vessel, full_params(AllocatorBlock.interface(vessel), params))


def outputs(vessel: VesselSpec, y: np.ndarray) -> dict[str, np.ndarray]:
    names = AllocatorBlock.interface(vessel).output_names()
    d = dict(zip(names, y, strict=True))
    m = vessel.thrusters.count
    return {
        "n": np.array([d[f"n_cmd_{i}"] for i in range(1, m + 1)]),
        "T": np.array([d[f"thrust_cmd_{i}"] for i in range(1, m + 1)]),
        "tau": np.array([d[f"tau_alloc_{t}"] for t in vessel.tau_names]),
        "err": np.array(d["alloc_error"]),
        "sat": np.array([d[f"sat_{i}"] for i in range(1, m + 1)]),
        "neg": np.array(d["front_negative_thrust"]),
        "energy": np.array(d["thrust_energy"]),
        "it": np.array(d["qp_iterations"]),
    }


def feasible_taus(B: np.ndarray, T_min: np.ndarray, T_max: np.ndarray, n: int, seed: int) -> list[np.ndarray]:
    """Random tau whose pseudo-inverse thrusts stay inside 95 % of the limits (nothing active)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        tau = rng.normal(size=6) * [300, 300, 300, 60, 60, 200]
        T = pseudo_inverse_allocation(B, tau)
        room = np.where(T > 0, T_max / np.maximum(T, 1e-12), T_min / np.minimum(T, -1e-12))
        out.append(tau * 0.95 * min(1.0, room.min()))
    return out


# -- the QP against the pseudo-inverse -----------------------------------------------------------
def test_qp_equals_pseudo_inverse_when_no_limit_is_active(minerva: VesselSpec, B: np.ndarray,
                                                          limits: tuple) -> None:
    T_min, T_max = limits
    qp, pinv = block(minerva, method=1), block(minerva, method=0)
    for tau in feasible_taus(B, T_min, T_max, 60, seed=3):
        a = outputs(minerva, qp.step(0.0, H, tau))
        b = outputs(minerva, pinv.step(0.0, H, tau))
        np.testing.assert_allclose(a["T"], b["T"], atol=1e-6)
        assert a["err"] < 1e-8 and not a["sat"].any()
    # the thesis's reference numbers through the plain function
    T = qp_allocation(B, [0, 100, 0, 0, 0, 0], T_min, T_max)
    np.testing.assert_allclose(T, [42.57, -42.57, -38.58, 38.58, 0.0, 14.77, -14.77], atol=0.01)
    # non-default weights: the weighted pseudo-inverse
    w = [1, 3, 1, 2, 1, 1, 5]
    tau = np.array([80.0, -60, 40, 5, -5, 30])
    np.testing.assert_allclose(qp_allocation(B, tau, T_min, T_max, weights=w),
                               pseudo_inverse_allocation(B, tau, weights=w), atol=1e-6)


def test_qp_respects_asymmetric_limits_and_uses_the_room_clipping_wastes(minerva: VesselSpec,
                                                                          limits: tuple) -> None:
    T_min, T_max = limits
    assert T_max[0] == pytest.approx(400.0) and T_min[0] == pytest.approx(-280.0)
    qp, pinv = block(minerva, method=1), block(minerva, method=0)
    rng = np.random.default_rng(4)
    hit_lo = hit_hi = 0
    for _ in range(60):
        tau = rng.normal(size=6) * [1500, 1500, 1500, 300, 300, 1000]
        a = outputs(minerva, qp.step(0.0, H, tau))
        assert np.all(a["T"] >= T_min - 1e-9) and np.all(a["T"] <= T_max + 1e-9)
        assert np.all(np.abs(a["n"]) <= minerva.thrusters.n_max + 1e-12)
        np.testing.assert_allclose(speed_to_thrust(minerva.thrusters, a["n"]), a["T"], atol=1e-6)
        assert a["err"] == pytest.approx(np.linalg.norm(a["tau"] - tau))
        at_lo, at_hi = np.isclose(a["T"], T_min, atol=1e-6), np.isclose(a["T"], T_max, atol=1e-6)
        np.testing.assert_array_equal(a["sat"] == 1, at_lo | at_hi)
        hit_lo += at_lo.sum()
        hit_hi += at_hi.sum()
    assert hit_lo > 20 and hit_hi > 20  # both the 280 N reverse and the 400 N forward limit were active
    # Sway 680 N: the pseudo-inverse clips (its capability is 658 N), the QP redistributes inside
    # the limits and still delivers it exactly.
    tau = np.array([0, 680.0, 0, 0, 0, 0])
    assert outputs(minerva, pinv.step(0.0, H, tau))["err"] > 1.0
    a = outputs(minerva, qp.step(0.0, H, tau))
    assert a["err"] < 1e-6 and a["sat"].sum() >= 1


def test_rate_limits_bound_the_change_per_step(minerva: VesselSpec) -> None:
    rate = 100.0  # N/s -> 5 N per 0.05 s step
    for method in (1, 0):
        alloc = block(minerva, method=method, **{f"thrust_rate_max_{i}": rate for i in range(1, 8)})
        free = block(minerva, method=method)
        tau = np.array([300.0, -200, 150, 20, -10, 100])
        prev = np.zeros(7)
        for k in range(200):
            out = outputs(minerva, alloc.step(k * H, H, tau))
            assert np.all(np.abs(out["T"] - prev) <= rate * H + 1e-9)
            if k == 0:
                assert out["err"] > 100.0 and out["sat"].all()  # held back by the rate limit
            prev = out["T"]
        target = outputs(minerva, free.step(0.0, H, tau))
        np.testing.assert_allclose(prev, target["T"], atol=1e-6)  # got there at 5 N per step
        assert outputs(minerva, alloc.step(0.0, H, tau))["err"] < 1e-6


def test_priority_slack_gives_up_surge_before_heading(minerva: VesselSpec) -> None:
    """Surge far beyond the thrusters plus a yaw moment they can make: the QP keeps most of the
    moment; clipping the pseudo-inverse loses all of it. A higher priority_N keeps it exactly."""
    tau = np.array([2000.0, 0, 0, 0, 0, 300])
    clipped = outputs(minerva, block(minerva, method=0).step(0.0, H, tau))
    qp = outputs(minerva, block(minerva, method=1).step(0.0, H, tau))
    strict = outputs(minerva, block(minerva, method=1, priority_N=1000).step(0.0, H, tau))
    assert abs(clipped["tau"][5]) < 1.0  # pseudo-inverse + clip: heading moment gone
    assert qp["tau"][5] > 0.75 * 300 and qp["tau"][0] > 900  # QP: moment mostly kept, surge given up
    assert strict["tau"][5] == pytest.approx(300, rel=0.01)
    assert strict["tau"][0] > 900
    # Heading no more important than surge: the moment is traded away like a force.
    flat = outputs(minerva, block(minerva, method=1, priority_N=1).step(0.0, H, tau))
    assert flat["tau"][5] < 0.25 * qp["tau"][5]


# -- camera-jet variants (thesis) ----------------------------------------------------------------
def test_default_camera_thrusters_are_the_fore_horizontals(minerva: VesselSpec) -> None:
    assert default_camera_thrusters(minerva) == [0, 1]
    assert default_camera_thrusters(load_vessel("amv_osf")) == []
    params = {p.name: p.start for p in AllocatorBlock.interface(minerva).parameters}
    assert [params[f"camera_{i}"] for i in range(1, 8)] == [1, 1, 0, 0, 0, 0, 0]
    assert params["camera_weight"] == 1e8 and params["method"] == 0


def test_camera_variants_keep_front_thrusters_out_of_reverse(minerva: VesselSpec) -> None:
    """Whenever tau is feasible without reverse on thrusters 1, 2, the min-negative-front QP keeps
    them >= 0 and meets tau. The thesis weighting (S = 1e8) removes most reverse thrust, not all:
    with both weights raised, T1 = -T2 along the null space [1, 1, -1, -1] costs nothing in S T^2
    and the weighted least norm settles there (docs/allocation.md)."""
    minneg, s1e8, plain = block(minerva, method=3), block(minerva, method=2), block(minerva, method=0)
    rng = np.random.default_rng(5)
    cases = 0
    neg_pinv = neg_s1e8 = 0.0
    for _ in range(60):
        tau = rng.normal(size=6) * [120, 120, 150, 30, 30, 80]
        q = outputs(minerva, minneg.step(0.0, H, tau))
        if q["err"] > 1e-6:
            continue  # out of reach without reverse front thrust: not this test
        assert q["T"][0] >= -1e-4 and q["T"][1] >= -1e-4 and q["neg"] < 2e-4
        w = outputs(minerva, s1e8.step(0.0, H, tau))
        p = outputs(minerva, plain.step(0.0, H, tau))
        assert w["err"] < 1e-6 and w["neg"] <= p["neg"] + 1e-9
        if p["neg"] > 1.0:
            cases += 1
            neg_pinv += float(p["neg"])
            neg_s1e8 += float(w["neg"])
    assert cases > 20  # the demands did ask the plain allocation for reverse front thrust
    assert neg_s1e8 < 0.1 * neg_pinv


def test_thesis_ordering_on_a_pure_sway_force(minerva: VesselSpec, B: np.ndarray) -> None:
    """S = 1e8 equals min-negative-front (and has the best indicator), S = 1 uses least energy,
    dropping thruster 1 saturates first."""
    variants = {"s1": dict(method=0), "s1e8": dict(method=2), "minneg": dict(method=3),
                "drop1": dict(method=0, enable_1=0)}
    blocks = {k: block(minerva, **p) for k, p in variants.items()}
    onset = {}
    for k, b in blocks.items():
        lo, hi = 0.0, 2000.0
        while hi - lo > 0.5:
            mid = 0.5 * (lo + hi)
            err = outputs(minerva, b.step(0.0, H, np.array([0, mid, 0, 0, 0, 0])))["err"]
            lo, hi = (mid, hi) if err < 1e-6 else (lo, mid)
        onset[k] = hi
    assert onset["drop1"] < onset["s1e8"] < onset["s1"]
    assert onset["s1e8"] == pytest.approx(onset["minneg"], abs=1.0)
    assert onset["drop1"] == pytest.approx(280 / 0.8515, abs=1.0)
    assert onset["s1"] == pytest.approx(658, abs=1.0)
    for y in (50.0, 150.0, 300.0):
        tau = np.array([0, y, 0, 0, 0, 0])
        out = {k: outputs(minerva, b.step(0.0, H, tau)) for k, b in blocks.items()}
        np.testing.assert_allclose(out["s1e8"]["T"], out["minneg"]["T"], atol=1e-3)
        assert out["s1e8"]["neg"] < 1e-3 and out["minneg"]["neg"] < 1e-3
        assert out["drop1"]["neg"] > out["s1"]["neg"] > 0.4 * y
        assert out["s1"]["energy"] < 0.6 * out["s1e8"]["energy"]
        assert out["s1"]["energy"] < 0.6 * out["drop1"]["energy"]
    # plain functions agree with the block
    T = camera_weighted_allocation(B, [0, 300, 0, 0, 0, 0], camera=[0, 1])
    np.testing.assert_allclose(T, out["s1e8"]["T"], atol=1e-4)
    assert negative_front_thrust(T, [0, 1]) < 1e-4


def test_min_negative_front_qp_keeps_protection_past_saturation(minerva: VesselSpec) -> None:
    """Past saturation the QP variant still never reverses thrusters 1, 2 and errs less than the
    clipped S = 1e8 weighting; with a camera_penalty below the priorities tau wins instead."""
    tau = np.array([0, 500.0, 0, 0, 0, 0])
    s1e8 = outputs(minerva, block(minerva, method=2).step(0.0, H, tau))
    minneg = outputs(minerva, block(minerva, method=3).step(0.0, H, tau))
    assert minneg["neg"] < 1e-3 and s1e8["neg"] < 1e-3
    assert 0 < minneg["err"] < s1e8["err"]
    soft = outputs(minerva, block(minerva, method=3, camera_penalty=0.01).step(0.0, H, tau))
    assert soft["err"] < 1e-6 and soft["neg"] > 10.0


# -- failures ------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", [0, 1, 3])
def test_failed_thruster_gets_zero_command_and_the_rest_deliver(minerva: VesselSpec, B: np.ndarray,
                                                                 limits: tuple, method: int) -> None:
    T_min, T_max = limits
    alloc = block(minerva, method=method)
    alloc.step(0.0, H, np.array([50.0, 50, 0, 0, 0, 20]))
    alloc.set_parameter("enable_3", 0)  # on the fly, as the failure event does
    keep = [0, 1, 3, 4, 5, 6]
    met = 0
    for tau in feasible_taus(B, T_min, T_max, 100, seed=6):
        T6 = np.linalg.solve(B[:, keep], tau)  # square: the only allocation without thruster 3
        if np.any(T6 < T_min[keep]) or np.any(T6 > T_max[keep]) or (method == 3 and min(T6[:2]) < 0):
            continue
        out = outputs(minerva, alloc.step(0.0, H, tau))
        assert out["T"][2] == 0.0 and out["n"][2] == 0.0 and out["sat"][2] == 0
        np.testing.assert_allclose(out["tau"], tau, atol=1e-6)
        np.testing.assert_allclose(out["T"][keep], T6, atol=1e-5)
        met += 1
    assert met >= 10
    alloc.set_parameter("enable_3", 1)  # repaired: back in use
    assert outputs(minerva, alloc.step(0.0, H, np.array([0, 100.0, 0, 0, 0, 0])))["T"][2] < -30


@pytest.mark.parametrize("method", [0, 1])
def test_stuck_thruster_is_a_known_force(minerva: VesselSpec, B: np.ndarray, method: int) -> None:
    """Thruster 1 stuck at 15 rev/s (225 N): its force is cancelled by the others (null space)."""
    alloc = block(minerva, method=method, enable_1=0, stuck_n_1=15.0)
    out = outputs(minerva, alloc.step(0.0, H, np.zeros(6)))
    assert out["n"][0] == 0.0  # nothing commanded to the failed drive
    assert out["T"][0] == pytest.approx(225.0)  # what the allocator counts on
    np.testing.assert_allclose(out["tau"], 0.0, atol=1e-6)
    np.testing.assert_allclose(out["T"][:4], [225, 225, -225, -225], atol=1e-6)
    # Stuck at full forward: the aft pair's 280 N reverse cannot cancel it; the error is reported.
    alloc.set_parameter("stuck_n_1", 20.0)
    out = outputs(minerva, alloc.step(0.0, H, np.zeros(6)))
    assert out["err"] > 100.0 and out["sat"].any()
    with pytest.raises(ValueError, match="stuck_n_1"):
        alloc.set_parameter("stuck_n_1", 25.0)


# -- warm start, state, parameters ----------------------------------------------------------------
def test_warm_start_gives_the_cold_answer(B: np.ndarray, limits: tuple) -> None:
    T_min, T_max = limits
    warm = QPAllocator(B, priorities=[1, 1, 1, 10, 10, 10], camera=[0, 1], camera_penalty=1e6,
                       thrust_scale=400.0)
    cold = QPAllocator(B, priorities=[1, 1, 1, 10, 10, 10], camera=[0, 1], camera_penalty=1e6,
                       thrust_scale=400.0)
    rng = np.random.default_rng(7)
    tau = np.zeros(6)
    iterations = []
    for _ in range(300):  # a smooth walk that goes in and out of saturation
        tau = tau + rng.normal(size=6) * [40, 40, 40, 8, 8, 30]
        tau *= 0.98
        Tw, fw = warm.solve(tau, T_min, T_max)
        iterations.append(warm.iterations)
        cold.cold_start()
        Tc, fc = cold.solve(tau, T_min, T_max)
        assert fw >= 1 and fc >= 1
        np.testing.assert_allclose(Tw, Tc, atol=1e-5)  # DAQP tolerances: 1e-6 primal
    assert np.mean(iterations) < 3  # the warm start is used (a cold solve takes ~5-25 iterations)


def test_qp_state_copies_and_continues_bit_identically(minerva: VesselSpec) -> None:
    alloc = block(minerva, method=3, thrust_rate_max_2=500.0)
    rng = np.random.default_rng(8)
    taus = rng.normal(size=(40, 6)) * [600, 600, 600, 100, 100, 400]
    for tau in taus[:20]:
        alloc.step(0.0, H, tau)
    snap = copy.deepcopy(alloc)
    restored = pickle.loads(pickle.dumps(snap))
    first = np.array([alloc.step(0.0, H, tau) for tau in taus[20:]])
    again = np.array([snap.step(0.0, H, tau) for tau in taus[20:]])
    third = np.array([restored.step(0.0, H, tau) for tau in taus[20:]])
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, third)


def test_method_switch_on_the_fly_and_bad_parameters(minerva: VesselSpec) -> None:
    alloc = block(minerva)
    tau = np.array([0, 680.0, 0, 0, 0, 0])
    assert outputs(minerva, alloc.step(0.0, H, tau))["err"] > 1.0
    alloc.set_parameter("method", 1)
    out = outputs(minerva, alloc.step(0.0, H, tau))
    assert out["err"] < 1e-6 and out["it"] >= 0
    assert len(METHODS) == 4
    for name, value in (("method", 4), ("camera_3", 2), ("priority_N", -1.0), ("thrust_rate_max_1", -5.0),
                        ("camera_penalty", float("nan"))):
        with pytest.raises(ValueError, match=name):
            alloc.set_parameter(name, value)
    with pytest.raises(ValueError, match="method"):
        block(minerva, method=7)


def test_amv_qp_matches_the_two_screw_method_inside_limits() -> None:
    amv = load_vessel("amv_osf")
    tau = np.array([30.0, 0.0, 2.0])
    a = outputs(amv, block(amv, method=1).step(0.0, H, tau))
    b = outputs(amv, block(amv, method=0).step(0.0, H, tau))
    np.testing.assert_allclose(a["n"], b["n"], atol=1e-6)  # sway is not demanded (priority_Y = 0)
    # beyond the screws: the QP keeps most of the yaw moment and gives up surge (the two-screw
    # method keeps all of it: a strict priority, which a large priority_N approaches)
    tau = np.array([100.0, 0.0, 8.0])
    out = outputs(amv, block(amv, method=1).step(0.0, H, tau))
    assert out["tau"][2] > 0.75 * 8.0 and out["tau"][0] < 60.0
    strict = outputs(amv, block(amv, method=1, priority_N=1000).step(0.0, H, tau))
    assert strict["tau"][2] == pytest.approx(8.0, rel=0.01)
    assert outputs(amv, block(amv, method=0).step(0.0, H, tau))["tau"][2] == pytest.approx(8.0)
