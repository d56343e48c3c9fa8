"""Simulation of the model: batched RK4 over parameter sets and restarted segments (output
error, simulation NRMSE, the prediction traces of the report).
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seafmu.components.kernels import maneuver as maneuver_kernel
from seafmu.components.thrusters import thruster_matrix
from seafmu.components.vessel_spec import VesselSpec
from seafmu.cores import core_count
from seafmu.identification import fitting
from seafmu.identification.effects.coupling import sway_yaw_entries
from seafmu.identification.effects.current import INERTIA_FORMS
from seafmu.identification.maneuver.preprocessing import _Prepared
from seafmu.identification.maneuver.terms import _Restoring, _sym, coriolis_tensor

_BASIS: dict[int, np.ndarray] = {}
_CROSS: dict[int, np.ndarray] = {}


def _coriolis_basis(d: int) -> np.ndarray:
    """coriolis_tensor of each d x d unit matrix (d*d, d, d*d), made once per d and process (6 DOF:
    576 Coriolis evaluations, which every simulator set-up repeated)."""
    if d not in _BASIS:
        eye = np.eye(d * d).reshape(d * d, d, d)
        _BASIS[d] = np.stack([coriolis_tensor(E) for E in eye])
        _BASIS[d].flags.writeable = False
    return _BASIS[d]


def _cross_basis(d: int) -> np.ndarray:
    """E (k, d*d) with (omega x nu_c)_i = sum_j E[i, j] (nu (x) nu - nu_r (x) nu_r)_j (k = 2 of 3 DOF,
    3 of 6): omega_a c_b = nu_a nu_b - nu_r,a nu_r,b for a rotation a and a translation b, as
    nu_r,a = nu_a. So the current's inertia term is a weight on the two quadratic blocks the
    compiled kernel already has (``_Simulator.run``), not a new term of the kernel."""
    if d not in _CROSS:
        rot, k = ((2,), 2) if d == 3 else ((3, 4, 5), 3)
        axes = (2,) if d == 3 else (0, 1, 2)  # the rotation axes of rot
        E = np.zeros((k, d * d))
        for i in range(k):
            for a, ra in zip(axes, rot, strict=True):
                for b in range(k):
                    eps = (i - a) * (a - b) * (b - i) / 2  # Levi-Civita symbol of (i, a, b)
                    E[i, ra * d + b] += eps
        E.flags.writeable = False
        _CROSS[d] = E
    return _CROSS[d]


class _Simulator:
    """RK4 of the model for many (M, D_L, D_Q) and many segments at once.

    State: nu (3 DOF) or [roll, pitch, nu] (6 DOF: restoring needs the attitude). tau is linear
    between samples (RK4 stages use tau at t, the midpoint and t + h). Each segment restarts
    from the measured (smoothed) state, so a fit is not dominated by drift from one start.
    Same equations as ``VesselModel.derivative`` without current (checked by a test).

    Diagnosis extensions (``run(..., F0=, vc=, vc_inertia=, thrust_gain=, sway_yaw=, added_mass=)``):
    sway-yaw damping coupling added to D_L and D_Q, added mass on M's diagonal, a thruster's gain, a
    constant generalised force F0 added to tau, and a constant NED current vc = (north, east):
    damping and the added-mass Coriolis terms then act on nu_r = nu - R^T [vc; 0] as in the plant
    (C_RB(nu) nu + C_A(nu_r) nu_r), with R from the simulated roll/pitch and the *measured* heading
    (``psi``, set by ``_sim_setup``), and the inertia acts on the current's rate as the vessel file's
    ``current_inertia`` says or as ``vc_inertia`` gives (``effects.current.INERTIA_FORMS``).

    The RK4 loop is compiled (``components/kernels/maneuver.py``: one loop over parameter sets,
    segments and steps instead of L steps of NumPy calls on (K, S, ...) arrays).
    """

    def __init__(self, vessel: VesselSpec, t: np.ndarray, tau: np.ndarray, x_meas: np.ndarray,
                 starts: np.ndarray, length: int) -> None:
        self.d = vessel.dof
        self.coriolis = vessel.coriolis != "none"  # the plant's model: none for a linear DP model
        self.g = _Restoring(vessel)
        self.length = length
        self.h = float(t[1] - t[0])
        n = t.size
        idx = starts[:, None] + np.arange(length + 1)[None, :]
        self.valid = idx < n
        idx = np.minimum(idx, n - 1)
        self.tau = tau[idx]  # (S, L+1, d)
        self.tau_mid = 0.5 * (self.tau[:, :-1] + self.tau[:, 1:])
        self.x0 = x_meas[starts]  # (S, nx)
        self.idx = idx
        self.M_RB = _sym(np.asarray(vessel.M_RB, dtype=float))
        self.current_inertia = INERTIA_FORMS[vessel.current_inertia]  # the file's, unless run() is told
        self.psi: np.ndarray | None = None  # (S, L+1) measured heading (unwrapped), for a current
        self.psi_mid: np.ndarray | None = None  # (S, L)
        # per-thruster thrust on the hull (S, L+1, m) and at the midpoints (S, L), with B (d, m):
        # a thruster's gain (thrust_gain) changes tau by B diag(gain - 1) thrust
        self.thrust: np.ndarray | None = None
        self.thrust_mid: np.ndarray | None = None
        self.B = thruster_matrix(vessel.thrusters, self.d)
        self._basis: np.ndarray | None = None  # coriolis_tensor of each unit matrix (``_tensor``)

    def _tensor(self, M: np.ndarray) -> np.ndarray:
        """coriolis_tensor of each of the K matrices M (K, d, d): (K, d, d*d), by linearity in M."""
        if self._basis is None:
            self._basis = _coriolis_basis(self.d)
        return np.einsum("ke,eab->kab", M.reshape(M.shape[0], -1), self._basis)

    def run(self, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, x0: np.ndarray | None = None,
            F0: np.ndarray | None = None, vc: np.ndarray | None = None,
            thrust_gain: np.ndarray | None = None, sway_yaw: np.ndarray | None = None,
            added_mass: np.ndarray | None = None, vc_inertia: np.ndarray | None = None) -> np.ndarray:
        """Simulated states (K, S, L+1, nx) for K parameter sets (M, DL, DQ each (K, d, d));
        ``x0`` (K, S, nx) replaces the measured segment starts; ``F0`` (K, d) constant force,
        ``vc`` (K, 2) NED current (see the class docstring); ``thrust_gain`` (K, m) the fraction
        of each thruster's thrust that acts (needs ``thrust``, set by ``_sim_setup``); ``sway_yaw``
        (K, 4) sway-yaw hydrodynamic derivatives Y_r, N_v, Y_|r|r, N_|v|v added to the model's
        (``effects.coupling.SWAY_YAW``: they enter DL and DQ with the sign changed); ``added_mass``
        (K, d) added to M's diagonal (the added mass, so also to C_A's); ``vc_inertia`` (K, 2) the
        weights (a, b) of the inertia a M_RB + b M_A the current's rate acts through (default: the
        vessel file's ``current_inertia``)."""
        K = M.shape[0]
        if added_mass is not None:
            M = np.array(M, dtype=float)
            ii = np.arange(M.shape[-1])
            M[:, ii, ii] += np.asarray(added_mass, dtype=float)
        if sway_yaw is not None:
            P = np.asarray(sway_yaw, dtype=float)
            mats = {"D_L": np.array(DL, dtype=float), "D_Q": np.array(DQ, dtype=float)}
            for k, (_, matrix, a, b) in enumerate(sway_yaw_entries(self.d)):
                mats[matrix][:, a, b] -= P[:, k]
            DL, DQ = mats["D_L"], mats["D_Q"]
        cur = vc is not None and self.psi is not None and self.psi_mid is not None
        d = self.d
        # W_k = [M^-1, -M^-1 T(M) (Coriolis; C_RB and C_A apart with a current), -M^-1 D_L, -M^-1 D_Q]^T,
        # all parameter sets at once: T(M) is linear in M, so it is M's entries times a basis
        Ms = _sym(np.asarray(M, dtype=float))
        Minv = np.linalg.inv(Ms)
        if not self.coriolis:  # ``coriolis: none`` in the vessel file: the blocks stay, as zeros
            cor = [np.zeros((K, d, d * d)) for _ in range(2 if cur else 1)]
        elif cur:  # C_RB(nu) nu + C_A(nu_r) nu_r: Coriolis is linear in M
            T_RB = coriolis_tensor(self.M_RB)
            cor = [-np.broadcast_to(Minv @ T_RB, (K, d, d * d)), -Minv @ self._tensor(Ms - self.M_RB)]
        else:
            cor = [-Minv @ self._tensor(Ms)]
        if cur:  # the inertia on the current's rate: -M^-1 C_I (omega x nu_c), C_I = a M_RB + b M_A
            wts = np.broadcast_to(np.asarray(self.current_inertia if vc_inertia is None else vc_inertia,
                                             dtype=float).reshape(-1, 2), (K, 2))
            if np.any(wts):
                C_I = wts[:, 0, None, None] * self.M_RB + wts[:, 1, None, None] * (Ms - self.M_RB)
                E = _cross_basis(d)
                X = -(Minv @ C_I)[:, :, : E.shape[0]] @ E  # on nu (x) nu, and minus it on nu_r (x) nu_r
                cor = [cor[0] + X, cor[1] - X]
        W = np.concatenate([Minv, *cor, -Minv @ DL, -Minv @ DQ], axis=2).transpose(0, 2, 1)
        x = np.ascontiguousarray(np.broadcast_to(self.x0 if x0 is None else x0, (K, *self.x0.shape)),
                                 dtype=float)
        out = np.empty((K, *self.x0.shape[:1], self.length + 1, self.x0.shape[-1]))
        # tau at the samples and the RK4 midpoints, per parameter set only where it differs
        tau, tau_mid = self.tau[None], self.tau_mid[None]
        if F0 is not None:
            f0 = np.asarray(F0, dtype=float)[:, None, None, :]
            tau, tau_mid = tau + f0, tau_mid + f0
        if thrust_gain is not None and self.thrust is not None and self.thrust_mid is not None:
            dB = (np.asarray(thrust_gain, dtype=float) - 1.0)[:, :, None] * self.B.T[None]  # (K, m, d)

            def gained(base: np.ndarray, T: np.ndarray) -> np.ndarray:
                """base + T dB per parameter set: one batched (S L, m) @ (m, d) product (BLAS)."""
                out = np.matmul(T.reshape(1, -1, T.shape[-1]), dB).reshape(K, *T.shape[:2], d)
                out += base
                return out

            tau, tau_mid = gained(tau, self.thrust), gained(tau_mid, self.thrust_mid)
        if cur and vc is not None:
            vck = np.ascontiguousarray(vc, dtype=float)
            psi = np.ascontiguousarray(self.psi, dtype=float)
            psi_mid = np.ascontiguousarray(self.psi_mid, dtype=float)
        else:
            vck, psi, psi_mid = np.zeros((K, 2)), np.zeros((1, 1)), np.zeros((1, 1))
        g = self.g
        g4 = np.array([g.wb, g.gx, g.gy, g.gz], dtype=float)
        _simulate(x, np.ascontiguousarray(tau, dtype=float), np.ascontiguousarray(tau_mid, dtype=float),
                  np.ascontiguousarray(W), self.h, d, g4, bool(cur), vck, psi, psi_mid, out)
        return out


