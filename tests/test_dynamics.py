"""components.dynamics: the textbook forms (Fossen's notation), and every unrolled hot path held equal
to them (plant right-hand side, observer restoring and model, controller feed-forward)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from seafmu.components.block import full_params
from seafmu.components.controller import ControllerBlock
from seafmu.components.dynamics import (
    J,
    coriolis_force,
    coriolis_kron,
    coriolis_tensor,
    gvect,
    m2c,
    restoring_coefficients,
    restoring_force,
    rpsi,
    rzyx,
    smtrx,
    tzyx,
    tzyx_inv,
    wrap_angle,
)
from seafmu.components.observer import ObserverBlock
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel

RNG = np.random.default_rng(7)


def _random_mass(d: int) -> np.ndarray:
    A = RNG.normal(size=(d, d))
    return A @ A.T + d * np.eye(d) + 0.3 * RNG.normal(size=(d, d))  # deliberately not symmetric


@pytest.fixture(scope="module")
def supply() -> VesselSpec:
    return load_vessel("supply")


# -- rotations ----------------------------------------------------------------------------------

def test_rzyx_is_the_zyx_euler_rotation_and_tzyx_inverts() -> None:
    for _ in range(20):
        phi, theta, psi = RNG.uniform(-1.2, 1.2, 3)
        R = rzyx(phi, theta, psi)
        ref = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()
        np.testing.assert_allclose(R, ref, atol=1e-14)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(tzyx(phi, theta) @ tzyx_inv(phi, theta), np.eye(3), atol=1e-12)
    psi = 0.7
    np.testing.assert_allclose(rpsi(psi), rzyx(0.0, 0.0, psi), atol=1e-15)
    np.testing.assert_allclose(J(np.array([1.0, 2.0, psi])), rpsi(psi))
    eta6 = np.array([0, 0, 0, 0.1, -0.2, psi])
    Jm = J(eta6)
    np.testing.assert_allclose(Jm[:3, :3], rzyx(0.1, -0.2, psi))
    np.testing.assert_allclose(Jm[3:, 3:], tzyx(0.1, -0.2))
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    np.testing.assert_allclose(smtrx(a) @ b, np.cross(a, b), atol=1e-14)
    assert wrap_angle(np.pi) == np.pi and wrap_angle(-np.pi) == np.pi and wrap_angle(0.5) == 0.5


# -- Coriolis -----------------------------------------------------------------------------------

@pytest.mark.parametrize("d", [3, 6])
def test_coriolis_forms_agree_and_do_no_work(d: int) -> None:
    M = _random_mass(d)
    for _ in range(10):
        nu = RNG.normal(size=d)
        C = m2c(M, nu)
        np.testing.assert_allclose(C + C.T, 0.0, atol=1e-12)  # skew-symmetric: nu^T C nu = 0
        np.testing.assert_allclose(coriolis_force(M, nu), C @ nu, atol=1e-10)
        G = coriolis_tensor(M)
        np.testing.assert_allclose(0.5 * (G @ nu) @ nu, C @ nu, atol=1e-10)
        np.testing.assert_allclose(coriolis_kron(M) @ np.kron(nu, nu), C @ nu, atol=1e-10)
        # G @ nu is the Jacobian of C(nu) nu
        eps = 1e-6
        num = np.column_stack([(m2c(M, nu + eps * e) @ (nu + eps * e) - m2c(M, nu - eps * e) @ (nu - eps * e))
                               / (2 * eps) for e in np.eye(d)])
        np.testing.assert_allclose(G @ nu, num, atol=1e-6)
    batch = RNG.normal(size=(4, 5, d))
    out = coriolis_force(M, batch)
    assert out.shape == batch.shape
    np.testing.assert_allclose(out[2, 3], m2c(M, batch[2, 3]) @ batch[2, 3], atol=1e-10)


def test_m2c_6dof_is_fossens_block_form() -> None:
    """C_RB(nu) of a rigid body at the CG: [[0, -m S(nu1)], [-m S(nu1), -S(I nu2)]] (Fossen eq. 3.56)."""
    m, Ib = 40.0, np.diag([2.0, 3.0, 4.0])
    M = np.block([[m * np.eye(3), np.zeros((3, 3))], [np.zeros((3, 3)), Ib]])
    nu = RNG.normal(size=6)
    expected = np.block([[np.zeros((3, 3)), -m * smtrx(nu[:3])], [-m * smtrx(nu[:3]), -smtrx(Ib @ nu[3:])]])
    np.testing.assert_allclose(m2c(M, nu), expected, atol=1e-12)


# -- restoring ----------------------------------------------------------------------------------

def test_gvect_is_weight_and_buoyancy_rotated_into_the_body() -> None:
    """g(eta) = -[f_g + f_b; r_g x f_g + r_b x f_b], f = R^T of the NED forces (Fossen eq. 4.5)."""
    W, B = 2800 * 9.81, 2800 * 9.81 + 30.0
    r_g, r_b = np.array([0.01, -0.02, 0.03]), np.array([0.0, 0.01, -0.05])
    for _ in range(10):
        phi, theta, psi = RNG.uniform(-0.8, 0.8, 3)
        Rt = rzyx(phi, theta, psi).T
        f_g, f_b = Rt @ [0.0, 0.0, W], Rt @ [0.0, 0.0, -B]
        expected = -np.concatenate([f_g + f_b, np.cross(r_g, f_g) + np.cross(r_b, f_b)])
        g = gvect(W, B, theta, phi, r_g, r_b)
        np.testing.assert_allclose(g, expected, rtol=1e-12, atol=1e-9)
        coeffs = restoring_coefficients(W, B, r_g, r_b)
        np.testing.assert_allclose(restoring_force(coeffs, phi, theta), g, rtol=1e-12, atol=1e-9)


# -- the hot paths, held equal to the matrix form -----------------------------------------------

def _vessels() -> list[str]:
    return ["minerva2", "minerva2_published_damping", "amv_osf", "supply"]


@pytest.mark.parametrize("name", _vessels())
def test_plant_rhs_equals_the_matrix_form(name: str) -> None:
    """VesselModel.rhs (unrolled floats) = derivative (m2c, J, gvect, D) with thrust and current."""
    vs = load_vessel(name)
    model = VesselModel(vs)
    d, m = vs.dof, vs.thrusters.count
    for k in range(10):
        eta = RNG.normal(scale=[1, 1, 1, 0.2, 0.2, 2][:d] if d == 6 else [1, 1, 2], size=d)
        nu = RNG.normal(scale=0.5, size=d)
        n = RNG.uniform(-1, 1, m) * vs.thrusters.n_max
        vcn, vce = (0.0, 0.0) if k == 0 else tuple(RNG.normal(scale=0.3, size=2))
        x = model.initial_state(eta, nu, n)
        xdot = model.rhs(x, model.clip(n), vcn, vce)
        nu_c = np.zeros(d)
        if d == 6:
            nu_c[:3] = rzyx(*eta[3:6]).T @ [vcn, vce, 0.0]
        else:
            nu_c[:2] = (rpsi(eta[2]).T @ [vcn, vce, 0.0])[:2]
        eta_dot, nu_dot = model.derivative(eta, nu, model.B @ model.thrust(n), nu_c)
        scale = np.abs(nu_dot).max() + 1.0
        np.testing.assert_allclose(xdot[:d], eta_dot, atol=1e-12)
        np.testing.assert_allclose(xdot[d : 2 * d], nu_dot, atol=1e-10 * scale)
        if d == 6:
            rs = vs.restoring
            g = gvect(rs.weight, rs.buoyancy, eta[4], eta[3], rs.r_g, rs.r_b)
            np.testing.assert_allclose(model.restoring(eta), g)


def _current_in_body(eta: np.ndarray, vc_ned: np.ndarray) -> np.ndarray:
    d = eta.size
    nu_c = np.zeros(d)
    nu_c[: 3 if d == 6 else 2] = (J(eta)[:3, :3].T @ vc_ned)[: 3 if d == 6 else 2]
    return nu_c


@pytest.mark.parametrize("form", ["absolute", "relative", "added"])
@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
def test_inertia_in_a_current_is_the_named_form(name: str, form: str) -> None:
    """current_inertia: the compiled right-hand side solves, with nu_c_dot taken by finite
    differences of R(eta)^T v_c along eta_dot = J(eta) nu (not from omega x nu_c, as the model does):
    absolute M nu_dot, relative M nu_r_dot, added M_RB nu_dot + M_A nu_r_dot (Fossen 2021), each
    + C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau. The three differ by metres over a
    minute of an open-loop turn in a current (docs/vessels.md), so each is held to its own form."""
    import dataclasses

    vs = dataclasses.replace(load_vessel(name), current_inertia=form)
    model = VesselModel(vs)
    d, m = vs.dof, vs.thrusters.count
    M_RB, M_A = 0.5 * (vs.M_RB + vs.M_RB.T), 0.5 * (vs.M_A + vs.M_A.T)
    on_rel = {"absolute": np.zeros((d, d)), "relative": M_RB + M_A, "added": M_A}[form]
    for _ in range(10):
        eta = RNG.normal(scale=[1, 1, 1, 0.3, 0.3, 2][:d] if d == 6 else [1, 1, 2], size=d)
        nu = RNG.normal(scale=0.4, size=d)
        nu[-1] = RNG.choice([-1, 1]) * RNG.uniform(0.1, 0.4)  # turning: the forms differ only then
        n = RNG.uniform(-1, 1, m) * vs.thrusters.n_max
        vc = np.array([*RNG.normal(scale=0.3, size=2), 0.0])
        h = 1e-6
        eta_dot = J(eta) @ nu
        nu_c = _current_in_body(eta, vc)
        ahead, behind = _current_in_body(eta + h * eta_dot, vc), _current_in_body(eta - h * eta_dot, vc)
        nu_c_dot = (ahead - behind) / (2 * h)
        nu_r = nu - nu_c
        rest = m2c(M_RB, nu) @ nu + m2c(M_A, nu_r) @ nu_r + vs.D_L @ nu_r + vs.D_Q @ (np.abs(nu_r) * nu_r)
        if d == 6:
            rs = vs.restoring
            rest = rest + gvect(rs.weight, rs.buoyancy, eta[4], eta[3], rs.r_g, rs.r_b)
        # (M_RB + M_A) nu_dot - on_rel nu_c_dot = tau - rest
        expected = np.linalg.solve(M_RB + M_A, model.B @ model.thrust(n) - rest + on_rel @ nu_c_dot)
        xdot = model.rhs(model.initial_state(eta, nu, n), model.clip(n), vc[0], vc[1])
        np.testing.assert_allclose(xdot[d : 2 * d], expected, rtol=1e-6, atol=1e-7 * np.abs(expected).max())
        _, nu_dot = model.derivative(eta, nu, model.B @ model.thrust(n), nu_c)
        np.testing.assert_allclose(nu_dot, expected, rtol=1e-6, atol=1e-7 * np.abs(expected).max())


def test_published_inertia_takes_the_files_matrices_as_given() -> None:
    """``inertia: published``: M nu_dot with M = M_RB + M_A exactly as the file gives them (Minerva 2's
    added mass is asymmetric: A35 = 61.56, A53 = 148.2), Coriolis from the symmetric parts (as
    Fossen's m2c), in the compiled right-hand side and the matrix form; the default differs."""
    import dataclasses

    vs = dataclasses.replace(load_vessel("minerva2_published_damping"), inertia="published")
    assert np.abs(vs.M_A - vs.M_A.T).max() > 80  # the published matrix, not a symmetrised copy
    model, default = VesselModel(vs), VesselModel(dataclasses.replace(vs, inertia="symmetric"))
    M_RB, M_A = 0.5 * (vs.M_RB + vs.M_RB.T), 0.5 * (vs.M_A + vs.M_A.T)
    rs = vs.restoring
    for _ in range(10):
        eta = RNG.normal(scale=[1, 1, 1, 0.3, 0.3, 2])
        nu = RNG.normal(scale=0.4, size=6)
        n = RNG.uniform(-1, 1, vs.thrusters.count) * vs.thrusters.n_max
        rest = (m2c(M_RB, nu) @ nu + m2c(M_A, nu) @ nu + vs.D_L @ nu + vs.D_Q @ (np.abs(nu) * nu)
                + gvect(rs.weight, rs.buoyancy, eta[4], eta[3], rs.r_g, rs.r_b))
        tau = model.B @ model.thrust(n)
        expected = np.linalg.solve(vs.M_RB + vs.M_A, tau - rest)
        x = model.initial_state(eta, nu, n)
        scale = np.abs(expected).max()
        np.testing.assert_allclose(model.rhs(x, model.clip(n), 0.0, 0.0)[6:12], expected, atol=1e-10 * scale)
        np.testing.assert_allclose(model.derivative(eta, nu, tau)[1], expected, atol=1e-10 * scale)
        other = default.rhs(x, default.clip(n), 0.0, 0.0)[6:12]
        assert np.abs(other - expected).max() > 1e-4 * scale  # the option changes the dynamics


@pytest.mark.parametrize("name", _vessels())
def test_observer_model_equals_the_plant_matrix_form(name: str) -> None:
    """The EKF's f(x) (tensor Coriolis, unrolled restoring) = VesselModel.derivative with tau + b."""
    vs = load_vessel(name)
    iface = ObserverBlock.interface(vs)
    obs = ObserverBlock(vs, full_params(iface, {}))
    model = VesselModel(vs)
    d = vs.dof
    for _ in range(5):
        x = np.concatenate([RNG.normal(scale=0.2, size=d), RNG.normal(scale=0.5, size=d),
                            RNG.normal(scale=10.0, size=d)])
        tau = RNG.normal(scale=100.0, size=d)
        f, _ = obs._model(x, tau)
        eta_dot, nu_dot = model.derivative(x[:d], x[d : 2 * d], tau + x[2 * d :])
        np.testing.assert_allclose(f[:d], eta_dot, atol=1e-12)
        np.testing.assert_allclose(f[d : 2 * d], nu_dot, atol=1e-9 * (np.abs(nu_dot).max() + 1.0))


@pytest.mark.parametrize("name", ["minerva2", "supply"])
def test_dp_feedforward_equals_the_matrix_form(name: str) -> None:
    """dp_pid's waypoint feed-forward M nu_d_dot + C(nu_d) nu_d + D(nu_d) nu_d, nu_d = J^-1 eta_d_dot,
    nu_d_dot = J^-1 eta_d_dd - omega x v (body turning under a NED velocity), in matrix form."""
    vs = load_vessel(name)
    ctl = ControllerBlock(vs, full_params(ControllerBlock.interface(vs), {}))
    d = vs.dof
    M = 0.5 * (vs.M + vs.M.T)
    for _ in range(5):
        eta = RNG.normal(scale=0.3, size=d)
        ed, edd = RNG.normal(scale=0.3, size=d), RNG.normal(scale=0.1, size=d)
        Jm = J(eta)
        nu_d = np.linalg.solve(Jm, ed)
        nu_dd = np.linalg.solve(Jm, edd)
        w = nu_d[3:] if d == 6 else np.array([0.0, 0.0, nu_d[2]])
        v = nu_d[:3] if d == 6 else np.array([nu_d[0], nu_d[1], 0.0])
        nu_dd[: 3 if d == 6 else 2] -= np.cross(w, v)[: 3 if d == 6 else 2]
        cor = m2c(M, nu_d) @ nu_d if vs.coriolis != "none" else 0.0
        expected = M @ nu_dd + cor + vs.D_L @ nu_d + vs.D_Q @ (np.abs(nu_d) * nu_d)
        np.testing.assert_allclose(ctl._feedforward(eta, ed, edd), expected, rtol=1e-10,
                                   atol=1e-9 * np.abs(expected).max())


def test_linear_model_has_no_coriolis(supply: VesselSpec) -> None:
    """coriolis: none (the supply vessel): M nu_dot + D nu = tau exactly, even while turning."""
    model = VesselModel(supply)
    nu = np.array([2.0, -0.5, 0.05])
    _, nu_dot = model.derivative(np.array([0, 0, 0.3]), nu, np.zeros(3))
    np.testing.assert_allclose(nu_dot, -np.linalg.solve(supply.M, supply.D_L @ nu), rtol=1e-12)
