"""The compiled kernels (components/kernels/) equal NumPy implementations of the same equations
to 1e-12 relative, on random states, for the three vessels (minerva2: 6 DOF, amv_osf and supply:
3 DOF). The references here are the textbook matrix forms (``VesselModel.derivative``, m2c-style
Coriolis, an explicit inverse in the Kalman gain), not the kernels' own scalar code, and the EKF
Jacobian is checked against complex-step derivatives of the textbook model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seafmu.components.allocation import allocation_matrix
from seafmu.components.dynamics import J, coriolis_tensor, restoring_coefficients, rzyx
from seafmu.components.kernels import alloc, control, ekf, maneuver, rigid_body, waves
from seafmu.components.reference_model import _exact_coefficients
from seafmu.components.thrusters import max_thrust, speed_to_thrust, thrust_to_speed, thruster_matrix
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import ANGLE_NAMES, load_vessel
from seafmu.components.waves import WaveField, load_matrix

VESSELS = ("minerva2", "amv_osf", "supply")
RTOL = 1e-12


def close(a: np.ndarray, ref: np.ndarray, rtol: float = RTOL) -> None:
    """|a - ref| <= rtol * max|ref| (relative to the array's scale: components near zero carry the
    rounding of the large ones)."""
    a, ref = np.asarray(a), np.asarray(ref)
    scale = max(float(np.max(np.abs(ref))), 1e-300)
    err = float(np.max(np.abs(a - ref))) / scale
    assert err <= rtol, f"relative error {err:.3g} > {rtol:g}"


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)


@pytest.fixture(scope="module", params=VESSELS)
def vessel(request: pytest.FixtureRequest):
    return load_vessel(request.param)


def _params(vessel) -> rigid_body.RigidBodyParams:
    th = vessel.thrusters
    d = vessel.dof
    rs = vessel.restoring
    g6 = restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b) if d == 6 else None
    angles = [i for i, n in enumerate(vessel.eta_names) if n in ANGLE_NAMES]
    return rigid_body.rigid_body_params(
        _sym(vessel.M_RB),
        _sym(vessel.M_A),
        vessel.D_L,
        vessel.D_Q,
        thruster_matrix(th, d),
        g6,
        th.k_forward,
        th.k_reverse,
        th.time_constant,
        th.law == "quadratic",
        vessel.coriolis != "none",
        vessel.current_inertia,
        angles,
    )


def _random_state(rng: np.random.Generator, vessel, n_extra: int) -> np.ndarray:
    d = vessel.dof
    eta = rng.normal(size=d) * 2.0
    if d == 6:
        eta[3:5] = rng.uniform(-0.5, 0.5, size=2)  # roll, pitch away from +-90 deg
    eta[d - 1] = rng.uniform(-math.pi, math.pi)
    return np.concatenate([eta, rng.normal(size=d) * 0.4, rng.normal(size=n_extra)])


# -- rigid body --------------------------------------------------------------------------------


def _xdot_ref(
    model: VesselModel, x: np.ndarray, ncmd: np.ndarray, vcn: float, vce: float, tau_ext: np.ndarray | None
) -> np.ndarray:
    """[eta_dot, nu_dot, n_dot] from the matrix form: J nu, M^-1 (B T(n) + tau_ext - C - D - g)."""
    d = model.dof
    eta, nu, n = x[:d], x[d : 2 * d], x[2 * d :]
    th = model.spec.thrusters
    tau = model.B @ speed_to_thrust(th, n) + (0.0 if tau_ext is None else tau_ext)
    nu_c = None
    if vcn or vce:
        if d == 6:
            nu_c = np.concatenate([rzyx(*eta[3:6]).T @ [vcn, vce, 0.0], np.zeros(3)])
        else:
            c, s = math.cos(eta[2]), math.sin(eta[2])
            nu_c = np.array([c * vcn + s * vce, -s * vcn + c * vce, 0.0])
    eta_dot, nu_dot = model.derivative(eta, nu, tau, nu_c)
    return np.concatenate([eta_dot, nu_dot, (ncmd - n) / th.time_constant])


def test_rigid_body_rhs_equals_matrix_form(vessel) -> None:
    rng = np.random.default_rng(1)
    model = VesselModel(vessel)
    p = _params(vessel)
    d, m = vessel.dof, vessel.thrusters.count
    z, out = np.zeros(m + 3 * d), np.empty(2 * d + m)
    for trial in range(60):
        x = _random_state(rng, vessel, m)
        x[2 * d :] *= 0.5 * vessel.thrusters.n_max
        ncmd = rng.uniform(-1, 1, size=m) * vessel.thrusters.n_max
        vcn, vce = (rng.normal(size=2) * 0.4).tolist() if trial % 2 else (0.0, 0.0)
        te = rng.normal(size=d) * 20.0 if trial % 3 == 0 else None
        rigid_body.rhs(
            x,
            ncmd,
            vcn,
            vce,
            np.zeros(d) if te is None else te,
            te is not None,
            p.K,
            p.MS,
            p.MAL,
            p.ML,
            p.g6,
            p.th,
            p.flags,
            z,
            out,
        )
        ref = _xdot_ref(model, x, ncmd, vcn, vce, te)
        close(out[:d], ref[:d])
        close(out[d : 2 * d], ref[d : 2 * d], rtol=1e-11)  # M^-1 precomputed vs a solve per call
        close(out[2 * d :], ref[2 * d :])


def test_rigid_body_rk4_equals_numpy_rk4(vessel) -> None:
    """RK4 sub-steps with held inputs and angle wrapping, against NumPy RK4 on the matrix form."""
    rng = np.random.default_rng(2)
    model = VesselModel(vessel)
    p = _params(vessel)
    d, m = vessel.dof, vessel.thrusters.count
    for trial in range(10):
        x = _random_state(rng, vessel, m)
        x[d - 1] = math.pi - 1e-4  # heading about to wrap
        x[d + d - 1] = 0.5  # turning: it does within the steps
        ncmd = rng.uniform(-1, 1, size=m) * vessel.thrusters.n_max
        vcn, vce = (0.3, -0.2) if trial % 2 else (0.0, 0.0)
        got = np.empty_like(x)
        rigid_body.rk4(
            x,
            ncmd,
            0.01,
            5,
            vcn,
            vce,
            np.zeros(d),
            False,
            p.K,
            p.MS,
            p.MAL,
            p.ML,
            p.g6,
            p.th,
            p.flags,
            p.angle_index,
            got,
        )
        ref = x.copy()
        for _ in range(5):
            k1 = _xdot_ref(model, ref, ncmd, vcn, vce, None)
            k2 = _xdot_ref(model, ref + 0.005 * k1, ncmd, vcn, vce, None)
            k3 = _xdot_ref(model, ref + 0.005 * k2, ncmd, vcn, vce, None)
            k4 = _xdot_ref(model, ref + 0.01 * k3, ncmd, vcn, vce, None)
            ref = ref + 0.01 / 6.0 * (k1 + k4 + 2.0 * (k2 + k3))
            for i in p.angle_index:
                ref[i] = (ref[i] + math.pi) % (2 * math.pi) - math.pi
        assert -math.pi < got[d - 1] <= math.pi
        close(got, ref, rtol=1e-11)
        assert x[d - 1] == math.pi - 1e-4  # input not modified


def test_thrust_law(vessel) -> None:
    rng = np.random.default_rng(3)
    p = _params(vessel)
    th = vessel.thrusters
    n = rng.uniform(-1, 1, size=th.count) * th.n_max
    out = np.empty(th.count)
    rigid_body.thrust(n, p.th, int(p.flags[1]), out)
    close(out, speed_to_thrust(th, n))


def test_wrap_matches_python() -> None:
    for a in (-7.0, -math.pi, -math.pi + 1e-12, 0.3, math.pi, math.pi + 1e-9, 3 * math.pi, 1e3):
        ref = a if -math.pi < a <= math.pi else (a + math.pi) % (2 * math.pi) - math.pi
        ref = math.pi if ref == -math.pi else ref
        assert rigid_body.wrap(a) == ref


# -- EKF ---------------------------------------------------------------------------------------


class _Ekf:
    """The observer's model in textbook form (complex-step capable) and its constant data."""

    def __init__(self, vessel, nw: int) -> None:
        d = self.d = vessel.dof
        self.nw = nw
        self.M = _sym(vessel.M)
        self.Minv = np.linalg.inv(self.M)
        self.DL, self.DQ = np.asarray(vessel.D_L, float), np.asarray(vessel.D_Q, float)
        self.cor = vessel.coriolis != "none"
        G = coriolis_tensor(self.M) if self.cor else np.zeros((d, d, d))
        self.MinvG = np.ascontiguousarray(np.einsum("ij,jkl->ikl", self.Minv, G))
        self.MinvDL, self.MinvDQ = self.Minv @ self.DL, self.Minv @ self.DQ
        rs = vessel.restoring
        self.g6 = np.array(
            restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b) if d == 6 else [0.0] * 4
        )
        self.inv_tb = 1.0 / 300.0
        w0, lam = 1.1, 0.1
        self.Aw = np.block(
            [[np.zeros((nw, nw)), np.eye(nw)], [-(w0**2) * np.eye(nw), -2 * lam * w0 * np.eye(nw)]]
        )
        n = self.n = 3 * d + 2 * nw
        self.A0 = np.zeros((n, n))
        self.A0[d : 2 * d, 2 * d : 3 * d] = self.Minv
        self.A0[2 * d : 3 * d, 2 * d : 3 * d] = -self.inv_tb * np.eye(d)
        self.A0[3 * d :, 3 * d :] = self.Aw
        self.angles = np.array(
            [i for i, nm in enumerate(vessel.eta_names) if nm in ANGLE_NAMES], dtype=np.int64
        )

    def f(self, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        d = self.d
        eta, nu, b = x[:d], x[d : 2 * d], x[2 * d : 3 * d]
        a = self.M @ nu
        if d == 6:
            ph, th, ps = eta[3], eta[4], eta[5]
            cf, sf, ct, st, cp, sp = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
            R = np.array(
                [
                    [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                    [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                    [-st, ct * sf, ct * cf],
                ]
            )
            T = np.array([[1, sf * st / ct, cf * st / ct], [0, cf, -sf], [0, sf / ct, cf / ct]])
            eta_dot = np.concatenate([R @ nu[:3], T @ nu[3:]])
            cor = np.concatenate([np.cross(nu[3:], a[:3]), np.cross(nu[:3], a[:3]) + np.cross(nu[3:], a[3:])])
            wb, gx, gy, gz = self.g6
            g = np.array(
                [
                    wb * st,
                    -wb * ct * sf,
                    -wb * ct * cf,
                    -gy * ct * cf + gz * ct * sf,
                    gz * st + gx * ct * cf,
                    -gx * ct * sf - gy * st,
                ]
            )
        else:
            c, s = np.cos(eta[2]), np.sin(eta[2])
            eta_dot = np.array([c * nu[0] - s * nu[1], s * nu[0] + c * nu[1], nu[2]])
            cor = np.array([-nu[2] * a[1], nu[2] * a[0], nu[0] * a[1] - nu[1] * a[0]])
            g = np.zeros(3)
        cor = cor if self.cor else 0.0
        absnu = np.where(nu.real >= 0.0, nu, -nu)  # |nu|, analytic for the complex step
        nu_dot = self.Minv @ (tau + b - cor - self.DL @ nu - self.DQ @ (absnu * nu) - g)
        return np.concatenate([eta_dot, nu_dot, -self.inv_tb * b, self.Aw @ x[3 * d :]])

    def jac(self, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        h = 1e-30
        cols = [self.f(x + 1j * h * e, tau).imag / h for e in np.eye(self.n)]
        return np.array(cols).T

    def kernel_model(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A, f = self.A0.copy(), np.empty(self.n)
        ekf.model(
            x,
            tau,
            self.d,
            self.nw,
            self.inv_tb,
            self.Minv,
            self.MinvG,
            self.MinvDL,
            self.MinvDQ,
            self.g6,
            np.ascontiguousarray(self.Aw),
            A,
            f,
        )
        return f, A


@pytest.mark.parametrize("nw", [0, 2])
def test_ekf_model_and_jacobian(vessel, nw: int) -> None:
    e = _Ekf(vessel, nw)
    rng = np.random.default_rng(4)
    for _ in range(20):
        x = _random_state(rng, vessel, vessel.dof + 2 * nw)
        x[2 * vessel.dof : 3 * vessel.dof] *= 50.0  # bias forces
        tau = rng.normal(size=vessel.dof) * 30.0
        f, A = e.kernel_model(x, tau)
        close(f, e.f(x, tau), rtol=1e-11)  # M^-1 G precomputed vs M nu then M^-1 per call
        close(A, e.jac(x, tau), rtol=1e-11)


def _random_cov(rng: np.random.Generator, n: int) -> np.ndarray:
    L = rng.normal(size=(n, n)) * 0.3
    return L @ L.T + np.diag(rng.uniform(0.01, 2.0, size=n))


def test_ekf_predict(vessel) -> None:
    e = _Ekf(vessel, 0)
    rng = np.random.default_rng(5)
    n, d = e.n, vessel.dof
    Qc = rng.uniform(1e-8, 1e-2, size=n)
    for _ in range(5):
        x = _random_state(rng, vessel, d)
        P = _random_cov(rng, n)
        tau = rng.normal(size=d) * 30.0
        xk, A, Pk = x.copy(), e.A0.copy(), P.copy()
        ekf.predict(
            xk,
            Pk,
            tau,
            2,
            0.025,
            Qc,
            d,
            0,
            e.inv_tb,
            e.Minv,
            e.MinvG,
            e.MinvDL,
            e.MinvDQ,
            e.g6,
            np.zeros((0, 0)),
            A,
            e.angles,
        )
        xr, Pr = x.copy(), P.copy()
        for _ in range(2):
            f, Ar = e.f(xr, tau), e.jac(xr, tau)
            hA = 0.025 * Ar
            xr = xr + 0.025 * (f + 0.5 * hA @ f)
            Phi = np.eye(n) + hA + 0.5 * hA @ hA
            Pr = Phi @ Pr @ Phi.T + np.diag(Qc * 0.025)
        for i in e.angles:
            xr[i] = (xr[i] + math.pi) % (2 * math.pi) - math.pi
        close(xk, xr, rtol=1e-11)
        close(Pk, Pr, rtol=1e-11)


def _joseph_ref(x: np.ndarray, P: np.ndarray, H: np.ndarray, y: np.ndarray, var: np.ndarray):
    S = H @ P @ H.T + np.diag(var)
    Sinv = np.linalg.inv(S)
    K = P @ H.T @ Sinv
    IKH = np.eye(len(x)) - K @ H
    Pn = IKH @ P @ IKH.T + K @ np.diag(var) @ K.T
    return x + K @ y, 0.5 * (Pn + Pn.T), float(y @ Sinv @ y)


def test_ekf_update_selection_equals_inverse_joseph(vessel) -> None:
    e = _Ekf(vessel, 0)
    rng = np.random.default_rng(6)
    n, d = e.n, vessel.dof
    names = vessel.eta_names + vessel.nu_names
    for s in vessel.sensors:
        idx = np.array([names.index(c) for c in s.channels], dtype=np.int64)
        angle = np.array([c in ANGLE_NAMES for c in s.channels])
        for _ in range(5):
            x = _random_state(rng, vessel, d)
            P = _random_cov(rng, n)
            var = np.maximum(np.asarray(s.noise_std, float) ** 2, 1e-12)
            z = x[idx] + rng.normal(size=len(idx)) * 0.5
            z[angle] = np.where(z[angle] > math.pi, z[angle] - 2 * math.pi, z[angle])
            y = ekf.innovation(z, x, idx, angle)
            yr = z - x[idx]
            yr[angle] = (yr[angle] + math.pi) % (2 * math.pi) - math.pi
            np.testing.assert_array_equal(y, yr)
            H = np.zeros((len(idx), n))
            H[np.arange(len(idx)), idx] = 1.0
            xr, Pr, nis_r = _joseph_ref(x, P, H, yr, var)
            xk = x.copy()
            Pk = P.copy()
            ok, nis = ekf.update_selection(xk, Pk, idx, y, var, np.inf, e.angles)
            for i in e.angles:
                xr[i] = xr[i] if -math.pi < xr[i] <= math.pi else (xr[i] + math.pi) % (2 * math.pi) - math.pi
            assert ok
            close(xk, xr, rtol=1e-11)
            close(Pk, Pr, rtol=1e-11)
            assert nis == pytest.approx(nis_r, rel=1e-10)
            xm = x.copy()
            Pm = P.copy()
            okm, nism = ekf.update_measured(xm, Pm, idx, z, angle, var / 2.0, 2.0, np.inf, e.angles)
            assert okm and nism == nis
            np.testing.assert_array_equal(xm, xk)
            np.testing.assert_array_equal(Pm, Pk)
            # the gate: a threshold below the NIS rejects and changes nothing
            xg = x.copy()
            Pg = P.copy()
            ok, nis2 = ekf.update_selection(xg, Pg, idx, y, var, 0.5 * nis, e.angles)
            assert not ok and nis2 == nis
            np.testing.assert_array_equal(Pg, P)
            np.testing.assert_array_equal(xg, x)


def test_ekf_update_general_equals_inverse_joseph(vessel) -> None:
    e = _Ekf(vessel, 2)
    rng = np.random.default_rng(7)
    n = e.n
    for m in (1, 2, 3):
        x = _random_state(rng, vessel, vessel.dof + 4)
        P = _random_cov(rng, n)
        H = rng.normal(size=(m, n)) * (rng.uniform(size=(m, n)) < 0.3)
        H[np.arange(m), np.arange(m)] = 1.0
        y = rng.normal(size=m)
        var = rng.uniform(0.01, 1.0, size=m)
        xr, Pr, nis_r = _joseph_ref(x, P, H, y, var)
        for i in e.angles:
            xr[i] = xr[i] if -math.pi < xr[i] <= math.pi else (xr[i] + math.pi) % (2 * math.pi) - math.pi
        xk = x.copy()
        Pk = P.copy()
        ok, nis = ekf.update_general(xk, Pk, H, y, var, np.inf, e.angles)
        assert ok
        close(xk, xr, rtol=1e-11)
        close(Pk, Pr, rtol=1e-11)
        assert nis == pytest.approx(nis_r, rel=1e-10)


def test_ekf_gain_without_positive_definite_s_falls_back() -> None:
    """An indefinite S (a corrupted P) still gives K = P H^T S^-1 (LU), as the inverse did."""
    P = np.array([[1.0, 2.0], [2.0, 1.0]])  # indefinite
    x = np.zeros(2)
    y = np.array([0.3, -0.1])
    ok, _ = ekf.update_selection(
        x,
        P.copy(),
        np.array([0, 1], dtype=np.int64),
        y,
        np.array([0.1, 0.1]),
        np.inf,
        np.zeros(0, dtype=np.int64),
    )
    S = P + 0.1 * np.eye(2)
    assert ok
    close(x, P @ np.linalg.inv(S) @ y)


# -- allocation --------------------------------------------------------------------------------


def test_pinv_clip_and_outputs(vessel) -> None:
    rng = np.random.default_rng(8)
    th = vessel.thrusters
    d, m = vessel.dof, th.count
    B = thruster_matrix(th, d)
    w = rng.uniform(0.5, 2.0, size=m)
    P = np.ascontiguousarray(allocation_matrix(B, w))
    p = _params(vessel)
    T_max = speed_to_thrust(th, th.n_max)
    lo, hi = -0.8 * T_max, 0.9 * T_max
    for any_off in (False, True):
        off = np.zeros(m, dtype=bool)
        T_fixed = np.zeros(m)
        if any_off:
            off[0] = True
            T_fixed[0] = 0.3 * T_max[0]
            lo, hi = np.where(off, T_fixed, lo), np.where(off, T_fixed, hi)
        tau_fixed = B @ T_fixed
        for _ in range(20):
            tau = rng.normal(size=d) * np.abs(B).sum(axis=1) * T_max.mean() * 0.4
            T, Tc, sat = np.empty(m), np.empty(m), np.empty(m, dtype=bool)
            alloc.pinv_clip(P, tau, tau_fixed, T_fixed, any_off, lo, hi, T, Tc, sat)
            Tr = P @ (tau - tau_fixed) + T_fixed
            close(T, Tr)
            np.testing.assert_array_equal(Tc, np.clip(T, lo, hi))
            np.testing.assert_array_equal(sat, Tc != T)
            y = np.zeros(3 * m + d + 3)
            k = 2 * m + d
            pos = np.array([0, m, 2 * m, k, k + 1, k + 2 + m])  # the allocator's output layout
            alloc.outputs(
                Tc, tau, np.ascontiguousarray(B), p.th, int(p.flags[1]), th.n_max, off, any_off, sat, y, pos
            )
            n_ref = np.where(off, 0.0, thrust_to_speed(th, Tc))
            close(y[:m], n_ref)
            np.testing.assert_array_equal(y[m : 2 * m], Tc)
            close(y[2 * m : k], B @ Tc)
            # ||B T - tau|| is a difference of large numbers when tau is within reach
            assert abs(y[k] - np.linalg.norm(B @ Tc - tau)) <= RTOL * float(np.abs(tau).max())
            np.testing.assert_array_equal(y[k + 1 : k + 1 + m], sat)
            assert y[k + 2 + m] == pytest.approx(Tc @ Tc, rel=1e-12)


def test_qp_bounds_and_result() -> None:
    rng = np.random.default_rng(9)
    m, d = 7, 6
    n = m + 2 * d
    bu, bl = np.full(n + d, 1e30), np.zeros(n + d)
    lo, hi, tau = -rng.uniform(1, 2, m), rng.uniform(1, 2, m), rng.normal(size=d)
    alloc.qp_bounds(bu, bl, lo, hi, tau, n)
    np.testing.assert_array_equal(bu[:m], hi)
    np.testing.assert_array_equal(bl[:m], lo)
    np.testing.assert_array_equal(bu[n:], tau)
    np.testing.assert_array_equal(bl[n:], tau)
    assert np.all(bu[m:n] == 1e30) and np.all(bl[m:n] == 0.0)
    x = rng.normal(size=n) * 2
    off = np.zeros(m, dtype=bool)
    off[2] = True
    T, sat = np.empty(m), np.empty(m, dtype=bool)
    alloc.qp_result(x, lo, hi, off, 1e-6, T, sat)
    Tr = np.minimum(np.maximum(x[:m], lo), hi)
    np.testing.assert_array_equal(T, Tr)
    np.testing.assert_array_equal(sat, ((Tr <= lo + 1e-6) | (Tr >= hi - 1e-6)) & ~off)


# -- controller --------------------------------------------------------------------------------


def test_pid_force_and_jacobian(vessel) -> None:
    rng = np.random.default_rng(10)
    d = vessel.dof
    angle = np.array([n in ANGLE_NAMES for n in vessel.eta_names])
    for _ in range(20):
        x = _random_state(rng, vessel, 0)
        eta, nu = x[:d], x[d:]
        eta_d = eta + rng.normal(size=d)
        eta_d_dot, z = rng.normal(size=d) * 0.1, rng.normal(size=d)
        kp, kd, ki = rng.uniform(1, 500, d), rng.uniform(1, 500, d), rng.uniform(0, 50, d)
        Jm, eta_dot, e, tau = np.empty((d, d)), np.empty(d), np.empty(d), np.empty(d)
        control.pid_force(eta, nu, eta_d, eta_d_dot, z, kp, kd, ki, angle, Jm, eta_dot, e, tau)
        Jr = J(eta)
        close(Jm, Jr)
        er = eta - eta_d
        er[angle] = (er[angle] + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_array_equal(e, er)
        close(eta_dot, Jr @ nu)
        close(tau, -(Jr.T @ (kp * er + kd * (Jr @ nu - eta_d_dot) + ki * z)))


def _integrate_ref(h, e, tau_unsat, tau_max, ki, z, z_max, Jt):
    """``ControllerBlock._integrate`` in NumPy (the block's own form)."""
    tau = np.minimum(np.maximum(tau_unsat, -tau_max), tau_max)
    dz = h * e
    over = tau_unsat - tau
    if over.any():
        sat = (over != 0.0) & (tau_max > 0.0)
        sig = np.sign(over[sat])[:, None]
        coupling = Jt[sat]
        effect = -(coupling * (ki * dz)) * sig
        current = -(coupling * (ki * z)) * sig
        unwinding = (effect < 0.0) & (current > 0.0)
        blocked = ((np.abs(coupling) > 0.1) & ~unwinding).any(axis=0)
        dz[blocked] = 0.0
    return tau, np.minimum(np.maximum(z + dz, -z_max), z_max)


def test_saturate_integrate(vessel) -> None:
    rng = np.random.default_rng(11)
    d = vessel.dof
    blocked_seen = 0
    for trial in range(200):
        eta = _random_state(rng, vessel, 0)[:d]
        Jm = J(eta)
        e, z = rng.normal(size=d), rng.normal(size=d) * 5
        ki = rng.uniform(0, 10, d)
        tau_max = rng.uniform(5, 20, d)
        if trial % 4 == 0:
            tau_max[0] = 0.0  # a DOF the thrusters cannot make
        tau_unsat = rng.normal(size=d) * 15
        z_max = rng.uniform(1, 10, d)
        tau = np.empty(d)
        zn = z.copy()
        control.saturate_integrate(0.05, e, tau_unsat, tau_max, ki, zn, z_max, np.ascontiguousarray(Jm), tau)
        tr, zr = _integrate_ref(0.05, e, tau_unsat, tau_max, ki, z, z_max, Jm.T)
        np.testing.assert_array_equal(tau, tr)
        np.testing.assert_array_equal(zn, zr)
        blocked_seen += int(np.any(zn == np.clip(z, -z_max, z_max)))
    assert blocked_seen > 0  # the anti-windup branch was exercised


def test_reference_step(vessel) -> None:
    rng = np.random.default_rng(12)
    d = vessel.dof
    angle = np.array([n in ANGLE_NAMES for n in vessel.eta_names])
    omega, zeta = rng.uniform(0.1, 1.0, d), rng.uniform(0.5, 1.5, d)
    zeta[0] = 1.0  # critically damped branch
    h = 0.05
    coef = np.ascontiguousarray(
        np.array([_exact_coefficients(w, zz, h) for w, zz in zip(omega, zeta, strict=True)]).T
    )
    for _ in range(20):
        x, v, x_ref = rng.normal(size=d) * 2, rng.normal(size=d), rng.normal(size=d) * 2
        x[angle] = (x[angle] + math.pi) % (2 * math.pi) - math.pi
        xo, vo, ao = np.empty(d), np.empty(d), np.empty(d)
        control.reference_step(x, v, x_ref, coef, omega**2, 2 * zeta * omega, angle, xo, vo, ao)
        e0 = x - x_ref
        e0[angle] = (e0[angle] + math.pi) % (2 * math.pi) - math.pi
        p11, p12, p21, p22 = coef
        e, vr = p11 * e0 + p12 * v, p21 * e0 + p22 * v
        xr = x + (e - e0)
        xr[angle] = (xr[angle] + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_array_equal(xo, xr)
        np.testing.assert_array_equal(vo, vr)
        np.testing.assert_array_equal(ao, -(omega**2) * e - 2 * zeta * omega * vr)


# -- waves -------------------------------------------------------------------------------------


def test_wave_force_and_elevation(vessel) -> None:
    rng = np.random.default_rng(13)
    field = WaveField(1.5, 6.0, 0.7, 3.3, 40, np.random.default_rng(0))
    W = np.ascontiguousarray(load_matrix(vessel))
    d = vessel.dof
    for _ in range(10):
        t = rng.uniform(0, 300)
        eta = _random_state(rng, vessel, 0)[:d]
        if d == 6:
            eta[2] = abs(eta[2])
        out = np.empty(d)
        waves.force(
            t, eta, d, field.omega, field.k, field.phase, field._acc_amp, field._cd, field._sd, W, out
        )
        down = float(eta[2]) if d == 6 else 0.0
        a_ned = np.array(field.acceleration(t, float(eta[0]), float(eta[1]), down))
        R = rzyx(*eta[3:6]) if d == 6 else rzyx(0.0, 0.0, float(eta[2]))
        a_b = R.T @ a_ned
        close(out, W @ (a_b if d == 6 else a_b[:2]), rtol=1e-11)
        el = waves.elevation(
            t,
            float(eta[0]),
            float(eta[1]),
            field.omega,
            field.k,
            field.phase,
            field.amp,
            field._cd,
            field._sd,
        )
        ref = float(field.amp @ np.cos(field._theta(t, float(eta[0]), float(eta[1]))))  # NumPy form
        assert el == pytest.approx(ref, rel=1e-11, abs=1e-12)


# -- identification simulator ------------------------------------------------------------------


@pytest.mark.parametrize("current", [False, True])
def test_maneuver_simulate(vessel, current: bool) -> None:
    rng = np.random.default_rng(14)
    d = vessel.dof
    nx = d + 2 if d == 6 else d
    K, S, L = 3, 4, 30
    x0 = rng.normal(size=(K, S, nx)) * 0.2
    Kt = K if current else 1
    tau = rng.normal(size=(Kt, S, L + 1, d))
    tau_mid = rng.normal(size=(Kt, S, L, d))
    nz = d + (2 if current else 1) * d * d + 2 * d
    W = rng.normal(size=(K, nz, d)) * 0.05
    W[2] *= 1e4  # this parameter set diverges: NaN from there on
    rs = vessel.restoring
    g4 = (
        np.array(restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b)) * 1e-3
        if d == 6
        else np.zeros(4)
    )
    vc = rng.normal(size=(K, 2)) * 0.3 if current else None
    psi = rng.normal(size=(S, L + 1))
    psi_mid = rng.normal(size=(S, L))
    out = np.empty((K, S, L + 1, nx))
    maneuver.simulate(
        x0, tau, tau_mid, W, 0.1, d, g4, current, np.zeros((K, 2)) if vc is None else vc, psi, psi_mid, out
    )
    ref = np.empty_like(out)
    maneuver.simulate_numpy(
        x0,
        np.broadcast_to(tau, (K, *tau.shape[1:])),
        np.broadcast_to(tau_mid, (K, *tau_mid.shape[1:])),
        W,
        0.1,
        d,
        g4,
        current,
        np.zeros((K, 2)) if vc is None else vc,
        psi,
        psi_mid,
        ref,
    )
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    assert np.isnan(out[2, :, -1]).all()
    fin = np.isfinite(ref)
    close(out[fin], ref[fin], rtol=1e-11)


def test_cache_folder_is_the_users_and_keyed_by_content(tmp_path, monkeypatch) -> None:
    from seafmu.components.kernels import _jit

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    path = _jit.cache_dir()
    assert path.startswith(str(tmp_path)) and _jit.DIGEST in path
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _jit.cache_dir().startswith(str(tmp_path / "xdg" / "seafmu" / "numba"))


def test_dp_step_is_its_parts(vessel) -> None:
    """The fused DP kernel = reference step, PID force and saturate/integrate called one by one."""
    rng = np.random.default_rng(15)
    d = vessel.dof
    angle = np.array([n in ANGLE_NAMES for n in vessel.eta_names])
    omega, zeta = rng.uniform(0.1, 1.0, d), np.ones(d)
    coef = np.ascontiguousarray(
        np.array([_exact_coefficients(w, zz, 0.05) for w, zz in zip(omega, zeta, strict=True)]).T
    )
    w2, two_zw = omega**2, 2 * zeta * omega
    for _ in range(20):
        x = _random_state(rng, vessel, 0)
        eta, nu = x[:d], x[d:]
        eta_ref, ref_x, ref_v = eta + rng.normal(size=d), eta + rng.normal(size=d), rng.normal(size=d) * 0.1
        kp, kd, ki = rng.uniform(1, 500, d), rng.uniform(1, 500, d), rng.uniform(0, 50, d)
        tau_max, z_max = rng.uniform(5, 200, d), rng.uniform(1, 10, d)
        z = rng.normal(size=d)
        fused = [np.empty(d) for _ in range(4)]
        zf = z.copy()
        control.dp_step(
            0.05,
            eta,
            nu,
            eta_ref,
            ref_x,
            ref_v,
            coef,
            w2,
            two_zw,
            angle,
            *fused[:3],
            zf,
            kp,
            kd,
            ki,
            angle,
            tau_max,
            z_max,
            fused[3],
        )
        xo, vo, ao = np.empty(d), np.empty(d), np.empty(d)
        control.reference_step(ref_x, ref_v, eta_ref, coef, w2, two_zw, angle, xo, vo, ao)
        Jm, eta_dot, e, tau_new, tau = np.empty((d, d)), np.empty(d), np.empty(d), np.empty(d), np.empty(d)
        control.pid_force(eta, nu, xo, vo, z, kp, kd, ki, angle, Jm, eta_dot, e, tau_new)
        zs = z.copy()
        control.saturate_integrate(0.05, e, tau_new, tau_max, ki, zs, z_max, Jm, tau)
        for a, b in zip(fused, (xo, vo, ao, tau), strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(zf, zs)


def test_pinv_step_is_its_parts(vessel) -> None:
    """The fused pinv allocator step = pinv_clip + outputs + the camera thrusters' negative thrust;
    a non-finite input writes nothing and says so."""
    rng = np.random.default_rng(16)
    th = vessel.thrusters
    d, m = vessel.dof, th.count
    B = np.ascontiguousarray(thruster_matrix(th, d))
    P = np.ascontiguousarray(allocation_matrix(B, np.ones(m)))
    p = _params(vessel)
    T_max = speed_to_thrust(th, th.n_max)
    lo, hi = -0.8 * T_max, 0.9 * T_max
    k = 2 * m + d
    pos = np.array([0, m, 2 * m, k, k + 1, k + 2 + m])
    camera = np.array([0, 1][: max(1, m - 1)], dtype=np.int64)
    off, zeros_m, zeros_d = np.zeros(m, dtype=bool), np.zeros(m), np.zeros(d)
    tau_idx = np.arange(2, 2 + d, dtype=np.int64)  # tau sits among other inputs

    def rest(out: np.ndarray) -> tuple:
        """pinv_step's arguments after the input vector, writing into ``out``."""
        return (tau_idx, P, zeros_d, zeros_m, False, lo, hi, B, p.th, int(p.flags[1]), th.n_max, off, camera,
                out, pos, k + 1 + m, k + 3 + m, Tc)

    for trial in range(20):
        u = rng.normal(size=d + 4) * T_max.mean() * 2
        # outputs' six groups, the camera sum at k + 1 + m and the QP iterations at k + 3 + m (the last)
        y, Tc = np.full(3 * m + d + 4, np.nan), np.empty(m)
        ok = alloc.pinv_step(u, *rest(y))
        assert ok
        tau = u[tau_idx]
        T, Tr, sat = np.empty(m), np.empty(m), np.empty(m, dtype=bool)
        alloc.pinv_clip(P, tau, zeros_d, zeros_m, False, lo, hi, T, Tr, sat)
        yr = np.full_like(y, np.nan)
        alloc.outputs(Tr, tau, B, p.th, int(p.flags[1]), th.n_max, off, False, sat, yr, pos)
        yr[k + 1 + m] = float(sum(-Tr[i] for i in camera if Tr[i] < 0.0))
        yr[k + 3 + m] = 0.0
        np.testing.assert_array_equal(Tc, Tr)
        np.testing.assert_array_equal(y, yr)
        if trial == 0:
            bad = u.copy()
            bad[0] = np.nan  # not even one of the tau inputs: every input is checked
            y2 = np.zeros_like(y)
            assert not alloc.pinv_step(bad, *rest(y2))
            assert not y2.any()


_COMPILE_IN_COPY = """
import sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from copied.kernels import ekf
x = np.zeros(3)
print(ekf.innovation(np.ones(2), x, np.array([0, 2]), np.array([False, True])).tolist())
"""
_LOAD_HERE = """
import numpy as np
from seafmu.components.kernels import ekf
x = np.zeros(3)
y = ekf.innovation(np.ones(2), x, np.array([0, 2]), np.array([False, True]))
st = ekf.innovation.stats
print(y.tolist(), sum(st.cache_hits.values()), sum(st.cache_misses.values()))
"""


def test_a_kernel_compiled_by_an_fmus_copy_loads_from_the_cache_here(tmp_path) -> None:
    """An FMU bundles the kernels under another package name and its folder is gone after the run;
    what it compiled into the shared cache still loads in the installed package (no recompile)."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from seafmu.components import kernels

    root = tmp_path / "bundle"
    shutil.copytree(
        Path(kernels.__file__).parent,
        root / "copied" / "kernels",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    (root / "copied" / "__init__.py").write_text("")
    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    first = subprocess.run(
        [sys.executable, "-c", _COMPILE_IN_COPY, str(root)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    shutil.rmtree(root)  # as an unpacked FMU at the end of a run
    second = subprocess.run(
        [sys.executable, "-c", _LOAD_HERE], env=env, capture_output=True, text=True, check=True
    )
    values, hits, misses = second.stdout.split("]")[0] + "]", *second.stdout.split("]")[1].split()
    assert values == first.stdout.strip()
    assert (int(hits), int(misses)) == (1, 0)  # loaded, not compiled again


def test_one_thrust_law_definition_for_every_caller() -> None:
    """The laws a vessel file may name are the compiled ones, and the NumPy helpers, the plant's
    kernel and the allocator's inverse all give the textbook law (T = k n or k n|n|)."""
    from seafmu.components.kernels import thrust_law
    from seafmu.components.vessel_spec import K_UNITS, load_vessel

    assert tuple(K_UNITS) == thrust_law.LAWS
    rng = np.random.default_rng(5)
    for name in ("minerva2", "amv_osf", "supply"):
        th = load_vessel(name).thrusters
        n = rng.uniform(-1.0, 1.0, (50, th.count)) * th.n_max
        k = np.where(n >= 0, th.k_forward, th.k_reverse)
        ref = k * n * np.abs(n) if th.law == "quadratic" else k * n
        np.testing.assert_array_equal(speed_to_thrust(th, n), ref)
        np.testing.assert_allclose(thrust_to_speed(th, ref, clip=False), n, rtol=1e-12, atol=1e-12)
        out = np.empty(th.count)
        p = np.ascontiguousarray(np.vstack([th.k_forward, th.k_reverse, 1.0 / th.time_constant]))
        rigid_body.thrust(np.ascontiguousarray(n[0]), p, thrust_law.code(th.law), out)
        np.testing.assert_array_equal(out, ref[0])
        # the limits, from the law's Python form, equal the compiled law at -n_max and +n_max
        t_min, t_max = max_thrust(th)
        np.testing.assert_array_equal(t_min, speed_to_thrust(th, -th.n_max))
        np.testing.assert_array_equal(t_max, speed_to_thrust(th, th.n_max))
        assert np.all(t_min < 0) and np.all(t_max > 0)



def test_validation_does_not_import_numba() -> None:
    """Validating a scenario reads the blocks' interfaces (thrust limits from the laws' plain form):
    the kernel modules, and numba with them, are imported on first use only (a sweep validates
    every case in a process that runs none), and every kernel module is reachable as
    ``kernels.<name>``."""
    import subprocess
    import sys
    from pathlib import Path

    from seafmu.components import kernels

    code = ("import sys\nfrom seafmu.scenario import load_scenario, scenario_path\n"
            "for name in ('minerva2_dp', 'amv_osf_autopilot', 'supply_dp'):\n"
            "    load_scenario(scenario_path(name))\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout[:300]
    files = {f.stem for f in Path(kernels.__file__).parent.glob("*.py") if not f.stem.startswith("_")}
    assert files == kernels.MODULES
    assert kernels.thrust_law.thrust_of.py_func is kernels.laws.thrust_of  # compiled from the plain form
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        kernels.nope  # noqa: B018

# -- the plant's whole step (kernels/plant.py) ---------------------------------------------------
PLANT_CASES = (
    {},
    {"current_speed": 0.3, "current_direction": 0.5, "substep": 0.05},
    {"wave_hs": 1.0, "current_speed": 0.2, "current_variation": 0.05, "mag_fault_amplitude": 0.1,
     "usbl_outlier_rate": 0.3, "usbl_dropout_start": 3.0, "usbl_dropout_length": 4.0, "fail_mode_2": 2,
     "fail_value_2": 3.0, "fail_mode_1": 1, "thruster_efficiency_1": 0.7, "seed": 5},
)


@pytest.mark.parametrize("case", range(len(PLANT_CASES)))
def test_plant_step_equals_its_reference_form(vessel, case: int) -> None:
    """One compiled call per step (clip, failed drives, RK4 with waves, sensors with their faults,
    every output) gives the outputs, state and random streams of the Python reference step, bit
    for bit, over enough steps to refill the sensors' noise (256 samples ahead)."""
    from seafmu.components.plant import PlantBlock

    params = {k: v for k, v in PLANT_CASES[case].items()
              if not k.startswith(("fail_", "thruster_efficiency_", "usbl_")) or vessel.name == "minerva2"}
    a, b = PlantBlock(vessel, dict(params)), PlantBlock(vessel, dict(params))
    nmax = np.asarray(vessel.thrusters.n_max, dtype=float)
    rng = np.random.default_rng(case)
    for k in range(700):
        u = rng.uniform(-1.2, 1.2, len(nmax)) * nmax  # beyond n_max: the clip
        ya, yb = a.step(k * 0.05, 0.05, u), b._step_reference(k * 0.05, 0.05, u)
        np.testing.assert_array_equal(ya, yb, err_msg=f"step {k}")
    np.testing.assert_array_equal(a.state, b.state)
    sa, sb = a._sensors, b._sensors
    for name in ("s_int_mut", "s_float_mut", "noise", "uniform"):
        np.testing.assert_array_equal(getattr(sa, name), getattr(sb, name), err_msg=name)
    assert sa.s_int_mut[: sa.G].max() >= 1 and sa.s_float_mut[sa.C : sa.C + sa.G].max() > 256
    with pytest.raises(ValueError, match="non-finite input"):
        a.step(35.0, 0.05, np.full(len(nmax), np.nan))


OBSERVER_CASES = (
    ({}, {}),
    ({"usbl_outlier_rate": 0.3, "usbl_outlier_size": 20.0, "usbl_dropout_start": 5.0,
      "usbl_dropout_length": 4.0, "current_speed": 0.3},
     {"gate_probability": 0.99, "gate_max_rejections": 2, "innovation_gate": 50.0}),
    ({"wave_hs": 1.0}, {"wave_filter": 1.0}),
)


@pytest.mark.parametrize("case", range(len(OBSERVER_CASES)))
def test_observer_step_equals_its_reference_form(vessel, case: int) -> None:
    """The observer's compiled step (prediction, the plain updates, the outputs in one call; what
    it leaves to Python: first fixes, gated samples, the wave filter) gives the outputs, x and P of
    the reference step (``predict``, ``_update`` per sensor, ``output``), bit for bit."""
    from seafmu.components.observer import ObserverBlock
    from seafmu.components.plant import PlantBlock

    pp, op = OBSERVER_CASES[case]
    if vessel.name != "minerva2":
        pp = {k: v for k, v in pp.items() if not k.startswith("usbl_")}
    plant = PlantBlock(vessel, dict(pp))
    a, b = ObserverBlock(vessel, dict(op)), ObserverBlock(vessel, dict(op))
    p_out, o_in = plant.out.names, a.inp.names
    src = np.array([p_out.index(n) if n in p_out else -1 for n in o_in])
    tau = np.array([n.startswith("tau_alloc_") for n in o_in])
    nmax = np.asarray(vessel.thrusters.n_max, dtype=float)
    rng = np.random.default_rng(case)

    def inputs(y: np.ndarray) -> np.ndarray:
        u = np.where(src >= 0, y[src], 0.0)
        u[tau] = rng.normal(size=int(tau.sum())) * 50.0
        return u

    u0 = inputs(plant.output())
    np.testing.assert_array_equal(a.start(u0), b.start(u0))
    rejected = 0
    for k in range(400):
        u = inputs(plant.step(k * 0.05, 0.05, rng.uniform(-0.5, 0.5, len(nmax)) * nmax))
        ya, yb = a.step(k * 0.05, 0.05, u), b._step_reference(k * 0.05, 0.05, u)
        np.testing.assert_array_equal(ya, yb, err_msg=f"step {k}")
        rejected = a.n_rejected
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    assert (a.n_rejected, a.pos_resets) == (b.n_rejected, b.pos_resets)
    if case == 1 and vessel.name == "minerva2":
        assert rejected > 0  # the gate's path was taken
    with pytest.raises(ValueError, match="not finite"):
        a.step(20.0, 0.05, np.full(len(o_in), np.nan))


@pytest.mark.parametrize("name", ["minerva2", "supply"])
def test_dp_controller_step_equals_its_reference_form(name: str) -> None:
    """The DP controller's held step as one compiled call from input to output vector equals the
    general step (``ControllerBlock.step``: mode key, ``_step_law``, ``_held_step``) bit for bit,
    through setpoint changes, a mode switch and back (the switch steps go the general way)."""
    from seafmu.components.controller import ControllerBlock

    vessel = load_vessel(name)
    a, b = ControllerBlock(vessel, {}), ControllerBlock(vessel, {})
    names = a.inp.names
    rng = np.random.default_rng(3)
    u = np.zeros(len(names))
    u0 = u.copy()
    np.testing.assert_array_equal(a.start(u0), b.start(u0))
    fast = 0
    for k in range(300):
        u = u + rng.normal(size=len(u)) * 0.05
        if k == 100:
            u[names.index("north_ref")] = 3.0
        for blk in (a, b):
            if k == 150:
                blk.set_parameter("mode", 4)  # joystick: the general path
            if k == 200:
                blk.set_parameter("mode", 0)
        before = a._active
        ya, yb = a.step(k * 0.05, 0.05, u), ControllerBlock.step(b, k * 0.05, 0.05, u)
        fast += before == a._active and a.mode == 0
        np.testing.assert_array_equal(ya, yb, err_msg=f"step {k}")
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.ref.x, b.ref.x)
    assert fast > 200
    with pytest.raises(ValueError, match="not finite"):
        a.step(20.0, 0.05, np.full(len(u), np.nan))
