"""Deadband: no thrust below a threshold shaft speed."""

from __future__ import annotations

import math
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
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Deadband(CatalogueEffect):
    name = "deadband"
    meaning = "no thrust below a threshold speed"
    params = ("n_0",)
    observable_in = "thrust-rpm table, step with shaft-speed command"
    position = 9
    units: ClassVar[dict[str, tuple[str, bool]]] = {"n_0": ("command", True)}
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {"n_0": (0.0, math.inf)}
    families = ("first",)
    input_stage = 20
    demo_kinds = ("step", "thrust")
    plant_missing = "the thruster model maps every non-zero shaft speed to thrust (T = k n or k n|n|)"

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        U = s["U"]
        return [{"n_0": x} for x in [0.05 * U, 0.15 * U, 0.3 * U]]

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        return {"n_0": [0.05 * xmax, 0.2 * xmax]}

    def applies(self, trial: Trial) -> str | None:
        return None if (static_thrust(trial) or rpm_step(trial)) else "needs a shaft-speed input"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return (f"the thruster gives no thrust below {fmt(params.get('n_0', 0))} {unit('n_0', trial)} "
                "(deadband)")

    def contradiction(self, params: dict[str, float], trial: Trial, fit: Any, noise: float) -> str | None:
        """Thrust measured inside the claimed band, beyond 3 x the noise (a table's points)."""
        n0 = params.get("n_0", 0.0)
        if trial.kind != "static" or n0 <= 0 or not noise > 0:
            return None
        x, y = np.asarray(fit.extras["x"]), np.asarray(fit.extras["y"])
        inside = (np.abs(x) < n0) & (x != 0)
        dev = np.abs(y - params.get("F_0", 0.0))
        bad = inside & (dev > 3.0 * noise)
        if not np.any(bad):
            return None
        i = int(np.argmax(np.where(bad, dev, -1.0)))
        u = unit("n_0", trial)
        return (f"a deadband below {fmt(n0)} {u} contradicts the thrust of {fmt(float(y[i]))} N measured at "
                f"{fmt(float(x[i]))} {u} ({float(dev[i]) / noise:.1f} x the noise {fmt(noise)} N)")

    def static_input(self, x: np.ndarray, v: dict[str, float]) -> np.ndarray:
        n0 = v.get("n_0", 0.0)
        return np.sign(x) * np.maximum(np.abs(x) - n0, 0.0) if n0 > 0 else x

    def command(self, t: np.ndarray, x: np.ndarray, v: dict[str, float], uniform: bool,
                before: float | None = None) -> tuple[np.ndarray, bool]:
        return self.static_input(x, v), False

    def hide(self, kind: str, amplitude: float) -> Hiding:
        if kind == "thrust":
            return Hiding(truth={"n_0": 0.25 * amplitude})
        # commands inside the band (0.4 > 0.3) and well outside it
        return Hiding(truth={"n_0": 0.3 * amplitude},
                      levels=((1.0, 2.0, 0.4, -1.0, -2.0, -0.4), (1.5, 0.6, -1.5, 2.2, 0.3, -0.6)))
