"""Linear damping: a drag term proportional to v is missing."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    not_a_damping_trial,
    register,
    replace_matrix,
    unit,
    words,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class LinearDamping(CatalogueEffect):
    name = "linear_damping"
    meaning = "drag term proportional to v missing"
    params = ("d_L",)
    observable_in = "static force-speed, decay, step, 2nd-order decay whose baseline lacks the linear term"
    position = 1
    units: ClassVar[dict[str, tuple[str, bool]]] = {"d_L": ("damping_L", True)}
    families = ("first", "second")
    demo_kinds = ("decay", "static")
    plant = ("surge_decay", "vessel D_L[0][0] = 8 N/(m/s); trial baseline: quadratic")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        F, V = s["F"], s["V"]
        return [{"d_L": x} for x in [0.1 * F / V, 0.5 * F / V]]

    def applies(self, trial: Trial) -> str | None:
        why = not_a_damping_trial(trial, "the pendulum law already has both terms")
        if why:
            return why
        has = trial.baseline in ("linear", "linear_quadratic")
        return "the baseline already has this term" if has else None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        what, _, _ = words(trial)
        return (f"the {what} damping has a missing linear (viscous/skin-friction) part, "
                f"d_L = {fmt(params.get('d_L', 0))} {unit('d_L', trial)}")

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        return v["d_L"] * w if "d_L" in v else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"d_L": -speed}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # the truth has the term (decay: a larger one, to be seen beside d_Q); the baseline lacks it
        return Hiding(truth={"d_L": 8.0} if kind == "decay" else {}, baseline="quadratic")

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_surge_d_L_8, baseline="quadratic")


def _surge_d_L_8(spec: Any) -> Any:
    return dataclasses.replace(spec, D_L=replace_matrix(spec.D_L, {(0, 0): 8.0}))
