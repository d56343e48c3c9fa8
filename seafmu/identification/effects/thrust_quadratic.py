"""Thrust quadratic: thrust proportional to n|n| rather than n."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    register,
    rpm_step,
    static_thrust,
    unit,
    with_thrusters,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustQuadratic(CatalogueEffect):
    name = "thrust_quadratic"
    meaning = "thrust proportional to n|n| rather than n"
    params = ("k_q",)
    observable_in = "thrust-rpm table, step with shaft-speed command, linear thrust law"
    position = 7
    units: ClassVar[dict[str, tuple[str, bool]]] = {"k_q": ("thrust_n2", True)}
    families = ("first",)
    demo_kinds = ("step", "thrust")
    plant = ("surge_step", "thruster law quadratic, k = 6 N/rps^2 per screw; trial: linear law")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        U = s["U"]
        return [{"k_q": x} for x in [-0.5 * vals.get("k", 1.0) / U, 0.3 * vals.get("k", 1.0) / U,
                                     vals.get("k", 1.0) / U]]

    def applies(self, trial: Trial) -> str | None:
        thr = static_thrust(trial)
        if (thr or rpm_step(trial)) and trial.thrust_law == "linear" and not (
                thr and trial.baseline == "quadratic"):
            return None
        return "needs a shaft-speed input with a linear thrust law"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"thrust grows with n|n| like a propeller's, not linearly with shaft speed "
                f"(k_q = {fmt(params.get('k_q', 0))} {unit('k_q', trial)})")

    def thrust_term(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        kq = v.get("k_q", 0.0)
        return kq * n * np.abs(n) if kq else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"k_q": (u * np.abs(u)) if u is not None else np.zeros_like(speed)}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        if kind == "thrust":
            return Hiding(truth={"k": 0.0, "k_q": 6.0})
        return Hiding(truth={"k": 6.0}, thrust_law="quadratic")  # the trial states a linear law

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_quadratic_screws)


def _quadratic_screws(spec: Any) -> Any:
    return with_thrusters(spec, law="quadratic", k_forward=6.0, k_reverse=6.0)
