"""Thrust power law: thrust k n|n|^(p-1), the exponent p free (1 linear, 2 propeller-like)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    register,
    rpm_step,
    static_thrust,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class ThrustPower(CatalogueEffect):
    name = "thrust_power"
    meaning = "thrust proportional to n|n|^(p-1): the exponent of the thrust law is not the baseline's"
    params = ("p_n",)
    observable_in = "thrust-rpm table, step with shaft-speed command"
    position = 16
    units: ClassVar[dict[str, tuple[str, bool]]] = {"p_n": ("ratio", False)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"p_n": (0.2, 5.0)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"p_n": (0.2, 5.0)}
    # a family containing other effects' shapes (p = 2: thrust_quadratic's law): named only where it
    # beats each accepted specific effect by the rule's margins (diagnosis.choose)
    general = True
    # the same model family as thrust_quadratic's (a reshaped thrust law): never fitted together
    excludes: ClassVar[tuple[str, ...]] = ("thrust_quadratic",)
    demo_kinds = ("step", "thrust")
    plant_missing = "the thruster model's law is T = k n or k n|n| (components/thrusters.py): no other power"

    def absent_values(self, trial: Trial) -> dict[str, float]:
        """The baseline's own exponent: 1 for a linear law, 2 for a quadratic one."""
        return {"p_n": 2.0 if trial.thrust_law == "quadratic" else 1.0}

    def neutral_values(self) -> dict[str, float]:
        return {}  # no neutral value: absent, the baseline's law applies (thrust_law returns None)

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        return [{"p_n": x} for x in (0.7, 1.3, 1.6, 2.0)]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"p_n": [0.8, 1.5, 2.0]}

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or rpm_step(trial)) else "needs a shaft-speed input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        p = params.get("p_n", 1.0)
        speed = "faster than linear" if p > 1 else "slower than linear"
        half = params.get("p_n_halfwidth")
        ci = f" ± {half:.2g}" if half is not None else ""
        return f"thrust grows {speed} with shaft speed: T = k n|n|^(p-1), p = {p:.3g}{ci}"

    def thrust_law(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        p = v.get("p_n")
        return None if p is None else np.sign(n) * np.abs(n) ** p

    def hide(self, kind: str, amplitude: float) -> Hiding:
        # an Archimedes-screw-like law, T = k n|n|^0.5, against the trial's linear law
        return Hiding(truth={"p_n": 1.5, "k": 9.0})
