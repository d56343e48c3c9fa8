"""Coulomb friction: a constant-magnitude force opposing the motion."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, static_force_speed, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class CoulombFriction(CatalogueEffect):
    name = "coulomb_friction"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        if model.family == "pendulum":
            return [{"f_c": x * s["F"]} for x in (0.01, 0.03, 0.1)]
        F = s["F"]
        return [{"f_c": x} for x in [0.03 * F, 0.1 * F, 0.3 * F]]

    def applies(self, trial: Trial) -> str | None:
        ok = static_force_speed(trial) or trial.kind in ("decay", "step", "decay2", "pendulum")
        return None if ok else "no motion to oppose"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        _, force, _ = words(trial)
        return (f"a constant-magnitude friction {force} of {fmt(params.get('f_c', 0))} {unit('f_c', trial)} "
                f"opposes the motion (bearing, seal or ground friction)")
