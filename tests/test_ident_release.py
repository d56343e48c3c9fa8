"""A decay or pendulum log that starts while the body is still held: the hold is found and left out.

The logs here are made with SciPy's ODE solver (not seafmu's fitter), a roll decay of 12 kg m^2,
c = 80 N m/rad, d_L = 1.2 N m s/rad, released from 0.25 rad; a clean one logged 0.6 s before its
release was diagnosed as three effects at once (cubic restoring, quadratic drag and friction).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from seafmu.identification.diagnosis import diagnose
from seafmu.identification.release import held_samples
from seafmu.identification.trial import load_trial

M, C, D_L = 12.0, 80.0, 1.2


def _roll_decay(dt: float, hold: float, noise: float, seed: int, d_q: float = 0.0, x0: float = 0.25,
                duration: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """(t, angle): held at x0 until ``hold``, then released from rest; white noise of ``noise`` x x0."""
    t = np.arange(0.0, duration, dt)

    def rhs(_: float, s: np.ndarray) -> list[float]:
        x, v = s
        return [v, -(C * x + D_L * v + d_q * v * abs(v)) / M]

    after = t[t >= hold] - hold
    sol = solve_ivp(rhs, (0.0, after[-1]), [x0, 0.0], t_eval=after, rtol=1e-10, atol=1e-12)
    y = np.concatenate([np.full(t.size - after.size, x0), sol.y[0]])
    return t, y + np.random.default_rng(seed).normal(0.0, noise * x0, t.size)


@pytest.mark.parametrize("dt", [0.001, 0.01, 0.04])
@pytest.mark.parametrize("noise", [0.002, 0.01, 0.05])
def test_a_log_that_starts_at_the_release_is_kept_whole(dt: float, noise: float) -> None:
    for seed in range(5):
        t, y = _roll_decay(dt, 0.0, noise, seed)
        assert held_samples(t, y, "decay2") == 0
        assert held_samples(t, y, "pendulum") == 0


@pytest.mark.parametrize("dt", [0.001, 0.01, 0.04])
@pytest.mark.parametrize("noise", [0.002, 0.01, 0.05])
def test_a_hold_before_the_release_is_found(dt: float, noise: float) -> None:
    """The release found within the last fifth of the hold (never after it)."""
    t, y = _roll_decay(dt, 0.3, noise, seed=1)
    h = held_samples(t, y, "decay2")
    assert 0.8 * 0.3 <= t[h] <= 0.3 + 1e-9


def test_a_speed_decay_hold_is_found_and_a_release_kept() -> None:
    """First order (a speed decay: its slope jumps at the release)."""
    t = np.arange(0.0, 30.0, 0.05)
    rng = np.random.default_rng(0)
    clean = np.exp(-t / 5.0) + rng.normal(0, 0.01, t.size)
    held = np.where(t < 1.0, 1.0, np.exp(-(t - 1.0) / 5.0)) + rng.normal(0, 0.01, t.size)
    assert held_samples(t, clean, "decay") == 0
    assert 0.8 <= t[held_samples(t, held, "decay")] <= 1.0 + 1e-9
    assert held_samples(t, held, "step") == 0  # a step trial starts with its command: no release


def _trial(folder: Path, hold: float, d_q: float = 0.0) -> Path:
    files = []
    for k in range(3):
        t, y = _roll_decay(0.04, hold, 0.01, seed=10 + k, d_q=d_q, x0=0.15 + 0.05 * k)
        f = folder / f"run{k + 1}.csv"
        np.savetxt(f, np.column_stack([t, y]), delimiter=",", header="time_s,y_rad", comments="")
        files.append(f.name)
    (folder / "trial.yaml").write_text(
        "name: roll_release\nkind: decay2\ndof: roll\nfiles: [" + ", ".join(files) + "]\n"
        "columns:\n  time: {column: time_s, unit: s}\n  output: {column: y_rad, unit: rad}\n"
        f"baseline: linear\nconstants:\n  mass: {M}\n")
    return folder / "trial.yaml"


def test_a_clean_decay_logged_before_its_release_is_clean(tmp_path: Path) -> None:
    trial = load_trial(_trial(tmp_path, hold=0.6))
    assert len(trial.notes) == 3 and all("left out" in n for n in trial.notes)
    assert all(r.t[0] == pytest.approx(0.6, abs=0.13) for r in trial.runs)
    d = diagnose(trial)
    assert d.effects == [], d.evidence
    assert d.baseline.params["c"] == pytest.approx(C, rel=0.01)
    assert d.baseline.params["d_L"] == pytest.approx(D_L, rel=0.1)
    assert d.baseline.warnings[:3] == trial.notes  # said with the fit


def test_an_effect_is_still_found_after_a_hold(tmp_path: Path) -> None:
    d = diagnose(load_trial(_trial(tmp_path, hold=0.6, d_q=15.0)))
    assert d.effects == ["quadratic_damping"], d.evidence


def test_a_hold_over_most_of_a_short_run_is_no_error() -> None:
    """The window past the departure ends with the run (found by test_ident_robustness's random
    decay logs: a log held for three quarters of its 40 samples raised a shape error)."""
    t = np.arange(40) * 0.001
    y = np.r_[np.full(30, 1e-6), np.linspace(1e-6, 5e-6, 10)]
    assert held_samples(t, y, "decay") == 30
