"""Preprocessing: uniform resampling, a noise estimate, nu_dot by Savitzky-Golay (the same
smoother on both sides of the equation) or central differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from seafmu.identification import fitting
from seafmu.identification.maneuver.io import ManeuverData
from seafmu.identification.trial import TrialError

DERIVATIVES = ("auto", "savgol", "central", "measured")


@dataclass
class _Prepared:
    t: np.ndarray
    dt: float
    eta: np.ndarray  # smoothed like nu
    nu: np.ndarray
    nu_dot: np.ndarray
    tau: np.ndarray
    nu_raw: np.ndarray
    edge: int  # samples at each end where the derivative filter is one-sided
    note: str
    # per-thruster thrust on the hull as the vessel file says (n, m), filtered like tau; None when
    # the log gives tau only (tau = B thrust when present)
    thrust: np.ndarray | None = None
    # std of white noise in nu_raw that stays in nu (the smoother's gain on it): the noise of the
    # segments' start states, which the whiteness test allows for (statistics.whiteness)
    noise_gain: float = 1.0


def _uniform(data: ManeuverData, warnings: list[str]) -> ManeuverData:
    """Resample onto a uniform grid when the log's sampling jitters (> 1 % of the median step)."""
    dt = np.diff(data.t)
    med = float(np.median(dt))
    if np.max(np.abs(dt - med)) <= 0.01 * med:
        return data
    t = np.arange(data.t[0], data.t[-1] + 0.5 * med, med)
    t = t[t <= data.t[-1] + 1e-12]

    def interp(a: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, data.t, a[:, j]) for j in range(a.shape[1])])

    warnings.append(f"non-uniform sampling: resampled linearly onto a {med:g} s grid")
    return ManeuverData(t=t, eta=interp(data.eta), nu=interp(data.nu), tau=interp(data.tau), dof=data.dof,
                        source=data.source, nu_dot=None if data.nu_dot is None else interp(data.nu_dot),
                        thrust=None if data.thrust is None else interp(data.thrust),
                        efficiency=data.efficiency)


def noise_ratio(nu: np.ndarray) -> float:
    """Largest per-DOF ratio of white-noise std to signal std, from second differences
    (robust MAD; a smooth signal's second difference is O(dt^2) and does not count)."""
    return float(np.max(noise_ratios(nu)))


def noise_ratios(nu: np.ndarray) -> np.ndarray:
    """Per DOF: white-noise std over signal std (``noise_ratio``)."""
    return fitting.white_noise_std(nu) / np.maximum(nu.std(axis=0), 1e-300)


def _prepare(data: ManeuverData, derivative: str, smoothing: float | None, polyorder: int) -> _Prepared:
    """nu_dot and the regressor signals, all filtered by the same smoother.

    Savitzky–Golay (default): a local polynomial of order ``polyorder`` over a window of
    ``smoothing`` seconds (None: the shortest window, polyorder + 3 samples, for clean logs)
    gives nu_dot as its derivative and smoothed nu, eta and tau as its value — the same filter on
    both sides of the equation, so smoothing adds no lag between regressors and output.
    Central differences: ``np.gradient`` (second order), no smoothing.
    """
    dt = float(np.median(np.diff(data.t)))
    thrust = data.thrust_on_hull
    if derivative == "measured":
        if data.nu_dot is None:
            raise TrialError(f"{data.source}: derivative='measured' but the log has no nu_dot")
        return _Prepared(data.t, dt, data.eta, data.nu, data.nu_dot, data.tau, data.nu, 0,
                         "nu_dot measured (from the log)", thrust)
    if derivative == "central":
        return _Prepared(data.t, dt, data.eta, data.nu, np.gradient(data.nu, dt, axis=0), data.tau,
                         data.nu, 1, "nu_dot by central differences (np.gradient), no smoothing", thrust)
    if derivative != "savgol":
        raise ValueError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {derivative!r}")
    min_win = polyorder + 3 if polyorder % 2 == 0 else polyorder + 2
    win = min_win if smoothing is None else max(min_win, 2 * round(0.5 * smoothing / dt) + 1)
    if win >= data.n:
        raise TrialError(f"{data.source}: smoothing window of {win} samples exceeds the {data.n}-sample log")

    def sg(a: np.ndarray, deriv: int = 0) -> np.ndarray:
        return savgol_filter(a, win, polyorder, deriv=deriv, delta=dt, axis=0, mode="interp")

    eta = data.eta.copy()
    if data.dof == 6:  # roll and pitch enter the restoring force
        eta[:, 3:5] = sg(data.eta[:, 3:5])
    return _Prepared(
        data.t, dt, eta, sg(data.nu), sg(data.nu, 1), sg(data.tau), data.nu, win // 2,
        f"nu_dot by Savitzky-Golay (order {polyorder}, window {win} samples = {win * dt:.3g} s); "
        "nu, roll/pitch and tau smoothed by the same filter",
        None if thrust is None else sg(thrust),
        float(np.sqrt(np.sum(savgol_coeffs(win, polyorder) ** 2))),
    )
