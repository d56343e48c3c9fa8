"""Trials made by seafmu's own plant (``PlantBlock``) with one catalogue effect hidden in it.

``synthetic.demo_trial`` generates data with the fitter's own simulator, so the truth always lies
inside the fitted model class. These trials are made the way a real test would be: the vessel
file (a ``dataclasses.replace`` of the shipped AMV OSF or Minerva 2 spec) or the plant's
environment parameters carry the effect, ``PlantBlock`` integrates the full 3- or 6-DOF model
(Coriolis, added-mass coupling, restoring, shaft dynamics, current), and the logged output is the
vessel's own sensor (its rate, its noise, ``noise_scale`` and ``seed``), sampled at that sensor's
rate. The diagnosis never sees the truth's model class; couplings the 1-DOF trial model lacks are
part of the data, as they would be at sea.

Which effect goes where (``DESIGN``) and which the plant cannot express (``NOT_EXPRESSIBLE``) is
documented in docs/identification.md, section "Hidden effects in plant-made trials".
"""

from __future__ import annotations

import dataclasses

import numpy as np

from seafmu.components.plant import PlantBlock
from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification.trial import Run, Trial, make_trial

# kind -> what the trial is (vessel, DOF, experiment)
KINDS: dict[str, str] = {
    "surge_decay": "AMV OSF coast-down in surge (speed log u at 5 Hz, 0.02 m/s noise)",
    "surge_step": "AMV OSF surge steps of both screws' shaft-speed command (u at 5 Hz)",
    "heave_decay": "Minerva 2 heave decay (DVL w at 5 Hz, 0.01 m/s noise)",
    "pitch_decay": "Minerva 2 free pitch decay, trimmed neutral (AHRS pitch at 10 Hz, 0.2 deg noise)",
    "sway_yaw_decay": "AMV OSF sway-yaw decay on a rig holding surge, linear-damping variant (v at 5 Hz, "
                      "r from the 20 Hz gyro, 0.002 rad/s)",
}

# effect -> (trial kind, how the plant carries it)
DESIGN: dict[str, tuple[str, str]] = {
    "linear_damping": ("surge_decay", "vessel D_L[0][0] = 8 N/(m/s); trial baseline: quadratic"),
    "quadratic_damping": ("surge_decay", "the shipped AMV (D_Q = 34.08); trial baseline: linear"),
    "current": ("surge_decay", "plant current_speed 0.1 m/s towards north, heading north; "
                               "runs ahead and astern"),
    "constant_force": ("heave_decay", "the shipped Minerva 2: buoyancy exceeds weight by 30 N"),
    "added_mass": ("surge_step", "vessel M_A[0][0] = 22 kg; the trial states 40 kg + 10 kg (file) and k"),
    "thrust_quadratic": ("surge_step", "thruster law quadratic, k = 6 N/rps^2 per screw; trial: linear law"),
    "thrust_asymmetry": ("surge_step", "thruster k_reverse = 0.65 k_forward"),
    "actuator_lag": ("surge_step", "the shipped AMV shaft lag, time_constant 0.25 s"),
    "saturation": ("surge_step", "thruster n_max = 1.4 rev/s (commands up to 2.2), both x amplitude"),
    "nonlinear_restoring": ("pitch_decay", "Minerva 2 trimmed neutral (righting moment BG W sin(theta)); "
                                           "trial restoring: linear"),
    "coupling": ("sway_yaw_decay", "vessel D_L[1][2] = D_L[2][1] = 8 (Y_r = N_v = -8)"),
}

# effects the plant model has no term for: their hidden-effect tests use demo_trial's data
NOT_EXPRESSIBLE: dict[str, str] = {
    "coulomb_friction": "the vessel model has no friction term (damping is D_L nu + D_Q |nu| nu)",
    "deadband": "the thruster model maps every non-zero shaft speed to thrust (T = k n or k n|n|)",
    "time_delay": "commands act at the next plant step; there is no transport delay",
}