MIN_SPLIT_STEPS = 2_000  # segment steps per thread at least (~0.7 ms of 6-DOF RK4; a hand-over costs ~0.1 ms)
_POOLS: dict[int, ThreadPoolExecutor] = {}  # by the process that made it (a fork has not its threads)


def _simulate(x0: np.ndarray, tau: np.ndarray, tau_mid: np.ndarray, W: np.ndarray, h: float, d: int,
              g4: np.ndarray, cur: bool, vc: np.ndarray, psi: np.ndarray, psi_mid: np.ndarray,
              out: np.ndarray) -> None:
    """``maneuver_kernel.simulate``, split over the cores this process may use: by parameter set
    (a Jacobian's, a bootstrap's), or for one set by segment. Why: a diagnosis of a 6-DOF log is
    ~60 % simulation (several hundred runs of its segments), each part independent and the kernel
    free of the GIL; the parts write disjoint slices of ``out``, so the result is the same."""
    K, S, L1 = out.shape[:3]
    axis_n = K if K > 1 else S
    n = min(core_count(), axis_n, max(1, K * S * (L1 - 1) // MIN_SPLIT_STEPS))
    if n < 2:
        maneuver_kernel.simulate(x0, tau, tau_mid, W, h, d, g4, cur, vc, psi, psi_mid, out)
        return
    pool = _POOLS.get(os.getpid())
    if pool is None:  # none yet, or made before this process forked: its threads are not here
        _POOLS.clear()
        pool = ThreadPoolExecutor(max_workers=core_count(), thread_name_prefix="seafmu-sim")
        _POOLS[os.getpid()] = pool
    edges = np.linspace(0, axis_n, n + 1).astype(int)
    parts = []
    for a, b in itertools.pairwise(edges.tolist()):
        if K > 1:  # parameter sets a..b; tau is per set or shared
            def per(v: np.ndarray, a: int = a, b: int = b) -> np.ndarray:
                return v[a:b] if v.shape[0] == K else v

            parts.append((x0[a:b], per(tau), per(tau_mid), W[a:b], h, d, g4, cur, vc[a:b], psi, psi_mid,
                          out[a:b]))
        else:  # segments a..b of the one set (psi is per segment only with a current)
            parts.append((x0[:, a:b], tau[:, a:b], tau_mid[:, a:b], W, h, d, g4, cur, vc,
                          psi[a:b] if cur else psi, psi_mid[a:b] if cur else psi_mid, out[:, a:b]))
    futures = [pool.submit(maneuver_kernel.simulate, *args) for args in parts[1:]]
    maneuver_kernel.simulate(*parts[0])
    for f in futures:
        f.result()


def _state(prep_eta: np.ndarray, nu: np.ndarray, d: int) -> np.ndarray:
    return nu if d == 3 else np.hstack([prep_eta[:, 3:5], nu])


@dataclass
class _SimSetup:
    sim: _Simulator
    meas: np.ndarray  # (S, L+1, d) measured nu on the simulation grid
    mask: np.ndarray  # (S, L+1) samples that exist and are compared (not the start)
    scale: np.ndarray  # (d,) spread of measured nu, normalises residuals per DOF
    t: np.ndarray | None = None  # (n_grid,) times of the simulation grid (for plots)
    # Ljung-Box Q of the noise-only residuals by (lags, replicates, seed) (``statistics.whiteness``):
    # the first fit on this setup simulates them, later fits (an extension of the same log) reuse them
    noise_q: dict[tuple[int, int, int], np.ndarray] = field(default_factory=dict)


def _sim_setup(vessel: VesselSpec, prep: _Prepared, i0: int, i1: int, segment: float, sim_dt: float,
               scale: np.ndarray | None = None, nodes: np.ndarray | None = None) -> _SimSetup | None:
    """Segments of ``segment`` seconds covering samples [i0, i1), on a grid of about ``sim_dt``;
    ``nodes`` (indices on that grid) start further segments, each compared up to the next start
    (all are simulated over one segment's length; what lies past the next start is not compared)."""
    if i1 - i0 < 3:
        return None
    stride = max(1, round(sim_dt / prep.dt))
    sel = np.arange(i0, i1, stride)
    t = prep.t[sel]
    d = prep.nu.shape[1]
    x_meas = _state(prep.eta[sel], prep.nu[sel], d)
    L = max(1, min(sel.size - 1, round(segment / (stride * prep.dt))))
    starts = np.arange(0, sel.size - 1, L)
    if nodes is not None and len(nodes):
        extra = np.asarray(nodes, dtype=int)
        starts = np.union1d(starts, extra[(extra > 0) & (extra < sel.size - 1)])
    sim = _Simulator(vessel, t, prep.tau[sel], x_meas, starts, L)
    # tau at the RK4 midpoints from the full-rate log (a logged sample when the stride is even)
    t_mid = 0.5 * (t[sim.idx[:, :-1]] + t[sim.idx[:, 1:]])
    sim.tau_mid = np.stack([np.interp(t_mid, prep.t, prep.tau[:, j]) for j in range(d)], axis=-1)
    psi = np.unwrap(prep.eta[:, d - 1])  # yaw: last eta entry (3 and 6 DOF)
    sim.psi = psi[sel][sim.idx]
    sim.psi_mid = np.interp(t_mid, prep.t, psi)
    if prep.thrust is not None:
        sim.thrust = prep.thrust[sel][sim.idx]
        sim.thrust_mid = np.stack([np.interp(t_mid, prep.t, prep.thrust[:, j])
                                   for j in range(prep.thrust.shape[1])], axis=-1)
    meas = prep.nu_raw[sel][sim.idx]
    mask = sim.valid.copy()
    mask[:, 0] = False
    span = np.append(starts[1:], sel.size - 1) - starts  # compared steps of each segment (L unless a node)
    mask &= np.arange(L + 1)[None, :] <= span[:, None]
    if scale is None:
        scale = np.maximum(prep.nu_raw[i0:i1].std(axis=0), 1e-9)
    return _SimSetup(sim, meas, mask, scale, t)


# Multiple shooting on a model that amplifies start errors: a segment along which the model (the
# vessel file's) amplifies a change of its start velocity more than NODE_GROWTH times, in the
# kinetic-energy norm, gets another start (node) where it does, its state estimated like every
# segment's. Why: the AMV, directionally unstable, speeds up from rest at the start of a log and
# turns one way or the other on a tiny difference (amplification 8-65 there); an output-error fit
# through that stretch had a ragged cost (a hidden added mass stopped at m_a[N] = 1.6 for 6.3,
# cost 37 for 32 at the truth) and converged in 11 evaluations once the stretch had nodes. A passive
# (dissipative) model does not amplify the energy of a start error; the logs of both vessels
# elsewhere reach 1.0-1.8. Pieces are at least NODE_MIN_S long, NODE_ROUNDS placements at most.
NODE_GROWTH = 4.0
NODE_MIN_S = 1.0
NODE_ROUNDS = 8


def shooting_nodes(vessel: VesselSpec, prep: _Prepared, i0: int, i1: int, segment: float, sim_dt: float,
                   M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, align: int = 1) -> np.ndarray:
    """Grid indices of the extra segment starts (``NODE_GROWTH``) for the model (M, DL, DQ): each
    round simulates every segment from its measured start and with its velocity moved along each
    direction of unit kinetic energy (one batched run), and starts a new segment where the largest
    amplification, ||M^1/2 Phi(t) M^-1/2||, first passes the bound (at the grid sample before, a
    multiple of ``align``: the output-error Jacobian's coarse grids then end every compared span on
    one of their samples, and never interpolate from a sample past it, where the piece runs on
    uncompared and may diverge)."""
    d = M.shape[0]
    w, V = np.linalg.eigh(_sym(M))
    if np.any(w <= 0):
        return np.zeros(0, dtype=int)
    Mh, Mhi = (V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T
    nodes = np.zeros(0, dtype=int)
    for _ in range(NODE_ROUNDS):
        setup = _sim_setup(vessel, prep, i0, i1, segment, sim_dt, nodes=nodes)
        if setup is None:
            break
        sim = setup.sim
        min_steps = max(align, round(NODE_MIN_S / sim.h))
        h = 1e-6 * max(float(np.max(np.abs(sim.x0[:, -d:]))), 1e-3) * float(np.sqrt(np.max(w)))
        X0 = np.repeat(sim.x0[None], 1 + d, axis=0)
        X0[1:, :, -d:] += h * Mhi.T[:, None, :]  # start velocity + h M^-1/2 e_j
        K = 1 + d
        x = sim.run(*(np.repeat(np.asarray(a, dtype=float)[None], K, axis=0) for a in (M, DL, DQ)), X0)
        dn = (x[1:, ..., -d:] - x[0, ..., -d:]) / h  # (d, S, L+1, d): column j of Phi M^-1/2
        A = np.einsum("ab,jslb->slaj", Mh, dn)  # (S, L+1, d, d)
        bad = ~np.all(np.isfinite(A), axis=(2, 3))  # diverged: amplified without bound
        amp = np.linalg.norm(np.where(bad[..., None, None], 0.0, A), ord=2, axis=(2, 3))  # (S, L+1)
        amp[bad] = np.inf
        amp = np.where(setup.mask | (np.arange(amp.shape[1]) == 0), amp, 0.0)
        new = []
        for s in range(amp.shape[0]):
            over = np.flatnonzero(amp[s, min_steps:] > NODE_GROWTH)
            span = int(np.sum(setup.mask[s]))
            if over.size and over[0] + min_steps <= span - min_steps:
                k = int(sim.idx[s, 0] + min_steps + over[0])
                new.append(max(k // align * align, int(sim.idx[s, 0]) + align))
        if not new:
            break
        nodes = np.union1d(nodes, new)
    return nodes


def _one(effect: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """Effect terms of one parameter set as the batched simulator takes them (K = 1)."""
    return {k: np.asarray(v, dtype=float)[None] for k, v in (effect or {}).items()}


def _trace(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, run: str,
           effect: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Measured and simulated nu on the simulation grid, every sample once, for the overlay and
    residual plots; ``restarts`` are the segment starts (the simulation restarts there)."""
    x = setup.sim.run(M[None], DL[None], DQ[None], **_one(effect))[0]
    d = setup.meas.shape[-1]
    mask = setup.mask
    assert setup.t is not None
    return {"run": run, "t": setup.t[setup.sim.idx][mask], "y": setup.meas[mask], "yhat": x[..., -d:][mask],
            "restarts": setup.t[setup.sim.idx[:, 0]]}


def _sim_residual(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                  x0: np.ndarray | None = None, **effect: np.ndarray) -> np.ndarray:
    """Normalised nu residuals (K, S, L+1, d); NaN where a simulation diverged."""
    x = setup.sim.run(M, DL, DQ, x0, **effect)
    d = setup.meas.shape[-1]
    return (x[..., -d:] - setup.meas[None]) / setup.scale


def _nrmse_per_dof(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                   effect: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-DOF NRMSE ‖y − ŷ‖/‖y − ȳ‖ of simulated nu, and the flat normalised residual."""
    r = _sim_residual(setup, M[None], DL[None], DQ[None], **_one(effect))[0]
    mask = setup.mask
    y = setup.meas[mask]
    res = r[mask] * setup.scale
    out = np.array([fitting.nrmse(y[:, j], y[:, j] - res[:, j]) if np.all(np.isfinite(res[:, j]))
                    else math.inf for j in range(y.shape[1])])
    return out, r[mask]
