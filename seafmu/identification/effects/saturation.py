"""Saturation: thrust or shaft speed capped."""

from __future__ import annotations

from typing import TYPE_CHECKING

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Saturation(CatalogueEffect):
    name = "saturation"

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or trial.kind == "step") else "needs a commanded input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the command is capped at {fmt(params.get('u_sat', 0))} {unit('u_sat', trial)} (thrust or "
                f"shaft-speed saturation)")
