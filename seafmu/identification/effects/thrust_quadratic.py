"""Quadratic thrust: thrust proportional to n|n| rather than n."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, rpm_step, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustQuadratic(CatalogueEffect):
    name = "thrust_quadratic"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        U = s["U"]
        return [{"k_q": x} for x in [-0.5 * vals.get("k", 1.0) / U, 0.3 * vals.get("k", 1.0) / U,
                                     vals.get("k", 1.0) / U]]

    def applies(self, trial: Trial) -> str | None:
        thr = static_thrust(trial)
        if (thr or rpm_step(trial)) and trial.thrust_law == "linear" and not (
                thr and trial.baseline == "quadratic"):
            return None
        return "needs a shaft-speed input with a linear thrust law"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust grows with n|n| like a propeller's, not linearly with shaft speed "
                f"(k_q = {fmt(params.get('k_q', 0))} {unit('k_q', trial)})")
