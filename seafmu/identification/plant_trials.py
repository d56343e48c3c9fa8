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
from typing import Any

import numpy as np

from seafmu.components.plant import PlantBlock
from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification import effects
from seafmu.identification.catalogue import CATALOGUE
from seafmu.identification.effects.base import Hiding, replace_matrix, with_thrusters
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


def _plant_design() -> tuple[dict[str, tuple[str, str]], dict[str, str]]:
    """From the effect objects: effect -> (trial kind, how the plant carries it), and the effects
    the plant model has no term for (their hidden-effect tests use demo_trial's data)."""
    design: dict[str, tuple[str, str]] = {}
    missing: dict[str, str] = {}
    for obj in effects.all_effects():
        if obj.name not in CATALOGUE:
            continue
        if obj.plant is not None:
            design[obj.name] = obj.plant
        elif obj.plant_missing is not None:
            missing[obj.name] = obj.plant_missing
    return design, missing


# effect -> (trial kind, how the plant carries it); effects the plant cannot express, and why
DESIGN, NOT_EXPRESSIBLE = _plant_design()

# kind -> effects plant_trial hides in it (effect=None gives the clean trial of any kind)
EFFECTS: dict[str, set[str]] = {k: {e for e, (kk, _) in DESIGN.items() if kk == k} for k in KINDS}

AMV_SURGE_MASS = 40.0  # rigid-body surge mass of the AMV file (M_RB[0][0])
AMV_SURGE_ADDED = 10.0  # the file's surge added mass (M_A[0][0])
FAST_DRIVE = 0.02  # s: shaft time constant of an "ideal" drive (clean step trials: no lag to find)
SURGE_HOLD = 3000.0  # N s/m: linear surge damping standing in for a rig that holds surge (sway-yaw trials)


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


def _hiding(effect: str | None, kind: str, amplitude: float) -> Hiding:
    """The effect object's hiding of itself in a plant trial of ``kind`` (clean: nothing)."""
    if effect is None:
        return Hiding()
    if kind not in KINDS or effect not in EFFECTS[kind]:
        raise ValueError(f"plant: '{effect}' is not hidden in a {kind.replace('_', ' ')} trial")
    obj = effects.get(effect)
    assert obj is not None, effect
    return obj.hide_in_plant(kind, amplitude)


def _carry(spec: VesselSpec, hid: Hiding) -> VesselSpec:
    """The vessel file carrying the hidden effect."""
    return hid.vessel(spec) if hid.vessel is not None else spec


def surge_step_vessel(effect: str | None, amplitude: float = 1.0) -> tuple[VesselSpec, dict[str, float]]:
    """The AMV spec of a surge step trial with `effect` in it, and the constants the trial states.

    Every step trial uses a fast drive (FAST_DRIVE) unless the effect is the shaft lag itself:
    the shipped 0.25 s lag IS the catalogue's actuator_lag, so a clean step trial must not have it.
    """
    hid = _hiding(effect, "surge_step", amplitude)
    spec = _carry(with_thrusters(load_vessel("amv_osf"), time_constant=FAST_DRIVE), hid)
    return spec, {"mass": AMV_SURGE_MASS + AMV_SURGE_ADDED, **hid.constants}


def plant_trial(effect: str | None, kind: str | None = None, seed: int = 0, noise_scale: float = 1.0,
                amplitude: float = 1.0, hold_surge: bool = True) -> Trial:
    """A trial made by PlantBlock with `effect` hidden (None: the clean trial of `kind`).

    noise_scale multiplies the vessel file's sensor noise; seed picks the noise (each run of the
    trial uses its own seed derived from it); amplitude scales the excitation (initial speeds or
    angles, command levels; a saturation cap scales with it so it stays active). hold_surge=False
    lets the sway-yaw hull move in surge (see ``_sway_yaw_decay``). How each effect is carried is
    its object's ``hide_in_plant``.
    """
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
    hid = _hiding(effect, kind, A)
    base = {"noise_scale": noise_scale, **hid.plant}
    trial_kw = {"name": name, "provenance": prov}
    if kind == "sway_yaw_decay":
        return _sway_yaw_decay(hid, A, base, seed, hold_surge, trial_kw)
    return _KIND_MAKERS[kind](hid, A, base, seed, trial_kw)


TrialKw = dict[str, Any]


def _surge_decay(hid: Hiding, A: float, base: dict[str, float], seed: int, kw: TrialKw) -> Trial:
    spec = _carry(load_vessel("amv_osf"), hid)
    starts = [s * A for s in (hid.starts or (1.0, 0.6))]
    runs = _decay_runs(spec, "u", [{"u_0": u0} for u0 in starts], 25.0, base, seed)
    return make_trial("decay", runs, dof="surge", baseline=hid.baseline or "linear_quadratic",
                      constants={"mass": AMV_SURGE_MASS + AMV_SURGE_ADDED}, **kw)


