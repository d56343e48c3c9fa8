"""Levenberg–Marquardt for least squares with an "arrow" Jacobian, in time and memory linear in the data.

The output-error fit of a maneuver log (``maneuver.estimation._output_error``) estimates a few model
parameters p shared by the whole log and, for each of S restarted segments, that segment's own
initial state x_s (multiple shooting). A residual of segment s depends on p and x_s only, so the
Jacobian is block-sparse::

    J = [Jp | blockdiag(Jx_1, ..., Jx_S)]        J^T J = [[A,     B_1 ... B_S     ],
                                                           [B_s^T, blockdiag(C_s) ]]

Stored densely it has (rows ∝ n) × (columns ∝ n) entries, and a dense QR of it costs ∝ n^3: this
was the quadratic memory and cubic time of the maneuver identification (issue 8). Here J is kept
as ``Jp`` (S, R, P) and ``Jx`` (S, R, nx) — R residual rows per segment, padded with zero rows — and
every linear solve goes through the Schur complement of the block diagonal,
(A + λI − Σ B_s (C_s + λI)⁻¹ B_sᵀ) a = …: one P × P system and S independent nx × nx blocks.

The iteration is MINPACK's ``lmder`` (Moré 1978), which ``scipy.optimize.least_squares(method="lm",
x_scale=1.0)`` runs: the same trust region, the same λ search (``lmpar``: safeguarded Newton on
‖p(λ)‖ = Δ), the same step acceptance, radius update and termination tests (ftol, xtol, gtol,
max_nfev counting function evaluations) and the same messages. It solves the normal equations
instead of a pivoted QR of J; the results equal MINPACK's to the optimiser's tolerance
(tests/test_ident_robustness.py compares both on problems small enough for the dense solver).

Lower bounds on model parameters (``lower``: a damping entry that must stay dissipative) are kept
inside the iteration, as a projected Levenberg-Marquardt (Kanzow, Yamashita & Fukushima 2004): a
parameter at its bound whose gradient pushes it further out is fixed for that iteration (the
step is solved over the others), the step is projected onto the bounds, and it is judged by the
decrease its own linear model predicts. A bound never reached leaves every iterate as without it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

_EPS = float(np.finfo(float).eps)
_DWARF = float(np.finfo(float).tiny)

# scipy.optimize.least_squares's message for each MINPACK status code
MESSAGES = {
    1: "`ftol` termination condition is satisfied.",
    2: "`xtol` termination condition is satisfied.",
    3: "Both `ftol` and `xtol` termination conditions are satisfied.",
    4: "`gtol` termination condition is satisfied.",
    5: "The maximum number of function evaluations is exceeded.",
    6: "`ftol` termination condition is satisfied.",
    7: "`xtol` termination condition is satisfied.",
    8: "`gtol` termination condition is satisfied.",
}


@dataclass
class ArrowJacobian:
    """d r / d z of residuals r (S, R) for z = [p (P) | x_1 (nx) | ... | x_S (nx)].

    ``Jp[s, i, k]`` = d r[s, i] / d p[k]; ``Jx[s, i, j]`` = d r[s, i] / d x_s[j] (no other
    segment's state enters segment s). Padding rows are zero in both.
    """

    Jp: np.ndarray  # (S, R, P)
    Jx: np.ndarray  # (S, R, nx)

    @property
    def dims(self) -> tuple[int, int, int, int]:
        S, R, P = self.Jp.shape
        return S, R, P, self.Jx.shape[2]

    def scaled(self, col: np.ndarray) -> ArrowJacobian:
        """The Jacobian with respect to p * col (parameter columns divided by col)."""
        return ArrowJacobian(self.Jp / col[None, None, :], self.Jx)

    def normal(self, f: np.ndarray | None = None) -> Normal:
        return Normal(self, f)


class Normal:
    """JᵀJ (blocks A, B_s, C_s) and Jᵀf of an arrow Jacobian; solves with JᵀJ + λI."""

    def __init__(self, J: ArrowJacobian, f: np.ndarray | None = None) -> None:
        S, R, P, nx = J.dims
        self.P, self.S, self.nx = P, S, nx
        Jp2 = J.Jp.reshape(S * R, P)
        self.A = Jp2.T @ Jp2
        self.B = np.matmul(J.Jp.transpose(0, 2, 1), J.Jx)  # (S, P, nx)
        self.C = np.matmul(J.Jx.transpose(0, 2, 1), J.Jx)  # (S, nx, nx)
        if f is not None:
            self.g = np.concatenate([Jp2.T @ f.reshape(S * R), np.einsum("srj,sr->sj", J.Jx, f).ravel()])
        self.ev, self.V = np.linalg.eigh(self.C)  # C_s = V_s diag(ev_s) V_sᵀ
        self.W = np.matmul(self.B, self.V)  # B_s V_s (S, P, nx)
        self.col_norms = np.sqrt(np.maximum(np.concatenate(
            [np.diag(self.A), np.diagonal(self.C, axis1=1, axis2=2).ravel()]), 0.0))

    def restricted(self, keep: np.ndarray) -> Normal:
        """The normal equations of the Jacobian with only the parameter columns ``keep`` (every
        state column kept): sub-blocks of these, no pass over the residual rows."""
        out = copy.copy(self)
        P = self.P
        out.P = keep.size
        out.A = self.A[np.ix_(keep, keep)]
        out.B = self.B[:, keep, :]
        out.W = self.W[:, keep, :]
        if hasattr(self, "g"):
            out.g = np.concatenate([self.g[keep], self.g[P:]])
        out.col_norms = np.concatenate([self.col_norms[keep], self.col_norms[P:]])
        return out

    def quad(self, v: np.ndarray) -> float:
        """‖J v‖² = vᵀ JᵀJ v from the blocks (no pass over the residual rows)."""
        P, S, nx = self.P, self.S, self.nx
        a, b = v[:P], v[P:].reshape(S, nx)
        return float(a @ self.A @ a + 2.0 * np.einsum("p,spk,sk->", a, self.B, b)
                     + np.einsum("sj,sjk,sk->", b, self.C, b))

    def _block_inverse(self, lam: float) -> tuple[np.ndarray, bool]:
        """Eigenvalues of (C_s + λI)⁻¹ per block, zero where the block is singular."""
        den = self.ev + lam
        top = np.max(np.abs(den), axis=1, keepdims=True)
        ok = den > _EPS * self.nx * top
        return np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0), bool(np.all(ok))

    def solve(self, lam: float, v: np.ndarray) -> tuple[np.ndarray, bool]:
        """(JᵀJ + λI)⁻¹ v through the Schur complement; pseudo-inverse where singular.

        Returns the solution and whether the system had full rank.
        """
        P, S, nx = self.P, self.S, self.nx
        inv, full = self._block_inverse(lam)
        h = np.einsum("sjk,sj->sk", self.V, v[P:].reshape(S, nx))  # V_sᵀ v_s
        Wi = self.W * inv[:, None, :]
        schur = self.A + lam * np.eye(P) - np.tensordot(Wi, self.W, axes=([0, 2], [0, 2]))
        rhs = v[:P] - np.einsum("spk,sk->p", Wi, h)
        a, full_s = _sym_solve(schur, rhs)
        b = np.einsum("sjk,sk->sj", self.V, inv * (h - np.einsum("spk,p->sk", self.W, a)))
        return np.concatenate([a, b.ravel()]), full and full_s

    def inverse_pp(self) -> np.ndarray:
        """The parameter block of (JᵀJ)⁻¹ = (A − Σ B_s C_s⁻¹ B_sᵀ)⁻¹, with every column scaled to
        unit norm and pseudo-inverses where a block is singular."""
        cp = np.sqrt(np.maximum(np.diag(self.A), 1e-300))
        cx = np.sqrt(np.maximum(np.diagonal(self.C, axis1=1, axis2=2), 1e-300))  # (S, nx)
        As = self.A / np.outer(cp, cp)
        Bs = self.B / (cp[None, :, None] * cx[:, None, :])
        Cs = self.C / (cx[:, :, None] * cx[:, None, :])
        Cinv = np.linalg.pinv(Cs, hermitian=True)
        schur = As - np.einsum("spk,skl,sql->pq", Bs, Cinv, Bs, optimize=True)
        return np.linalg.pinv(_sym(schur), hermitian=True) / np.outer(cp, cp)


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)


def _sym_solve(M: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """Solution of a symmetric positive semi-definite system (column-scaled; pseudo-inverse)."""
    d = np.diag(M)
    cs = np.sqrt(np.where(d > 0, d, 1.0))
    Ms = _sym(M / np.outer(cs, cs))
    w, V = np.linalg.eigh(Ms)
    top = float(np.max(np.abs(w))) if w.size else 0.0
    ok = w > _EPS * max(M.shape[0], 1) * top
    winv = np.where(ok, 1.0 / np.where(ok, w, 1.0), 0.0)
    return (V @ (winv * (V.T @ (b / cs)))) / cs, bool(np.all(ok)) and top > 0


@dataclass
class Result:
    """What ``scipy.optimize.least_squares`` returns, for the arrow problem."""

    x: np.ndarray
    fun: np.ndarray  # (S, R) residuals at x
    jac: ArrowJacobian | None  # at x; None for final_jac=False (a caller forming its own at x)
    cost: float
    nfev: int
    njev: int
    status: int  # MINPACK's info
    message: str

    @property
    def success(self) -> bool:
        return self.status != 5


def _lmpar(ne: Normal, g: np.ndarray, delta: float, par: float) -> tuple[float, np.ndarray]:
    """MINPACK's lmpar with unit scaling: λ ≥ 0 and p = −(JᵀJ + λI)⁻¹ g with ‖p‖ ≈ Δ (within
    10 %), or the Gauss-Newton step (λ = 0) when it lies inside the trust region."""
    p, full = ne.solve(0.0, -g)
    dxnorm = float(np.linalg.norm(p))
    fp = dxnorm - delta
    if fp <= 0.1 * delta:
        return 0.0, p
    parl = 0.0
    if full and dxnorm > 0:  # lower bound from the Newton step of φ(λ) = ‖p(λ)‖ − Δ at λ = 0
        w = p / dxnorm
        q, _ = ne.solve(0.0, w)
        wq = float(w @ q)
        parl = fp / delta / wq if wq > 0 else 0.0
    gnorm = float(np.linalg.norm(g))
    paru = gnorm / delta
    if paru == 0.0:
        paru = _DWARF / min(delta, 0.1)
    par = min(max(par, parl), paru)
    if par == 0.0:
        par = gnorm / dxnorm
    for it in range(1, 11):
        if par == 0.0:
            par = max(_DWARF, 0.001 * paru)
        p, _ = ne.solve(par, -g)
        dxnorm = float(np.linalg.norm(p))
        temp, fp = fp, dxnorm - delta
        if abs(fp) <= 0.1 * delta or (parl == 0.0 and fp <= temp < 0.0) or it == 10:
            break
        w = p / dxnorm
        q, _ = ne.solve(par, w)
        parc = fp / delta / float(w @ q)
        if fp > 0:
            parl = max(parl, par)
        elif fp < 0:
            paru = min(paru, par)
        par = max(parl, par + parc)
    return par, p


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], ArrowJacobian],
                        x0: np.ndarray, max_nfev: int, ftol: float = 1e-8, xtol: float = 1e-8,
                        gtol: float = 1e-8, factor: float = 100.0, final_jac: bool = True,
                        lower: np.ndarray | None = None) -> Result:
    """Minimise ½‖fun(x)‖² (fun: (S, R) residuals) from x0 as MINPACK's lmder does (unit scaling).

    ``lower``: a lower bound for each of the first ``len(lower)`` entries of x (the model
    parameters; −inf where free); x0 is projected onto them and every iterate stays within them
    (``_free_normal``, ``_projected``)."""
    # Over 80 lines: MINPACK's lmder loop, kept in one piece so that it can be read against the
    # Fortran line by line (step, ratio, radius update, the eight termination tests).
    x = np.array(x0, dtype=float)
    lo = None if lower is None or not np.any(np.isfinite(lower)) else np.asarray(lower, dtype=float)
    if lo is not None:
        x[: lo.size] = np.maximum(x[: lo.size], lo)
    f = fun(x)
    nfev, njev = 1, 0
    fnorm = float(np.linalg.norm(f))
    par, it, info = 0.0, 1, 0
    delta = xnorm = 0.0
    J: ArrowJacobian | None = None
    J_at_x = False
    while info == 0:
        J = jac(x)
        njev += 1
        J_at_x = True
        full, ne, free = _free_normal(J, f, x, lo)
        g = ne.g
        cn = ne.col_norms
        if it == 1:
            xnorm = float(np.linalg.norm(x))
            delta = factor * xnorm if xnorm > 0 else factor
        gnorm = 0.0
        if fnorm != 0.0:
            nz = cn != 0.0
            if np.any(nz):
                gnorm = float(np.max(np.abs(g[nz]) / cn[nz])) / fnorm
        if gnorm <= gtol:
            info = 4
            break
        while True:
            par, step = _lmpar(ne, g, delta, par)
            if free is not None:
                step = _expand(step, free, x.size)
            pnorm = float(np.linalg.norm(step))  # the trust region's measure: the step before projection
            x_new, clipped = _projected(x, step, lo)
            if clipped:
                step = x_new - x
            if it == 1:
                delta = min(delta, pnorm)
            f_new = fun(x_new)
            nfev += 1
            fnorm1 = float(np.linalg.norm(f_new))
            actred = 1.0 - (fnorm1 / fnorm) ** 2 if 0.1 * fnorm1 < fnorm else -1.0
            t1 = math.sqrt(max(full.quad(step), 0.0)) / fnorm
            if clipped:  # the projected step's own linear model: 1 - ‖f + J s‖² / ‖f‖²
                gs = float(full.g @ step) / fnorm**2
                prered = -2.0 * gs - t1 * t1
                dirder = gs
            else:
                t2 = math.sqrt(par) * pnorm / fnorm
                prered = t1 * t1 + t2 * t2 / 0.5
                dirder = -(t1 * t1 + t2 * t2)
            ratio = actred / prered if prered > 0.0 else 0.0
            if ratio <= 0.25:
                temp = 0.5 if actred >= 0.0 or dirder > 0.0 else 0.5 * dirder / (dirder + 0.5 * actred)
                if 0.1 * fnorm1 >= fnorm or temp < 0.1:
                    temp = 0.1
                delta = temp * min(delta, pnorm / 0.1)
                par /= temp
            elif par == 0.0 or ratio >= 0.75:
                delta = pnorm / 0.5
                par *= 0.5
            if ratio >= 1e-4:  # successful step
                x, f, fnorm = x_new, f_new, fnorm1
                xnorm = float(np.linalg.norm(x))
                it += 1
                J_at_x = False
            if abs(actred) <= ftol and abs(prered) <= ftol and 0.5 * ratio <= 1.0:
                info = 1
            if delta <= xtol * xnorm:
                info = 3 if info == 1 else 2
            if info:
                break
            if nfev >= max_nfev:
                info = 5
            if abs(actred) <= _EPS and abs(prered) <= _EPS and 0.5 * ratio <= 1.0:
                info = 6
            if delta <= _EPS * xnorm:
                info = 7
            if gnorm <= _EPS:
                info = 8
            if info or ratio >= 1e-4:
                break
    if final_jac and (not J_at_x or J is None):  # scipy returns the Jacobian at the solution
        J = jac(x)
        njev += 1
    return Result(x=x, fun=f, jac=J if final_jac else None, cost=0.5 * fnorm * fnorm, nfev=nfev, njev=njev,
                  status=info, message=MESSAGES[info])


def _free_normal(J: ArrowJacobian, f: np.ndarray, x: np.ndarray,
                 lo: np.ndarray | None) -> tuple[Normal, Normal, np.ndarray | None]:
    """The normal equations over all of z, those over the entries free in this iteration, and
    their indices in z (None: all): an entry at its lower bound whose gradient Jᵀf is positive
    (the cost falls as it goes below) is left out, so the step keeps it where it is."""
    ne = J.normal(f)
    if lo is None:
        return ne, ne, None
    at = np.flatnonzero(x[: lo.size] <= lo)
    fixed = at[ne.g[at] > 0.0]
    if not fixed.size:
        return ne, ne, None
    keep = np.setdiff1d(np.arange(ne.P), fixed)
    return ne, ne.restricted(keep), np.concatenate([keep, np.arange(ne.P, x.size)])


def _expand(step: np.ndarray, free: np.ndarray, n: int) -> np.ndarray:
    """A step over the free entries as a step over all of z (zero for the fixed ones)."""
    out = np.zeros(n)
    out[free] = step
    return out


def _projected(x: np.ndarray, step: np.ndarray, lo: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """x + step with the bounded entries raised to their bounds; and whether any was."""
    x_new = x + step
    if lo is None:
        return x_new, False
    below = x_new[: lo.size] < lo
    if not np.any(below):
        return x_new, False
    x_new[: lo.size] = np.where(below, lo, x_new[: lo.size])
    return x_new, True
