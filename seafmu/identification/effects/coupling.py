"""Coupling: cross-coupling between sway and yaw (Y_r, N_v)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Coupling(CatalogueEffect):
    name = "coupling"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        from seafmu.identification.timeseries import equation_error, extend  # imports the catalogue

        est = equation_error(extend(model.copy(values=vals), "coupling"), preps)
        return [{"Y_r": est.get("Y_r", 0.0), "N_v": est.get("N_v", 0.0)}, {"Y_r": 0.0, "N_v": 0.0}]

    def applies(self, trial: Trial) -> str | None:
        # a sway_yaw trial tests the coupling only (decided in catalogue.not_applicable)
        return None if trial.dof == "sway_yaw" else "needs a sway_yaw trial (v and r measured)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"sway and yaw are coupled: Y_r = {fmt(params.get('Y_r', 0))} {unit('Y_r', trial)}, "
                f"N_v = {fmt(params.get('N_v', 0))} {unit('N_v', trial)}")
