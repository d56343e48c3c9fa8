"""Deadband: no thrust below a threshold shaft speed."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, rpm_step, static_thrust, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Deadband(CatalogueEffect):
    name = "deadband"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        U = s["U"]
        return [{"n_0": x} for x in [0.05 * U, 0.15 * U, 0.3 * U]]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"n_0": [0.05 * xmax, 0.2 * xmax]}

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or rpm_step(trial)) else "needs a shaft-speed input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the thruster gives no thrust below {fmt(params.get('n_0', 0))} {unit('n_0', trial)} "
                "(deadband)")
