"""AMV OSF on land: kinematic screw model (thesis) as pure functions and a helper for the plant.

On land the Archimedes screws roll on the ground like threads: the body velocities follow the
screw speeds kinematically (thesis, brief section 2),

    normal:   u = p (n1 + n2) / 2,   v = 0,                 r = p (n1 - n2) / (2 l_y)
    sideways: u = 0,                 v = d (n1 + n2) / 2,   r = 0     (button held)

with the screw pitch p = 0.35 m, the effective "diameter" d = 0.465 m (the screw circumference)
and the half track l_y = 0.22 m; speed caps 2 m/s forward and 1 m/s sideways (assumed).

Yaw form: the thesis printed r = p (n1 - n2), whose units do not match (m/s, not rad/s). We use
the physical form r = p (n1 - n2) / (2 l_y) by default: each screw's ground speed is p n_i, and
a vehicle whose sides move at p n1 and p n2 with track width 2 l_y turns at their difference over
the track (differential drive). It is 1 / 0.44 = 2.27 times the printed number.
``yaw_form = "published"`` keeps the printed one for comparison.

No on-the-spot rotation (thesis): the yaw rate is limited to |r| <= |u| / l_y, i.e. at most a
pivot about the slower screw; with the screws in opposition (u = 0) the vessel does not turn.
This is the only reading of "no on-the-spot rotation" that is continuous in the screw speeds.

Bumpless land/water transfer: the state vector is the plant's own [north, east, yaw, u, v, r, n1,
n2], so position and heading carry over unchanged; the velocities approach their kinematic values
with a first-order lag ``slip_time`` (assumed 0.5 s: ground contact is not instantaneous), so they
carry over too instead of jumping from the water speed to the screw speed. The screw shafts keep
their first-order lag. ``slip_time = 0`` gives the pure kinematic model (velocities jump).

The plant calls ``LandModel.step`` instead of its water RK4 while its ``land_mode`` parameter is
set (see docs/guidance.md for the hook); everything here is plain functions of arrays, tested
directly in tests/test_amv_modes.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .dynamics import wrap_angle

DEFAULT_SLIP_TIME = 0.5  # s, assumed (see module doc)
YAW_FORMS = ("physical", "published")


@dataclass(frozen=True)
class LandParams:
    """Land kinematics of the AMV; defaults are the thesis's numbers (vessel file ``extra.land``)."""

    pitch: float = 0.35  # m per revolution
    diameter: float = 0.465  # m: effective "diameter" (circumference) in sideways mode
    half_track: float = 0.22  # m: l_y
    u_max: float = 2.0  # m/s (assumed)
    v_max: float = 1.0  # m/s (assumed)
    slip_time: float = DEFAULT_SLIP_TIME
    yaw_form: str = "physical"

    def __post_init__(self) -> None:
        for name in ("pitch", "diameter", "half_track", "u_max", "v_max"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"land: {name} must be positive, got {v!r}")
        if not (math.isfinite(self.slip_time) and self.slip_time >= 0.0):
            raise ValueError(f"land: slip_time must be >= 0, got {self.slip_time!r}")
        if self.yaw_form not in YAW_FORMS:
            raise ValueError(f"land: yaw_form must be one of {', '.join(YAW_FORMS)}, got {self.yaw_form!r}")

    @classmethod
    def from_vessel(cls, vessel: Any, **overrides: Any) -> LandParams:
        """Numbers from the vessel file's ``extra.land`` section (missing entries: the defaults)."""
        land = (getattr(vessel, "extra", None) or {}).get("land", {}) or {}

        def num(key: str, default: float) -> float:
            v = land.get(key, default)
            return float(v["value"] if isinstance(v, dict) else v)

        th = getattr(vessel, "thrusters", None)
        half = float(np.max(np.abs(th.positions[:, 1]))) if th is not None else cls.half_track
        kw: dict[str, Any] = dict(
            pitch=num("pitch", cls.pitch),
            diameter=num("effective_diameter", cls.diameter),
            half_track=num("track_width", 2.0 * half) / 2.0,
            u_max=num("max_forward_speed", cls.u_max),
            v_max=num("max_sideways_speed", cls.v_max),
        )
        kw.update(overrides)
        return cls(**kw)


