"""EKF observer: model and Jacobian, consistency on noisy simulated runs, bias, sample handling."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import numpy as np
import pytest

from seafmu.components.block import full_params
from seafmu.components.kinematics import wrap_angle
from seafmu.components.observer import ObserverBlock
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel


def observer(vessel: VesselSpec, **params: object) -> ObserverBlock:
    return ObserverBlock(vessel, full_params(ObserverBlock.interface(vessel), params))


def random_state(vessel: VesselSpec, rng: np.random.Generator) -> np.ndarray:
    d = vessel.dof
    x = np.concatenate([rng.normal(size=d) * 3.0, rng.normal(size=d) * 0.3, rng.normal(size=d) * 20.0])
    if d == 6:
        x[3:5] = rng.uniform(-0.3, 0.3, 2)
    return x


# -- the model inside the filter ------------------------------------------------------------------


@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
def test_jacobian_matches_finite_differences(name: str) -> None:
    vessel = load_vessel(name)
    obs = observer(vessel)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = random_state(vessel, rng)
        tau = rng.normal(size=vessel.dof) * 50.0
        A = obs._model(x, tau)[1].copy()
        num = np.zeros_like(A)
        for j in range(len(x)):
            dx = np.zeros_like(x)
            dx[j] = 1e-6 * max(1.0, abs(x[j]))
            num[:, j] = (obs._model(x + dx, tau)[0] - obs._model(x - dx, tau)[0]) / (2 * dx[j])
        np.testing.assert_allclose(A, num, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
def test_model_is_the_plant_model_without_current(name: str) -> None:
    """With b = 0 the filter predicts what the plant's vessel model integrates."""
    vessel = load_vessel(name)
    obs, model = observer(vessel), VesselModel(vessel)
    rng = np.random.default_rng(4)
    d = vessel.dof
    for _ in range(5):
        x = random_state(vessel, rng)
        tau = rng.normal(size=d) * 50.0
        f, _ = obs._model(x, tau)
        eta_dot, nu_dot = model.derivative(x[:d], x[d : 2 * d], tau + x[2 * d :])
        np.testing.assert_allclose(f[:d], eta_dot, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(f[d : 2 * d], nu_dot, rtol=1e-9, atol=1e-12)


# -- closed runs against a simulated truth --------------------------------------------------------


def run(vessel: VesselSpec, obs: ObserverBlock, seconds: float, eta0: np.ndarray, nu0: np.ndarray,
        tau_fn: Callable[[float], np.ndarray], f_ext: np.ndarray | None = None, seed: int = 0,
        h: float = 0.05) -> dict[str, np.ndarray]:
    """Truth: the plant's vessel model (RK4) with an extra body force; sensors as the plant samples.

    Each step: truth t -> t + h with tau held, sensors due at t + h sample (count + 1), then the
    observer steps with those samples and the same tau (seafmu's master order).
    """
    d = vessel.dof
    model = VesselModel(vessel)
    rng = np.random.default_rng(seed)
    names = ObserverBlock.interface(vessel).input_names()
    u = np.zeros(len(names))
    f_ext = np.zeros(d) if f_ext is None else np.asarray(f_ext, float)
    eta, nu = np.array(eta0, float), np.array(nu0, float)
    state_names = vessel.eta_names + vessel.nu_names
    every = [max(1, round(1.0 / (s.rate_hz * h))) for s in vessel.sensors]

    def sample(k: int) -> None:
        truth = np.concatenate([eta, nu])
        for s, n in zip(vessel.sensors, every, strict=True):
            if k % n:
                continue
            for c, std in zip(s.channels, s.noise_std, strict=True):
                val = truth[state_names.index(c)] + std * rng.standard_normal()
                u[names.index(f"meas_{c}")] = wrap_angle(val) if c in ("roll", "pitch", "yaw") else val
            u[names.index(f"{s.name}_count")] += 1.0

    def deriv(eta: np.ndarray, nu: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return model.derivative(eta, nu, tau + f_ext)

    sample(0)  # the plant's initial sample (count = 1)
    out: dict[str, list] = {"t": [], "truth": [], "est": [], "std": [], "pos_std": []}
    for k in range(round(seconds / h)):
        t = k * h
        tau = tau_fn(t)
        # RK4 on (eta, nu) with tau held.
        k1 = deriv(eta, nu, tau)
        k2 = deriv(eta + h / 2 * k1[0], nu + h / 2 * k1[1], tau)
        k3 = deriv(eta + h / 2 * k2[0], nu + h / 2 * k2[1], tau)
        k4 = deriv(eta + h * k3[0], nu + h * k3[1], tau)
        eta = eta + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        nu = nu + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        ai = [i for i, n in enumerate(vessel.eta_names) if n in ("roll", "pitch", "yaw")]
        eta[ai] = wrap_angle(eta[ai])
        sample(k + 1)
        u[-d:] = tau
        y = obs.step(t, h, u)
        out["t"].append(t + h)
        out["truth"].append(np.concatenate([eta, nu, f_ext]))
        out["est"].append(y[: 3 * d])
        out["std"].append(np.sqrt(np.diag(obs.P)))
        out["pos_std"].append(y[3 * d])  # position_std follows the estimates
    res = {k: np.array(v) for k, v in out.items()}
    err = res["est"] - res["truth"]
    err[:, ai] = wrap_angle(err[:, ai])
    res["err"] = err
    return res


def minerva_forces(t: float) -> np.ndarray:
    """Slowly varying thrust in every DOF (the ROV manoeuvres around)."""
    return np.array([150 * math.sin(0.05 * t), 120 * math.cos(0.07 * t), 60 * math.sin(0.04 * t + 1),
                     10 * math.sin(0.1 * t), 10 * math.cos(0.09 * t), 40 * math.sin(0.06 * t)])


def test_minerva_wrong_start_converges_and_is_consistent(minerva: VesselSpec) -> None:
    """The filter knows nothing at start (zeros); truth is 10 m away, turned 2 rad and moving."""
    eta0 = np.array([10.0, -5.0, 3.0, 0.0, 0.0, 2.0])
    nu0 = np.array([0.3, -0.1, 0.05, 0.0, 0.0, 0.02])
    res = run(minerva, observer(minerva), 120.0, eta0, nu0, minerva_forces, seed=1)
    err, std, t = res["err"], res["std"], res["t"]
    after = t > 20.0
    # Converged: position within centimetres, velocity within mm/s.
    assert np.max(np.abs(err[after, :3])) < 0.15
    assert np.max(np.abs(err[after, 6:9])) < 0.03
    assert np.max(np.abs(err[after, 5])) < 0.02  # yaw
    # Consistent: the error stays within 3 sigma of the filter's own covariance most of the time.
    inside = np.abs(err[after, :12]) <= 3.0 * std[after, :12]
    assert inside.mean(axis=0).min() > 0.9, inside.mean(axis=0)
    # position_std is honest: neither over- nor grossly under-confident.
    rms = math.sqrt(np.mean(np.sum(err[after, :2] ** 2, axis=1)))
    mean_std = float(np.mean(res["pos_std"][after]))
    assert 0.5 * mean_std < rms < 2.0 * mean_std
    # Before the first USBL fix nothing is known: position_std said so.
    assert res["pos_std"][0] < 1.0  # initialised from the first sample (USBL at t = 0)


def test_minerva_bias_recovers_constant_external_force(minerva: VesselSpec) -> None:
    f_ext = np.array([80.0, -50.0, 40.0, 0.0, 0.0, 15.0])
    res = run(minerva, observer(minerva), 250.0, np.zeros(6), np.zeros(6), minerva_forces, f_ext, seed=2)
    late = res["t"] > 200.0
    b_hat = res["est"][late, 12:].mean(axis=0)
    tol = np.array([8.0, 8.0, 8.0, 5.0, 5.0, 2.0])
    assert np.all(np.abs(b_hat - f_ext) <= tol), b_hat
    # Without a bias state the same force would show up as velocity/position errors; with it the
    # estimate stays unbiased.
    assert np.max(np.abs(res["err"][late, :3].mean(axis=0))) < 0.05


def test_amv_3dof_tracks_and_finds_current_like_force(amv: VesselSpec) -> None:
    f_ext = np.array([-3.0, 4.0, 0.5])

    def tau(t: float) -> np.ndarray:
        return np.array([25.0 + 10 * math.sin(0.1 * t), 0.0, 1.5 * math.sin(0.2 * t)])

    res = run(amv, observer(amv), 150.0, np.array([5.0, 5.0, -3.0]), np.array([0.5, 0.0, 0.1]),
              tau, f_ext, seed=3)
    after = res["t"] > 20.0
    err, std = res["err"], res["std"]
    assert np.max(np.abs(err[after, :2])) < 0.15
    inside = np.abs(err[after, :6]) <= 3.0 * std[after, :6]
    assert inside.mean(axis=0).min() > 0.9, inside.mean(axis=0)
    late = res["t"] > 100.0
    b_hat = res["est"][late, 6:].mean(axis=0)
    assert np.all(np.abs(b_hat - f_ext) <= [1.0, 1.5, 0.3]), b_hat


# -- sample handling --------------------------------------------------------------------------------


def test_update_only_when_count_changes(minerva: VesselSpec) -> None:
    names = ObserverBlock.interface(minerva).input_names()
    u = np.zeros(len(names))
    for s in minerva.sensors:
        u[names.index(f"{s.name}_count")] = 1.0
    a, b = observer(minerva), observer(minerva)
    a.step(0.0, 0.05, u)
    b.step(0.0, 0.05, u)
    u2 = u.copy()
    u2[names.index("meas_north")] = 5.0  # a held value changed, but no new sample: ignored
    np.testing.assert_array_equal(a.step(0.05, 0.05, u), b.step(0.05, 0.05, u2))
    u2[names.index("usbl_count")] = 2.0  # now it is a new sample
    assert b.step(0.1, 0.05, u2)[0] > 0.5


def test_heading_innovation_is_wrapped(minerva: VesselSpec) -> None:
    names = ObserverBlock.interface(minerva).input_names()
    u = np.zeros(len(names))
    obs = observer(minerva)
    u[names.index("meas_yaw")] = 3.1
    u[names.index("ahrs_count")] = 1.0
    obs.step(0.0, 0.05, u)
    for k in range(1, 40):  # the heading crosses +-pi: 3.1 -> -3.1 is 0.083 rad, not 6.2
        u[names.index("meas_yaw")] = -3.1
        u[names.index("ahrs_count")] += 1.0
        y = obs.step(k * 0.05, 0.05, u)
        assert abs(y[5]) > 3.0  # never swings through zero
    assert y[5] == pytest.approx(-3.1, abs=0.01)


def test_innovation_gate_rejects_outlier(minerva: VesselSpec) -> None:
    names = ObserverBlock.interface(minerva).input_names()

    def feed(obs: ObserverBlock) -> float:
        """North estimate right after one acoustic outlier (30 m) among zero-mean samples."""
        u = np.zeros(len(names))
        for s in minerva.sensors:
            u[names.index(f"{s.name}_count")] = 1.0
        for k in range(81):
            for s in minerva.sensors:
                u[names.index(f"{s.name}_count")] += 1.0
            u[names.index("meas_north")] = 30.0 if k == 80 else 0.0
            y = obs.step(k * 0.05, 0.05, u)
        return float(y[0])

    gated = observer(minerva, innovation_gate=16.0)
    assert abs(feed(gated)) < 0.05 and gated.n_rejected == 1
    default = observer(minerva)  # the default gate: gross errors (a 30 m jump of a 0.1 m USBL is one)
    assert abs(feed(default)) < 0.05 and default.n_rejected == 1
    assert feed(observer(minerva, innovation_gate=0.0)) > 0.2  # no gate: it drags the estimate


def test_errors_name_input_and_parameter(minerva: VesselSpec) -> None:
    obs = observer(minerva)
    u = np.zeros(len(ObserverBlock.interface(minerva).inputs))
    u[-1] = np.nan
    with pytest.raises(ValueError, match="tau_alloc_N"):
        obs.step(0.0, 0.05, u)
    with pytest.raises(ValueError, match="bias_time_constant"):
        observer(minerva, bias_time_constant=0.0)
    with pytest.raises(ValueError, match="q_velocity"):
        obs.set_parameter("q_velocity", -1.0)


def test_interface_and_deepcopy(amv: VesselSpec) -> None:
    iface = ObserverBlock.interface(amv)
    assert iface.input_names() == ["meas_north", "meas_east", "gnss_count", "meas_yaw", "compass_count",
                                   "meas_r", "gyro_count", "meas_u", "meas_v", "speed_count",
                                   "tau_alloc_X", "tau_alloc_Y", "tau_alloc_N"]
    assert iface.output_names() == ["north_hat", "east_hat", "yaw_hat", "u_hat", "v_hat", "r_hat",
                                    "bias_X_hat", "bias_Y_hat", "bias_N_hat", "position_std",
                                    "pos_fixes_rejected", "dead_reckoning",  # appended (issue 5)
                                    "samples_rejected", "wave_north_hat", "wave_east_hat"]
    obs = observer(amv)
    u = np.ones(len(iface.inputs))
    obs.step(0.0, 0.05, u)
    twin = copy.deepcopy(obs)
    u[0] = 2.0
    u[2] = 2.0
    np.testing.assert_array_equal(obs.step(0.05, 0.05, u), twin.step(0.05, 0.05, u))
