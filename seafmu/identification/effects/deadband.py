"""Deadband: no thrust below a threshold shaft speed."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, rpm_step, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Deadband(CatalogueEffect):
    name = "deadband"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or rpm_step(trial)) else "needs a shaft-speed input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the thruster gives no thrust below {fmt(params.get('n_0', 0))} {unit('n_0', trial)} "
                "(deadband)")
