"""Current: the water moves, damping and the added-mass Coriolis terms act on nu - nu_c.

In a maneuver log the inertia term has two physical forms that differ while the hull turns in the
current (components/vessel_model.py, ``current_inertia``): M nu_dot (the vessel files' default,
``absolute``) and Fossen's hull in an irrotational current, M_RB nu_dot + M_A nu_r_dot (``added``);
``relative`` is M nu_r_dot (the supply vessel's DP model). A log made with another form than the
fitted one left a spurious constant force beside the current (Minerva 2: F_0[Y] = 0.96 N,
F_0[K] = -2.2 N m, and a current 15 % low), so the maneuver fit tries the vessel file's form and
Fossen's (``maneuver_forms``) and keeps the one that fits better.
"""

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

# The inertia the current's rate acts through, as weights (a, b) of a M_RB + b M_A: with a current
# constant in NED, nu_c_dot = -omega x nu_c in the body, so M nu_dot gets -(a M_RB + b M_A)(omega x nu_c).
INERTIA_FORMS: dict[str, tuple[float, float]] = {"absolute": (0.0, 0.0), "added": (0.0, 1.0),
                                                 "relative": (1.0, 1.0)}
_FORM_WORDS = {"absolute": "the inertia acting on the absolute acceleration, M nu_dot",
               "added": "the added mass acting on the acceleration through the water, "
                        "M_RB nu_dot + M_A nu_r_dot (Fossen's hull in an irrotational current)",
               "relative": "the inertia acting on the acceleration through the water, M nu_r_dot"}


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

    def __init__(self, inertia: str | None = None) -> None:
        # the registered object simulates the vessel file's form; its forms name one each
        if inertia is not None and inertia not in INERTIA_FORMS:
            raise ValueError(f"current inertia must be one of {', '.join(INERTIA_FORMS)}, got {inertia!r}")
        self.inertia = inertia

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
        """vc (K, 2), and vc_inertia (K, 2), the weights of the form, unless it is the vessel file's."""
        if self.inertia is None:
            return {"vc": P[:, :2]}
        return {"vc": P[:, :2], "vc_inertia": np.tile(INERTIA_FORMS[self.inertia], (P.shape[0], 1))}

    def maneuver_forms(self, vessel: Any) -> list[CatalogueEffect]:
        """The vessel file's inertia form and Fossen's (``added``), once each when they are one; an
        object of one form, itself."""
        if self.inertia is not None:
            return [self]
        return [Current(f) for f in dict.fromkeys((vessel.current_inertia, "added"))]

    def maneuver_form(self) -> str | None:
        """The form in words (None: the vessel file's, unnamed)."""
        if self.inertia is None:
            return None
        return f"current inertia '{self.inertia}': {_FORM_WORDS[self.inertia]}"

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        vn, ve = params.get("v_c_north", 0.0), params.get("v_c_east", 0.0)
        towards = math.degrees(math.atan2(ve, vn)) % 360.0
        return (f"the hull moves through a current of {fmt(math.hypot(vn, ve))} m/s towards "
                f"{towards:.0f} deg (north {fmt(vn)}, east {fmt(ve)} m/s): the damping acts on the "
                "velocity through the water")