def land_velocity(n1: float, n2: float, sideways: bool, prm: LandParams) -> tuple[float, float, float]:
    """Body velocities (u, v, r) the screws impose on land (see module doc)."""
    mean = 0.5 * (n1 + n2)
    if sideways:
        v = min(max(prm.diameter * mean, -prm.v_max), prm.v_max)
        return 0.0, v, 0.0
    u = min(max(prm.pitch * mean, -prm.u_max), prm.u_max)
    if prm.yaw_form == "physical":
        r = prm.pitch * (n1 - n2) / (2.0 * prm.half_track)
    else:
        r = prm.pitch * (n1 - n2)  # as printed in the thesis (units do not match)
    r_lim = abs(u) / prm.half_track  # no on-the-spot rotation: at most a pivot about one screw
    return u, 0.0, min(max(r, -r_lim), r_lim)


def land_rhs(x: np.ndarray, n_cmd: np.ndarray, sideways: bool, prm: LandParams,
             shaft_time: np.ndarray) -> np.ndarray:
    """x_dot for x = [north, east, yaw, u, v, r, n1, n2] on land (n_cmd already clipped)."""
    _, _, psi, u, v, r, n1, n2 = (float(c) for c in x)
    uk, vk, rk = land_velocity(n1, n2, sideways, prm)
    c, s = math.cos(psi), math.sin(psi)
    if prm.slip_time > 0.0:
        k = 1.0 / prm.slip_time
        nu_dot = [k * (uk - u), k * (vk - v), k * (rk - r)]
    else:
        nu_dot = [0.0, 0.0, 0.0]
    n_dot = (np.asarray(n_cmd, dtype=float) - x[6:8]) / shaft_time
    return np.array([c * u - s * v, s * u + c * v, r, *nu_dot, *n_dot])


def land_step(x: np.ndarray, n_cmd: np.ndarray, h: float, prm: LandParams, shaft_time: np.ndarray,
              n_max: np.ndarray, sideways: bool = False, substeps: int = 1) -> np.ndarray:
    """Advance the land model by h (RK4, ``substeps`` equal steps); returns the new state.

    With ``slip_time = 0`` the velocities are set to their kinematic values at the end of each
    sub-step (pure kinematics; the position uses the RK4 of the shaft-driven velocities).
    """
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f"land: step h must be finite and > 0, got {h!r}")
    x = np.asarray(x, dtype=float).copy()
    nc = np.clip(np.asarray(n_cmd, dtype=float), -n_max, n_max)
    tc = np.asarray(shaft_time, dtype=float)
    dt = h / max(1, int(substeps))
    pure = prm.slip_time == 0.0
    for _ in range(max(1, int(substeps))):
        if pure:
            x[3:6] = land_velocity(float(x[6]), float(x[7]), sideways, prm)
        k1 = land_rhs(x, nc, sideways, prm, tc)
        k2 = land_rhs(x + 0.5 * dt * k1, nc, sideways, prm, tc)
        k3 = land_rhs(x + 0.5 * dt * k2, nc, sideways, prm, tc)
        k4 = land_rhs(x + dt * k3, nc, sideways, prm, tc)
        x = x + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        if pure:
            x[3:6] = land_velocity(float(x[6]), float(x[7]), sideways, prm)
        x[2] = wrap_angle(float(x[2]))
    return x


class LandModel:
    """What PlantBlock calls in land mode: the vessel's land numbers and screws, one ``step``.

    ``step(x, n_cmd, h, substeps, sideways)`` has the signature of the water model's RK4 call in
    PlantBlock.step (state in, state out), so the hook is one ``if``.
    """

    def __init__(self, vessel: Any, **overrides: Any) -> None:
        th = vessel.thrusters
        if th.count != 2:
            raise ValueError(f"land mode needs exactly two screws, vessel '{vessel.name}' has {th.count}")
        self.params = LandParams.from_vessel(vessel, **overrides)
        self.shaft_time = np.asarray(th.time_constant, dtype=float)
        self.n_max = np.asarray(th.n_max, dtype=float)

    def step(self, x: np.ndarray, n_cmd: list[float] | np.ndarray, h: float, substeps: int = 1,
             sideways: bool = False) -> np.ndarray:
        return land_step(x, np.asarray(n_cmd, dtype=float), h, self.params, self.shaft_time, self.n_max,
                         sideways=sideways, substeps=substeps)
