"""Model terms of M nu_dot + C(nu) nu + D_L nu + D_Q |nu| nu + g(eta) = tau, vectorised over
samples (and over parameter sets in the simulator), and the diagnosis extensions' parameter names.
"""

from __future__ import annotations

import numpy as np

from seafmu.components.dynamics import coriolis_force  # C_M(nu) nu, vectorised; one copy for all
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec
from seafmu.identification import effects
from seafmu.identification.catalogue import MANEUVER_EFFECTS
from seafmu.identification.effects import CatalogueEffect


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def coriolis_tensor(M: np.ndarray) -> np.ndarray:
    """T (d, d*d) with C_M(nu) nu = T (nu kron nu): the quadratic form by polarisation."""
    d = M.shape[0]
    eye = np.eye(d)
    q = coriolis_force(M, eye)  # row j: Q(e_j)
    T = np.zeros((d, d, d))
    for j in range(d):
        T[:, j, j] = q[j]
        for k in range(j + 1, d):
            T[:, j, k] = T[:, k, j] = 0.5 * (coriolis_force(M, eye[j] + eye[k]) - q[j] - q[k])
    return T.reshape(d, d * d)


class _Restoring:
    """g(eta) of the vessel file (roll and pitch enter; zero for 3 DOF), vectorised."""

    def __init__(self, vessel: VesselSpec) -> None:
        self.dof = vessel.dof
        rs = vessel.restoring
        if self.dof == 6 and rs is not None:
            W, Bu = rs.weight, rs.buoyancy
            self.wb = W - Bu
            self.gx, self.gy, self.gz = (W * np.asarray(rs.r_g) - Bu * np.asarray(rs.r_b)).tolist()
        else:
            self.wb = self.gx = self.gy = self.gz = 0.0

    def __call__(self, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
        if self.dof == 3:
            return np.zeros((*np.shape(phi), 3))
        sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
        wb, gx, gy, gz = self.wb, self.gx, self.gy, self.gz
        return np.stack([
            wb * st,
            -wb * ct * sp,
            -wb * ct * cp,
            -gy * ct * cp + gz * ct * sp,
            gz * st + gx * ct * cp,
            -gx * ct * sp - gy * st,
        ], axis=-1)


def plant_matrices(vessel: VesselSpec) -> dict[str, np.ndarray]:
    """M, D_L, D_Q as the plant simulates them (symmetric parts of M_RB and M_A)."""
    vm = VesselModel(vessel)
    return {"M": vm.M.copy(), "D_L": vm.D_L.copy(), "D_Q": vm.D_Q.copy(), "M_RB": vm.M_RB.copy()}



def effect_names(effect: str | None, d: int) -> list[str]:
    """Parameter names a maneuver extension adds (its effect object's, ``effects/<name>.py``)."""
    if effect is None:
        return []
    return maneuver_effect(effect).maneuver_params(d)


def maneuver_effect(effect: str) -> CatalogueEffect:
    """The effect object of a maneuver extension; a ValueError names the ones there are."""
    obj = effects.get(effect)
    if obj is None or not obj.maneuver:
        raise ValueError(f"maneuver effect must be one of {', '.join(MANEUVER_EFFECTS)}, got {effect!r}")
    return obj
