"""Guidance: lawnmower geometry, the leg speed profile, switching at the circle of acceptance,
the speed limit, the corner and cross-track measures (components/guidance.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seafmu.components.guidance import LegProfile, PathGuidance, lawnmower, parse_waypoints


def test_lawnmower_geometry_six_lines_four_metres_apart() -> None:
    wp = lawnmower(6, 4.0, 15.0, 0.0, origin=(10.0, 2.0), side=1)
    assert wp.shape == (12, 2)
    # Lines run north and back, stepped 4 m to starboard (east when heading north).
    np.testing.assert_allclose(wp[:4], [[10, 2], [25, 2], [25, 6], [10, 6]], atol=1e-12)
    np.testing.assert_allclose(wp[-1], [10, 22], atol=1e-12)
    lines = wp.reshape(6, 2, 2)
    np.testing.assert_allclose(np.diff(lines[:, 0, 1]), 4.0)  # spacing
    np.testing.assert_allclose(np.hypot(*(lines[:, 1] - lines[:, 0]).T), 15.0)  # length
    # Heading 90 deg: lines run east; starboard of east is south, port is north.
    east = lawnmower(2, 4.0, 10.0, math.pi / 2, side=1)
    np.testing.assert_allclose(east, [[0, 0], [0, 10], [-4, 10], [-4, 0]], atol=1e-12)
    port = lawnmower(2, 4.0, 10.0, math.pi / 2, side=-1)
    np.testing.assert_allclose(port[2], [4, 10], atol=1e-12)
    with pytest.raises(ValueError, match="lines"):
        lawnmower(0, 4.0, 10.0, 0.0)
    with pytest.raises(ValueError, match="side"):
        lawnmower(2, 4.0, 10.0, 0.0, side=0)


def test_parse_waypoints() -> None:
    np.testing.assert_allclose(parse_waypoints("1, 2; 3 4;\n-5,6"), [[1, 2], [3, 4], [-5, 6]])
    with pytest.raises(ValueError, match="entry 2"):
        parse_waypoints("1, 2; 3")
    with pytest.raises(ValueError, match="no waypoint"):
        parse_waypoints(" ; ")


@pytest.mark.parametrize("length", [15.0, 1.5])
def test_leg_profile_bounds_continuity_and_consistency(length: float) -> None:
    prof = LegProfile(length, speed=0.3, accel=0.05)
    T = prof.duration
    t = np.linspace(0.0, T, 4001)
    s, v, a = np.array([prof.at(x) for x in t]).T
    assert s[0] == 0.0 and s[-1] == pytest.approx(length, abs=1e-12)
    assert np.all(np.diff(s) >= -1e-12)  # never goes back
    assert v.max() <= 0.3 + 1e-12 and np.abs(a).max() <= 0.05 + 1e-12
    if length == 15.0:
        assert v.max() == pytest.approx(0.3)  # cruise reached
        assert T == pytest.approx(15.0 / 0.3 + math.pi * 0.3 / (2 * 0.05))
    else:  # too short to reach the speed: peak speed sqrt(2 a L / pi), peak acceleration still a
        assert v.max() == pytest.approx(math.sqrt(2 * 0.05 * 1.5 / math.pi), rel=1e-6)
        assert np.abs(a).max() == pytest.approx(0.05, rel=1e-4)
    dt = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(s, dt)[1:-1], v[1:-1], atol=2e-5)  # v = ds/dt
    np.testing.assert_allclose(np.gradient(v, dt)[1:-1], a[1:-1], atol=2e-4)  # a = dv/dt
    assert np.abs(np.diff(v)).max() < 1e-3 and np.abs(np.diff(a)).max() < 1e-3  # continuous
    assert prof.at(T + 5.0) == (length, 0.0, 0.0) and prof.at(-1.0) == (0.0, 0.0, 0.0)


def fly(guide: PathGuidance, seconds: float, offset: tuple[float, float] = (0.0, 0.0), h: float = 0.05,
        lag_steps: int = 0) -> list:
    """A vessel that follows the reference point exactly (optionally offset or some steps late)."""
    out, history = [], []
    pos = guide.points[0].copy()
    for _ in range(round(seconds / h)):
        g = guide.step(h, pos)
        history.append(g.pos + np.asarray(offset))
        pos = history[max(0, len(history) - 1 - lag_steps)]
        out.append(g)
    return out


def test_perfect_follower_flies_every_leg_within_the_speed_limit() -> None:
    guide = PathGuidance(speed=0.3, accel=0.05, acceptance=0.5, yaw_rate=0.2)
    guide.start(lawnmower(6, 4.0, 15.0, 0.0, origin=(10.0, 2.0)), pos=(0.0, 0.0), yaw=0.0)
    assert guide.legs == 12  # approach + 11
    out = fly(guide, guide.total_time() + 5.0, lag_steps=4)
    legs = [g.leg for g in out]
    assert legs[-1] == 13 and np.all(np.diff(legs) >= 0)  # all done, in order
    speeds = np.array([g.speed for g in out])
    vel = np.array([np.hypot(*g.vel) for g in out])
    acc = np.array([np.hypot(*g.acc) for g in out])
    assert speeds.max() == pytest.approx(0.3) and vel.max() <= 0.3 + 1e-12 and acc.max() <= 0.05 + 1e-12
    # A follower 0.2 s late is accepted on arrival: the survey takes the sum of the leg times.
    t_done = 0.05 * (legs.index(13) + 1)
    assert t_done == pytest.approx(guide.total_time(), abs=0.2)
    # Heading along each leg: north, east, south, east, north ... (lines 1 and 2, connector east).
    np.testing.assert_allclose(guide.courses[1:4], [0.0, math.pi / 2, math.pi], atol=1e-12)
    # The reference stops on every corner, so a follower this close passes within centimetres.
    assert max(guide.corner_errors) < 0.02 and len(guide.corner_errors) == 11


def test_reference_waits_at_the_corner_until_the_vessel_is_inside_the_circle() -> None:
    guide = PathGuidance(speed=0.3, accel=0.05, acceptance=0.5, yaw_rate=0.2)
    guide.start(np.array([[10.0, 0.0], [10.0, 5.0]]), pos=(0.0, 0.0), yaw=0.0)
    h = 0.05
    stuck = np.array([0.0, 0.0])  # the vessel does not move (e.g. saturated against a current)
    for _ in range(round((guide.profiles[0].duration + 30.0) / h)):
        g = guide.step(h, stuck)
    assert g.leg == 1 and np.allclose(g.pos, [10.0, 0.0]) and g.speed == 0.0  # waits at the corner
    g = guide.step(h, (9.6, 0.2))  # 0.447 m from the corner: inside the 0.5 m circle
    assert g.leg == 2
    guide.start(np.array([[10.0, 0.0], [10.0, 5.0]]), pos=(0.0, 0.0), yaw=0.0)
    for _ in range(round((guide.profiles[0].duration + 1.0) / h)):
        g = guide.step(h, (9.4, 0.0))  # 0.6 m short: outside the circle, no switch
    assert g.leg == 1


def test_corner_error_is_the_closest_approach_and_cross_track_is_signed() -> None:
    guide = PathGuidance(speed=0.3, accel=0.05, acceptance=0.5, yaw_rate=0.2)
    guide.start(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 6.0]]), pos=(0.0, 0.0), yaw=0.0)
    # Follow the reference 0.1 m ahead (north) and 0.05 m to starboard (east) of it: the vessel
    # passes the corner (10, 0) 5 cm to its side (when the reference is 0.1 m short of it).
    out = fly(guide, guide.total_time() + 10.0, offset=(0.1, 0.05))
    assert guide.corner_errors == [pytest.approx(0.05, abs=1e-3)]
    assert guide.legs == 2  # the approach from (0, 0) to waypoint 1 at (0, 0) has no length: dropped
    north_leg = [g for g in out if g.leg == 1]
    assert north_leg[100].cross_track == pytest.approx(0.05, abs=1e-9)  # heading north, east = starboard
    east_leg = [g for g in out if g.leg == 2]
    assert east_leg[-1].cross_track == pytest.approx(-0.1, abs=1e-9)  # heading east, north = port
    assert out[-1].corner_error == pytest.approx(0.05, abs=1e-3)  # held after the corner


def test_heading_turns_smoothly_at_the_rate_limit() -> None:
    guide = PathGuidance(speed=0.3, accel=0.05, acceptance=0.5, yaw_rate=0.2)
    guide.start(np.array([[0.0, 5.0], [-5.0, 5.0]]), pos=(0.0, 0.0), yaw=0.0)
    out = fly(guide, guide.total_time() + 30.0)
    yaw = np.array([g.yaw for g in out])
    rate = np.array([g.yaw_rate for g in out])
    assert np.abs(rate).max() == pytest.approx(0.2, abs=1e-9)  # the limit binds for 90 deg turns
    assert yaw[-1] == pytest.approx(math.pi, abs=1e-3) or yaw[-1] == pytest.approx(-math.pi, abs=1e-3)
    steps = np.abs(np.angle(np.exp(1j * np.diff(yaw))))
    assert steps.max() <= 0.2 * 0.05 + 1e-9  # no jumps, also not at +-pi
