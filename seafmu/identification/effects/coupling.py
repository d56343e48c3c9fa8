"""Coupling: cross-coupling between DOFs (sway-yaw Y_r, N_v).

In a sway_yaw trial the baseline has no coupling and the effect is the coupling itself. In a
maneuver log the baseline is the vessel file's full model, its damping diagonals fitted; the effect
is what the file's sway-yaw damping coupling gets wrong: the hydrodynamic derivatives Y_r, N_v
(linear) and Y_|r|r, N_|v|v (``Y_r_quadratic``, ``N_v_quadratic``) added to the file's, each
entering D_L or D_Q with the sign changed (``SWAY_YAW``).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import (
    CatalogueEffect,
    Hiding,
    fmt,
    register,
    replace_matrix,
    unit,
    vessel_dof,
)

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class Coupling(CatalogueEffect):
    name = "coupling"
    meaning = "cross-coupling between DOFs (sway-yaw Y_r, N_v)"
    params = ("Y_r", "N_v")
    observable_in = ("sway_yaw step or decay with v and r measured; maneuver (the vessel file's sway-yaw "
                     "damping coupling off by Y_r, N_v, Y_r_quadratic, N_v_quadratic)")
    position = 14
    maneuver = True
    families = ("sway_yaw",)
    demo_kinds = ("sway_yaw",)
    plant = ("sway_yaw_decay", "vessel D_L[1][2] = D_L[2][1] = 8 (Y_r = N_v = -8)")
    _units: ClassVar[dict[str, str]] = {"Y_r": "N/(rad/s)", "N_v": "N·m/(m/s)",
                                        "Y_r_quadratic": "N/(rad/s)²", "N_v_quadratic": "N·m/(m/s)²"}

    def unit(self, param: str, trial: Trial) -> str:
        return self._units.get(param, "") if trial.dof == "sway_yaw" or trial.kind == "maneuver" else ""

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

    # -- maneuver model --

    def maneuver_applies(self, trial: Trial) -> str | None:
        """3-DOF logs (a surface vessel's sway-yaw maneuvering coupling) only. In 6-DOF Minerva 2 logs
        with a current and lost thrusters the four derivatives took over what those explain
        (N_|v|v = 696, Y_r = -73 +- 675 beside a lost thruster instead of the current), and no test
        of physical sense (a dissipative sway-yaw block) is made yet to reject such a fit."""
        return (None if vessel_dof(trial) == 3
                else "the maneuver-level sway-yaw coupling is fitted to 3-DOF models only")

    def maneuver_params(self, d: int) -> list[str]:
        """Y_r, N_v and their quadratic forms Y_|r|r, N_|v|v, beyond the vessel file's."""
        return [param for param, *_ in SWAY_YAW]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        """A few % of the force (moment) of each derivative's row per rms speed of its column (per
        its square for a quadratic one)."""
        f = 0.05 * np.maximum(tau.std(axis=0), 1e-3)
        d = tau.shape[1]
        s = np.maximum(np.sqrt(np.mean(nu**2, axis=0)), 1e-3) if nu is not None else np.full(d, 0.1)
        return [float(f[a] / s[b] ** (2 if matrix == "D_Q" else 1))
                for _, matrix, a, b in sway_yaw_entries(d)]

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"sway_yaw": P[:, :4]}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        def one(key: str, label: str, unit: str) -> str | None:
            if key not in params:
                return None
            hw = params.get(f"{key}_halfwidth")
            return f"{label} = {fmt(params[key])}{'' if hw is None else f' ± {fmt(hw)}'} {unit}"

        labels = {"Y_r": "Y_r", "N_v": "N_v", "Y_r_quadratic": "Y_|r|r", "N_v_quadratic": "N_|v|v"}
        parts = [x for k, label in labels.items() if (x := one(k, label, self._units[k]))]
        return ("the sway-yaw damping coupling of the vessel file is off: the hull's coupling derivatives "
                "differ from the file's by " + ", ".join(parts) + " (its D_L and D_Q sway-yaw and yaw-sway "
                "entries change by minus these)")


# The maneuver extension's derivatives: (parameter, vessel-file matrix, row DOF, column DOF) by the
# DOF names of sway (Y) and yaw (N); each enters its matrix with the sign changed (D = -[derivatives]).
# The simulator (``maneuver.simulation._Simulator.run``) and the write-back read this one table.
SWAY_YAW = (("Y_r", "D_L", "Y", "N"), ("N_v", "D_L", "N", "Y"),
            ("Y_r_quadratic", "D_Q", "Y", "N"), ("N_v_quadratic", "D_Q", "N", "Y"))


def sway_yaw_entries(d: int) -> list[tuple[str, str, int, int]]:
    """``SWAY_YAW`` with the row and column as indices of a d-DOF model."""
    # imported here: the catalogue imports this module, which stays light without the components
    from seafmu.components.vessel_spec import TAU_NAMES

    names = TAU_NAMES[d]
    return [(param, matrix, names.index(row), names.index(col)) for param, matrix, row, col in SWAY_YAW]


def _coupled(spec: Any) -> Any:
    return dataclasses.replace(spec, D_L=replace_matrix(spec.D_L, {(1, 2): 8.0, (2, 1): 8.0}))
