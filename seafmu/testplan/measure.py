"""Run a trial's scenario (plant or vessel) and turn the log into measured signals.

What a trial measures is what a vessel reports: the sensors' samples (``meas_<channel>`` at each
new ``<sensor>_count``) and the shaft speeds (``n_i``), never the plant's true state. The force on
the axis is the thrusters' force tau = B T(n) from the measured shaft speeds through the file's
thrust law (the bollard-pull law, as on a real vessel). A velocity no sensor measures (a surface
vessel with GNSS only) is differentiated from the position fixes with a Savitzky-Golay filter and
turned into the body frame with the measured heading: model-free, unlike the observer's estimate,
which follows the very damping the trial is to measure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.signal import savgol_filter

from seafmu.components.thrusters import speed_to_thrust
from seafmu.components.vessel_spec import VesselSpec
from seafmu.master import RunResult, run
from seafmu.scenario import load_scenario
from seafmu.testplan.design import TrialPlan, scenario_doc, thrust_matrix

TRANSLATION_POS = {"u": "north", "v": "east", "w": "down"}


class TestplanError(ValueError):
    """A test plan that cannot go on; the message is one line."""


@dataclass
class Measurement:
    """A trial's measured signals (SI), on the sample times of its velocity sensor."""

    plan: TrialPlan
    t: np.ndarray  # s
    y: np.ndarray  # velocity (m/s, rad/s) of the trial's DOF; roll/pitch: the angle (rad)
    tau: np.ndarray  # (n, dof) thrusters' generalised force at t
    nu: np.ndarray  # (n, dof) measured/derived body velocities at t (nan where not measured)
    source: str  # how y was measured, in words
    noise: float  # sensor noise std of y's channel(s) as the vessel file states it
    scenario: Path | None = None
    eta: np.ndarray | None = None  # (n, dof) measured pose at t (nan where no sensor has it)
    noise_nu: dict[str, float] = field(default_factory=dict)  # noise std per nu channel
    noise_model: dict[str, Any] = field(default_factory=dict)  # nu channel -> how noise reaches it
    t_log: np.ndarray | None = None  # the log's time (every master step) ...
    tau_log: np.ndarray | None = None  # ... and the thrusters' force on it (impulses)
    truth: dict[str, np.ndarray] = field(default_factory=dict)  # true states (simulation only)
    wall: float = 0.0

    def force_held(self) -> np.ndarray:
        """The thrusters' force as the fit's integrator holds it: on [t_i, t_i+1) the mean of the
        logged force over that interval (``interval_mean``), so every interval carries its true
        impulse. The force sampled at t_i and held instead lags a ramping force by half a sample
        (1 s fixes on the supply vessel): X_u +0.10 %, m_a -0.4 % of M with true velocities."""
        if self.t_log is None or self.tau_log is None:
            return self.tau
        return interval_mean(self.t_log, self.tau_log, self.t)


