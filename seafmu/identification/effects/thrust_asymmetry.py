"""Thrust asymmetry: reverse thrust efficiency differs from forward."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    has_both_signs,
    register,
    rpm_step,
    static_thrust,
    with_thrusters,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustAsymmetry(CatalogueEffect):
    name = "thrust_asymmetry"
    meaning = "reverse thrust efficiency differs from forward"
    params = ("eta_rev",)
    observable_in = "thrust-rpm table, step with shaft-speed command, commands of both signs"
    position = 8
    units: ClassVar[dict[str, tuple[str, bool]]] = {"eta_rev": ("ratio", False)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"eta_rev": (-0.99, 10.0)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"eta_rev": (-0.95, 10.0)}
    families = ("first",)
    demo_kinds = ("step", "thrust")
    plant = ("surge_step", "thruster k_reverse = 0.65 k_forward")

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        return [{"eta_rev": x} for x in [-0.4, -0.15, 0.15, 0.4]]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"eta_rev": [-0.3, 0.3]}

    def applies(self, trial: Trial) -> str | None:
        if not (static_thrust(trial) or rpm_step(trial)):
            return "needs a shaft-speed input"
        return None if has_both_signs(trial) else "all commands have one sign: reverse thrust unseen"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"astern thrust is {fmt(100 * (1 + params.get('eta_rev', 0)))} % of ahead thrust at "
                f"the same shaft speed")

    def thrust_gain(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        eta = v.get("eta_rev", 0.0)
        return np.where(n < 0, 1.0 + eta, 1.0) if eta else None

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"eta_rev": -0.35})

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_weak_astern)


def _weak_astern(spec: Any) -> Any:
    return with_thrusters(spec, k_reverse=0.65 * float(spec.thrusters.k_forward[0]))
