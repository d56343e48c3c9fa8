"""Quadratic damping: a drag term proportional to v|v| is missing."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, static_force_speed, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class QuadraticDamping(CatalogueEffect):
    name = "quadratic_damping"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        F, V = s["F"], s["V"]
        return [{"d_Q": x} for x in [0.1 * F / V**2, 0.5 * F / V**2]]

    def applies(self, trial: Trial) -> str | None:
        k = trial.kind
        if not (static_force_speed(trial) or k in ("decay", "step", "decay2")):
            return "not a damping trial" if k != "pendulum" else "the pendulum law already has both terms"
        has = trial.baseline in ("quadratic", "linear_quadratic")
        return "the baseline already has this term" if has else None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        what, _, _ = words(trial)
        return (f"the {what} resistance grows with the square of speed: a quadratic drag term "
                f"d_Q = {fmt(params.get('d_Q', 0))} {unit('d_Q', trial)} is missing")
