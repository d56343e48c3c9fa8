"""Quadratic thrust: thrust proportional to n|n| rather than n."""

from __future__ import annotations

from typing import TYPE_CHECKING

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, rpm_step, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustQuadratic(CatalogueEffect):
    name = "thrust_quadratic"

    def applies(self, trial: Trial) -> str | None:
        thr = static_thrust(trial)
        if (thr or rpm_step(trial)) and trial.thrust_law == "linear" and not (
                thr and trial.baseline == "quadratic"):
            return None
        return "needs a shaft-speed input with a linear thrust law"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust grows with n|n| like a propeller's, not linearly with shaft speed "
                f"(k_q = {fmt(params.get('k_q', 0))} {unit('k_q', trial)})")
