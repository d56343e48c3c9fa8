"""Coupling: cross-coupling between sway and yaw (Y_r, N_v)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Coupling(CatalogueEffect):
    name = "coupling"

    def applies(self, trial: Trial) -> str | None:
        # a sway_yaw trial tests the coupling only (decided in catalogue.not_applicable)
        return None if trial.dof == "sway_yaw" else "needs a sway_yaw trial (v and r measured)"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"sway and yaw are coupled: Y_r = {fmt(params.get('Y_r', 0))} {unit('Y_r', trial)}, "
                f"N_v = {fmt(params.get('N_v', 0))} {unit('N_v', trial)}")
