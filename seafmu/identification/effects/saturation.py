"""Saturation: thrust or shaft speed capped."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    register,
    static_thrust,
    unit,
    with_thrusters,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Saturation(CatalogueEffect):
    name = "saturation"
    meaning = "thrust or speed capped"
    params = ("u_sat",)
    observable_in = "thrust-rpm table, step"
    position = 12
    units: ClassVar[dict[str, tuple[str, bool]]] = {"u_sat": ("command", True)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"u_sat": (1e-9, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"u_sat": (1e-6, math.inf)}
    start_at_absent = False  # the cap has no gradient where it is inactive
    families = ("first",)
    neutral: ClassVar[dict[str, float]] = {"u_sat": math.inf}
    input_stage = 30
    demo_kinds = ("step", "thrust")
    plant = ("surge_step", "thruster n_max = 1.4 rev/s (commands up to 2.2), both x amplitude")

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

    def contradiction(self, params: dict[str, float], trial: Trial, fit: Any, noise: float) -> str | None:
        """A cap at or above every command: no measurement shows it (its value is not identifiable)."""
        from seafmu.identification.catalogue import input_scale

        cap, top = params.get("u_sat", math.inf), input_scale(trial)
        if top > 0 and cap >= top * (1.0 - 1e-6):
            u = unit("u_sat", trial)
            return (f"the cap of {fmt(cap)} {u} is above every command (largest {fmt(top)} {u}): no "
                    "measurement shows a saturation")
        return None

    def static_input(self, x: np.ndarray, v: dict[str, float]) -> np.ndarray:
        us = v.get("u_sat", math.inf)
        return np.clip(x, -us, us) if math.isfinite(us) else x

    def command(self, t: np.ndarray, x: np.ndarray, v: dict[str, float], uniform: bool,
                before: float | None = None) -> tuple[np.ndarray, bool]:
        return self.static_input(x, v), False

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # the cap sits inside the commanded range (bollard table up to 2.2, steps up to 2.2)
        return Hiding(truth={"u_sat": (0.7 * 2.2 if kind == "thrust" else 1.4) * amplitude})

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=lambda spec: with_thrusters(spec, n_max=1.4 * amplitude))
