"""Time delay: a pure transport delay between command and response."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, Hiding, fmt, register

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class TimeDelay(CatalogueEffect):
    name = "time_delay"
    meaning = "pure transport delay between command and response"
    params = ("t_d",)
    observable_in = "step"
    position = 11
    units: ClassVar[dict[str, tuple[str, bool]]] = {"t_d": ("time", False)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"t_d": (0.0, math.inf)}
    families = ("first",)
    input_stage = 10  # first: the command arrives late
    demo_kinds = ("step",)
    plant_missing = "commands act at the next plant step; there is no transport delay"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        h = s["h"]
        return [{"t_d": x} for x in [x * h for x in (0.5, 1.0, 2.0, 4.0, 8.0) if x * h < 0.1 * s["dur"]]
                or [0.5 * h]]

    def applies(self, trial: Trial) -> str | None:
        return None if trial.kind == "step" else "needs a commanded input over time (step trial)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return f"the response starts {fmt(params.get('t_d', 0))} s after the command (transport delay)"

    def command(self, t: np.ndarray, x: np.ndarray, v: dict[str, float], uniform: bool,
                before: float | None = None) -> tuple[np.ndarray, bool]:
        td = v.get("t_d", 0.0)
        if td <= 0:
            return x, False
        # before the log: the command before it (None: the first sample's, held)
        return np.interp(t - td, t, x, left=x[0] if before is None else before), False

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"t_d": 0.5})
