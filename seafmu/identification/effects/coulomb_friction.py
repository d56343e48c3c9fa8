"""Coulomb friction: a constant-magnitude force opposing the motion."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    register,
    static_force_speed,
    unit,
    words,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class CoulombFriction(CatalogueEffect):
    name = "coulomb_friction"
    meaning = "constant-magnitude force opposing motion (bearing, ground, seal)"
    params = ("f_c",)
    observable_in = "static force-speed, decay, step, 2nd-order decay, pendulum"
    position = 3
    units: ClassVar[dict[str, tuple[str, bool]]] = {"f_c": ("force", True)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"f_c": (0.0, math.inf)}
    families = ("first", "second", "pendulum")
    # the simulators use f_c tanh(v/eps) (smooth in f_c, which output error needs): a significant
    # friction is refitted with the law 3 and 10 times sharper (timeseries.fit_effect)
    regularised = ("f_c", "eps")
    demo_kinds = ("pendulum", "decay", "decay2")
    plant_missing = "the vessel model has no friction term (damping is D_L nu + D_Q |nu| nu)"
    _demo: ClassVar[dict[str, float]] = {"pendulum": 0.06, "decay": 1.0, "decay2": 0.15}

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

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        return v["f_c"] * np.sign(x) if "f_c" in v else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"f_c": -np.sign(speed)}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # a decay needs motion both ways to tell friction from a current or a constant force
        starts = (1.0, -1.0, 0.7) if kind == "decay" else None
        return Hiding(truth={"f_c": self._demo[kind]}, starts=starts)
