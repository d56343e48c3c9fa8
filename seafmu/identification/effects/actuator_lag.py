"""Actuator lag: a first-order lag between command and thrust."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from scipy.signal import lfilter

from seafmu.identification.effects.base import CatalogueEffect, Hiding, fmt, register, with_thrusters

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


def first_order_lag(t: np.ndarray, x: np.ndarray, T: float, uniform: bool,
                    before: float | None = None) -> np.ndarray:
    """First-order lag, exact for a command held constant between samples; starts in steady state
    at ``before`` (None: at the first sample's command). Why it matters: a step from rest logged
    from the instant of the step has thrust 0 at t0, not the full command; starting at the command
    there biased T_lag low by a quarter and named a time delay instead."""
    if T <= 0:
        return x
    y0 = x[0] if before is None else before
    if uniform:
        a = math.exp(-(t[1] - t[0]) / T)
        y, _ = lfilter([0.0, 1.0 - a], [1.0, -a], x, zi=[y0])
        return y
    y = np.empty_like(x)
    y[0] = y0
    for i in range(len(x) - 1):
        a = math.exp(-(t[i + 1] - t[i]) / T)
        y[i + 1] = a * y[i] + (1 - a) * x[i]
    return y


@register
class ActuatorLag(CatalogueEffect):
    name = "actuator_lag"
    meaning = "first-order lag between command and thrust"
    params = ("T_lag",)
    observable_in = "step"
    position = 10
    units: ClassVar[dict[str, tuple[str, bool]]] = {"T_lag": ("time", False)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"T_lag": (0.0, math.inf)}
    families = ("first",)
    input_stage = 40  # last: the shaft lags whatever the command became
    demo_kinds = ("step",)
    plant = ("surge_step", "the shipped AMV shaft lag, time_constant 0.25 s")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        h, Tv = s["h"], s["Tv"]
        return [{"T_lag": x} for x in sorted({max(0.5 * h, x * Tv) for x in (0.05, 0.15, 0.4)})]

    def applies(self, trial: Trial) -> str | None:
        return None if trial.kind == "step" else "needs a commanded input over time (step trial)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust builds up with a first-order lag of {fmt(params.get('T_lag', 0))} s after the "
                f"command (shaft/actuator dynamics)")

    def command(self, t: np.ndarray, x: np.ndarray, v: dict[str, float], uniform: bool,
                before: float | None = None) -> tuple[np.ndarray, bool]:
        lag = v.get("T_lag", 0.0)
        return first_order_lag(t, x, lag, uniform, before), lag > 0

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"T_lag": 0.8})

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=lambda spec: with_thrusters(spec, time_constant=0.25))
