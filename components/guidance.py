"""Waypoint guidance for a fully actuated vessel (Minerva 2): lawnmower surveys along straight lines.

Path following with a speed-limited reference point (Fossen 2011, ch. 10, "trajectory tracking
along straight lines"): the path is a polyline of waypoints; on each leg a reference point runs
from the start to the end waypoint with a smooth trapezoidal speed profile (cosine ramps, so the
acceleration is continuous and bounded by ``accel``, the speed by ``speed``). The DP controller
tracks the reference point (position, velocity and acceleration as feed-forward).

Why this and not line-of-sight: an ROV can push sideways, so it does not need to steer its
heading onto the line to stay on it, and a reference point that *stops* at every corner gives a
corner error of the order of the tracking error (centimetres) instead of the turning radius an
LOS vessel cuts off (the original HIL runs: about 0.4 m). The price is a little time per corner
(one ramp down and one up: ``pi speed / (2 accel)`` seconds).

Switching: the next leg starts when the reference point has reached the end waypoint AND the
vessel (its estimate) is inside the circle of acceptance of radius ``acceptance`` around it. The
reference waits at the corner otherwise, so a vessel that falls behind (saturation, current) is
never left behind by its own reference: that is the path-following element.

Heading: along the active leg (``yaw_mode`` 0: the camera looks where the vessel goes) or the
external heading setpoint (``yaw_mode`` 1), smoothed by a rate-limited second-order reference
model so a 90 degree corner becomes a smooth turn.

Measures (from the estimate): the signed cross-track error to the active leg (positive = to
starboard of the leg direction), and the corner error = the distance of closest approach to each
corner waypoint, monitored from the start of the leg that ends there until the vessel has left
twice the acceptance circle on the next leg (or the leg after starts).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .dynamics import wrap_angle

RK4_DT_MAX = 0.05  # s: largest sub-step of the heading filter
MIN_LEG = 1e-3  # m: shorter legs (e.g. the approach leg when the vessel starts on waypoint 1) are dropped


MAX_LINES = 1000  # a survey of more lines is a list of waypoints; a bound keeps one step short


def lawnmower(lines: int, spacing: float, length: float, heading: float,
              origin: Sequence[float] = (0.0, 0.0), side: int = 1) -> np.ndarray:
    """Waypoints (north, east) of a lawnmower survey: ``lines`` parallel lines of ``length`` metres.

    The first line starts at ``origin`` and runs along ``heading`` (rad from north); each next
    line is ``spacing`` metres to starboard (``side`` = 1) or port (-1) and runs the other way.
    Returns a (2 lines, 2) array: start and end of every line, in the order they are flown.
    """
    if int(lines) != lines or not 1 <= lines <= MAX_LINES:
        raise ValueError(f"lawnmower: lines must be a whole number from 1 to {MAX_LINES}, got {lines!r}")
    if not (length > 0.0 and math.isfinite(length)):
        raise ValueError(f"lawnmower: length must be positive, got {length!r}")
    if not (spacing >= 0.0 and math.isfinite(spacing)):
        raise ValueError(f"lawnmower: spacing must be >= 0, got {spacing!r}")
    if side not in (-1, 1):
        raise ValueError(f"lawnmower: side must be 1 (starboard) or -1 (port), got {side!r}")
    c, s = math.cos(heading), math.sin(heading)
    along = np.array([c, s])
    right = side * np.array([-s, c])  # starboard of the line direction, in NED
    o = np.asarray(origin, dtype=float)
    pts: list[np.ndarray] = []
    for i in range(int(lines)):
        a = o + i * spacing * right
        b = a + length * along
        pts += [a, b] if i % 2 == 0 else [b, a]
    return np.array(pts)


def parse_waypoints(text: str) -> np.ndarray:
    """'n1, e1; n2, e2; ...' (metres) -> (k, 2) array; ValueError names the bad entry."""
    pts = []
    for k, item in enumerate(t for t in text.replace("\n", ";").split(";") if t.strip()):
        parts = [p for p in item.replace(",", " ").split() if p]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"waypoints: entry {k + 1} '{item.strip()}' is not 'north, east'") from None
        if len(vals) != 2 or not all(math.isfinite(v) for v in vals):
            raise ValueError(f"waypoints: entry {k + 1} '{item.strip()}' is not 'north, east'")
        pts.append(vals)
    if not pts:
        raise ValueError("waypoints: no waypoint given")
    return np.array(pts)


@dataclass(frozen=True)
class LegProfile:
    """Smooth trapezoidal speed profile over a straight leg: s(t), v(t), a(t) in closed form.

    Ramps are half cosines, v = U/2 (1 - cos(pi t / T_a)) with T_a = pi U / (2 a_max), so the peak
    acceleration is exactly a_max and it is continuous (no force steps from the feed-forward). A leg
    too short to reach ``speed`` gets the peak speed U = sqrt(2 a_max L / pi) instead.
    """

    length: float
    speed: float
    accel: float

    @cached_property
    def peak_speed(self) -> float:
        return min(self.speed, math.sqrt(2.0 * self.accel * self.length / math.pi))

    @cached_property
    def ramp_time(self) -> float:
        return math.pi * self.peak_speed / (2.0 * self.accel)

    @cached_property
    def duration(self) -> float:
        u = self.peak_speed
        if u <= 0.0:
            return 0.0
        return self.length / u + self.ramp_time

    def at(self, t: float) -> tuple[float, float, float]:
        """(s, v, a) at time t after the start of the leg; holds (length, 0, 0) after the end."""
        u, ta, total = self.peak_speed, self.ramp_time, self.duration
        if t <= 0.0 or u <= 0.0:
            return (0.0, 0.0, 0.0) if t <= 0.0 else (self.length, 0.0, 0.0)
        if t >= total:
            return self.length, 0.0, 0.0
        w = math.pi / ta
        if t < ta:
            return (0.5 * u * (t - math.sin(w * t) / w), 0.5 * u * (1.0 - math.cos(w * t)),
                    0.5 * u * w * math.sin(w * t))
        tau = total - t  # time to go
        if tau < ta:
            return (self.length - 0.5 * u * (tau - math.sin(w * tau) / w),
                    0.5 * u * (1.0 - math.cos(w * tau)), -0.5 * u * w * math.sin(w * tau))
        return 0.5 * u * ta + u * (t - ta), u, 0.0


class HeadingFilter:
    """Critically damped 2nd-order heading reference with a rate limit (scalar, wrapped error).

    The same law as ``ReferenceModel`` with ``v_max`` (x_dd = -w^2 e - 2 w x_d, no push past the
    rate limit, rate clipped after each RK4 sub-step), in plain floats: called every step.
    """

    def __init__(self, omega: float, rate_max: float) -> None:
        self.omega, self.rate_max = float(omega), float(rate_max)
        self.x = self.v = self.a = 0.0

    def reset(self, x: float, v: float = 0.0) -> None:
        self.x, self.v, self.a = float(wrap_angle(x)), float(v), 0.0

    def _accel(self, e: float, v: float) -> float:
        w = self.omega
        a = -w * w * e - 2.0 * w * v
        return 0.0 if abs(v) >= self.rate_max and a * v > 0.0 else a

    def step(self, h: float, target: float) -> tuple[float, float, float]:
        e0 = (self.x - target + math.pi) % (2.0 * math.pi) - math.pi
        e, v, vm = e0, self.v, self.rate_max
        k = max(1, math.ceil(h / RK4_DT_MAX - 1e-9))
        dt = h / k
        f = self._accel
        for _ in range(k):
            k1e, k1v = v, f(e, v)
            k2e, k2v = v + 0.5 * dt * k1v, f(e + 0.5 * dt * k1e, v + 0.5 * dt * k1v)
            k3e, k3v = v + 0.5 * dt * k2v, f(e + 0.5 * dt * k2e, v + 0.5 * dt * k2v)
            k4e, k4v = v + dt * k3v, f(e + dt * k3e, v + dt * k3v)
            e += dt / 6.0 * (k1e + 2.0 * k2e + 2.0 * k3e + k4e)
            v = min(max(v + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v), -vm), vm)
        x = self.x + (e - e0)
        self.x = x if -math.pi < x <= math.pi else float(wrap_angle(x))
        self.v, self.a = v, f(e, v)
        return self.x, self.v, self.a


@dataclass
class GuidanceOutput:
    """One guidance step: reference point (NED), its derivatives, heading reference, measures."""

    pos: np.ndarray  # (north, east) of the reference point, m
    vel: np.ndarray  # m/s
    acc: np.ndarray  # m/s^2
    yaw: float  # rad
    yaw_rate: float  # rad/s
    yaw_acc: float  # rad/s^2
    cross_track: float  # m, estimate to the active leg, + = starboard of the leg direction
    corner_error: float  # m, closest approach to the last corner passed (0 before the first)
    leg: int  # 1-based active leg; legs + 1 when the last waypoint has been accepted
    speed: float  # m/s, reference speed along the path


class PathGuidance:
    """Reference point along a polyline, legs switched at a circle of acceptance (see module doc)."""

    def __init__(self, speed: float, accel: float, acceptance: float, yaw_rate: float,
                 yaw_omega: float = 0.5, yaw_mode: int = 0) -> None:
        for name, v in (("speed", speed), ("accel", accel), ("acceptance", acceptance),
                        ("yaw_rate", yaw_rate), ("yaw_omega", yaw_omega)):
            if not (v > 0.0 and math.isfinite(v)):
                raise ValueError(f"guidance: {name} must be positive and finite, got {v!r}")
        if yaw_mode not in (0, 1):
            raise ValueError(f"guidance: yaw_mode must be 0 (along the leg) or 1 (setpoint), "
                             f"got {yaw_mode!r}")
        self.speed, self.accel, self.acceptance = float(speed), float(accel), float(acceptance)
        self.yaw_mode = int(yaw_mode)
        self.yaw_ref = HeadingFilter(yaw_omega, yaw_rate)
        self.points = np.zeros((1, 2))
        self.profiles: list[LegProfile] = []
        self.courses: list[float] = []
        self.leg = 0  # 0-based active leg; == len(profiles) when done
        self.t_leg = 0.0
        self.corner_error = 0.0
        self.corner_errors: list[float] = []
        self._d_min = math.inf  # closest approach to the end of the active leg so far
        self._prev: tuple[np.ndarray, float] | None = None  # corner still monitored after the switch

    @property
    def legs(self) -> int:
        return len(self.profiles)

    @property
    def done(self) -> bool:
        return self.leg >= len(self.profiles)

    def start(self, waypoints: np.ndarray, pos: Sequence[float], yaw: float, yaw_rate: float = 0.0) -> None:
        """Begin at ``pos`` (north, east): the first leg runs from there to waypoint 1."""
        wp = np.asarray(waypoints, dtype=float).reshape(-1, 2)
        pts = [np.asarray(pos, dtype=float)]
        for p in wp:
            if np.hypot(*(p - pts[-1])) > MIN_LEG:
                pts.append(p)
        self.points = np.array(pts)
        d = np.diff(self.points, axis=0)
        lengths = np.hypot(d[:, 0], d[:, 1])
        self.profiles = [LegProfile(float(L), self.speed, self.accel) for L in lengths]
        # Heading along each leg; a leg shorter than the acceptance circle keeps the previous one.
        courses, last = [], float(yaw)
        for dk, L in zip(d, lengths, strict=True):
            if L >= self.acceptance:
                last = math.atan2(dk[1], dk[0])
            courses.append(last)
        self.courses = courses
        self.leg, self.t_leg = 0, 0.0
        self.corner_error, self.corner_errors = 0.0, []
        self._d_min, self._prev = math.inf, None
        self.yaw_ref.reset(yaw, yaw_rate)

    def _reference(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        if self.done:
            return self.points[-1].copy(), np.zeros(2), np.zeros(2), 0.0
        a, b = self.points[self.leg], self.points[self.leg + 1]
        prof = self.profiles[self.leg]
        t = (b - a) / prof.length
        s, v, acc = prof.at(self.t_leg)
        return a + s * t, v * t, acc * t, v

    def step(self, h: float, pos: Sequence[float], yaw_setpoint: float = 0.0) -> GuidanceOutput:
        """Advance by h; ``pos`` is the vessel's estimated (north, east)."""
        p = np.asarray(pos, dtype=float)
        if not self.done:
            self.t_leg += h
            end = self.points[self.leg + 1]
            dist = float(np.hypot(*(p - end)))
            self._d_min = min(self._d_min, dist)
            excess = self.t_leg - self.profiles[self.leg].duration
            if excess >= 0.0 and dist <= self.acceptance:
                self._finish_corner()  # the corner before this one, if still monitored
                if self.leg + 1 < len(self.profiles):
                    self._prev = (end.copy(), self._d_min)
                self.leg += 1
                # Arrived during this step: the rest of the step belongs to the next leg.
                self.t_leg = excess if excess < h else 0.0
                self._d_min = math.inf
        if self._prev is not None:
            corner, dmin = self._prev
            dist = float(np.hypot(*(p - corner)))
            self._prev = (corner, min(dmin, dist))
            if dist > 2.0 * self.acceptance:
                self._finish_corner()
        ref_pos, ref_vel, ref_acc, speed = self._reference()
        # Heading: along the active leg (the last one when done) or the external setpoint.
        if self.yaw_mode == 0 and self.courses:
            target = self.courses[min(self.leg, len(self.courses) - 1)]
        else:
            target = yaw_setpoint
        y, r, ra = self.yaw_ref.step(h, target)
        return GuidanceOutput(ref_pos, ref_vel, ref_acc, y, r, ra, self.cross_track(p), self.corner_error,
                              self.leg + 1, speed)

    def _finish_corner(self) -> None:
        if self._prev is not None:
            self.corner_error = self._prev[1]
            self.corner_errors.append(self.corner_error)
            self._prev = None

    def cross_track(self, pos: np.ndarray) -> float:
        """Signed distance of ``pos`` to the active leg's line (+ = starboard of its direction)."""
        if not self.profiles:
            return 0.0
        k = min(self.leg, len(self.profiles) - 1)
        a, b = self.points[k], self.points[k + 1]
        t = (b - a) / self.profiles[k].length
        e = np.asarray(pos, dtype=float) - a
        return float(-e[0] * t[1] + e[1] * t[0])

    def total_time(self) -> float:
        """Sum of the leg durations: the survey time if every corner is accepted on arrival."""
        return float(sum(p.duration for p in self.profiles))

