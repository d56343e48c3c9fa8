"""Actuator lag: a first-order lag between command and thrust."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ActuatorLag(CatalogueEffect):
    name = "actuator_lag"
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"T_lag": (0.0, math.inf)}

    def applies(self, trial: Trial) -> str | None:
        return None if trial.kind == "step" else "needs a commanded input over time (step trial)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust builds up with a first-order lag of {fmt(params.get('T_lag', 0))} s after the "
                f"command (shaft/actuator dynamics)")
