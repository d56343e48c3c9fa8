"""What the run report's figures show, for a simulation and for a hardware link (which reports no true
state and no thrust): read from the drawn matplotlib figures, not from pixels."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from seafmu import plots

ETA = ("north", "east", "down", "roll", "pitch", "yaw")


def _signals(hardware: bool, n: int = 601, thrusters: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    sig: dict[str, np.ndarray] = {}
    for i, name in enumerate(ETA):
        true = np.cumsum(rng.normal(0, 0.02, n)) + i
        if not hardware:
            sig[f"plant.{name}"] = true
        if name not in ("north", "east"):  # an ROV: no position sensor, its position is estimated
            sig[f"plant.meas_{name}"] = true + rng.normal(0, 0.05, n)
        sig[f"observer.{name}_hat"] = true + rng.normal(0, 0.01, n)
        sig[f"controller.{name}_ref"] = np.zeros(n)
    for k in range(1, thrusters + 1):
        sig[f"plant.n_{k}"] = rng.normal(0, 5, n)
        sig[f"allocator.n_cmd_{k}"] = rng.normal(0, 5, n)
        if not hardware:
            sig[f"plant.thrust_{k}"] = rng.normal(0, 50, n)
    return sig


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The figures drawn, by file name, instead of saved."""
    drawn: dict[str, Any] = {}
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.__setitem__(Path(path).name, fig))
    return drawn


def _legend(ax: Any) -> list[str]:
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg is not None else []


def test_a_hardware_run_shows_estimates_measurements_and_shaft_speeds(figures: dict[str, Any]) -> None:
    s = plots.Series("hil", np.linspace(0, 60, 601), _signals(hardware=True))
    drawn, failed = plots.draw_all(s, Path("unused"))
    assert not failed
    assert [name for _, name in drawn] == ["trajectory.png", "states.png", "thrusters.png"]
    (traj,) = figures["trajectory.png"].axes
    assert "estimated" in _legend(traj) and "true" not in _legend(traj)
    assert "estimated" in traj.get_title()
    states = figures["states.png"].axes
    assert [ax.get_ylabel().split()[0] for ax in states] == list(ETA)  # every state, none true
    assert _legend(states[0]) == ["estimate", "reference", "measured"]  # measured: in later panels
    assert len(states[0].lines) == 2 and len(states[2].lines) == 3  # north: no sensor; down: depth
    th = figures["thrusters.png"].axes
    assert len(th) == 3 and all(len(ax.lines) == 2 for ax in th)  # one row each: command, shaft speed
    assert "shaft speed" in th[0].get_title() and all("thrust" not in ax.get_title() for ax in th)


def test_a_simulation_shows_the_true_state_not_the_measurements(figures: dict[str, Any]) -> None:
    s = plots.Series("sim", np.linspace(0, 60, 601), _signals(hardware=False, thrusters=7))
    plots.draw_all(s, Path("unused"))
    (traj,) = figures["trajectory.png"].axes
    assert _legend(traj)[:2] == ["true", "estimated"]
    states = figures["states.png"].axes
    assert "measured" not in _legend(states[0])
    assert all(len(ax.lines) == 3 for ax in states)  # true, estimate, reference
    th = figures["thrusters.png"].axes
    assert len(th) == 14  # seven rows: shaft speed with its command, thrust
    assert "thrust [N]" in th[1].get_title() and len(th[1].lines) == 1
    np.testing.assert_array_equal(th[-1].lines[0].get_ydata(), s.signals["plant.thrust_7"])


@pytest.mark.parametrize("peak", [3e-13, 50.0])
def test_allocation_error_is_on_a_log_axis_and_rounding_is_called_rounding(figures: dict[str, Any],
                                                                          peak: float) -> None:
    """On a linear axis 1e-13 of rounding looked like a fault; a real shortfall (saturation) must
    not be called rounding."""
    t = np.linspace(0, 60, 601)
    err = np.abs(np.sin(t)) * peak
    err[0] = 0.0  # exactly 0: drawn at the floor, not lost to the log axis
    plots.draw_all(plots.Series("x", t, {"allocator.alloc_error": err}), Path("unused"))
    (ax,) = figures["allocation.png"].axes
    assert ax.get_yscale() == "log" and ax.lines[0].get_ydata().min() == plots.FLOOR
    texts = [x.get_text() for x in ax.texts]
    assert any("exact to rounding" in x for x in texts) == (peak < plots.EXACT), texts
    assert ax.get_ylim()[1] >= 100 * max(peak, plots.EXACT) * 0.999
