"""Quadratic damping: a drag term proportional to v|v| is missing."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    not_a_damping_trial,
    register,
    unit,
    words,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class QuadraticDamping(CatalogueEffect):
    name = "quadratic_damping"
    meaning = "drag term proportional to v|v| missing"
    params = ("d_Q",)
    observable_in = "static force-speed, decay, step, 2nd-order decay whose baseline lacks the quadratic term"
    position = 2
    units: ClassVar[dict[str, tuple[str, bool]]] = {"d_Q": ("damping_Q", True)}
    families = ("first", "second")
    demo_kinds = ("decay", "static", "decay2")
    plant = ("surge_decay", "the shipped AMV (D_Q = 34.08); trial baseline: linear")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        F, V = s["F"], s["V"]
        return [{"d_Q": x} for x in [0.1 * F / V**2, 0.5 * F / V**2]]

    def applies(self, trial: Trial) -> str | None:
        why = not_a_damping_trial(trial, "the pendulum law already has both terms")
        if why:
            return why
        has = trial.baseline in ("quadratic", "linear_quadratic")
        return "the baseline already has this term" if has else None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        what, _, _ = words(trial)
        return (f"the {what} resistance grows with the square of speed: a quadratic drag term "
                f"d_Q = {fmt(params.get('d_Q', 0))} {unit('d_Q', trial)} is missing")

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        return v["d_Q"] * w * np.abs(w) if "d_Q" in v else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"d_Q": -speed * np.abs(speed)}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # the 2nd-order rig's truth gets the term (its clean truth has none); the baseline lacks it
        return Hiding(truth={"d_Q": 3.0} if kind == "decay2" else {}, baseline="linear")

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(baseline="linear")  # the shipped AMV has it
