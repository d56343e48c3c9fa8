"""Damping power law: the quadratic drag term is d v|v|^(p-1), its exponent free."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    not_a_damping_trial,
    register,
    words,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class DampingPower(CatalogueEffect):
    name = "damping_power"
    meaning = "drag proportional to v|v|^(p-1): the exponent of the quadratic drag term is not 2"
    params = ("p_v",)
    observable_in = ("static force-speed, decay, step, 2nd-order decay whose baseline has the quadratic "
                     "term")
    position = 17
    absent = 2.0
    units: ClassVar[dict[str, tuple[str, bool]]] = {"p_v": ("ratio", False)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"p_v": (1.05, 4.0)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"p_v": (1.05, 4.0)}
    # a family close to other effects' shapes (p near 1 looks like linear damping): named only where
    # it beats each accepted specific effect by the rule's margins (diagnosis.choose)
    general = True
    families = ("first", "second")  # the loops' d_Q w|w|^(p_v - 1) (ts_kernels), neutral 2
    demo_kinds = ("decay",)
    plant_missing = "the vessel model's damping is D_L nu + D_Q |nu| nu: no other exponent"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        return [{"p_v": x} for x in (1.5, 1.8, 2.3)]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"p_v": [1.5, 2.5]}

    def applies(self, trial: Trial) -> str | None:
        why = not_a_damping_trial(trial, "the pendulum law fixes its exponents")
        if why:
            return why
        if trial.baseline not in ("quadratic", "linear_quadratic"):
            return ("the baseline has no quadratic drag term whose exponent could differ (see "
                    "quadratic_damping)")
        return None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        what, _, _ = words(trial)
        p = params.get("p_v", 2.0)
        half = params.get("p_v_halfwidth")
        ci = f" ± {half:.2g}" if half is not None else ""
        speed = "faster" if p > 2 else "slower"
        return (f"the {what} drag grows {speed} than the square of speed: d_Q v|v|^(p-1), "
                f"p = {p:.3g}{ci}")

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        """The quadratic term's change: d_Q (w|w|^(p-1) - w|w|) (quadratic_damping's term stays)."""
        p = v.get("p_v")
        if p is None or "d_Q" not in v or p == 2.0:
            return None
        return v["d_Q"] * (np.sign(w) * np.abs(w) ** p - w * np.abs(w))

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # drag ~ v|v|^0.5; coast-downs from up to 2 m/s span the speeds that show the exponent
        return Hiding(truth={"p_v": 1.5, "d_Q": 30.0}, starts=(2.0, 1.0, 0.5))