# kind -> effects plant_trial hides in it (effect=None gives the clean trial of any kind)
EFFECTS: dict[str, set[str]] = {k: {e for e, (kk, _) in DESIGN.items() if kk == k} for k in KINDS}

AMV_SURGE_MASS = 40.0  # rigid-body surge mass of the AMV file (M_RB[0][0])
AMV_SURGE_ADDED = 10.0  # the file's surge added mass (M_A[0][0])
AMV_K = 12.63  # thrust coefficient of each screw (N/rps)
FAST_DRIVE = 0.02  # s: shaft time constant of an "ideal" drive (clean step trials: no lag to find)
SURGE_HOLD = 3000.0  # N s/m: linear surge damping standing in for a rig that holds surge (sway-yaw trials)


def _replace_matrix(m: np.ndarray, entries: dict[tuple[int, int], float]) -> np.ndarray:
    out = np.array(m, dtype=float)
    for (i, j), v in entries.items():
        out[i, j] = v
    return out


def _with_thrusters(spec: VesselSpec, **changes: float | str) -> VesselSpec:
    """The spec with every thruster's field(s) set (numbers broadcast over the thrusters)."""
    th = spec.thrusters
    kw: dict[str, object] = {}
    for name, value in changes.items():
        kw[name] = value if isinstance(value, str) else np.full(th.count, float(value))
    return dataclasses.replace(spec, thrusters=dataclasses.replace(th, **kw))


