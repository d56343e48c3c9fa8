"""Added mass: the inertia differs from the rigid-body value.

In a 1-2-DOF trial with known mass the effect is the added mass itself. In a maneuver log the
baseline is the vessel file's full model, its damping diagonals fitted; the effect is what the
file's added-mass diagonal gets wrong (X_u̇, Y_v̇, N_ṙ, ... with the sign changed): ``m_a[X]``,
``m_a[Y]``, ... added to the diagonal of M_A (kg, or kg·m² for a rotation).
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

# The AMV OSF file's surge numbers the plant-made trial states (M_RB[0][0], M_A[0][0], k per screw).
_AMV_MASS, _AMV_ADDED, _AMV_K = 40.0, 10.0, 12.63


@register
class AddedMass(CatalogueEffect):
    name = "added_mass"
    meaning = "inertia differs from the rigid-body value"
    params = ("m_a",)
    observable_in = ("step with known force (force input or known thrust coefficient) and known mass; "
                     "2nd-order decay with known stiffness and mass; maneuver (the vessel file's added-mass "
                     "diagonal off by m_a[X], m_a[Y], ...)")
    position = 6
    maneuver = True
    units: ClassVar[dict[str, tuple[str, bool]]] = {"m_a": ("inertia", True)}
    families = ("first", "second")
    demo_kinds = ("step", "decay2")
    plant = ("surge_step", "vessel M_A[0][0] = 22 kg; the trial states 40 kg + 10 kg (file) and k")

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

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"m_a": -acc}

    def hide(self, kind: str, amplitude: float) -> Hiding:
        if kind == "decay2":  # known stiffness separates inertia from restoring
            return Hiding(truth={"m_a": 1.5}, constants={"stiffness": 20.0})
        # a step commanded by force (known) on a body of stated rigid-body mass
        return Hiding(truth={"M": 40.0, "m_a": 12.0}, constants={"mass": 40.0}, input_kind="force",
                      levels=((20.0, 40.0, 10.0, -20.0, -40.0, 0.0), (30.0, 15.0, -30.0, 45.0, 5.0, -10.0)))

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(vessel=_surge_added_22, constants={"mass": _AMV_MASS, "added_mass": _AMV_ADDED,
                                                         "thrust_coefficient": 2 * _AMV_K})

    # -- maneuver model --

    def maneuver_applies(self, trial: Trial) -> str | None:
        """3-DOF logs only. On a 6-DOF Minerva 2 log with two lost thrusters six added-mass
        corrections took over what the lost thrust explains (sway -871 +- 711 kg), as the sway-yaw
        coupling did; no test of physical sense rejects such a fit yet."""
        return (None if vessel_dof(trial) == 3
                else "the maneuver-level added mass is fitted to 3-DOF models only")

    def maneuver_params(self, d: int) -> list[str]:
        """One added-mass correction per DOF, m_a[X], m_a[Y], ... (kg, kg·m²): added to the vessel
        file's M_A diagonal."""
        # imported here: the catalogue imports this module, which stays light without the components
        from seafmu.components.vessel_spec import TAU_NAMES

        return [f"m_a[{n}]" for n in TAU_NAMES[d]]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        """A tenth of each DOF's force per rms speed times a second: the order of its inertia."""
        f = np.maximum(tau.std(axis=0), 1e-3)
        s = np.maximum(np.sqrt(np.mean(nu**2, axis=0)), 1e-3) if nu is not None else np.full(f.size, 0.1)
        return list(0.1 * f / s)

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        return {"added_mass": P}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        def one(key: str, value: float) -> str:
            axis, hw = key[4:-1], params.get(f"{key}_halfwidth")
            unit = "kg" if axis in "XYZ" else "kg·m²"
            return f"{axis}: {fmt(value)}{'' if hw is None else f' ± {fmt(hw)}'} {unit}"

        parts = ", ".join(one(k, v) for k, v in params.items() if k.startswith("m_a[") and k.endswith("]"))
        return (f"the vessel file's added mass is off: the hull's inertia differs from the file's by {parts} "
                "(its M_A diagonal changes by these)")


def _surge_added_22(spec: Any) -> Any:
    return dataclasses.replace(spec, M_A=replace_matrix(spec.M_A, {(0, 0): 22.0}))
