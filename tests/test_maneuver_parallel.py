"""The maneuver simulator split over threads, and the noise-only Ljung-Box Q compiled: both must give
what the single-threaded kernel and NumPy give (the diagnosis's answers may not depend on the cores)."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from seafmu.components.kernels import maneuver as maneuver_kernel
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import load_vessel
from seafmu.identification import fitting
from seafmu.identification.maneuver import simulation
from seafmu.identification.maneuver.simulation import _Simulator
from seafmu.identification.maneuver.statistics import _noise_q


def _simulator(name: str, segments: int, length: int) -> tuple[_Simulator, VesselModel]:
    """A simulator over ``segments`` restarted segments of a turning, heaving log with a heading
    history (so a current acts)."""
    vessel = load_vessel(name)
    vm = VesselModel(vessel)
    d = vessel.dof
    n = segments * length + 1
    t = np.arange(n) * 0.05
    rng = np.random.default_rng(1)
    scale = np.diag(vm.M) * 2e-3
    tau = scale * np.sin(0.1 * t[:, None] * (1 + np.arange(d))[None]) + rng.normal(0, 0.1, (n, d)) * scale
    nx = d if d == 3 else d + 2
    x_meas = rng.normal(0, 0.05, (n, nx))
    sim = _Simulator(vessel, t, tau, x_meas, np.arange(0, n - 1, length), length)
    sim.psi = 0.7 * np.arange(segments)[:, None] + np.cumsum(np.full(sim.idx.shape, 0.002), axis=1)
    sim.psi_mid = sim.psi[:, :-1] + 0.001  # each segment on its own heading
    return sim, vm


@pytest.mark.parametrize("name", ["minerva2", "amv_osf"])
@pytest.mark.parametrize("sets", [1, 7])
@pytest.mark.parametrize("current", [False, True])
def test_the_threaded_simulation_equals_one_thread(monkeypatch: pytest.MonkeyPatch, name: str, sets: int,
                                                   current: bool) -> None:
    """Split by parameter set (7) or by segment (1), with and without a current (its heading is per
    segment): bit for bit what one kernel call gives, and it is split (several parts ran)."""
    sim, vm = _simulator(name, segments=9, length=1000)
    rng = np.random.default_rng(2)
    M = np.repeat(vm.M[None], sets, axis=0)
    DL = vm.D_L[None] * rng.uniform(0.5, 1.5, (sets, 1, 1))
    DQ = vm.D_Q[None] * rng.uniform(0.5, 1.5, (sets, 1, 1))
    vc = rng.normal(0, 0.2, (sets, 2)) if current else None

    calls: list[int] = []
    kernel = maneuver_kernel.simulate

    def counted(*args: object) -> None:
        calls.append(1)
        kernel(*args)

    monkeypatch.setattr(simulation.maneuver_kernel, "simulate", counted)
    monkeypatch.setattr(simulation, "core_count", lambda: 2)
    split = sim.run(M, DL, DQ, vc=vc)
    assert len(calls) == 2
    monkeypatch.setattr(simulation, "core_count", lambda: 1)
    whole = sim.run(M, DL, DQ, vc=vc)
    assert len(calls) == 3
    assert np.all(np.isfinite(whole)) and np.ptp(whole) > 0.01
    np.testing.assert_array_equal(split, whole)


def test_a_short_simulation_stays_in_one_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """Below ``MIN_SPLIT_STEPS`` steps per part the hand-over would cost more than it saves."""
    sim, vm = _simulator("minerva2", segments=2, length=50)
    calls: list[int] = []
    kernel = maneuver_kernel.simulate
    monkeypatch.setattr(simulation.maneuver_kernel, "simulate", lambda *a: (calls.append(1), kernel(*a)))
    monkeypatch.setattr(simulation, "core_count", lambda: 2)
    sim.run(vm.M[None], vm.D_L[None], vm.D_Q[None])
    assert len(calls) == 1


def test_the_compiled_noise_only_q_is_ljung_box_of_each_residual() -> None:
    """``_noise_q`` against ``fitting.ljung_box_q`` of the residual made with NumPy; a replicate
    with a non-finite sample gives NaN (it is dropped by the caller)."""
    rng = np.random.default_rng(3)
    B, S, L1, nx, d, k = 5, 4, 60, 8, 6, 20
    x = rng.normal(size=(S, L1, nx))
    xs = x[None] + np.cumsum(rng.normal(0, 0.01, (B, S, L1, nx)), axis=2)  # coloured, as restarts give
    mask = np.ones((S, L1), dtype=bool)
    mask[:, 0] = False
    mask[-1, 50:] = False
    n = int(mask.sum())
    eps = rng.normal(size=(B, n, d))
    sigma, scale = rng.uniform(0.01, 0.03, d), rng.uniform(0.1, 1.0, d)
    xs[3, 2, 10, 4] = np.nan
    q = _noise_q(xs, x, mask, eps, sigma, scale, k)
    r = (xs[:, mask][..., -d:] - x[mask][..., -d:] - eps * sigma) / scale  # (B, n, d)
    for b in range(B):
        if b == 3:
            assert np.all(np.isnan(q[b]))
            continue
        np.testing.assert_allclose(q[b], fitting.ljung_box_q(r[b], k)[0], rtol=1e-10)
    assert np.all(q[[0, 1, 2, 4]] > 0)


def test_a_process_forked_after_a_split_simulation_simulates_too() -> None:
    """The thread pool's threads are not in a forked child: the child makes its own pool (a pool
    inherited as it was would queue the parts for threads that do not exist, and wait forever)."""
    sim, vm = _simulator("minerva2", segments=9, length=1000)
    mats = [np.repeat(a[None], 7, axis=0) for a in (vm.M, vm.D_L, vm.D_Q)]
    before = sim.run(*mats)
    pid = os.fork()
    if pid == 0:  # the child: exit 0 when it simulates the same
        os._exit(0 if np.array_equal(sim.run(*mats), before) else 3)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            assert os.waitstatus_to_exitcode(status) == 0
            return
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    pytest.fail("the forked child did not finish its simulation in 60 s")