def record(spec: VesselSpec, params: dict[str, float], commands: np.ndarray, h: float,
           channels: list[str], substep: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Run PlantBlock for len(commands) samples of step h; return t and the measured channels.

    The plant's sensor outputs (meas_<channel>) carry the vessel's sensor noise and are sampled
    at the end of each step, so h should be the sensor period (a faster log repeats held values).
    """
    plant = PlantBlock(spec, {**params, "substep": substep})
    names = PlantBlock.interface(spec).output_names()
    idx = [names.index(f"meas_{c}") for c in channels]
    y = plant.output()
    out = [y[idx]]
    for k in range(len(commands) - 1):
        y = plant.step(k * h, h, np.asarray(commands[k], dtype=float))
        out.append(y[idx])
    return np.arange(len(commands)) * h, np.array(out)


def _sensor_period(spec: VesselSpec, channel: str) -> float:
    rate = next(s.rate_hz for s in spec.sensors if channel in s.channels)
    return 1.0 / float(rate)


def _decay_runs(spec: VesselSpec, channel: str, starts: list[dict[str, float]], duration: float,
                base: dict[str, float], seed: int, substep: float = 0.01) -> list[Run]:
    h = _sensor_period(spec, channel)
    n = round(duration / h) + 1
    cmds = np.zeros((n, spec.thrusters.count))
    runs = []
    for i, x0 in enumerate(starts):
        t, y = record(spec, {**base, **x0, "seed": seed + 1000 * i}, cmds, h, [channel], substep)
        runs.append(Run(f"{channel}_decay{i + 1}", y[:, 0], t))
    return runs


def surge_step_vessel(effect: str | None, amplitude: float = 1.0) -> tuple[VesselSpec, dict[str, float]]:
    """The AMV spec of a surge step trial with `effect` in it, and the constants the trial states.

    Every step trial uses a fast drive (FAST_DRIVE) unless the effect is the shaft lag itself:
    the shipped 0.25 s lag IS the catalogue's actuator_lag, so a clean step trial must not have it.
    """
    spec = _with_thrusters(load_vessel("amv_osf"), time_constant=FAST_DRIVE)
    constants = {"mass": AMV_SURGE_MASS + AMV_SURGE_ADDED}
    if effect == "added_mass":
        spec = dataclasses.replace(spec, M_A=_replace_matrix(spec.M_A, {(0, 0): 22.0}))
        constants = {"mass": AMV_SURGE_MASS, "added_mass": AMV_SURGE_ADDED, "thrust_coefficient": 2 * AMV_K}
    elif effect == "thrust_quadratic":
        spec = _with_thrusters(spec, law="quadratic", k_forward=6.0, k_reverse=6.0)
    elif effect == "thrust_asymmetry":
        spec = _with_thrusters(spec, k_reverse=0.65 * AMV_K)
    elif effect == "actuator_lag":
        spec = _with_thrusters(spec, time_constant=0.25)
    elif effect == "saturation":
        spec = _with_thrusters(spec, n_max=1.4 * amplitude)
    elif effect is not None:
        raise ValueError(f"plant: '{effect}' is not hidden in a surge step trial")
    return spec, constants


def plant_trial(effect: str | None, kind: str | None = None, seed: int = 0, noise_scale: float = 1.0,
                amplitude: float = 1.0, hold_surge: bool = True) -> Trial:
    """A trial made by PlantBlock with `effect` hidden (None: the clean trial of `kind`).

    noise_scale multiplies the vessel file's sensor noise; seed picks the noise (each run of the
    trial uses its own seed derived from it); amplitude scales the excitation (initial speeds or
    angles, command levels; a saturation cap scales with it so it stays active). hold_surge=False
    lets the sway-yaw hull move in surge (see the sway_yaw_decay comment below).
    """
    # Over 80 lines: one short branch per plant trial kind (vessel, DOF, experiment), kept together so
    # the trial designs of docs/identification.md read side by side.
    A = float(amplitude)
    if effect is not None and effect in NOT_EXPRESSIBLE:
        raise ValueError(f"plant: '{effect}' cannot be hidden in the plant ({NOT_EXPRESSIBLE[effect]})")
    if effect is not None and effect not in DESIGN:
        raise ValueError(f"plant: unknown effect '{effect}'")
    kind = kind or (DESIGN[effect][0] if effect else "surge_decay")
    if kind not in KINDS:
        raise ValueError(f"plant kind '{kind}': one of {', '.join(KINDS)}")
    if effect is not None and effect not in EFFECTS[kind]:
        raise ValueError(f"plant: '{effect}' is not hidden in a '{kind}' trial "
                         f"(there: {', '.join(sorted(EFFECTS[kind])) or 'none'})")
    name = f"plant_{effect or 'none'}_{kind}"
    prov = f"PlantBlock, {KINDS[kind]}, noise_scale {noise_scale:g}, seed {seed}"
    if effect:
        prov += f"; hidden: {effect} ({DESIGN[effect][1]})"
    base = {"noise_scale": noise_scale}

    if kind in ("surge_decay", "surge_step"):
        spec = load_vessel("amv_osf")
        M_total = AMV_SURGE_MASS + AMV_SURGE_ADDED
        if kind == "surge_decay":
            baseline = {"linear_damping": "quadratic", "quadratic_damping": "linear"}.get(effect or "",
                                                                                         "linear_quadratic")
            starts = [1.0 * A, 0.6 * A]
            if effect == "linear_damping":
                spec = dataclasses.replace(spec, D_L=_replace_matrix(spec.D_L, {(0, 0): 8.0}))
            if effect == "current":
                base |= {"current_speed": 0.1, "current_direction": 0.0}
                starts = [1.0 * A, -1.0 * A, 0.7 * A]
            runs = _decay_runs(spec, "u", [{"u_0": u0} for u0 in starts], 25.0, base, seed)
            return make_trial("decay", runs, dof="surge", baseline=baseline, constants={"mass": M_total},
                              name=name, provenance=prov)
        # surge steps: both screws get the same command; the logged input is the command (rev/s)
        spec, constants = surge_step_vessel(effect, A)
        levels = [(1.0, 2.0, 0.5, -1.0, -2.0, 0.0), (1.5, 0.8, -1.5, 2.2, 0.3, -0.6)]
        h = _sensor_period(spec, "u")
        runs = []
        for i, lv in enumerate(levels):
            t = np.arange(0.0, 48.0 + 1e-9, h)
            n = A * np.array(lv)[np.minimum((t // 8).astype(int), len(lv) - 1)]
            t, y = record(spec, {**base, "seed": seed + 1000 * i}, np.column_stack([n, n]), h, ["u"])
            runs.append(Run(f"steps{i + 1}", y[:, 0], t, n))
        return make_trial("step", runs, dof="surge", baseline="linear_quadratic", constants=constants,
                          name=name, provenance=prov, input_kind="rpm")

    if kind == "heave_decay":
        spec = load_vessel("minerva2")
        if effect is None:  # neutrally buoyant: no constant force to find
            spec = _neutral(spec)
        mass = float(spec.M_RB[2, 2] + spec.M_A[2, 2])
        runs = _decay_runs(spec, "w", [{"w_0": w0 * A} for w0 in (0.3, -0.3, 0.2)], 40.0, base, seed, 0.02)
        return make_trial("decay", runs, dof="heave", baseline="linear_quadratic", constants={"mass": mass},
                          name=name, provenance=prov)

    if kind == "pitch_decay":
        # Trimmed to neutral buoyancy, as for a decay test: with the shipped 30 N the ROV rises
        # while it pitches, and the Munk moment of that rise stiffens pitch by ~3 % and makes the
        # restoring look far more nonlinear than the sin law (c3 ~ -1100 instead of -c/6 ~ -229).
        spec = _neutral(load_vessel("minerva2"))
        inertia = float(spec.M_RB[4, 4] + spec.M_A[4, 4])
        # The largest release is the last run, the held-out one: the sin law shows at large angles.
        starts = [{"pitch_0": a * A} for a in (0.8, -0.9, 1.0)]
        runs = _decay_runs(spec, "pitch", starts, 30.0, base, seed, 0.02)
        return make_trial("decay2", runs, dof="pitch", baseline="linear_quadratic",
                          constants={"mass": inertia}, restoring="linear" if effect else "sin",
                          name=name, provenance=prov)

    # sway_yaw_decay: the AMV with linear sway/yaw damping (the trial model is linear), surge held
    # by the rig. On a free hull the centripetal surge force -r (m22 v + m26 r) makes u, and u
    # feeds Coriolis/Munk terms back into Y and N: a real sway-yaw coupling that the plant has
    # even with zero off-diagonal damping (the diagnosis names it; docs/identification.md).
    spec = load_vessel("amv_osf")
    DL = {(0, 0): SURGE_HOLD if hold_surge else float(spec.D_L[0, 0]), (1, 1): 60.0, (2, 2): 20.0}
    if effect == "coupling":
        DL |= {(1, 2): 8.0, (2, 1): 8.0}
    DQ = {(1, 1): 0.0, (2, 2): 0.0, (1, 2): 0.0, (2, 1): 0.0}
    spec = dataclasses.replace(spec, D_L=_replace_matrix(spec.D_L, DL), D_Q=_replace_matrix(spec.D_Q, DQ))
    h = _sensor_period(spec, "v")
    n = round(12.0 / h) + 1
    cmds = np.zeros((n, spec.thrusters.count))
    runs = []
    for i, (v0, r0) in enumerate([(0.6, 0.0), (0.0, 0.8), (0.5, 0.6), (0.5, -0.6)]):
        x0 = {"v_0": v0 * A, "r_0": r0 * A}
        t, y = record(spec, {**base, **x0, "seed": seed + 1000 * i}, cmds, h, ["v", "r"])
        runs.append(Run(f"sway_yaw{i + 1}", y, t))
    M = spec.M_RB + spec.M_A
    constants = {"mass": float(M[1, 1]), "inertia": float(M[2, 2]),
                 "mass_coupling": float(0.5 * (M[1, 2] + M[2, 1]))}
    return make_trial("decay", runs, dof="sway_yaw", baseline="linear", constants=constants, name=name,
                      provenance=prov)


def _neutral(spec: VesselSpec) -> VesselSpec:
    """The spec ballasted to neutral buoyancy (buoyancy = weight)."""
    assert spec.restoring is not None
    neutral = dataclasses.replace(spec.restoring, buoyancy=spec.restoring.weight)
    return dataclasses.replace(spec, restoring=neutral)
