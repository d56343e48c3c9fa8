"""Current: the water moves, damping and the added-mass Coriolis terms act on nu - nu_c."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    moves_both_ways,
    register,
    static_force_speed,
    unit,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Current(CatalogueEffect):
    name = "current"
    meaning = "the water moves: damping acts on v - v_c"
    params = ("v_c",)
    observable_in = ("static force-speed, decay, step with quadratic damping and motion ahead and astern (to "
                     "tell it from a constant force); maneuver (NED current v_c_north, v_c_east)")
    position = 4
    maneuver = True
    units: ClassVar[dict[str, tuple[str, bool]]] = {"v_c": ("speed", False)}
    families = ("first",)  # a state term of the 1st-order loop: damping acts on v - v_c
    input_stage = 15  # a table's speed through the water
    demo_kinds = ("decay",)
    plant = ("surge_decay", "plant current_speed 0.1 m/s towards north, heading north; runs ahead and astern")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        V = s["V"]
        return [{"v_c": x} for x in [-0.3 * V, -0.1 * V, 0.1 * V, 0.3 * V]]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"v_c": [-0.2 * xmax, -0.05 * xmax, 0.05 * xmax, 0.2 * xmax]}

    def applies(self, trial: Trial) -> str | None:
        if not (static_force_speed(trial) or trial.kind in ("decay", "step")):
            return "a current shows in damping of a translating or turning hull, not here"
        if trial.baseline == "linear":
            return "with linear damping only, a current is the same model as a constant force"
        if trial.mirror:
            return "a mirrored table is antisymmetric by construction: no current can show"
        if not moves_both_ways(trial):
            return ("needs motion ahead and astern: in one direction a current looks like a constant "
                    "force plus a change of linear damping")
        return None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the hull moves through a current of {fmt(params.get('v_c', 0))} {unit('v_c', trial)}: the "
                f"damping acts on the speed through the water, not the measured speed")

    def static_input(self, x: np.ndarray, v: dict[str, float]) -> np.ndarray:
        return x - v["v_c"] if "v_c" in v else x

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"v_c": 0.1}, starts=(1.0, -1.0, 0.7))

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(plant={"current_speed": 0.1, "current_direction": 0.0}, starts=(1.0, -1.0, 0.7))

    def maneuver_params(self, d: int) -> list[str]:
        """The NED current (north, east), m/s."""
        return ["v_c_north", "v_c_east"]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        return [0.1, 0.1]  # m/s

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"vc": P[:, :2]}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        vn, ve = params.get("v_c_north", 0.0), params.get("v_c_east", 0.0)
        towards = math.degrees(math.atan2(ve, vn)) % 360.0
        return (f"the hull moves through a current of {fmt(math.hypot(vn, ve))} m/s towards "
                f"{towards:.0f} deg (north {fmt(vn)}, east {fmt(ve)} m/s): the damping acts on the "
                "velocity through the water")
