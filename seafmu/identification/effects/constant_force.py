"""Constant force: a steady external force or moment (wind, tether, trim, buoyancy error)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ConstantForce(CatalogueEffect):
    name = "constant_force"
    maneuver = True

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        if model.family == "pendulum":
            return [{"F_0": x * s["F"]} for x in (-0.05, 0.05)]
        F = s["F"]
        return [{"F_0": x} for x in [-0.2 * F, -0.05 * F, 0.05 * F, 0.2 * F]]

    def applies(self, trial: Trial) -> str | None:
        return None  # every kind (sway_yaw trials test the coupling only: catalogue.not_applicable)

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        _, force, _ = words(trial)
        return (f"a steady external {force} of {fmt(params.get('F_0', 0))} {unit('F_0', trial)} acts "
                f"(wind, tether pull, trim or a sensor offset)")

    def maneuver_params(self, d: int) -> list[str]:
        """One force per DOF: F_0[X], F_0[Y], ... (N or N m)."""
        # imported here: the catalogue imports this module, which stays light without the components
        from seafmu.components.vessel_spec import TAU_NAMES

        return [f"F_0[{n}]" for n in TAU_NAMES[d]]

    def maneuver_scales(self, tau: np.ndarray) -> list[float]:
        return list(0.05 * np.maximum(tau.std(axis=0), 1e-3))  # a few % of the force each DOF sees

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"F0": P}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        forces = ", ".join(f"{k[4:-1]} = {fmt(v)} {'N' if k[4:-1] in 'XYZ' else 'N·m'}"
                           for k, v in params.items() if k.startswith("F_0["))
        return (f"a steady external force acts on the hull ({forces}): wind, tether pull, trim or buoyancy "
                "error")
