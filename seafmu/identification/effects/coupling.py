"""Coupling: cross-coupling between DOFs (sway-yaw Y_r, N_v)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

from seafmu.identification.effects.base import CatalogueEffect, Hiding, fmt, register, replace_matrix, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Coupling(CatalogueEffect):
    name = "coupling"
    meaning = "cross-coupling between DOFs (sway-yaw Y_r, N_v)"
    params = ("Y_r", "N_v")
    observable_in = "sway_yaw step or decay with v and r measured"
    position = 14
    families = ("sway_yaw",)
    demo_kinds = ("sway_yaw",)
    plant = ("sway_yaw_decay", "vessel D_L[1][2] = D_L[2][1] = 8 (Y_r = N_v = -8)")
    _units: ClassVar[dict[str, str]] = {"Y_r": "N/(rad/s)", "N_v": "N·m/(m/s)"}

    def unit(self, param: str, trial: Trial) -> str:
        return self._units.get(param, "") if trial.dof == "sway_yaw" else ""

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

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"Y_r": 12.0, "N_v": 6.0})

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_coupled)


def _coupled(spec: Any) -> Any:
    return dataclasses.replace(spec, D_L=replace_matrix(spec.D_L, {(1, 2): 8.0, (2, 1): 8.0}))
