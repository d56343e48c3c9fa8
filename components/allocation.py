"""Thrust allocation: generalised force tau -> thruster thrusts T -> shaft speed commands n.

Two methods, chosen by the vessel:
- over-actuated vessels (Minerva 2, 6 DOF, 7 thrusters; any vessel that is not the two-screw case):
  weighted pseudo-inverse T = W^-1 B^T (B W^-1 B^T)^-1 tau (minimum weighted thrust energy, the
  thesis's method), then per-thruster thrust limits;
- a 3-DOF vessel with exactly two thrusters (AMV OSF, two fixed screws): solve the surge and yaw
  rows exactly (2 x 2), then saturate with heading priority: the yaw part is kept, the surge part
  is scaled down until both screws are inside their limits. Sway is not controllable and ignored.

After the limits, ``tau_alloc`` = B T (what the thrusters are asked to deliver) and
``alloc_error`` = ||B T - tau|| (thesis: report the allocation error after saturation). For the two
screws this includes the sway force k_y (n1 - n2) that comes with every yaw moment, so it is not
zero even when nothing saturates: it is the honest distance between demanded and delivered force.

The thrust law, its inverse and the limits come from ``components.thrusters`` (one definition of
the thruster shared with the plant).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from components.block import Block, Interface, Signal
from components.thrusters import max_thrust, thrust_to_speed, thruster_matrix
from components.vessel_spec import VesselSpec

FORCE_UNIT = {"X": "N", "Y": "N", "Z": "N", "K": "N.m", "M": "N.m", "N": "N.m"}

# --- plain functions (usable without the block) -------------------------------------------------


def allocation_matrix(B: np.ndarray, weights: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """P with T = P tau minimising T^T W T subject to B T = tau (least squares if rank deficient).

    Computed as W^-1/2 pinv(B W^-1/2): the same as W^-1 B^T (B W^-1 B^T)^-1 for full row rank,
    but through NumPy's SVD pseudo-inverse, which stays accurate when a weight is very large
    (the thesis's S = 1e8 on the front thrusters) and when B loses rank (thrusters dropped).
    """
    B = np.asarray(B, dtype=float)
    w = np.ones(B.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (B.shape[1],) or np.any(~np.isfinite(w)) or np.any(w <= 0.0):
        raise ValueError(f"weights must be {B.shape[1]} positive finite numbers, got {w.tolist()}")
    s = 1.0 / np.sqrt(w)
    return s[:, None] * np.linalg.pinv(B * s)


def pseudo_inverse_allocation(
    B: np.ndarray,
    tau: Sequence[float] | np.ndarray,
    weights: Sequence[float] | np.ndarray | None = None,
    drop: Sequence[int] = (),
) -> np.ndarray:
    """Thrusts T (one per column of B) for ``tau``; thrusters in ``drop`` (0-based) get T = 0.

    ``drop`` is the benchmark variant (thesis: drop thruster 1 and solve 6 x 6): the columns are
    removed before solving, which is the exact limit of an infinite weight on them.
    """
    B = np.asarray(B, dtype=float)
    keep = [i for i in range(B.shape[1]) if i not in set(drop)]
    w = None if weights is None else np.asarray(weights, dtype=float)[keep]
    T = np.zeros(B.shape[1])
    T[keep] = allocation_matrix(B[:, keep], w) @ np.asarray(tau, dtype=float)
    return T


def drop_thruster(B: np.ndarray, index: int) -> np.ndarray:
    """B without column ``index`` (0-based): the configuration with that thruster removed."""
    return np.delete(np.asarray(B, dtype=float), index, axis=1)


def max_scale(T: np.ndarray, T_min: np.ndarray, T_max: np.ndarray, base: np.ndarray | None = None) -> float:
    """Largest s in [0, 1] with T_min <= base + s T <= T_max (``base`` must itself be feasible)."""
    base = np.zeros_like(T) if base is None else base
    s = 1.0
    for ti, lo, hi, b in zip(T.tolist(), T_min.tolist(), T_max.tolist(), base.tolist(), strict=True):
        if ti > 0.0:
            s = min(s, (hi - b) / ti)
        elif ti < 0.0:
            s = min(s, (lo - b) / ti)
    return max(s, 0.0)


def priority_allocation(
    B2: np.ndarray, tau2: Sequence[float] | np.ndarray, T_min: np.ndarray, T_max: np.ndarray
) -> np.ndarray:
    """Two thrusters, rows [surge; yaw] of B: yaw moment first, surge with what is left.

    The yaw-only solution (zero surge) is scaled into the limits first; then as much of the
    surge-only solution as still fits is added. For two identical screws this is exactly "keep
    n1 - n2, reduce the common mode n1 + n2" (AMV thesis), and it also handles asymmetric
    forward/reverse limits without ever trading yaw moment for surge.
    """
    Binv = np.linalg.inv(np.asarray(B2, dtype=float))
    tau_x, tau_n = float(tau2[0]), float(tau2[1])
    T_yaw = Binv[:, 1] * tau_n
    T_surge = Binv[:, 0] * tau_x
    T0 = max_scale(T_yaw, T_min, T_max) * T_yaw
    return T0 + max_scale(T_surge, T_min, T_max, base=T0) * T_surge


def thrust_capability(vessel: VesselSpec) -> np.ndarray:
    """Largest |tau_j| per DOF that the allocator delivers without saturating (default weights).

    Pure-DOF demand in both directions through the allocation the block uses, limited by the
    asymmetric thrust limits; the smaller of the two directions is returned (a symmetric limit for
    the controller's anti-windup). DOFs the thrusters cannot produce on their own get 0.
    """
    th = vessel.thrusters
    T_min, T_max = max_thrust(th)
    B = thruster_matrix(th, vessel.dof)
    out = np.zeros(vessel.dof)
    if _two_screw(vessel):
        rows = [0, 2]  # surge and yaw: the sway that comes with yaw is not a demand
        P = np.zeros((2, vessel.dof))
        P[:, rows] = np.linalg.inv(B[rows, :])
    else:
        rows = list(range(vessel.dof))
        P = allocation_matrix(B)
    for j in rows:
        e = np.zeros(vessel.dof)
        e[j] = 1.0
        if np.linalg.norm((B @ (P @ e) - e)[rows]) > 1e-9:  # this DOF cannot be produced alone
            continue
        T = P[:, j]
        out[j] = min(_max_gain(T, T_min, T_max), _max_gain(-T, T_min, T_max))
    return out


def _max_gain(T: np.ndarray, T_min: np.ndarray, T_max: np.ndarray) -> float:
    """Largest s >= 0 with T_min <= s T <= T_max."""
    s = np.inf
    for ti, lo, hi in zip(T.tolist(), T_min.tolist(), T_max.tolist(), strict=True):
        if ti > 1e-12:
            s = min(s, hi / ti)
        elif ti < -1e-12:
            s = min(s, lo / ti)
    return float(s)


def _two_screw(vessel: VesselSpec) -> bool:
    return vessel.dof == 3 and vessel.thrusters.count == 2


# --- the block ----------------------------------------------------------------------------------


class AllocatorBlock(Block):
    """tau -> thruster speed commands, with thrust limits and the allocation error."""

    kind = "allocator"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        th = vessel.thrusters
        m = th.count
        inputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"demanded generalised force {t} (body)")
                  for t in vessel.tau_names]
        outputs = [Signal(f"n_cmd_{i + 1}", "1/s", f"shaft speed command, thruster {th.names[i]} (rev/s)")
                   for i in range(m)]
        outputs += [Signal(f"thrust_cmd_{i + 1}", "N", f"thrust command, thruster {th.names[i]}")
                    for i in range(m)]
        outputs += [Signal(f"tau_alloc_{t}", FORCE_UNIT[t], f"allocated generalised force {t} = B T")
                    for t in vessel.tau_names]
        outputs.append(Signal("alloc_error", "", "||B T - tau|| after thrust limits (N and N.m mixed)"))
        params = []
        for i in range(m):
            params.append(Signal(f"w_{i + 1}", "", f"pseudo-inverse weight of thruster {th.names[i]} "
                                 "(higher = used less; ignored by the two-screw priority method)",
                                 min=0.0, start=1.0, tunable=True))
        for i in range(m):
            params.append(Signal(f"reverse_weight_{i + 1}", "",
                                 f"weight of thruster {th.names[i]} used instead of w when its thrust "
                                 "would be negative (thesis: 1e8 keeps the front thrusters out of reverse; "
                                 "0 = off)", min=0.0, start=0.0, tunable=True))
        for i in range(m):
            params.append(Signal(f"enable_{i + 1}", "", f"1 = thruster {th.names[i]} in use, 0 = dropped "
                                 "(column removed, thrust 0)", min=0, max=1, start=1, type="integer",
                                 tunable=True))
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        th = vessel.thrusters
        self._m = th.count
        self._names = self.interface(vessel).input_names()
        self.B = thruster_matrix(th, vessel.dof)
        self.T_min, self.T_max = max_thrust(th)
        self._two_screw = _two_screw(vessel)
        self._rows2 = [0, 2]  # surge and yaw rows of the 3-DOF B
        self._cache: dict[tuple, np.ndarray] = {}
        self._y = np.zeros(2 * self._m + vessel.dof + 1)
        for name, value in self.params.items():
            self._check(name, value)
        self._apply_params()

    # -- parameters ----------------------------------------------------------------------------
    def _check(self, name: str, value: Any) -> None:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"allocator: parameter '{name}' must be a number, got {value!r}") from None
        if name.startswith("w_") and not (np.isfinite(v) and v > 0.0):
            raise ValueError(f"allocator: parameter '{name}' must be a positive finite weight, got {value!r}")
        if name.startswith("reverse_weight_") and not (np.isfinite(v) and v >= 0.0):
            raise ValueError(f"allocator: parameter '{name}' must be >= 0 (0 = off), got {value!r}")
        if name.startswith("enable_") and v not in (0.0, 1.0):
            raise ValueError(f"allocator: parameter '{name}' must be 0 or 1, got {value!r}")

    def set_parameter(self, name: str, value: Any) -> None:
        self._check(name, value)
        super().set_parameter(name, value)
        self._apply_params()

    def _apply_params(self) -> None:
        m, p = self._m, self.params
        self._w = np.array([float(p[f"w_{i + 1}"]) for i in range(m)])
        self._rw = np.array([float(p[f"reverse_weight_{i + 1}"]) for i in range(m)])
        self._enabled = tuple(int(float(p[f"enable_{i + 1}"])) == 1 for i in range(m))
        self._use_priority = self._two_screw and all(self._enabled)
        self._P = self._matrix(self._w)

    def _matrix(self, w: np.ndarray) -> np.ndarray:
        """Full-size allocation matrix (zero rows for dropped thrusters), cached per weight set."""
        key = (tuple(w.tolist()), self._enabled)
        P = self._cache.get(key)
        if P is None:
            keep = [i for i, on in enumerate(self._enabled) if on]
            P = np.zeros((self._m, self.B.shape[0]))
            if keep:
                P[keep] = allocation_matrix(self.B[:, keep], w[keep])
            self._cache[key] = P
        return P

    # -- numerics ------------------------------------------------------------------------------
    def thrusts(self, tau: np.ndarray) -> np.ndarray:
        """Thrust commands within limits for ``tau`` (before conversion to speed)."""
        if self._use_priority:
            return priority_allocation(self.B[self._rows2], tau[self._rows2], self.T_min, self.T_max)
        T = self._P @ tau
        raise_w = (T < 0.0) & (self._rw > 0.0)
        if raise_w.any():
            # Thesis variant: raise the weight only for thrusters that would go into reverse.
            T = self._matrix(np.where(raise_w, self._rw, self._w)) @ tau
        return np.minimum(np.maximum(T, self.T_min), self.T_max)

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        tau = np.asarray(u, dtype=float)
        if tau.shape != (self.vessel.dof,):
            raise ValueError(f"allocator: expected {self.vessel.dof} inputs, got {tau.shape}")
        if not np.isfinite(tau).all():
            bad = [n for n, v in zip(self._names, tau.tolist(), strict=True) if not np.isfinite(v)]
            raise ValueError(f"allocator: input '{bad[0]}' is not finite")
        T = self.thrusts(tau)
        n = thrust_to_speed(self.vessel.thrusters, T)
        tau_alloc = self.B @ T
        m = self._m
        y = self._y
        y[:m] = n
        y[m : 2 * m] = T
        y[2 * m : -1] = tau_alloc
        y[-1] = np.linalg.norm(tau_alloc - tau)
        return y.copy()
