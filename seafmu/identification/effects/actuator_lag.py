"""Actuator lag: a first-order lag between command and thrust."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ActuatorLag(CatalogueEffect):
    name = "actuator_lag"
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"T_lag": (0.0, math.inf)}

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        h, Tv = s["h"], s["Tv"]
        return [{"T_lag": x} for x in sorted({max(0.5 * h, x * Tv) for x in (0.05, 0.15, 0.4)})]

    def applies(self, trial: Trial) -> str | None:
        return None if trial.kind == "step" else "needs a commanded input over time (step trial)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust builds up with a first-order lag of {fmt(params.get('T_lag', 0))} s after the "
                f"command (shaft/actuator dynamics)")