def interval_mean(t_log: np.ndarray, f_log: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Mean of f_log (n_log, k; linear between log steps) over each [t_i, t_i+1); the last row is
    the value at t[-1]. Non-finite log rows (a vessel link before its first shaft-speed report) are
    bridged linearly from their finite neighbours, as ``np.interp`` did for the sampled force."""
    f_log = np.array(f_log, dtype=float)
    for k in range(f_log.shape[1]):
        ok = np.isfinite(f_log[:, k])
        if not ok.all():
            f_log[:, k] = np.interp(t_log, t_log[ok], f_log[ok, k]) if ok.any() else 0.0
    cum = np.concatenate([np.zeros((1, f_log.shape[1])),
                          np.cumsum(0.5 * (f_log[1:] + f_log[:-1]) * np.diff(t_log)[:, None], axis=0)])
    at = np.column_stack([np.interp(t, t_log, cum[:, k]) for k in range(f_log.shape[1])])
    out = np.empty((len(t), f_log.shape[1]))
    out[:-1] = np.diff(at, axis=0) / np.diff(t)[:, None]
    out[-1] = np.array([np.interp(t[-1], t_log, f_log[:, k]) for k in range(f_log.shape[1])])
    return out


def run_trial(tp: TrialPlan, vessel: VesselSpec, folder: Path, hardware: str | None, mode: str,
              seed: int) -> Measurement:
    """Write the trial's scenario, run it, and measure."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{tp.name}_scenario.yaml"
    path.write_text(yaml.safe_dump(scenario_doc(tp, vessel, hardware, seed), sort_keys=False))
    scenario = load_scenario(path)
    rec = folder / f"{tp.name}_recording" if hardware else None
    result = run(scenario, mode="inprocess" if mode == "inprocess" else "fmu", progress=False,
                 record_dir=rec)
    m = measure(tp, vessel, result)
    m.scenario = path
    return m


def _samples(result: RunResult, sensor: str) -> np.ndarray:
    """Row indices where a sensor delivered a new sample."""
    count = result.signals[f"plant.{sensor}_count"]
    idx = np.flatnonzero(np.diff(count) != 0) + 1
    return idx


def _sensor_of(vessel: VesselSpec, channel: str) -> tuple[str, float] | None:
    for s in vessel.sensors:
        if channel in s.channels:
            return s.name, float(s.noise_std[s.channels.index(channel)])
    return None


def _window(n_per_s: float, seconds: float) -> int:
    w = max(5, round(seconds * n_per_s))
    return w + 1 if w % 2 == 0 else w


def body_velocities(vessel: VesselSpec, result: RunResult, t_grid: np.ndarray, smooth_s: float,
                    noise_model: dict[str, Any] | None = None
                    ) -> tuple[np.ndarray, dict[str, str], dict[str, float]]:
    """Body velocities at ``t_grid``: measured channels where a sensor has them, else the horizontal
    ones differentiated from the position fixes (Savitzky-Golay over ``smooth_s``) and rotated
    by the measured heading. Returns (nu, source per channel, noise per channel); ``noise_model``
    is filled with how the file's sensor noise reaches each channel (``NoiseModel.draw``)."""
    nm = noise_model if noise_model is not None else {}
    t_all = result.time
    nu = np.full((len(t_grid), vessel.dof), np.nan)
    how: dict[str, str] = {}
    noise: dict[str, float] = {}
    for j, name in enumerate(vessel.nu_names):
        s = _sensor_of(vessel, name)
        if s is None:
            continue
        idx = _samples(result, s[0])
        ts, ys = t_all[idx], result.signals[f"plant.meas_{name}"][idx]
        nu[:, j] = np.interp(t_grid, ts, ys)
        nm[name] = {"t": ts, "sigma": s[1]}
        how[name] = f"{s[0]} ({name} measured)"
        noise[name] = s[1]
    missing = [n for n in ("u", "v") if n in vessel.nu_names and n not in how]
    if missing:
        pos = _sensor_of(vessel, "north")
        head = _sensor_of(vessel, "yaw")
        if pos is None or head is None:
            raise TestplanError(f"vessel '{vessel.name}': no sensor measures {', '.join(missing)} and no "
                                "position and heading sensors to derive them from")
        idx = _samples(result, pos[0])
        ts = t_all[idx]
        dt = float(np.median(np.diff(ts)))
        w = _window(1.0 / dt, smooth_s)
        n_dot = savgol_filter(result.signals["plant.meas_north"][idx], w, 2, deriv=1, delta=dt)
        e_dot = savgol_filter(result.signals["plant.meas_east"][idx], w, 2, deriv=1, delta=dt)
        hidx = _samples(result, head[0])
        psi = np.unwrap(result.signals["plant.meas_yaw"][hidx])
        psi_s = np.interp(ts, t_all[hidx], psi)
        c, s_ = np.cos(psi_s), np.sin(psi_s)
        body = {"u": c * n_dot + s_ * e_dot, "v": -s_ * n_dot + c * e_dot}
        # noise of a quadratic Savitzky-Golay slope over w samples
        k = np.arange(w) - (w - 1) / 2
        sg_noise = pos[1] / (dt * math.sqrt(float(np.sum(k**2))))
        derived = {"t": ts, "w": w, "dt": dt, "sigma": pos[1], "psi": psi_s, "sigma_psi": head[1],
                   "n_dot": n_dot, "e_dot": e_dot}
        for name in missing:
            nm[name] = {"derived": derived, "channel": name}
            nu[:, vessel.nu_names.index(name)] = np.interp(t_grid, ts, body[name])
            how[name] = (f"{name} differentiated from {pos[0]} positions (Savitzky-Golay, {w} samples = "
                         f"{w * dt:g} s, quadratic) and rotated by the {head[0]} heading")
            noise[name] = sg_noise
    return nu, how, noise


def noise_draws(model: dict[str, Any], names: list[str], t: np.ndarray, n: int,
                rng: np.random.Generator) -> np.ndarray:
    """``n`` realisations (n, len(t), len(names)) of the sensor noise in the measured body
    velocities, as the file states it and as ``body_velocities`` processes it: white noise on the
    sensor's samples (interpolated like the data), or position and heading noise on the fixes,
    Savitzky-Golay differentiated and rotated. Channels without a model get zeros."""
    out = np.zeros((n, len(t), len(names)))

    def interp(ts: np.ndarray, vals: np.ndarray) -> np.ndarray:  # vals (n, len(ts)) -> (n, len(t))
        i = np.clip(np.searchsorted(ts, t) - 1, 0, len(ts) - 2)
        w = np.clip((t - ts[i]) / (ts[i + 1] - ts[i]), 0.0, 1.0)
        return vals[:, i] * (1.0 - w) + vals[:, i + 1] * w

    derived_cache: dict[str, np.ndarray] = {}
    for c, name in enumerate(names):
        spec = model.get(name)
        if spec is None:
            continue
        if "derived" not in spec:
            out[:, :, c] = interp(spec["t"], rng.normal(0.0, spec["sigma"], (n, len(spec["t"]))))
            continue
        d = spec["derived"]
        if not derived_cache:
            shape = (n, len(d["t"]))
            dn = savgol_filter(rng.normal(0.0, d["sigma"], shape), d["w"], 2, deriv=1, delta=d["dt"], axis=1)
            de = savgol_filter(rng.normal(0.0, d["sigma"], shape), d["w"], 2, deriv=1, delta=d["dt"], axis=1)
            psi = d["psi"] + rng.normal(0.0, d["sigma_psi"], shape)
            nd, ed = d["n_dot"] + dn, d["e_dot"] + de
            c0, s0 = np.cos(d["psi"]), np.sin(d["psi"])
            cp, sp = np.cos(psi), np.sin(psi)
            derived_cache["u"] = cp * nd + sp * ed - (c0 * d["n_dot"] + s0 * d["e_dot"])
            derived_cache["v"] = -sp * nd + cp * ed - (-s0 * d["n_dot"] + c0 * d["e_dot"])
        out[:, :, c] = interp(d["t"], derived_cache[spec["channel"]])
    return out


def measured_pose(vessel: VesselSpec, result: RunResult, t_grid: np.ndarray) -> np.ndarray:
    """The pose channels a sensor measures, at ``t_grid`` (angles unwrapped); nan elsewhere."""
    eta = np.full((len(t_grid), vessel.dof), np.nan)
    for j, name in enumerate(vessel.eta_names):
        s = _sensor_of(vessel, name)
        if s is None:
            continue
        idx = _samples(result, s[0])
        ys = result.signals[f"plant.meas_{name}"][idx]
        if name in ("roll", "pitch", "yaw"):
            ys = np.unwrap(ys)
        eta[:, j] = np.interp(t_grid, result.time[idx], ys)
    return eta


def measure(tp: TrialPlan, vessel: VesselSpec, result: RunResult) -> Measurement:
    """The trial's measured signals from a run's log."""
    if not result.complete:
        raise TestplanError(f"{tp.name}: the run stopped at t = {result.t_end:g} s of {tp.duration:g} s")
    t_all = result.time
    chan = tp.dof if tp.kind == "release" else tp.nu
    s = _sensor_of(vessel, chan)
    if s is not None:
        t_grid = t_all[_samples(result, s[0])]
    else:  # derived velocity: on the position fixes
        pos = _sensor_of(vessel, "north")
        if pos is None:
            raise TestplanError(f"vessel '{vessel.name}': nothing measures {chan}")
        t_grid = t_all[_samples(result, pos[0])]
    smooth = 0.15 * max(tp.t_step - tp.t_release, 20.0)
    noise_model: dict[str, Any] = {}
    nu, how, noise = body_velocities(vessel, result, t_grid, smooth, noise_model)
    if tp.kind == "release":
        idx = _samples(result, s[0])
        y = result.signals[f"plant.meas_{chan}"][idx]
        src, sig = f"{s[0]} ({chan} measured)", s[1]
    else:
        j = vessel.nu_names.index(chan)
        y = nu[:, j]
        src, sig = how[chan], noise[chan]
    n_thr = vessel.thrusters.positions.shape[0]
    n = np.column_stack([result.signals[f"plant.n_{i + 1}"] for i in range(n_thr)])
    thrust = speed_to_thrust(vessel.thrusters, n)
    tau_all = thrust @ thrust_matrix(vessel).T
    tau = np.column_stack([np.interp(t_grid, t_all, tau_all[:, k]) for k in range(vessel.dof)])
    truth = {k.split(".", 1)[1]: v for k, v in result.signals.items()
             if k.split(".", 1)[1] in vessel.eta_names + vessel.nu_names}
    truth["time"] = t_all
    return Measurement(tp, t_grid, y, tau, nu, src, sig, truth=truth, wall=result.wall_time,
                       eta=measured_pose(vessel, result, t_grid), noise_nu=noise, noise_model=noise_model,
                       t_log=t_all, tau_log=tau_all)
