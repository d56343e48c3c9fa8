"""Sensor faults and what the observer does about them: chi-square gating of position fixes at the
stated false-alarm rate, dead reckoning through a dropout, the magnetometer calibration fault, the
plant's outlier/dropout injection, and the observer's wave filter."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from seafmu.components.block import full_params
from seafmu.components.kinematics import rzyx, wrap_angle
from seafmu.components.observer import ObserverBlock, chi2_quantile
from seafmu.components.plant import PlantBlock
from seafmu.components.sensors import mag_heading_error
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel

DEPTH = 5.0


def observer(vessel: VesselSpec, **params: object) -> ObserverBlock:
    return ObserverBlock(vessel, full_params(ObserverBlock.interface(vessel), params))


def plant(vessel: VesselSpec, **params: object) -> PlantBlock:
    return PlantBlock(vessel, full_params(PlantBlock.interface(vessel), params))


FixHook = Callable[[int, float, np.ndarray], np.ndarray | None]


def feed(vessel: VesselSpec, obs: ObserverBlock, seconds: float, h: float, rng: np.random.Generator,
         fix: FixHook | None = None,
         truth: Callable[[float], tuple[np.ndarray, np.ndarray]] | None = None) -> dict[str, np.ndarray]:
    """Drive ``obs`` with sampled noisy sensors of ``truth(t)`` (default: at rest at DEPTH).

    ``fix(k, t, z)`` may replace the k-th position fix (outlier) or return None (no fix: dropout).
    tau_alloc holds the restoring force, so the rest state is an equilibrium of the filter's model.
    Records the outputs per step and, per position fix, whether the gate rejected it.
    """
    names = ObserverBlock.interface(vessel).input_names()
    states = vessel.eta_names + vessel.nu_names
    d = vessel.dof
    eta_rest = np.zeros(d)
    eta_rest[2] = DEPTH
    truth = truth or (lambda t: (eta_rest, np.zeros(d)))
    u = np.zeros(len(names))
    u[-d:] = VesselModel(vessel).restoring(eta_rest)
    n_fix = 0
    out: dict[str, list] = {"t": [], "y": [], "fix_t": [], "fix_rejected": []}

    def sample(t_prev: float, t: float) -> bool:
        nonlocal n_fix
        eta, nu = truth(t)
        x = np.concatenate([eta, nu])
        new_fix = False
        for s in vessel.sensors:
            if t_prev >= 0 and math.floor(t * s.rate_hz + 1e-9) == math.floor(t_prev * s.rate_hz + 1e-9):
                continue
            noise = np.asarray(s.noise_std) * rng.standard_normal(len(s.channels))
            z = np.array([x[states.index(c)] for c in s.channels]) + noise
            if "north" in s.channels:
                if fix is not None:
                    z = fix(n_fix, t, z)
                n_fix += 1
                if z is None:
                    continue
                new_fix = True
            for c, v in zip(s.channels, z, strict=True):
                u[names.index(f"meas_{c}")] = wrap_angle(v) if c in ("roll", "pitch", "yaw") else v
            u[names.index(f"{s.name}_count")] += 1.0
        return new_fix

    sample(-1.0, 0.0)
    obs.start(u.copy())
    for k in range(round(seconds / h)):
        t = k * h
        got_fix = sample(t, t + h)
        before = obs.pos_rejected + obs.pos_resets
        y = obs.step(t, h, u.copy())
        if got_fix:
            out["fix_t"].append(t + h)
            out["fix_rejected"].append(obs.pos_rejected + obs.pos_resets > before)
        out["t"].append(t + h)
        out["y"].append(y)
    return {k: np.array(v) for k, v in out.items()}


def col(vessel: VesselSpec, name: str) -> int:
    return ObserverBlock.interface(vessel).output_names().index(name)


# -- chi-square gate --------------------------------------------------------------------------------
@pytest.mark.parametrize("p", [0.95, 0.99])
def test_gate_rejects_outliers_and_accepts_normal_fixes_at_stated_rate(minerva: VesselSpec, p: float) -> None:
    """Every 10th fix is 5 m off (random direction): all rejected. Of the normal fixes a fraction
    1 - p is rejected (a consistent filter's NIS is chi2_2): binomial, within 3 sigma."""
    rng = np.random.default_rng(11)
    outlier = np.zeros(0, dtype=bool)

    def fix(k: int, t: float, z: np.ndarray) -> np.ndarray:
        nonlocal outlier
        is_out = k >= 30 and k % 10 == 5
        outlier = np.append(outlier, is_out)
        if is_out:
            a = rng.uniform(0, 2 * math.pi)
            return z + 5.0 * np.array([math.cos(a), math.sin(a)])
        return z

    obs = observer(minerva, gate_probability=p)
    res = feed(minerva, obs, 1300.0, 0.1, np.random.default_rng(5), fix)
    rejected = res["fix_rejected"]
    outlier = outlier[1:]  # the fix at t = 0 initialises the filter (no gate)
    assert outlier.sum() > 100 and np.all(rejected[outlier])
    settled = ~outlier & (res["fix_t"] > 30.0)
    n = int(settled.sum())
    false_alarms = int(rejected[settled].sum())
    expected, sd = n * (1 - p), math.sqrt(n * p * (1 - p))
    assert abs(false_alarms - expected) <= 3 * sd, (false_alarms, expected, sd)
    assert res["y"][-1, col(minerva, "pos_fixes_rejected")] == obs.pos_rejected == rejected.sum()
    err = res["y"][res["t"] > 30.0][:, :2] - np.array([0.0, 0.0])
    assert np.max(np.abs(err)) < 0.15  # outliers never got in


def test_gate_threshold_is_the_chi_square_quantile() -> None:
    assert chi2_quantile(0.999, 2) == pytest.approx(-2 * math.log(0.001), rel=1e-9)  # 13.8155
    assert chi2_quantile(0.95, 1) == pytest.approx(1.959964**2, rel=1e-5)


def test_consecutive_rejections_reset_the_position(minerva: VesselSpec) -> None:
    """If the fixes disagree with the estimate for good (a filter that drifted, a moved transponder),
    the gate must not lock the filter out: after gate_max_rejections the position is reset."""

    def jump(k: int, t: float, z: np.ndarray) -> np.ndarray:
        return z + (np.array([3.0, 0.0]) if t > 60.0 else 0.0)

    for max_rej, locked in ((5, False), (0, True)):
        obs = observer(minerva, gate_probability=0.999, gate_max_rejections=max_rej)
        res = feed(minerva, obs, 90.0, 0.1, np.random.default_rng(2), jump)
        north = res["y"][-1, 0]
        if locked:
            assert abs(north) < 0.3 and obs.pos_rejected >= 25
        else:
            assert north == pytest.approx(3.0, abs=0.3) and obs.pos_resets == 1 and obs.pos_rejected == 5


# -- dead reckoning ---------------------------------------------------------------------------------
def test_dead_reckoning_flag_and_covariance_growth(minerva: VesselSpec) -> None:
    def dropout(k: int, t: float, z: np.ndarray) -> np.ndarray | None:
        return None if 60.0 < t <= 120.0 else z

    obs = observer(minerva, dr_timeout=3.0)
    res = feed(minerva, obs, 150.0, 0.05, np.random.default_rng(3), dropout)
    t, y = res["t"], res["y"]
    dr, std = y[:, col(minerva, "dead_reckoning")], y[:, col(minerva, "position_std")]
    assert np.all(dr[(t > 5.0) & (t <= 60.0)] == 0.0)
    assert np.all(dr[(t > 63.05) & (t < 120.0)] == 1.0)  # last fix at 60 s, timeout 3 s
    assert np.all(dr[(t > 60.0) & (t < 62.95)] == 0.0)
    assert np.all(dr[t > 121.0] == 0.0)  # the first fix after the dropout clears it
    during = std[(t > 60.0) & (t < 120.0)]
    every_10s = std[np.isin(np.round(t, 6), [70.0, 80.0, 90.0, 100.0, 110.0, 119.95])]
    assert np.all(np.diff(every_10s) > 0)  # grows without fixes (a DVL update may trim it a little)
    normal = std[(t > 50.0) & (t <= 60.0)].max()
    assert during[-1] > 1.5 * normal
    assert std[-1] < 1.2 * normal  # and comes back
    err = np.abs(y[(t > 60.0) & (t < 120.0)][:, 0])
    assert err.max() < 3.0 * during.max()  # the grown std still covers the error


# -- magnetometer calibration fault -----------------------------------------------------------------
def test_magnetometer_fault_model() -> None:
    a = 0.2
    assert mag_heading_error(0.0, a) == 0.0
    assert abs(mag_heading_error(math.pi, a)) < 1e-15
    assert mag_heading_error(math.pi / 2, a) == pytest.approx(a)
    assert mag_heading_error(-math.pi / 2, a) == pytest.approx(-a)
    psi = np.linspace(-math.pi, math.pi, 361)
    err = np.array([mag_heading_error(p, a) for p in psi])
    assert sorted(np.degrees(psi[np.argsort(np.abs(err))[-2:]]).round()) == [-90.0, 90.0]


@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
def test_plant_heading_sensor_carries_the_fault(name: str) -> None:
    vessel = load_vessel(name)
    names = PlantBlock.interface(vessel).output_names()
    d = vessel.dof
    u = np.zeros(vessel.thrusters.count)
    for deg in (0.0, 45.0, 90.0, 180.0, -90.0):
        psi = math.radians(deg)
        p = plant(vessel, noise_scale=0.0, mag_fault_amplitude=0.15, **{"yaw_0": psi})
        y = p.output()
        assert y[names.index("meas_yaw")] - y[d - 1] == pytest.approx(0.15 * math.sin(psi), abs=1e-12)
        assert y[names.index("mag_heading_error")] == pytest.approx(0.15 * math.sin(psi), abs=1e-12)
    p = plant(vessel, noise_scale=0.0, yaw_0=math.pi / 2)
    assert p.output()[names.index("meas_yaw")] == pytest.approx(math.pi / 2)
    p.set_parameter("mag_fault_amplitude", 0.1)  # an event switches it on: next heading sample
    y = [p.step(k * 0.05, 0.05, u) for k in range(4)][-1]
    assert y[names.index("meas_yaw")] - y[d - 1] == pytest.approx(0.1 * math.sin(y[d - 1]), abs=1e-9)


# -- the plant's position-fix faults ------------------------------------------------------------------
def test_plant_outliers_are_injected_counted_and_leave_other_noise_alone(minerva: VesselSpec) -> None:
    names = PlantBlock.interface(minerva).output_names()
    u = np.zeros(7)
    clean = plant(minerva, seed=4)
    faulty = plant(minerva, seed=4, usbl_outlier_rate=0.3, usbl_outlier_size=4.0)
    yc = np.array([clean.step(k * 0.1, 0.1, u) for k in range(3000)])
    yf = np.array([faulty.step(k * 0.1, 0.1, u) for k in range(3000)])
    meas = [names.index("meas_north"), names.index("meas_east")]
    others = [i for i, n in enumerate(names) if n.startswith("meas_") and i not in meas]
    np.testing.assert_array_equal(yc[:, others], yf[:, others])  # own stream: nothing else changes
    fixes = np.r_[True, np.diff(yf[:, names.index("usbl_count")]) > 0]
    jump = np.hypot(*(yf[fixes][:, meas] - yc[fixes][:, meas]).T)
    is_out = jump > 1e-9
    np.testing.assert_allclose(jump[is_out], 4.0, rtol=1e-9)  # exactly the size, random direction
    assert yf[-1, names.index("pos_fix_outliers")] == is_out.sum()
    assert is_out.mean() == pytest.approx(0.3, abs=0.05)


def test_plant_dropout_stops_the_fixes_and_holds_the_value(minerva: VesselSpec) -> None:
    names = PlantBlock.interface(minerva).output_names()
    p = plant(minerva, seed=1, usbl_dropout_start=10.0, usbl_dropout_length=5.0)
    y = np.array([p.step(k * 0.05, 0.05, np.zeros(7)) for k in range(400)])
    t = 0.05 * np.arange(1, 401)
    count, flag = y[:, names.index("usbl_count")], y[:, names.index("pos_fix_dropout")]
    assert count[np.isclose(t, 9.95)] == 10.0 and count[np.isclose(t, 14.95)] == 10.0
    assert count[np.isclose(t, 15.0)] == 11.0 and count[-1] == 16.0  # fixes at 15..20 s again
    held = (t >= 10.0) & (t < 15.0)
    assert np.all(y[held, names.index("meas_north")] == y[np.isclose(t, 9.95), names.index("meas_north")])
    assert np.all(flag[held] == 1.0) and np.all(flag[t < 10.0] == 0.0) and np.all(flag[t >= 15.0] == 0.0)
    assert y[-1, names.index("depth_count")] == 201.0  # the other sensors go on


def test_fault_parameters_validate(minerva: VesselSpec) -> None:
    with pytest.raises(ValueError, match="usbl_outlier_rate"):
        plant(minerva, usbl_outlier_rate=1.5)
    p = plant(minerva)
    with pytest.raises(ValueError, match="usbl_dropout_length"):
        p.set_parameter("usbl_dropout_length", -1.0)
    with pytest.raises(ValueError, match="gate_probability"):
        observer(minerva, gate_probability=1.0)


# -- wave filter ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
def test_wave_filter_velocity_jacobian(name: str) -> None:
    vessel = load_vessel(name)
    obs = observer(vessel, wave_filter=1)
    rng = np.random.default_rng(1)
    d, nw = vessel.dof, obs.nw
    for _ in range(5):
        x = rng.normal(size=obs.n) * 0.3
        zeta = rng.normal(size=nw) * 0.2
        v, dv, Rt = obs._body_wave_velocity(x, zeta)
        if d == 6:
            np.testing.assert_allclose(v, rzyx(*x[3:6]).T @ zeta, atol=1e-12)
        for j in range(nw):  # d/d zeta
            dz = np.zeros(nw)
            dz[j] = 1e-6
            num = (obs._body_wave_velocity(x, zeta + dz)[0] - obs._body_wave_velocity(x, zeta - dz)[0]) / 2e-6
            np.testing.assert_allclose(Rt[:, j], num, atol=1e-8)
        for idx, column in dv:
            xp, xm = x.copy(), x.copy()
            xp[idx] += 1e-6
            xm[idx] -= 1e-6
            num = (obs._body_wave_velocity(xp, zeta)[0] - obs._body_wave_velocity(xm, zeta)[0]) / 2e-6
            np.testing.assert_allclose(column, num, atol=1e-8)


def test_wave_filter_separates_wave_motion_from_the_low_frequency_estimate(minerva: VesselSpec) -> None:
    """Truth: at rest plus a 0.1 m wave oscillation north at 1.2 rad/s. With the filter the estimate
    the controller gets stays still and wave_north_hat carries the oscillation; without it the
    estimate oscillates with the waves."""
    w, a = 1.2, 0.1

    def truth(t: float) -> tuple[np.ndarray, np.ndarray]:
        eta = np.array([a * math.sin(w * t), 0.0, DEPTH, 0.0, 0.0, 0.0])
        nu = np.array([a * w * math.cos(w * t), 0.0, 0.0, 0.0, 0.0, 0.0])
        return eta, nu

    t0 = 60.0
    res_on = feed(minerva, observer(minerva, wave_filter=1, wave_filter_omega=w), 180.0, 0.1,
                  np.random.default_rng(7), truth=truth)
    res_off = feed(minerva, observer(minerva), 180.0, 0.1, np.random.default_rng(7), truth=truth)
    late = res_on["t"] > t0
    wave_true = a * np.sin(w * res_on["t"][late])
    rms = a / math.sqrt(2)
    lf_on = res_on["y"][late, 0]
    wave_hat = res_on["y"][late, col(minerva, "wave_north_hat")]
    lf_off = res_off["y"][late, 0]
    # what is left in the low-frequency estimate is about the USBL-limited estimation noise (3 cm)
    assert np.sqrt(np.mean(lf_on**2)) < 0.45 * rms
    assert np.sqrt(np.mean((wave_hat - wave_true) ** 2)) < 0.3 * rms
    assert np.sqrt(np.mean(lf_off**2)) > 0.8 * rms  # without: the waves go to the controller
    assert np.all(res_off["y"][:, col(minerva, "wave_north_hat")] == 0.0)


def _depth_stream(vessel: VesselSpec, obs: ObserverBlock, depth: Callable[[int], float],
                  steps: int, h: float = 0.1) -> np.ndarray:
    """Outputs per step of ``obs`` fed a hull at rest at DEPTH, every sensor sampling every step
    (noise-free) except the depth sensor, which reads ``depth(k)`` at step k."""
    names = ObserverBlock.interface(vessel).input_names()
    d = vessel.dof
    eta = np.zeros(d)
    eta[2] = DEPTH
    u = np.zeros(len(names))
    u[-d:] = VesselModel(vessel).restoring(eta)
    values = dict(zip(vessel.eta_names + vessel.nu_names, [*eta, *np.zeros(d)], strict=True))
    ys = []
    for k in range(steps):
        for s in vessel.sensors:
            for c in s.channels:
                u[names.index(f"meas_{c}")] = depth(k) if c == "down" else values[c]
            u[names.index(f"{s.name}_count")] = k + 1.0
        ys.append(obs.step(k * h, h, u).copy())
    return np.array(ys)


def test_a_gross_error_of_any_sensor_is_rejected_by_default(minerva: VesselSpec) -> None:
    """A depth of 500 m (a corrupt sentence with a good checksum) once, at 5 m: the default gate
    rejects it, the estimate does not move, samples_rejected counts it; without the gate the same
    sample throws the depth estimate and its rate far off (what diverged the filter over the wire)."""
    col = ObserverBlock.interface(minerva).output_names()
    spike = lambda k: 500.0 if k == 100 else DEPTH  # noqa: E731
    y = _depth_stream(minerva, observer(minerva), spike, 150)
    assert np.all(np.isfinite(y))
    assert np.max(np.abs(y[:, col.index("down_hat")] - DEPTH)) < 1e-6
    assert y[-1, col.index("samples_rejected")] == 1.0 and y[99, col.index("samples_rejected")] == 0.0
    assert y[-1, col.index("pos_fixes_rejected")] == 0.0  # not a position fix
    free = _depth_stream(minerva, observer(minerva, innovation_gate=0.0), spike, 102)
    assert abs(free[100, col.index("down_hat")] - DEPTH) > 10.0


@pytest.mark.parametrize("max_rej", [5, 0])
def test_a_sensor_that_disagrees_for_good_is_taken_after_max_rejections(minerva: VesselSpec,
                                                                       max_rej: int) -> None:
    """A depth sensor re-zeroed by 3 m (far beyond the gate: 300 sigma of 0.01 m) must not be locked
    out for good: after gate_max_rejections consecutive rejections its next sample resets the depth
    (0: never, the filter keeps its own depth). A gross error now and then, between good samples,
    never builds up to a reset."""
    col = ObserverBlock.interface(minerva).output_names()
    obs = observer(minerva, gate_max_rejections=max_rej)
    y = _depth_stream(minerva, obs, lambda k: DEPTH + (3.0 if k >= 100 else 0.0), 160)
    down = y[:, col.index("down_hat")]
    if max_rej:
        assert obs.resets == 1 and obs.n_rejected == max_rej
        assert np.max(np.abs(down[100 : 100 + max_rej] - DEPTH)) < 1e-6  # the rejected ones
        assert down[-1] == pytest.approx(DEPTH + 3.0, abs=0.01)
    else:
        assert obs.resets == 0 and obs.n_rejected == 60 and abs(down[-1] - DEPTH) < 0.01
    sparse = observer(minerva, gate_max_rejections=max_rej)
    _depth_stream(minerva, sparse, lambda k: 500.0 if k % 3 == 0 and k > 0 else DEPTH, 160)
    assert sparse.resets == 0 and sparse.n_rejected == 53
