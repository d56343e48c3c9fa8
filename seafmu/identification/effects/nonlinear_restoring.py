"""Nonlinear restoring: restoring not proportional to the angle (sin or a cubic term)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, Hiding, fmt, register, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class NonlinearRestoring(CatalogueEffect):
    name = "nonlinear_restoring"
    meaning = "restoring not proportional to the angle (sin or cubic term)"
    params = ("c3",)
    observable_in = "2nd-order decay with a linear restoring baseline"
    position = 13
    units: ClassVar[dict[str, tuple[str, bool]]] = {"c3": ("stiffness3", True)}
    families = ("second",)
    demo_kinds = ("decay2",)
    plant = ("pitch_decay", "Minerva 2 trimmed neutral (righting moment BG W sin(theta)); trial restoring: "
                            "linear")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        V = s["V"]
        return [{"c3": x} for x in [x * abs(vals.get("c", 1.0)) / V**2 for x in (-0.3, -0.1, 0.1, 0.3)]]

    def applies(self, trial: Trial) -> str | None:
        if trial.kind == "decay2" and trial.restoring == "linear":
            return None
        return "needs a 2nd-order decay with a linear restoring baseline"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        _, force, rot = words(trial)
        return (f"the restoring {force} is not linear in the "
                f"{'angle' if rot else 'displacement'} "
                f"(cubic term c3 = {fmt(params.get('c3', 0))} {unit('c3', trial)}, e.g. a sin-shaped "
                f"righting arm)")

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"c3": -pos**3} if pos is not None else {}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(restoring="sin")  # the truth's restoring is sin x; the trial states linear

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(trial_restoring="linear")  # the plant's righting moment is BG W sin(theta)
