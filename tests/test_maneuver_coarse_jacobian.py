"""The output-error Jacobian's coarse grid: the same simulation at a quarter of the samples, and
sensitivities interpolated between them, agree with the fine grid's (the fit's minimum is the fine
grid's; only the search direction comes from the coarse one)."""

from __future__ import annotations

import numpy as np

from seafmu.components.vessel_spec import load_vessel
from seafmu.identification.maneuver import _prepare, _sim_setup, plant_matrices, simulate_maneuver
from seafmu.identification.maneuver.estimation import _coarse_sim, _coarse_sims, _interp_rows, _segments


def test_interpolation_is_linear_between_coarse_samples() -> None:
    rng = np.random.default_rng(0)
    Rc = rng.normal(size=(2, 3, 6, 2))
    for c in (2, 4):
        R = _interp_rows(Rc, c)
        assert R.shape == (2, 3, 5 * c + 1, 2)
        np.testing.assert_allclose(R[:, :, ::c], Rc)  # the coarse samples themselves
        np.testing.assert_allclose(R[:, :, 1 : c * 5 : c], Rc[:, :, :-1] + (Rc[:, :, 1:] - Rc[:, :, :-1]) / c)


def test_coarse_simulation_and_sensitivity_match_the_fine_grid() -> None:
    spec = load_vessel("minerva2")
    data, _ = simulate_maneuver(spec, duration=60.0, dt=0.05, seed=3)
    prep = _prepare(data, "savgol", None, 4)
    setup = _sim_setup(spec, prep, 0, data.n, 30.0, 0.05)
    assert setup is not None
    co, c = _coarse_sim(setup)  # type: ignore[misc]
    assert c > 1 and co.h == setup.sim.h * c
    pl = plant_matrices(spec)
    M, DL, DQ = (np.repeat(pl[k][None], 2, axis=0) for k in ("M", "D_L", "D_Q"))
    DQ[1, 0, 0] *= 1.1  # a damping sensitivity, by a finite difference as the fit takes it
    fine, coarse = setup.sim.run(M, DL, DQ), co.run(M, DL, DQ)
    spread = np.std(fine[0], axis=(0, 1))
    assert np.max(np.abs(coarse - fine[:, :, ::c]) / spread) < 1e-2  # measured: 0.3 %
    sens_f = fine[1] - fine[0]
    sens_c = _interp_rows((coarse[1] - coarse[0])[None], c)[0]
    m = setup.mask  # the compared samples
    assert np.max(np.abs(sens_f[m])) > 1e-3 * np.max(spread)  # the change is felt at all
    err = np.max(np.abs(sens_c - sens_f)[m]) / np.max(np.abs(sens_f[m]))
    assert err < 0.02, err


def test_a_subset_of_segments_simulates_as_in_the_whole() -> None:
    """A segment misleading on the coarse grid is redone alone on a finer one (``_segments``): its
    simulation there equals its rows of the whole log's simulation."""
    spec = load_vessel("minerva2")
    data, _ = simulate_maneuver(spec, duration=120.0, dt=0.05, seed=4)
    prep = _prepare(data, "savgol", None, 4)
    setup = _sim_setup(spec, prep, 0, data.n, 30.0, 0.05)
    assert setup is not None
    pl = plant_matrices(spec)
    M, DL, DQ = (np.repeat(pl[k][None], 2, axis=0) for k in ("M", "D_L", "D_Q"))
    DQ[1, 3, 3] *= 3.0
    seg = np.array([1, 3])
    for sim in (setup.sim, *(co for co, _ in _coarse_sims(setup))):
        whole = sim.run(M, DL, DQ)
        part = _segments(sim, seg).run(M, DL, DQ, whole[:, seg, 0])
        assert part.shape == whole[:, seg].shape and setup.sim.x0.shape[0] > seg.size
        np.testing.assert_array_equal(part, whole[:, seg])
