"""Added mass: the inertia differs from the rigid-body value."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, unit

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class AddedMass(CatalogueEffect):
    name = "added_mass"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        M = s["M"]
        return [{"m_a": x} for x in [-0.3 * M, 0.3 * M, M, 2 * M]]

    def applies(self, trial: Trial) -> str | None:
        k = trial.kind
        if k == "step" and "mass" in trial.constants and (
                trial.input_kind == "force" or "thrust_coefficient" in trial.constants):
            return None
        if k == "decay2" and "mass" in trial.constants and "stiffness" in trial.constants:
            return None
        return ("inertia is separable only with known mass and known force (step) or known stiffness "
                "(2nd-order decay); otherwise it trades off against damping or restoring")

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the inertia is not the rigid-body value: an added mass of {fmt(params.get('m_a', 0))} "
                f"{unit('m_a', trial)} is missing")
