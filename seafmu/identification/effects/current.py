"""Current: the water moves, damping and the added-mass Coriolis terms act on nu - nu_c."""

from __future__ import annotations

import math

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, fmt, register


@register
class Current(CatalogueEffect):
    name = "current"
    maneuver = True

    def maneuver_params(self, d: int) -> list[str]:
        """The NED current (north, east), m/s."""
        return ["v_c_north", "v_c_east"]

    def maneuver_scales(self, tau: np.ndarray) -> list[float]:
        return [0.1, 0.1]  # m/s

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"vc": P[:, :2]}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        vn, ve = params.get("v_c_north", 0.0), params.get("v_c_east", 0.0)
        towards = math.degrees(math.atan2(ve, vn)) % 360.0
        return (f"the hull moves through a current of {fmt(math.hypot(vn, ve))} m/s towards "
                f"{towards:.0f} deg (north {fmt(vn)}, east {fmt(ve)} m/s): the damping acts on the "
                "velocity through the water")
