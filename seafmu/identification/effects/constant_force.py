"""Constant force: a steady external force or moment (wind, tether, trim, buoyancy error)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, Hiding, fmt, register, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ConstantForce(CatalogueEffect):
    name = "constant_force"
    meaning = "constant external force/moment or offset (wind, tether, trim)"
    params = ("F_0",)
    observable_in = "every kind except sway_yaw (maneuver: one per DOF, F_0[X] ...)"
    position = 5
    maneuver = True
    units: ClassVar[dict[str, tuple[str, bool]]] = {"F_0": ("force", True)}
    families = ("first", "second", "pendulum")
    demo_kinds = ("step", "thrust", "decay", "decay2", "pendulum")
    plant = ("heave_decay", "the shipped Minerva 2: buoyancy exceeds weight by 30 N")
    _demo: ClassVar[dict[str, float]] = {"thrust": 1.5, "decay": 1.0, "step": 1.5, "decay2": 0.8,
                                         "pendulum": 0.15}

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

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> float | None:
        return v["F_0"] if "F_0" in v else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"F_0": np.ones_like(speed)}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # a decay needs motion both ways to tell the force from a current or friction
        return Hiding(truth={"F_0": self._demo[kind]}, starts=(1.0, -1.0, 0.7) if kind == "decay" else None)

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_buoyant_30N)

    def maneuver_params(self, d: int) -> list[str]:
        """One force per DOF: F_0[X], F_0[Y], ... (N or N m)."""
        # imported here: the catalogue imports this module, which stays light without the components
        from seafmu.components.vessel_spec import TAU_NAMES

        return [f"F_0[{n}]" for n in TAU_NAMES[d]]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        return list(0.05 * np.maximum(tau.std(axis=0), 1e-3))  # a few % of the force each DOF sees

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"F0": P}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        def one(key: str, value: float) -> str:
            axis, hw = key[4:-1], params.get(f"{key}_halfwidth")  # the words carry each CI half-width
            unit = "N" if axis in "XYZ" else "N·m"
            return f"{axis} = {fmt(value)}{'' if hw is None else f' ± {fmt(hw)}'} {unit}"

        forces = ", ".join(one(k, v) for k, v in params.items() if k.startswith("F_0[") and k.endswith("]"))
        return (f"a steady external force acts on the hull ({forces}): wind, tether pull, trim or buoyancy "
                "error")


def _buoyant_30N(spec: Any) -> Any:
    """The (neutrally trimmed) vessel with buoyancy 30 N above its weight, as Minerva 2 ships."""
    restoring = dataclasses.replace(spec.restoring, buoyancy=spec.restoring.weight + 30.0)
    return dataclasses.replace(spec, restoring=restoring)
