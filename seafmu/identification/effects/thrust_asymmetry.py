"""Thrust asymmetry: reverse thrust efficiency differs from forward."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import (
    CatalogueEffect,
    fmt,
    has_both_signs,
    register,
    rpm_step,
    static_thrust,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustAsymmetry(CatalogueEffect):
    name = "thrust_asymmetry"
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"eta_rev": (-0.99, 10.0)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"eta_rev": (-0.95, 10.0)}

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
