"""Time delay: a pure transport delay between command and response."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class TimeDelay(CatalogueEffect):
    name = "time_delay"
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"t_d": (0.0, math.inf)}

    def applies(self, trial: Trial) -> str | None:
        return None if trial.kind == "step" else "needs a commanded input over time (step trial)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return f"the response starts {fmt(params.get('t_d', 0))} s after the command (transport delay)"
