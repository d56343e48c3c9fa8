"""The simulators behind output error agree with closed-form physics, and output error recovers
parameters that equation error (regression on differentiated noisy data) gets biased."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ellipk

from seafmu.identification import timeseries as ts
from seafmu.identification.trial import Run, make_trial


def _first(**kw: float) -> tuple[ts.TSModel, dict[str, float]]:
    v = {**ts.DEFAULTS["first"], **kw}
    return ts.TSModel("first", v, [], "force"), v


def test_linear_decay_is_exponential_and_step_settles_at_force_over_damping() -> None:
    m, v = _first(M=50.0, d_L=10.0)
    t = np.linspace(0, 20, 201)
    y = ts.simulate(m, v, t, None, (1.2,))
    np.testing.assert_allclose(y, 1.2 * np.exp(-10 / 50 * t), rtol=1e-6)
    y = ts.simulate(m, v, t, np.full(t.size, 30.0), (0.0,))
    np.testing.assert_allclose(y, 3.0 * (1 - np.exp(-0.2 * t)), atol=1e-6)


def test_quadratic_decay_and_coulomb_stop_match_closed_forms() -> None:
    m, v = _first(M=50.0, d_Q=34.0)
    t = np.linspace(0, 10, 1001)
    np.testing.assert_allclose(ts.simulate(m, v, t, None, (1.0,)), 1.0 / (1.0 + 34.0 / 50.0 * t), rtol=1e-6)
    # Friction alone: constant deceleration f_c/M until the hull stops, then it stays stopped.
    m, v = _first(M=50.0, f_c=10.0)
    y = ts.simulate(m, v, t, None, (1.0,))
    stop = 1.0 / (10.0 / 50.0)
    assert y[t < stop - 0.05] == pytest.approx(1.0 - 0.2 * t[t < stop - 0.05], abs=1e-9)
    assert np.all(y[t > stop + 0.02] == 0.0)


def test_input_chain_delay_lag_deadband_saturation() -> None:
    t = np.arange(0, 10, 0.1)
    u = np.where(t >= 1.0, 2.0, 0.0)
    m = ts.TSModel("first", dict(ts.DEFAULTS["first"]), [], "rpm", "linear")
    v = {**m.values, "k": 1.0}
    tau, interp = ts.generalised_force({**v, "t_d": 0.5}, m, t, u)
    assert not interp
    assert tau[t < 1.45] == pytest.approx(0.0, abs=1e-12) and tau[t > 1.55] == pytest.approx(2.0)
    tau, interp = ts.generalised_force({**v, "T_lag": 0.8}, m, t, u)
    assert interp
    np.testing.assert_allclose(tau[t > 1.05], 2.0 * (1 - np.exp(-(t[t > 1.05] - 1.0) / 0.8)), rtol=1e-9)
    tau, _ = ts.generalised_force({**v, "n_0": 0.5, "u_sat": 1.2}, m, t, u)
    assert tau.max() == pytest.approx(1.2)  # (2 - 0.5) capped at 1.2
    tau, _ = ts.generalised_force({**v, "n_0": 0.5}, m, t, u)
    assert tau.max() == pytest.approx(1.5)
    m2 = ts.TSModel("first", dict(ts.DEFAULTS["first"]), [], "rpm", "quadratic")
    tau, _ = ts.generalised_force({**v, "eta_rev": -0.3}, m2, t, -u)
    assert tau.min() == pytest.approx(-4.0 * 0.7)


def test_second_order_frequency_damping_and_pendulum_period() -> None:
    v = {**ts.DEFAULTS["second"], "M": 5.0, "c": 20.0, "d_L": 1.0}
    m = ts.TSModel("second", v, [])
    t = np.linspace(0, 10, 2001)
    wn, zeta = 2.0, 1.0 / (2 * math.sqrt(100.0))
    wd = wn * math.sqrt(1 - zeta**2)
    exact = 0.1 * np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    np.testing.assert_allclose(ts.simulate(m, v, t, None, (0.1, 0.0)), exact, atol=1e-7)
    # Pendulum law: small swing period 2 pi / sqrt(-alpha); a large swing takes the elliptic-integral
    # time K(sin^2(theta0/2)) / omega to reach the bottom.
    p = ts.TSModel("pendulum", {**ts.DEFAULTS["pendulum"], "alpha": -4.0}, [], restoring="sin")
    t = np.linspace(0, 2 * math.pi / 2.0, 4001)
    small = ts.simulate(p, p.values, t, None, (0.01, 0.0))
    assert small[-1] == pytest.approx(0.01, rel=1e-4)
    large = ts.simulate(p, p.values, t, None, (1.0, 0.0))
    i = int(np.argmax(large < 0))
    t0 = t[i - 1] - large[i - 1] * (t[i] - t[i - 1]) / (large[i] - large[i - 1])
    assert t0 == pytest.approx(ellipk(math.sin(0.5) ** 2) / 2.0, rel=1e-5)


def test_sway_yaw_exact_discretisation_matches_fine_rk4() -> None:
    v = {**ts.DEFAULTS["sway_yaw"], "m22": 91.4, "m66": 25.4, "m26": 5.0, "Y_v": -60.0, "N_r": -20.0,
         "Y_r": 12.0, "N_v": 6.0}
    m = ts.TSModel("sway_yaw", v, [], "force")
    t = np.arange(0, 20, 0.1)
    u = np.column_stack([np.where(t > 2, 20.0, 0.0), np.where(t > 8, -5.0, 0.0)])
    y = ts.simulate(m, v, t, u, (0.1, -0.05))
    M = np.array([[91.4, 5.0], [5.0, 25.4]])
    D = np.array([[60.0, -12.0], [-6.0, 20.0]])
    x, h, out = np.array([0.1, -0.05]), 0.001, [np.array([0.1, -0.05])]
    for i in range(len(t) - 1):
        for _ in range(100):
            f = lambda z, ui=u[i]: np.linalg.solve(M, ui - D @ z)  # noqa: E731
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x)
    np.testing.assert_allclose(y, np.array(out), atol=1e-9)


def _coast_trial(seed: int, noise: float = 0.02) -> object:
    rng = np.random.default_rng(seed)
    m, v = _first(M=50.0, d_L=3.0, d_Q=34.0)
    t = np.arange(0, 20, 0.1)
    runs = [Run(f"r{i}", ts.simulate(m, v, t, None, (v0,), substeps=10) + rng.normal(0, noise, t.size), t)
            for i, v0 in enumerate((1.0, 0.7, 0.85))]
    return make_trial("decay", runs, dof="surge", baseline="linear_quadratic", constants={"mass": 50.0})


def test_output_error_beats_equation_error_on_noisy_coast_downs() -> None:
    """Over several noisy trials the regression start scatters widely, output error does not."""
    ee_err, oe_err = [], []
    for seed in range(6):
        trial = _coast_trial(seed)
        model = ts.baseline_model(trial)
        ee = ts.equation_error(model, ts.split(trial).fit)
        fit = ts.fit_timeseries(trial, model)
        ee_err.append([ee["d_L"] - 3.0, ee["d_Q"] - 34.0])
        oe_err.append([fit.params["d_L"] - 3.0, fit.params["d_Q"] - 34.0])
        lo, hi = fit.ci95["d_Q"]
        assert abs(fit.params["d_Q"] - 34.0) < (hi - lo)  # within two half-widths of its own interval
        assert fit.whiteness["white"] and fit.nrmse_validation < 0.2 and not fit.warnings
    rms_ee = np.sqrt(np.mean(np.square(ee_err), axis=0))
    rms_oe = np.sqrt(np.mean(np.square(oe_err), axis=0))
    assert np.all(rms_oe < rms_ee / 2), (rms_oe, rms_ee)


def test_decay_without_mass_gives_per_unit_inertia_parameters() -> None:
    """A decay cannot separate inertia from damping: without a known mass, d/M is what is fitted."""
    trial = _coast_trial(0)
    trial.constants = {}
    fit = ts.fit_timeseries(trial, ts.baseline_model(trial))
    assert fit.params["d_Q"] == pytest.approx(34.0 / 50.0, rel=0.05)


def test_unphysical_fits_are_flagged() -> None:
    trial = make_trial("decay2", [Run("r", np.zeros(30), np.arange(30.0))], dof="roll")
    m = ts.baseline_model(trial)
    warn = ts.sanity(m, {**m.values, "c": -1.0, "d_L": -0.5}, trial)
    assert any("unstable" in w for w in warn) and any("negative linear damping" in w for w in warn)
    p = ts.TSModel("pendulum", dict(ts.DEFAULTS["pendulum"]), ["alpha", "beta", "gamma"])
    assert any("unstable" in w for w in ts.sanity(p, {**p.values, "alpha": 1.0}, trial))
