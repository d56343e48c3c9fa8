"""Saturation: thrust or shaft speed capped."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Saturation(CatalogueEffect):
    name = "saturation"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"u_sat": (1e-9, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"u_sat": (1e-6, math.inf)}
    start_at_absent = False  # the cap has no gradient where it is inactive

    def absent_values(self, trial: Trial) -> dict[str, float]:
        """The cap at the largest command: inactive."""
        from seafmu.identification.catalogue import input_scale

        return {"u_sat": input_scale(trial)}

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        U = s["U"]
        return [{"u_sat": x} for x in [0.5 * U, 0.7 * U, 0.9 * U]]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"u_sat": [0.5 * xmax, 0.8 * xmax]}

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or trial.kind == "step") else "needs a commanded input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the command is capped at {fmt(params.get('u_sat', 0))} {unit('u_sat', trial)} (thrust or "
                f"shaft-speed saturation)")
