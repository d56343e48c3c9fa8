"""Thrust allocation: generalised force tau -> thruster thrusts T -> shaft speed commands n.

Allocation laws are named variants (``components.registry.ALLOCATORS``); the vessel file names its
own (``gnc.allocator``) and the block's string parameter ``allocator`` may choose another:

- ``pinv``: weighted pseudo-inverse T = W^-1 B^T (B W^-1 B^T)^-1 tau (minimum weighted thrust
  energy, the Minerva 2 thesis's method), then per-thruster limits (clip).
- ``two_screw`` (AMV OSF, two fixed screws): solve the surge and yaw rows exactly (2 x 2), then
  saturate with heading priority (the yaw part is kept, the surge part scaled down). Sway is not
  demanded. With a thruster disabled it falls back to ``pinv`` on the rest.
- ``qp``: constrained QP (``QPAllocator``, solver DAQP): minimum weighted energy subject to
  asymmetric thrust limits, thrust-rate limits and B T = tau + s with an exactly penalised slack s
  whose per-DOF priorities decide what is given up first when tau is out of reach (heading before
  surge by default). Equal to ``pinv`` whenever no limit is active.
- ``pinv_camera``, weighted camera-jet (thesis): ``pinv`` with the weight of each camera thruster
  (``camera_i``, by default the vessel file's ``gnc.camera_thrusters``: Minerva 2's fore horizontal
  thrusters 1 and 2, whose jets hit the cameras) raised to S = ``camera_weight`` (thesis 1e8) only
  when its thrust would be negative; one re-solve.
- ``qp_camera``, QP with minimum negative camera thrust: ``qp`` plus a variable z_k >= -T_k,
  z_k >= 0 per camera thruster with an exact penalty ``camera_penalty`` on z: the thesis's
  indicator (sum of negative front thrust) is minimised above the allocation error (default).

The integer parameter ``method`` also selects the law (0 = the variant named by ``allocator``,
1 = ``qp``, 2 = ``pinv_camera``, 3 = ``qp_camera``): a number lets the allocation-comparison and
thruster-failure scenarios switch laws by event and lets a host without string parameters choose.

The thesis's benchmark variant "drop thruster 1 and solve 6 x 6" is ``enable_1 = 0`` with any method.

Failures: ``enable_i = 0`` removes thruster i from the allocation and ``stuck_n_i`` tells the
allocator the speed it is stuck at (0 = stopped); its thrust is counted as a known force. The
allocator has no speed input, so it does not detect failures itself: fault detection (a scenario
event today, a diagnosis block later) sets both at the time of the failure. See docs/allocation.md.

After the limits, ``tau_alloc`` = B T (what the thrusters are asked to deliver, with the stuck
thrust) and ``alloc_error`` = ||B T - tau|| (thesis: the allocation error after saturation). For
the two screws this includes the sway force k_y (n1 - n2) that comes with every yaw moment, so it
is not zero even when nothing saturates: it is the honest distance between demanded and delivered.

The thrust law, its inverse and the limits come from ``components.thrusters`` (one definition of
the thruster shared with the plant).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from . import kernels, registry
from .block import Block, Interface, Signal
from .thrusters import max_thrust, speed_to_thrust, thrust_to_speed, thruster_matrix
from .vessel_spec import TAU_NAMES, VesselSpec

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
    rows, P = declared_law(vessel).capability_matrix(vessel, B)
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


def declared_law_name(vessel: VesselSpec) -> str:
    """The allocation variant the vessel file names (``gnc.allocator``)."""
    if vessel.gnc is None:
        raise ValueError(f"vessel '{vessel.name}' names no GNC variants (gnc section)")
    return vessel.gnc.allocator


def check_allocator(name: Any, vessel: VesselSpec) -> None:
    """ValueError unless ``name`` is a registered allocation variant that can serve ``vessel``."""
    registry.check("allocator", name)
    registry.allocator_law(name).check_vessel(vessel)


def declared_law(vessel: VesselSpec) -> AllocationLaw:
    """The allocation law the vessel file names (``gnc.allocator``)."""
    return registry.allocator_law(declared_law_name(vessel))


# --- constrained QP allocation ------------------------------------------------------------------

QP_INF = 1e30  # DAQP's infinity for bounds
_SLACK_EPS = 1e-9  # quadratic regulariser on the slack and camera variables (DAQP needs H > 0)
_K_LINEAR = 1e3  # exact (linear) part of the penalties, per unit of relative error
_K_QUAD = 1e6  # quadratic part: dominant beyond an error of ~0.05 % of C_j (0.2 N for Minerva 2)


def error_scale(B: np.ndarray, thrust_scale: float) -> np.ndarray:
    """Thrust-equivalent scale of each DOF's allocation error: U for a force, U L for a moment.

    L is the thrusters' mean moment arm (|moment| / |force| of each column of B): 0.95 m for
    Minerva 2, 0.21 m for the AMV's screws. So 1 N.m of yaw weighs like 1/L N of force, what
    it costs in thrust, and a priority means the same on a ROV and on a small surface vessel.
    Rows: X, Y, Z, K, M, N (6 DOF) or X, Y, N (3 DOF).
    """
    B = np.asarray(B, dtype=float)
    moment = np.array([t in ("K", "M", "N") for t in TAU_NAMES[B.shape[0]]])
    f = np.linalg.norm(B[~moment], axis=0)
    mo = np.linalg.norm(B[moment], axis=0)
    arm = float(np.mean(mo[f > 1e-12] / f[f > 1e-12])) if np.any(f > 1e-12) else 1.0
    return np.where(moment, thrust_scale * max(arm, 1e-3), thrust_scale)


class QPAllocator:
    """Constrained thrust allocation as one QP, set up once and warm-started at every call.

    Variables x = [T (m), s+ (d), s- (d), z (c)], s = s+ - s- the allocation error, z the negative
    thrust of the c camera thrusters; e_j = s_j / C_j is the error in thrust-equivalent units
    (``error_scale``: C_j = U for a force, U L for a moment, U the largest thrust)::

        min  sum_i (w_i / w_max) (T_i / U)^2 + sum_j p_j (K1 |e_j| + K2 e_j^2) + q K1 sum_k z_k / U
        s.t. B T - s+ + s- = tau,   lo <= T <= hi,   T_k + z_k >= 0,   s+, s-, z >= 0

    Why this form:
    - the linear part of the penalties is exact: s and z are zero whenever the constraints allow
      it, because the energy's multipliers (about 2/U per N) are far below K1 p_j / C_j. So an
      unsaturated demand gets exactly the weighted pseudo-inverse;
    - beyond a tiny error the quadratic part dominates, so a saturated demand spreads the error
      over the DOFs in inverse proportion to p_j (heading before surge with p_N > p_X) instead
      of dropping whole DOFs one after the other: a purely linear (lexicographic) penalty made the
      closed loop hunt between DOFs in saturation (Minerva 2 starting up in a 0.45 m/s current);
    - thrust-equivalent errors make p_j mean the same for a ROV and a small surface vessel (1 N.m
      of yaw is a lot for the AMV's 0.21 m screw arm, little for Minerva 2);
    - the camera penalty is linear only: q compares 1 N of negative camera thrust with 1 N of
      small allocation error at priority 1; q = 1e6 (default) wins over any allocation error up
      to about 50 times the DOF's scale, q < 1 lets tau win (the cameras get the jet).
    Only the bounds (lo, hi, tau) change per call: the matrices are built once, DAQP's workspace is
    reused, and its active set from the last call is the warm start (typically 1-2 iterations).
    """

    def __init__(
        self,
        B: np.ndarray,
        weights: Sequence[float] | np.ndarray | None = None,
        priorities: Sequence[float] | np.ndarray | None = None,
        camera: Sequence[int] = (),
        camera_penalty: float = 0.0,
        thrust_scale: float = 1.0,
        tau_scale: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        try:
            import daqp  # imported here: only the QP methods need it
        except ImportError:
            raise ValueError("allocator: the QP methods need the solver DAQP (pip install daqp)") from None
        self._daqp = daqp
        B = np.asarray(B, dtype=float)
        d, m = B.shape
        c = len(camera)
        w = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
        p = np.ones(d) if priorities is None else np.asarray(priorities, dtype=float)
        C = np.full(d, thrust_scale) if tau_scale is None else np.asarray(tau_scale, dtype=float)
        if w.shape != (m,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ValueError(f"weights must be {m} positive finite numbers, got {w.tolist()}")
        if p.shape != (d,) or not np.all(np.isfinite(p)) or np.any(p < 0):
            raise ValueError(f"priorities must be {d} finite numbers >= 0, got {p.tolist()}")
        if C.shape != (d,) or not np.all(np.isfinite(C)) or np.any(C <= 0):
            raise ValueError(f"tau_scale must be {d} positive finite numbers, got {C.tolist()}")
        U = float(thrust_scale)
        self.m, self.d, self.c = m, d, c
        n = m + 2 * d + c
        self.n = n
        h = np.full(n, 2.0 * _SLACK_EPS)
        h[:m] = 2.0 * w / (w.max() * U**2)
        quad_s = 2.0 * p * _K_QUAD / C**2
        h[m : m + d] += quad_s
        h[m + d : m + 2 * d] += quad_s
        H = np.diag(h)
        f = np.zeros(n)
        f[m : m + d] = p * _K_LINEAR / C
        f[m + d : m + 2 * d] = p * _K_LINEAR / C
        f[m + 2 * d :] = camera_penalty * _K_LINEAR / U
        A = np.zeros((d + c, n))
        A[:d, :m] = B
        A[:d, m : m + d] = -np.eye(d)
        A[:d, m + d : m + 2 * d] = np.eye(d)
        for k, i in enumerate(camera):
            A[d + k, i] = 1.0
            A[d + k, m + 2 * d + k] = 1.0
        bu = np.full(n + d + c, QP_INF)
        bl = np.zeros(n + d + c)
        bl[n + d :] = 0.0  # T_k + z_k >= 0
        sense = np.zeros(n + d + c, dtype=np.int32)
        sense[n : n + d] = 5  # equality rows
        self._H, self._f, self._A, self._bu, self._bl, self._sense = H, f, A, bu, bl, sense
        self._model: Any = None
        self._lam: np.ndarray | None = None  # last dual solution: the warm start after a copy
        self.iterations = 0

    def solve(self, tau: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, int]:
        """Thrusts within [lo, hi] for ``tau`` and DAQP's exit flag (1 = optimal; < 0 = failed)."""
        m, n = self.m, self.n
        bu, bl = self._bu, self._bl
        c = np.ascontiguousarray
        kernels.alloc.qp_bounds(bu, bl, c(lo, dtype=float), c(hi, dtype=float), c(tau, dtype=float), n)
        if self._model is None:
            self._setup()
        else:
            self._model.update(bupper=bu, blower=bl)
        x, _, flag, info = self._model.solve()
        self._lam = info["lam"]
        self.iterations = int(info["iterations"])
        return np.minimum(np.maximum(x[:m], lo), hi), int(flag)

    def cold_start(self) -> None:
        """Forget the active set: the next call is set up from scratch (tests, benchmarks)."""
        self._model = None
        self._lam = None

    def _setup(self) -> None:
        self._model = self._daqp.Model()
        flag, _ = self._model.setup(self._H, self._f, self._A, self._bu, self._bl, self._sense,
                                    dual_start=self._lam)
        if flag < 0:
            raise ValueError(f"allocator: QP set-up failed (DAQP flag {flag})")

    def __getstate__(self) -> dict[str, Any]:
        """Copy/pickle without DAQP's C workspace (not copyable); the copy is set up again from the
        last dual solution. The original is re-set up the same way, so a restored FMU state and the
        run it was saved from continue bit-identically. A run whose state was never saved keeps its
        warm workspace and may differ from them in the last bits (1e-15 relative: the same QP
        optimum, reached from another start)."""
        self._model = None
        state = dict(self.__dict__)
        state["_daqp"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        import daqp

        self.__dict__.update(state)
        self._daqp = daqp


def qp_allocation(
    B: np.ndarray,
    tau: Sequence[float] | np.ndarray,
    T_min: np.ndarray,
    T_max: np.ndarray,
    weights: Sequence[float] | np.ndarray | None = None,
    priorities: Sequence[float] | np.ndarray | None = None,
    camera: Sequence[int] = (),
    camera_penalty: float = 0.0,
) -> np.ndarray:
    """One cold QP solve (see ``QPAllocator``): thrusts in [T_min, T_max] for ``tau``."""
    T_min, T_max = np.asarray(T_min, dtype=float), np.asarray(T_max, dtype=float)
    scale = float(max(np.abs(T_min).max(), np.abs(T_max).max()))
    qp = QPAllocator(B, weights, priorities, camera, camera_penalty, thrust_scale=scale,
                     tau_scale=error_scale(B, scale))
    T, flag = qp.solve(np.asarray(tau, dtype=float), T_min, T_max)
    if flag < 0:
        raise ValueError(f"QP allocation failed (DAQP flag {flag})")
    return T


def camera_weighted_allocation(
    B: np.ndarray,
    tau: Sequence[float] | np.ndarray,
    camera: Sequence[int],
    S: float = 1e8,
    weights: Sequence[float] | np.ndarray | None = None,
) -> np.ndarray:
    """Thesis: pseudo-inverse, then the weight of the camera thrusters that came out negative is
    raised to S and the pseudo-inverse solved again, until no other camera thruster turns
    negative (no limits; the block's method 2 adds them)."""
    B = np.asarray(B, dtype=float)
    tau = np.asarray(tau, dtype=float)
    w = np.ones(B.shape[1]) if weights is None else np.asarray(weights, dtype=float).copy()
    T = allocation_matrix(B, w) @ tau
    neg = [i for i in camera if T[i] < 0.0 and w[i] != S]
    while neg:
        w[neg] = S
        T = allocation_matrix(B, w) @ tau
        neg = [i for i in camera if T[i] < 0.0 and w[i] != S]
    return T


def negative_front_thrust(T: np.ndarray, camera: Sequence[int]) -> float:
    """Thesis's performance indicator: the sum of the camera thrusters' negative thrust (>= 0)."""
    Tl = T.tolist()
    return float(sum(-Tl[i] for i in camera if Tl[i] < 0.0))


def default_camera_thrusters(vessel: VesselSpec) -> list[int]:
    """0-based thrusters whose reverse jet hits the cameras: the vessel file's
    ``gnc.camera_thrusters`` (Minerva 2: the fore horizontal thrusters 1 and 2; none elsewhere)."""
    return list(vessel.gnc.camera_thrusters) if vessel.gnc is not None else []


# --- the block ----------------------------------------------------------------------------------

METHODS = ("the variant named by 'allocator'", "qp", "pinv_camera", "qp_camera")
_SAT_TOL = 1e-6  # N: a thrust this close to a bound counts as saturated


class AllocationLaw:
    """One named allocation variant (``registry.ALLOCATORS``): how tau becomes thrusts in a box.

    Stateless: the block owns the state (weights, cached matrices, QP workspaces, last thrusts) and
    keeps only the variant's name, so a block's state never depends on which law object exists.
    """

    uses_qp = False  # the block sets up a QPAllocator for it
    camera = False  # keeps the camera thrusters out of reverse

    def rows(self, vessel: VesselSpec) -> list[int]:
        """The DOFs the law allocates (all by default)."""
        return list(range(vessel.dof))

    def priority_defaults(self, vessel: VesselSpec) -> dict[str, float]:
        """QP priorities: moments first (10: heading, and roll/pitch, which a lost moment would
        tip), forces 1. Minerva 2's vertical thrusters make sway and roll together: with roll
        priority 1 the saturated move of scenario minerva2_thruster_failure rolls 2.8 deg (0.6 deg
        with 10); 100 made a start in a strong current drift away (docs/allocation.md)."""
        return {t: (10.0 if t in ("K", "M", "N") else 1.0) for t in vessel.tau_names}

    def check_vessel(self, vessel: VesselSpec) -> None:
        """ValueError if this law cannot serve the vessel's thrusters (default: every law can)."""

    def capability_matrix(self, vessel: VesselSpec, B: np.ndarray) -> tuple[list[int], np.ndarray]:
        """(rows, P) with T = P tau for a pure demand in one of the rows (default weights)."""
        return self.rows(vessel), allocation_matrix(B)

    def allocate(self, blk: AllocatorBlock, tau: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Thrusts in [lo, hi], saturation flags, QP iterations (0 here)."""
        T, sat = blk.pseudo_inverse(tau, lo, hi)
        return T, sat, 0


class PseudoInverseLaw(AllocationLaw):
    """``pinv``: weighted pseudo-inverse, then clip into the box."""


class CameraWeightedLaw(PseudoInverseLaw):
    """``pinv_camera``: the thesis's S on camera thrusters that would go negative."""

    camera = True


class QPLaw(AllocationLaw):
    """``qp``: the constrained QP; pseudo-inverse + clip if DAQP fails (flag < 0)."""

    uses_qp = True

    def allocate(self, blk: AllocatorBlock, tau: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        qp = blk._qp
        T, flag = qp.solve(tau, lo, hi)
        if flag >= 0:  # sat = ((T <= lo + tol) | (T >= hi - tol)) & ~off, compiled (T is clipped already)
            sat = np.empty(len(T), dtype=bool)
            kernels.alloc.qp_result(T, lo, hi, blk._off, _SAT_TOL, T, sat)
            return T, sat, qp.iterations
        qp.cold_start()  # never keep a failed active set
        T, sat = blk.pseudo_inverse(tau, lo, hi)
        return T, sat, -1


class CameraQPLaw(QPLaw):
    """``qp_camera``: the QP minimising the negative thrust of the camera thrusters."""

    camera = True


class TwoScrewLaw(AllocationLaw):
    """``two_screw``: surge and yaw rows solved exactly, heading priority in saturation
    (``priority_allocation``); sway is not demanded. With a thruster disabled: ``pinv``."""

    @staticmethod
    def _rows(vessel: VesselSpec) -> list[int]:
        names = vessel.tau_names
        return [names.index("X"), names.index("N")]

    def rows(self, vessel: VesselSpec) -> list[int]:
        return self._rows(vessel)

    def priority_defaults(self, vessel: VesselSpec) -> dict[str, float]:
        """Sway 0: the two screws' side force only comes with a yaw moment, it is never demanded."""
        out = super().priority_defaults(vessel)
        out["Y"] = 0.0
        return out

    def check_vessel(self, vessel: VesselSpec) -> None:
        """Two screws that make surge and yaw independently: else every step would fail."""
        try:
            self.capability_matrix(vessel, thruster_matrix(vessel.thrusters, vessel.dof))
        except np.linalg.LinAlgError:
            raise ValueError(f"allocator 'two_screw': the two thrusters of vessel '{vessel.name}' do not "
                             "make surge and yaw independently") from None

    def capability_matrix(self, vessel: VesselSpec, B: np.ndarray) -> tuple[list[int], np.ndarray]:
        rows = self._rows(vessel)  # surge and yaw: the sway that comes with yaw is not a demand
        if B.shape[1] != 2:
            raise ValueError(f"allocator 'two_screw' needs exactly two thrusters, vessel '{vessel.name}' "
                             f"has {B.shape[1]}")
        P = np.zeros((2, vessel.dof))
        P[:, rows] = np.linalg.inv(B[rows, :])
        return rows, P

    def allocate(self, blk: AllocatorBlock, tau: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        if blk._any_off:
            return super().allocate(blk, tau, lo, hi)
        rows = self._rows(blk.vessel)
        T = priority_allocation(blk.B[rows], tau[rows], blk.T_min, blk.T_max)
        Tc = np.minimum(np.maximum(T, lo), hi)
        sat = (Tc <= lo + _SAT_TOL) | (Tc >= hi - _SAT_TOL)
        return Tc, sat, 0


def _priority_defaults(vessel: VesselSpec) -> dict[str, float]:
    """QP priorities of the vessel's own allocation law (see ``AllocationLaw.priority_defaults``)."""
    return declared_law(vessel).priority_defaults(vessel)


class AllocatorBlock(Block):
    """tau -> thruster speed commands, with thrust and rate limits, failures and the allocation error."""

    kind = "allocator"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        th = vessel.thrusters
        m = th.count
        inputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"demanded generalised force {t} (body)")
                  for t in vessel.tau_names]
        outputs = [Signal(f"n_cmd_{i + 1}", "rev/s", f"shaft speed command, thruster {th.names[i]}")
                   for i in range(m)]
        outputs += [Signal(f"thrust_cmd_{i + 1}", "N", f"thrust command, thruster {th.names[i]}")
                    for i in range(m)]
        outputs += [Signal(f"tau_alloc_{t}", FORCE_UNIT[t], f"allocated generalised force {t} = B T")
                    for t in vessel.tau_names]
        outputs.append(Signal("alloc_error", "", "||B T - tau|| after thrust limits (N and N.m mixed)"))
        outputs += [Signal(f"sat_{i + 1}", "", f"1 = thruster {th.names[i]} at a thrust or rate limit "
                           "(clipped, or at a bound of the QP), 0 = inside")
                    for i in range(m)]
        outputs.append(Signal("front_negative_thrust", "N", "thesis indicator: sum of the negative thrust "
                              "of the camera thrusters (camera_i = 1), >= 0"))
        outputs.append(Signal("thrust_energy", "", "sum of T_i^2 (N^2): the thesis's energy measure"))
        outputs.append(Signal("qp_iterations", "", "active-set iterations of the QP this step (0 for "
                              "methods 0 and 2; -1 = the QP failed and pseudo-inverse + clip was used)"))
        params = []
        for i in range(m):
            params.append(Signal(f"w_{i + 1}", "", f"pseudo-inverse weight of thruster {th.names[i]} "
                                 "(higher = used less; ignored by the two-screw priority method)",
                                 min=0.0, min_open=True, start=1.0, tunable=True))
        for i in range(m):
            params.append(Signal(f"reverse_weight_{i + 1}", "",
                                 f"weight of thruster {th.names[i]} used instead of w when its thrust "
                                 "would be negative (thesis: 1e8 keeps the front thrusters out of reverse; "
                                 "0 = off)", min=0.0, start=0.0, tunable=True))
        for i in range(m):
            params.append(Signal(f"enable_{i + 1}", "", f"1 = thruster {th.names[i]} in use, 0 = dropped "
                                 "or failed (thrust counted as that of stuck_n; command 0)", min=0, max=1,
                                 start=1, type="integer", tunable=True))
        params.append(Signal("method", "", "law by number: 0 = the variant named by 'allocator', 1 = qp "
                             "(constrained QP), 2 = pinv_camera (thesis S on camera thrusters going "
                             "negative), 3 = qp_camera (QP minimising negative camera thrust)",
                             min=0, max=len(METHODS) - 1, start=0, type="integer", tunable=True,
                             choices=tuple(range(len(METHODS)))))
        camera = default_camera_thrusters(vessel)
        for i in range(m):
            params.append(Signal(f"camera_{i + 1}", "", f"1 = thruster {th.names[i]}'s reverse jet hits "
                                 "the cameras (methods 2 and 3 keep it out of negative thrust)", min=0,
                                 max=1, start=int(i in camera), type="integer", tunable=True))
        params.append(Signal("camera_weight", "", "method 2: weight S of a camera thruster whose thrust "
                             "would be negative (thesis 1e8)", min=0.0, start=1e8, tunable=True))
        params.append(Signal("camera_penalty", "", "method 3: cost of 1 N of negative camera thrust "
                             "relative to 1 N of allocation error at priority 1 (1e6: protection wins; "
                             "< 1: tau wins)", min=0.0, start=1e6, tunable=True))
        for t, p in _priority_defaults(vessel).items():
            params.append(Signal(f"priority_{t}", "", f"QP: cost per {FORCE_UNIT[t]} of allocation error "
                                 f"in {t}; the smallest is given up first when tau is out of reach",
                                 min=0.0, start=p, tunable=True))
        for i in range(m):
            params.append(Signal(f"thrust_rate_max_{i + 1}", "N/s", f"largest thrust change per second "
                                 f"of thruster {th.names[i]} (0 = no limit)", min=0.0, start=0.0,
                                 tunable=True))
        for i in range(m):
            n_max = float(th.n_max[i])
            params.append(Signal(f"stuck_n_{i + 1}", "rev/s", f"shaft speed of thruster {th.names[i]} "
                                 "while enable = 0 (0 = stopped; else the speed it is stuck at): its "
                                 "thrust is a known force", min=-n_max, max=n_max, start=0.0, tunable=True))
        params.append(Signal("allocator", "", f"allocation variant ({', '.join(registry.ALLOCATORS)}); "
                             "default: the vessel file's gnc.allocator. Used when method = 0",
                             start=declared_law_name(vessel), type="string", tunable=True))
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        th = vessel.thrusters
        self._m = m = th.count
        self.B = thruster_matrix(th, vessel.dof)
        self.T_min, self.T_max = max_thrust(th)
        self._U = float(max(np.abs(self.T_min).max(), self.T_max.max()))
        self._C = error_scale(self.B, self._U)  # QP: thrust-equivalent scale of each DOF's error
        self._cache: dict[tuple, np.ndarray] = {}
        self._qps: dict[tuple, QPAllocator] = {}
        self._in_tau = self.inp.at(f"tau_{t}" for t in vessel.tau_names)
        o = self.out
        thr = range(1, m + 1)
        self._o_n = o.at(f"n_cmd_{i}" for i in thr)
        self._o_T = o.at(f"thrust_cmd_{i}" for i in thr)
        self._o_tau = o.at(f"tau_alloc_{t}" for t in vessel.tau_names)
        self._o_sat = o.at(f"sat_{i}" for i in thr)
        self._o_err, self._o_front = o["alloc_error"], o["front_negative_thrust"]
        self._o_energy, self._o_iter = o["thrust_energy"], o["qp_iterations"]
        # the compiled output step writes consecutive groups from their first positions
        groups = (self._o_n, self._o_T, self._o_tau, self._o_sat)
        self._o_pos = None
        if all(isinstance(g, slice) for g in groups):
            starts = [g.start for g in groups]  # type: ignore[union-attr]
            self._o_pos = np.array([starts[0], starts[1], starts[2], self._o_err, starts[3], self._o_energy])
        th = vessel.thrusters
        self._th = np.ascontiguousarray(np.vstack([th.k_forward, th.k_reverse, 1.0 / th.time_constant]))
        self._thrust_law = kernels.thrust_law.code(th.law)
        self._n_max = np.ascontiguousarray(th.n_max, dtype=float)
        self._B_c = np.ascontiguousarray(self.B)
        self._tau_idx = np.arange(len(self.inp), dtype=np.int64)[self._in_tau]
        self._y = np.zeros(len(o))
        self._T_prev = np.zeros(m)
        self._check_variant(self.params["allocator"])
        self._apply_params()

    # -- parameters ----------------------------------------------------------------------------
    def _check_variant(self, value: Any) -> None:
        """The allocation variant must be registered (the registry's error names the known ones) and
        able to serve this vessel."""
        try:
            check_allocator(value, self.vessel)
        except ValueError as exc:
            raise ValueError(f"allocator: parameter 'allocator': {exc}") from None

    def check_parameter(self, name: str, value: Any) -> None:
        super().check_parameter(name, value)
        if name == "allocator":
            self._check_variant(value)

    def set_parameter(self, name: str, value: Any) -> None:
        super().set_parameter(name, value)
        self._apply_params()

    def _apply_params(self) -> None:
        m, p, th = self._m, self.params, self.vessel.thrusters
        self._method = int(float(p["method"]))
        # The active variant's name (the law object itself is looked up, never stored: state).
        self._variant = registry.METHOD_VARIANTS[self._method] or str(p["allocator"])
        law = self._law
        self._w = np.array([float(p[f"w_{i + 1}"]) for i in range(m)])
        self._enabled = tuple(int(float(p[f"enable_{i + 1}"])) == 1 for i in range(m))
        self._camera = [i for i in range(m) if int(float(p[f"camera_{i + 1}"])) == 1]
        rw = np.array([float(p[f"reverse_weight_{i + 1}"]) for i in range(m)])
        if law.camera and not law.uses_qp:  # thesis S on camera thrusters (a larger reverse_weight wins)
            for i in self._camera:
                rw[i] = max(rw[i], float(p["camera_weight"]))
        self._rw = rw
        self._any_rw = bool((rw > 0.0).any())
        self._rate = np.array([float(p[f"thrust_rate_max_{i + 1}"]) for i in range(m)])
        self._has_rate = bool(np.any(self._rate > 0.0))
        off = np.array([not e for e in self._enabled])
        stuck = np.array([float(p[f"stuck_n_{i + 1}"]) for i in range(m)])
        self._off = off
        self._any_off = bool(off.any())
        self._T_fixed = np.where(off, speed_to_thrust(th, stuck), 0.0)
        self._tau_fixed = self.B @ self._T_fixed
        self._priority = np.array([float(p[f"priority_{t}"]) for t in self.vessel.tau_names])
        self._P = self._matrix(self._w)
        self._qp = self._qp_for() if law.uses_qp else None
        # The plain pseudo-inverse without rate limits or weights to raise: the whole step is one
        # compiled call (``alloc.pinv_step``) with the box of ``box(None)``.
        self._fast_pinv = (type(law).allocate is AllocationLaw.allocate and not self._any_rw
                           and not self._has_rate and self._o_pos is not None)
        self._lo_fixed, self._hi_fixed = (np.ascontiguousarray(b, dtype=float) for b in self.box(None))
        self._camera_idx = np.array(self._camera, dtype=np.int64)

    @property
    def _law(self) -> AllocationLaw:
        return registry.allocator_law(self._variant)

    @property
    def variant(self) -> str:
        """Name of the allocation variant in use (``registry.ALLOCATORS``)."""
        return self._variant

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

    def _qp_for(self) -> QPAllocator:
        """The QP of the current method and weights, built once per set (failures only move bounds)."""
        camera = tuple(self._camera) if self._law.camera else ()
        penalty = float(self.params["camera_penalty"]) if camera else 0.0
        key = (tuple(self._w.tolist()), tuple(self._priority.tolist()), camera, penalty)
        qp = self._qps.get(key)
        if qp is None:
            qp = QPAllocator(self.B, self._w, self._priority, camera, penalty, thrust_scale=self._U,
                             tau_scale=self._C)
            self._qps[key] = qp
        return qp

    # -- numerics ------------------------------------------------------------------------------
    def box(self, h: float | None) -> tuple[np.ndarray, np.ndarray]:
        """Thrust bounds this step: limits, rate limits around the last command (not without a
        step size h), a failed thruster fixed at its known thrust."""
        lo, hi = self.T_min, self.T_max
        if self._has_rate and h is not None:
            r = np.where(self._rate > 0.0, self._rate * h, np.inf)
            lo = np.maximum(lo, self._T_prev - r)
            hi = np.minimum(hi, self._T_prev + r)
        if self._any_off:
            lo = np.where(self._off, self._T_fixed, lo)
            hi = np.where(self._off, self._T_fixed, hi)
        return lo, hi

    def allocate(self, tau: np.ndarray, h: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """Thrusts within the bounds for ``tau``, saturation flags, QP iterations (-1 = QP failed)."""
        lo, hi = self.box(h)
        return self._law.allocate(self, tau, lo, hi)

    def pseudo_inverse(
        self, tau: np.ndarray, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``pinv`` and ``pinv_camera`` (and the fallback of a failed QP): pseudo-inverse with the
        block's weights (reverse weights raised where thrust would go negative), then clip."""
        if not self._any_rw:  # no weight to raise: one compiled call
            m = self._m
            T, Tc, sat = np.empty(m), np.empty(m), np.empty(m, dtype=bool)
            kernels.alloc.pinv_clip(self._P, np.ascontiguousarray(tau, dtype=float), self._tau_fixed,
                                    self._T_fixed, self._any_off, lo, hi, T, Tc, sat)
            return Tc, sat
        if self._any_off:
            tau = tau - self._tau_fixed
        T = self._P @ tau
        raise_w = (T < 0.0) & (self._rw > 0.0)
        while raise_w.any():
            # Thesis variant: raise the weight only for thrusters that would go into reverse; again
            # if that turns another one negative (at most once per thruster: the set only grows).
            T = self._matrix(np.where(raise_w, self._rw, self._w)) @ tau
            more = (T < 0.0) & (self._rw > 0.0) & ~raise_w
            if not more.any():
                break
            raise_w = raise_w | more
        if self._any_off:
            T = T + self._T_fixed
        Tc = np.minimum(np.maximum(T, lo), hi)
        sat = Tc != T  # clipped (a failed thruster's T is its fixed value: never clipped)
        return Tc, sat

    def thrusts(self, tau: np.ndarray) -> np.ndarray:
        """Thrust commands within limits for ``tau`` (before conversion to speed)."""
        return self.allocate(np.asarray(tau, dtype=float))[0]

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != self._in_shape:
            raise ValueError(f"allocator: expected {len(self.inp)} inputs, got {u.shape}")
        if self._fast_pinv:
            Tc = np.empty(self._m)
            if kernels.alloc.pinv_step(
                    np.ascontiguousarray(u), self._tau_idx, self._P, self._tau_fixed, self._T_fixed,
                    self._any_off, self._lo_fixed, self._hi_fixed, self._B_c, self._th, self._thrust_law,
                    self._n_max, self._off, self._camera_idx, self._y, self._o_pos, self._o_front,
                    self._o_iter, Tc):
                self._T_prev = Tc
                return self._y.copy()
            # a non-finite input: the general path below names it
        tau = u[self._in_tau]
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(self.inp.names, u.tolist(), strict=True) if not np.isfinite(v)]
            raise ValueError(f"allocator: input '{bad[0]}' is not finite")
        T, sat, iterations = self.allocate(tau, h)
        self._T_prev = T
        y = self._y
        if self._o_pos is not None:  # n, T, tau_alloc, alloc_error, sat, thrust_energy: one compiled call
            kernels.alloc.outputs(
                np.ascontiguousarray(T, dtype=float), np.ascontiguousarray(tau, dtype=float), self._B_c,
                self._th, self._thrust_law, self._n_max, self._off, self._any_off, np.ascontiguousarray(sat),
                y, self._o_pos)
            y[self._o_front] = negative_front_thrust(T, self._camera) if self._camera else 0.0
            y[self._o_iter] = iterations
            return y.copy()
        n = thrust_to_speed(self.vessel.thrusters, T)
        if self._any_off:
            n = np.where(self._off, 0.0, n)  # a failed or dropped thruster is commanded to stop
        tau_alloc = self.B @ T
        y = self._y
        y[self._o_n] = n
        y[self._o_T] = T
        y[self._o_tau] = tau_alloc
        y[self._o_err] = np.linalg.norm(tau_alloc - tau)
        y[self._o_sat] = sat
        y[self._o_front] = negative_front_thrust(T, self._camera) if self._camera else 0.0
        y[self._o_energy] = T @ T
        y[self._o_iter] = iterations
        return y.copy()
