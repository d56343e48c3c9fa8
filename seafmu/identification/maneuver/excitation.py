"""Experiment design and simulated trials: multisine excitation, a maneuver flown by seafmu's own
plant (``PlantBlock``), sensor noise added to a log (tests, benchmarks, replay).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from seafmu.components.allocation import allocation_matrix
from seafmu.components.plant import PlantBlock
from seafmu.components.thrusters import thrust_to_speed, thruster_matrix
from seafmu.components.vessel_spec import ETA_NAMES, NU_NAMES, VesselSpec
from seafmu.identification.maneuver.io import ManeuverData


def multisine(t: np.ndarray, channels: int, fmax: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean multisines, one per channel on interleaved frequency grids (mutually orthogonal
    over the record), peak-normalised to 1; amplitudes fall as 1/sqrt(k) so slow DOFs move."""
    duration = float(t[-1] - t[0]) if t.size > 1 else 1.0
    f0 = 1.0 / duration
    ks = np.arange(1, max(int(fmax / f0), channels + 1) + 1)
    out = np.zeros((t.size, channels))
    for i in range(channels):
        k = ks[(ks % channels) == i]
        phase = rng.uniform(0.0, 2.0 * np.pi, k.size)
        s = (np.sin(2.0 * np.pi * f0 * np.outer(t - t[0], k) + phase) / np.sqrt(k)).sum(axis=1)
        out[:, i] = s / max(float(np.max(np.abs(s))), 1e-12)
    return out


def default_amplitude(vessel: VesselSpec) -> np.ndarray:
    """Generalised-force amplitudes of the excitation: large in the DOFs the thrusters push
    well, small in roll/pitch (weak restoring: 0.05 m metacentric height on Minerva 2)."""
    if vessel.dof == 6:
        return np.array([250.0, 250.0, 150.0, 80.0, 100.0, 80.0])
    return np.array([25.0, 8.0, 2.0])


def simulate_maneuver(
    vessel: VesselSpec,
    duration: float = 300.0,
    dt: float = 0.01,
    seed: int = 0,
    amplitude: np.ndarray | None = None,
    fmax: float = 0.25,
    attitude_gains: tuple[float, float] = (1000.0, 800.0),
    commands: np.ndarray | None = None,
    substep: float = 0.01,
    plant_params: dict[str, float] | None = None,
) -> tuple[ManeuverData, np.ndarray]:
    """A noise-free maneuver trial from seafmu's own plant (``PlantBlock``, noise_scale = 0).

    Excitation: a multisine generalised force per DOF (``amplitude``, up to ``fmax`` Hz),
    allocated to the thrusters by the pseudo-inverse; for 6 DOF a PD term on roll and pitch
    (``attitude_gains`` = (K_p, K_d) in N m/rad, N m s/rad) keeps the angles moderate, as an
    ROV's attitude control would in a sea trial. ``commands`` (n, m) replays given shaft-speed
    commands open loop instead (the close-the-loop check). ``plant_params`` are further
    PlantBlock parameters (e.g. ``current_speed``, ``current_direction``: an environment the
    identified model may lack). Returns the log (tau = B T from the plant's true thrusts) and the
    commands used, one row per step.
    """
    d, m = vessel.dof, vessel.thrusters.count
    steps = round(duration / dt)
    t = np.arange(steps + 1) * dt
    B = thruster_matrix(vessel.thrusters, d)
    if commands is not None:
        commands = np.asarray(commands, dtype=float)
        if commands.shape != (steps, m):
            raise ValueError(f"commands must have shape ({steps}, {m}), got {commands.shape}")
        tau_d = None
    else:
        amp = default_amplitude(vessel) if amplitude is None else np.asarray(amplitude, dtype=float)
        tau_d = multisine(t, d, fmax, np.random.default_rng(seed)) * amp
        P = allocation_matrix(B)
    plant = PlantBlock(vessel, {**(plant_params or {}), "noise_scale": 0.0, "substep": min(substep, dt)})
    names = PlantBlock.interface(vessel).output_names()  # outputs located by name, not position
    i_eta = [names.index(n) for n in vessel.eta_names]
    i_nu = [names.index(n) for n in vessel.nu_names]
    i_thr = [names.index(f"thrust_{i + 1}") for i in range(m)]
    i_roll, i_pitch, i_p, i_q = (names.index(n) for n in ("roll", "pitch", "p", "q")) if d == 6 else (0,) * 4
    y = plant.output()
    out = np.empty((steps + 1, y.size))
    out[0] = y
    cmds = np.empty((steps, m)) if commands is None else commands
    kp, kd = attitude_gains
    for k in range(steps):
        if tau_d is not None:
            demand = tau_d[k].copy()
            if d == 6:
                demand[3] -= kp * y[i_roll] + kd * y[i_p]
                demand[4] -= kp * y[i_pitch] + kd * y[i_q]
            cmds[k] = thrust_to_speed(vessel.thrusters, P @ demand)
        y = plant.step(float(t[k]), dt, cmds[k])
        out[k + 1] = y
    data = ManeuverData(
        t=t, eta=out[:, i_eta], nu=out[:, i_nu], tau=out[:, i_thr] @ B.T, dof=d,
        source=f"simulated by PlantBlock ({vessel.name}, {duration:g} s, dt {dt:g} s, seed {seed})",
        thrust=out[:, i_thr],
    )
    return data, cmds



def add_sensor_noise(data: ManeuverData, vessel: VesselSpec, scale: float, seed: int = 0) -> ManeuverData:
    """White Gaussian noise on eta and nu, std = ``scale`` x the vessel file's sensor noise_std
    (0 for channels no sensor measures); tau stays exact (thrust from measured shaft speed)."""
    rng = np.random.default_rng(seed)
    std = {c: float(s) for sen in vessel.sensors for c, s in zip(sen.channels, sen.noise_std, strict=True)}
    d = data.dof
    s_eta = np.array([std.get(n, 0.0) for n in ETA_NAMES[d]]) * scale
    s_nu = np.array([std.get(n, 0.0) for n in NU_NAMES[d]]) * scale
    return replace(
        data,
        eta=data.eta + rng.standard_normal(data.eta.shape) * s_eta,
        nu=data.nu + rng.standard_normal(data.nu.shape) * s_nu,
        source=f"{data.source} + sensor noise x{scale:g} (seed {seed})",
        nu_dot=None,
    )
