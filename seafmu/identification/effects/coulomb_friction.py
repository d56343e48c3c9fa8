"""Coulomb friction: a constant-magnitude force opposing the motion."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, static_force_speed, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class CoulombFriction(CatalogueEffect):
    name = "coulomb_friction"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}

    def applies(self, trial: Trial) -> str | None:
        ok = static_force_speed(trial) or trial.kind in ("decay", "step", "decay2", "pendulum")
        return None if ok else "no motion to oppose"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        _, force, _ = words(trial)
        return (f"a constant-magnitude friction {force} of {fmt(params.get('f_c', 0))} {unit('f_c', trial)} "
                f"opposes the motion (bearing, seal or ground friction)")