def _surge_step(hid: Hiding, A: float, base: dict[str, float], seed: int, kw: TrialKw) -> Trial:
    # both screws get the same command; the logged input is the command (rev/s)
    spec = _carry(with_thrusters(load_vessel("amv_osf"), time_constant=FAST_DRIVE), hid)
    constants = {"mass": AMV_SURGE_MASS + AMV_SURGE_ADDED, **hid.constants}
    levels = hid.levels or ((1.0, 2.0, 0.5, -1.0, -2.0, 0.0), (1.5, 0.8, -1.5, 2.2, 0.3, -0.6))
    h = _sensor_period(spec, "u")
    runs = []
    for i, lv in enumerate(levels):
        t = np.arange(0.0, 48.0 + 1e-9, h)
        n = A * np.array(lv)[np.minimum((t // 8).astype(int), len(lv) - 1)]
        t, y = record(spec, {**base, "seed": seed + 1000 * i}, np.column_stack([n, n]), h, ["u"])
        runs.append(Run(f"steps{i + 1}", y[:, 0], t, n))
    return make_trial("step", runs, dof="surge", baseline=hid.baseline or "linear_quadratic",
                      constants=constants, input_kind="rpm", **kw)


def _heave_decay(hid: Hiding, A: float, base: dict[str, float], seed: int, kw: TrialKw) -> Trial:
    # neutrally buoyant, so the clean trial has no constant force to find
    spec = _carry(_neutral(load_vessel("minerva2")), hid)
    mass = float(spec.M_RB[2, 2] + spec.M_A[2, 2])
    runs = _decay_runs(spec, "w", [{"w_0": w0 * A} for w0 in (0.3, -0.3, 0.2)], 40.0, base, seed, 0.02)
    return make_trial("decay", runs, dof="heave", baseline=hid.baseline or "linear_quadratic",
                      constants={"mass": mass}, **kw)


def _pitch_decay(hid: Hiding, A: float, base: dict[str, float], seed: int, kw: TrialKw) -> Trial:
    # Trimmed to neutral buoyancy, as for a decay test: with the shipped 30 N the ROV rises
    # while it pitches, and the Munk moment of that rise stiffens pitch by ~3 % and makes the
    # restoring look far more nonlinear than the sin law (c3 ~ -1100 instead of -c/6 ~ -229).
    spec = _carry(_neutral(load_vessel("minerva2")), hid)
    inertia = float(spec.M_RB[4, 4] + spec.M_A[4, 4])
    # The largest release is the last run, the held-out one: the sin law shows at large angles.
    starts = [{"pitch_0": a * A} for a in (0.8, -0.9, 1.0)]
    runs = _decay_runs(spec, "pitch", starts, 30.0, base, seed, 0.02)
    return make_trial("decay2", runs, dof="pitch", baseline=hid.baseline or "linear_quadratic",
                      constants={"mass": inertia}, restoring=hid.trial_restoring or "sin", **kw)


def _sway_yaw_decay(hid: Hiding, A: float, base: dict[str, float], seed: int, hold_surge: bool,
                    kw: TrialKw) -> Trial:
    # The AMV with linear sway/yaw damping (the trial model is linear), surge held by the rig. On a
    # free hull the centripetal surge force -r (m22 v + m26 r) makes u, and u feeds Coriolis/Munk
    # terms back into Y and N: a real sway-yaw coupling that the plant has even with zero
    # off-diagonal damping (the diagnosis names it; docs/identification.md).
    spec = load_vessel("amv_osf")
    DL = {(0, 0): SURGE_HOLD if hold_surge else float(spec.D_L[0, 0]), (1, 1): 60.0, (2, 2): 20.0}
    DQ = {(1, 1): 0.0, (2, 2): 0.0, (1, 2): 0.0, (2, 1): 0.0}
    spec = dataclasses.replace(spec, D_L=replace_matrix(spec.D_L, DL), D_Q=replace_matrix(spec.D_Q, DQ))
    spec = _carry(spec, hid)
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
    return make_trial("decay", runs, dof="sway_yaw", baseline=hid.baseline or "linear", constants=constants,
                      **kw)


_KIND_MAKERS = {"surge_decay": _surge_decay, "surge_step": _surge_step, "heave_decay": _heave_decay,
                "pitch_decay": _pitch_decay}


def _neutral(spec: VesselSpec) -> VesselSpec:
    """The spec ballasted to neutral buoyancy (buoyancy = weight)."""
    assert spec.restoring is not None
    neutral = dataclasses.replace(spec.restoring, buoyancy=spec.restoring.weight)
    return dataclasses.replace(spec, restoring=neutral)
