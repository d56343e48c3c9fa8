"""Waves and current variation: spectrum, realisation, seeding, depth attenuation, wave loads in the plant."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from seafmu.components.block import full_params
from seafmu.components.environment import GaussMarkovCurrent
from seafmu.components.plant import WAVE_STREAM, PlantBlock
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.components.waves import WaveField, WaveLoad, jonswap


def plant(vessel: VesselSpec, **params: object) -> PlantBlock:
    return PlantBlock(vessel, full_params(PlantBlock.interface(vessel), params))


def field(hs: float = 0.5, tp: float = 5.0, seed: int = 1, n: int = 40, direction: float = 0.0) -> WaveField:
    return WaveField(hs, tp, direction, 3.3, n, np.random.default_rng(seed))


# -- spectrum and realisation ---------------------------------------------------------------------
@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.3, 5.0, 7.0])
@pytest.mark.parametrize("hs, tp", [(0.5, 5.0), (3.0, 10.0)])
def test_spectrum_integrates_to_hs_squared_over_16(hs: float, tp: float, gamma: float) -> None:
    wp = 2 * math.pi / tp
    m0 = quad(lambda w: float(jonswap(w, hs, tp, gamma)[0]), 1e-3, 40 * wp, points=[wp], limit=400)[0]
    assert m0 == pytest.approx(hs**2 / 16, rel=0.025)  # the DNV normalisation is good to 2 % in [1, 7]
    assert jonswap(wp, hs, tp, gamma)[0] == pytest.approx(jonswap(wp, hs, tp, 1.0)[0] * gamma
                                                          * (1 - 0.287 * math.log(gamma)), rel=1e-12)


def test_components_carry_the_variance_and_the_sea_has_the_right_height() -> None:
    f = field(hs=0.5, n=60)
    assert f.variance == pytest.approx(0.5**2 / 16, rel=0.03)
    t = np.arange(0.0, 3600.0, 0.25)
    elev = np.array([f.elevation(tk) for tk in t])
    assert 4 * elev.std() == pytest.approx(0.5, rel=0.08)  # H_s = 4 sqrt(m0) over an hour
    assert abs(elev.mean()) < 0.01


def test_seeded_reproducibility() -> None:
    a, b, c = field(seed=7), field(seed=7), field(seed=8)
    np.testing.assert_array_equal(a.omega, b.omega)
    np.testing.assert_array_equal(a.phase, b.phase)
    assert not np.array_equal(a.phase, c.phase)
    assert a.elevation(12.3, 1.0, 2.0) == b.elevation(12.3, 1.0, 2.0) != c.elevation(12.3, 1.0, 2.0)


def test_plant_with_waves_is_reproducible_and_seeded(minerva: VesselSpec) -> None:
    u = np.full(7, 2.0)
    runs = []
    for seed in (3, 3, 4):
        p = plant(minerva, seed=seed, wave_hs=0.5, down_0=3.0, noise_scale=0.0)
        runs.append(np.array([p.step(k * 0.05, 0.05, u) for k in range(100)]))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.max(np.abs(runs[0][:, :12] - runs[2][:, :12])) > 1e-3  # another sea, another motion


def test_wave_force_is_zero_without_waves_and_the_plant_unchanged(minerva: VesselSpec) -> None:
    f = field(hs=0.0)
    load = WaveLoad(minerva, f)
    assert load.force(3.0, np.zeros(6)) == [0.0] * 6
    assert f.elevation(3.0) == 0.0 and f.acceleration(3.0, 0, 0, 5.0) == (0.0, 0.0, 0.0)
    u = np.full(7, 1.0)
    a = plant(minerva, seed=2)
    b = plant(minerva, seed=2, wave_hs=0.0, wave_tp=9.0, wave_components=7)
    ya = np.array([a.step(k * 0.05, 0.05, u) for k in range(50)])
    yb = np.array([b.step(k * 0.05, 0.05, u) for k in range(50)])
    np.testing.assert_array_equal(ya, yb)
    names = PlantBlock.interface(minerva).output_names()
    cols = [names.index(n) for n in names if n.startswith("tau_wave_") or n == "wave_elevation"]
    assert np.all(ya[:, cols] == 0.0)


def test_deeper_feels_less(minerva: VesselSpec) -> None:
    f = field(hs=0.5)
    load = WaveLoad(minerva, f)
    t = np.arange(0.0, 600.0, 0.5)
    rms = []
    for depth in (0.0, 2.0, 5.0, 10.0, 20.0):
        eta = np.array([0.0, 0.0, depth, 0.0, 0.0, 0.0])
        tau = np.array([load.force(tk, eta) for tk in t])
        rms.append(np.sqrt(np.mean(tau[:, :3] ** 2, axis=0)))
    rms = np.array(rms)
    assert np.all(np.diff(rms[:, 0]) < 0) and np.all(np.diff(rms[:, 2]) < 0)
    kp = (2 * math.pi / 5.0) ** 2 / 9.81
    # e^(-k z) at the peak: 0.45 from 5 to 10 m; the shorter components fade faster, so a bit less
    assert 0.25 < rms[3, 0] / rms[2, 0] < math.exp(-kp * 5.0) + 0.05
    assert rms[4, 0] < 0.1 * rms[0, 0]  # 20 m: a few per cent of the surface load


def test_neutrally_buoyant_body_accelerates_with_the_water(minerva: VesselSpec) -> None:
    """Taylor's long-wave result: with m = displaced mass the force gives the body the water's
    acceleration, (m_d + A) a / (m + A) = a. Within 1 %: Minerva 2 is 30 N buoyant, and the
    Froude-Krylov force acts at the centre of buoyancy, 5 cm above CG, so the body also pitches and
    rolls a little (a pendulum in an accelerating fluid), which the added-mass coupling feeds back."""
    f = field(hs=0.5, direction=0.7)
    load = WaveLoad(minerva, f)
    M = VesselModel(minerva).M
    for t in (1.0, 7.3, 20.0):
        eta = np.array([1.0, -2.0, 5.0, 0.0, 0.0, 0.3])
        tau = np.array(load.force(t, eta))
        acc_body = np.linalg.solve(M, tau)[:3]  # what the wave force alone does (body at rest)
        an, ae, ad = f.acceleration(t, 1.0, -2.0, 5.0)
        c, s_ = math.cos(0.3), math.sin(0.3)
        water_body = np.array([c * an + s_ * ae, -s_ * an + c * ae, ad])
        np.testing.assert_allclose(acc_body, water_body, rtol=0.0, atol=1e-2 * np.max(np.abs(water_body)))


def test_floating_body_moves_with_the_water() -> None:
    """One regular wave along the AMV's heading: the surge velocity is the particle's, 2 omega a peak to
    peak (surface, 3 DOF); the model's quadratic damping takes a few per cent. (The position also
    creeps forward by a second-order drift, so the velocity is compared.)"""
    amv = load_vessel("amv_osf")
    f = field(hs=0.5)
    f.omega, f.k = np.array([1.2]), np.array([1.2**2 / 9.81])
    f.phase = np.array([math.pi / 2])  # water at rest at t = 0, like the body
    f._unit_amp = np.array([0.05])
    f.set_hs(1.0)  # a = 0.05 m
    load, model = WaveLoad(amv, f), VesselModel(amv)
    x = model.initial_state(np.zeros(3), np.zeros(3))
    dt, surge = 0.02, []
    for k in range(int(30.0 / dt)):
        x = model.rk4(x, [0.0, 0.0], dt, 1, tau_ext=load.force((k + 0.5) * dt, x[:3]))
        surge.append(x[3])
    assert (max(surge) - min(surge)) == pytest.approx(2 * 1.2 * 0.05, rel=0.06)
    assert abs(np.mean(x[0])) < 0.1  # and it stays around where it was
    assert abs(x[1]) < 1e-9 and abs(x[2]) < 1e-9  # a wave along the heading: no sway, no yaw


# -- the plant's sub-step evaluation ---------------------------------------------------------------
def test_plant_wave_outputs_match_the_load_model(minerva: VesselSpec) -> None:
    p = plant(minerva, seed=5, wave_hs=1.0, wave_direction=0.4, down_0=4.0)
    for k in range(40):
        y = p.step(k * 0.1, 0.1, np.zeros(7))
    names = PlantBlock.interface(minerva).output_names()
    tau = p.waves.force(4.0, p.state[:6])
    np.testing.assert_allclose(y[names.index("tau_wave_X") : names.index("tau_wave_N") + 1], tau, rtol=1e-12)
    assert y[names.index("wave_elevation")] == p.waves.field.elevation(4.0, *p.state[:2])
    ref = WaveField(1.0, 5.0, 0.4, 3.3, 40, np.random.default_rng(np.random.SeedSequence([5, WAVE_STREAM])))
    np.testing.assert_array_equal(ref.phase, p.waves.field.phase)  # the plant's sea is the seed's sea


def test_wave_hs_is_tunable(minerva: VesselSpec) -> None:
    p = plant(minerva, seed=1)
    p.step(0.0, 0.05, np.zeros(7))
    p.set_parameter("wave_hs", 0.8)
    assert p.waves.field.hs == 0.8 and p.waves.field.variance == pytest.approx(0.8**2 / 16, rel=0.05)
    with pytest.raises(ValueError, match="wave_hs"):
        p.set_parameter("wave_hs", -1.0)
    with pytest.raises(ValueError, match="wave_gamma"):
        plant(minerva, wave_gamma=9.0)
    with pytest.raises(ValueError, match="wave_components"):
        plant(minerva, wave_components=0)


# -- current variation ---------------------------------------------------------------------------
def test_gauss_markov_current_statistics_and_seed() -> None:
    def series(seed: int, sigma: float = 0.05, T: float = 20.0) -> np.ndarray:
        c = GaussMarkovCurrent(0.1, 0.0, variation=sigma, time_constant=T, rng=np.random.default_rng(seed))
        out = []
        for _ in range(40000):
            c.step(0.5)
            out.append(c.ned())
        return np.array(out)

    a = series(1)
    np.testing.assert_array_equal(a, series(1))
    assert not np.array_equal(a, series(2))
    assert a[:, 0].mean() == pytest.approx(0.1, abs=0.01)  # around the mean current
    assert a.std(axis=0) == pytest.approx([0.05, 0.05], rel=0.1)
    dev = a[:, 0] - a[:, 0].mean()
    lag = int(20.0 / 0.5)  # one time constant: correlation e^-1
    rho = np.mean(dev[:-lag] * dev[lag:]) / dev.var()
    assert rho == pytest.approx(math.exp(-1), abs=0.1)
    const = GaussMarkovCurrent(0.1, 0.3, variation=0.0, rng=np.random.default_rng(0))
    const.step(10.0)
    assert const.ned() == pytest.approx((0.1 * math.cos(0.3), 0.1 * math.sin(0.3)))


def test_plant_current_variation_moves_the_water(minerva: VesselSpec) -> None:
    p = plant(minerva, seed=1, current_speed=0.1, current_variation=0.05, current_time_constant=10.0)
    names = PlantBlock.interface(minerva).output_names()
    i = names.index("current_north")
    vals = [p.step(k * 0.5, 0.5, np.zeros(7))[i] for k in range(200)]
    assert np.std(vals) > 0.01
    q = plant(minerva, seed=1, current_speed=0.1)
    assert q.step(0.0, 0.5, np.zeros(7))[i] == pytest.approx(0.1)
