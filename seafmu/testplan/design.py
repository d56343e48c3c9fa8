"""The test plan's trials, designed from the vessel file, and the scenarios that run them.

AAUSHIP method one (brief section 5) per body axis surge, sway, yaw: accelerate with a constant
open-loop force, hold it until the speed is steady, release (force zero: the decay), and once at
rest a step of a second force from rest. Method two: roll and pitch released from an angle (where
the vessel has those DOFs). Every trial runs the ``axis_trial`` controller variant: the trial's DOF
has zero gains (free) and its joystick axis carries the force profile; the others are held.

Amplitudes come from the vessel's thrust capability (``allocation.thrust_capability``, the pure-DOF
force the allocator can make): the accelerate/hold force is ``HOLD_FRACTION`` of it, the step
``STEP_FRACTION`` (two levels also separate linear from quadratic damping). The remaining capability
holds the other DOFs. Phase durations come from the file's own model of the axis (the prior; a
trial is planned before the vessel is known better): long enough to settle within ``SETTLED``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seafmu.components.allocation import thrust_capability
from seafmu.components.controller import restoring_stiffness
from seafmu.components.vessel_spec import VesselSpec

HOLD_FRACTION = 0.4  # accelerate/hold force, fraction of the pure-DOF thrust capability
STEP_FRACTION = 0.2  # step from rest
SETTLED = 0.02  # a phase lasts until the file's model is within 2 % of its end value
SETTLE_START = 5.0  # s at rest before the first force (observer and hold settle)
PHASE_MIN, PHASE_MAX = 20.0, 600.0  # s, bounds of one phase
RELEASE_ANGLE = math.radians(10.0)  # roll/pitch release angle
DECAY2_PERIODS = 8.0  # roll/pitch record length in natural periods
DECAY2_MAX = 120.0  # s
# a roll/pitch release leaves free the DOFs its inertia couples to (|M_kj| / sqrt(M_kk M_jj) above
# this): holding them against the swing takes energy out of it (Minerva 2 roll: sway and yaw)
COUPLED_FREE = 0.05

# body axis -> (tau name, NED DOF whose gains are zeroed, nu name, joystick axis)
AXES = {
    "surge": ("X", "north", "u", "surge"),
    "sway": ("Y", "east", "v", "sway"),
    "yaw": ("N", "yaw", "r", "yaw"),
    "roll": ("K", "roll", "p", None),
    "pitch": ("M", "pitch", "q", None),
}


@dataclass
class TrialPlan:
    """One trial: its axis, forces and phase times (s)."""

    axis: str
    kind: str  # "method_one" (accelerate, hold, release, step) or "release" (roll/pitch)
    tau: str
    dof: str
    nu: str
    joy: str | None
    index: int  # index of the DOF in nu / tau
    force_hold: float = 0.0
    force_step: float = 0.0
    t_accelerate: float = 0.0
    t_release: float = 0.0
    t_step: float = 0.0
    duration: float = 0.0
    angle0: float = 0.0
    mass: float = 0.0  # the file's inertia of the DOF (M_jj, total)
    prior: dict[str, float] = field(default_factory=dict)  # the file's d_L, d_Q (and c)
    free: list[str] = field(default_factory=list)  # other NED DOFs left free (release trials)

    @property
    def name(self) -> str:
        return f"{self.axis}_trial"

    @property
    def rotational(self) -> bool:
        return self.axis in ("yaw", "roll", "pitch")


def _settle_time(M: float, dL: float, dQ: float, v0: float, F: float) -> float:
    """Time for M v' + dL v + dQ v|v| = F from v0 to come within SETTLED of its end value."""
    v_end = steady_speed(dL, dQ, F)
    span = abs(v_end - v0)
    if span == 0.0:
        return PHASE_MIN
    h = 0.02 * M / max(dL + 2.0 * dQ * max(abs(v0), abs(v_end)), 1e-12)
    v, t = v0, 0.0
    while abs(v - v_end) > SETTLED * span and t < PHASE_MAX:
        a = lambda x: (F - dL * x - dQ * x * abs(x)) / M  # noqa: E731
        k1 = a(v)
        k2 = a(v + 0.5 * h * k1)
        k3 = a(v + 0.5 * h * k2)
        k4 = a(v + h * k3)
        v += h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += h
    return float(min(max(t, PHASE_MIN), PHASE_MAX))


def steady_speed(dL: float, dQ: float, F: float) -> float:
    """v with dL v + dQ v|v| = F."""
    if dQ > 0.0:
        v = (-dL + math.sqrt(dL * dL + 4.0 * dQ * abs(F))) / (2.0 * dQ)
    else:
        v = abs(F) / dL
    return math.copysign(v, F)


def plan(vessel: VesselSpec, scale: float = 1.0) -> list[TrialPlan]:
    """The trials of the plan for this vessel; ``scale`` shortens every phase (tests)."""
    cap = thrust_capability(vessel)
    M = 0.5 * (vessel.M + vessel.M.T)
    stiff = restoring_stiffness(vessel)
    trials = []
    for axis, (tau, dof, nu, joy) in AXES.items():
        if tau not in vessel.tau_names or dof not in vessel.eta_names:
            continue
        j = vessel.nu_names.index(nu)
        m, dL, dQ = float(M[j, j]), float(vessel.D_L[j, j]), float(vessel.D_Q[j, j])
        tp = TrialPlan(axis, "method_one" if joy else "release", tau, dof, nu, joy, j, mass=m,
                       prior={"d_L": dL, "d_Q": dQ})
        if joy is not None:
            tp.force_hold = HOLD_FRACTION * float(cap[vessel.tau_names.index(tau)])
            tp.force_step = STEP_FRACTION * float(cap[vessel.tau_names.index(tau)])
            v_hold = steady_speed(dL, dQ, tp.force_hold)
            accel = _settle_time(m, dL, dQ, 0.0, tp.force_hold) * scale
            release = _settle_time(m, dL, dQ, v_hold, 0.0) * scale
            step = _settle_time(m, dL, dQ, 0.0, tp.force_step) * scale
            tp.t_accelerate = SETTLE_START
            tp.t_release = round(tp.t_accelerate + 1.5 * accel)  # the last third is the hold
            tp.t_step = round(tp.t_release + release)
            tp.duration = float(round(tp.t_step + 1.2 * step))
        else:
            c = float(stiff[vessel.eta_names.index(dof)])
            if c <= 0.0:
                continue  # no restoring: nothing oscillates
            tp.prior["c"] = c
            tp.free = coupled_dofs(vessel, j)
            period = 2.0 * math.pi / math.sqrt(c / m)
            tp.angle0 = RELEASE_ANGLE
            tp.duration = float(round(min(max(DECAY2_PERIODS * period, PHASE_MIN), DECAY2_MAX) * scale))
        trials.append(tp)
    return trials


def coupled_dofs(vessel: VesselSpec, j: int) -> list[str]:
    """NED DOFs whose inertia couples to body DOF j beyond ``COUPLED_FREE`` (nu and eta align)."""
    M = 0.5 * (vessel.M + vessel.M.T)
    return [vessel.eta_names[i] for i in range(vessel.dof)
            if i != j and abs(M[j, i]) > COUPLED_FREE * math.sqrt(M[j, j] * M[i, i])]


def master_step(vessel: VesselSpec) -> float:
    """Master step: 0.1 s, finer where a sensor is faster (every sample is recorded)."""
    fastest = max((s.rate_hz for s in vessel.sensors), default=10.0)
    return 0.05 if fastest > 10.0 else 0.1


def scenario_doc(tp: TrialPlan, vessel: VesselSpec, hardware: str | None, seed: int) -> dict[str, Any]:
    """The scenario (as YAML data) of one trial."""
    step = master_step(vessel)
    ctrl: dict[str, Any] = {"controller_variant": "axis_trial"}
    for dof in (tp.dof, *tp.free):
        for g in ("kp", "kd", "ki"):
            ctrl[f"{g}_{dof}"] = 0.0
    events: list[dict[str, Any]] = []
    if tp.joy is not None:
        ctrl[f"joy_max_{tp.tau}"] = round(tp.force_hold, 6)
        events = [
            {"time": tp.t_accelerate, "set": f"controller.joy_{tp.joy}", "value": 1.0},
            {"time": tp.t_release, "set": f"controller.joy_{tp.joy}", "value": 0.0},
            {"time": tp.t_step, "set": f"controller.joy_{tp.joy}",
             "value": round(tp.force_step / tp.force_hold, 9)},
        ]
    plant: dict[str, Any]
    if hardware is not None:
        plant = {"hardware": hardware}
    else:
        params: dict[str, Any] = {"seed": seed}
        if tp.kind == "release":
            params[f"{tp.dof}_0"] = tp.angle0
        plant = {"kind": "plant", "parameters": params}
    n = len(vessel.thrusters.positions) if hasattr(vessel.thrusters, "positions") else 0
    outputs = [f"plant.meas_{c}" for s in vessel.sensors for c in s.channels]
    outputs += [f"plant.{s.name}_count" for s in vessel.sensors]
    outputs += [f"plant.n_{i + 1}" for i in range(n)]
    outputs += [f"controller.tau_{t}" for t in vessel.tau_names]
    if hardware is None:  # the true motion, for the report only (a vessel reports none)
        outputs += [f"plant.{x}" for x in vessel.eta_names + vessel.nu_names]
    return {
        "name": f"testplan_{vessel.name}_{tp.axis}",
        "description": f"seafmu testplan: {tp.axis} trial of {vessel.name} (axis_trial controller)",
        "vessel": vessel.name,
        "duration": tp.duration,
        "step": step,
        "record_interval": step,
        "fmus": {"plant": plant, "observer": {"kind": "observer"},
                 "controller": {"kind": "controller", "parameters": ctrl},
                 "allocator": {"kind": "allocator"}},
        "events": events,
        "outputs": outputs,
    }


def thrust_matrix(vessel: VesselSpec) -> np.ndarray:
    """The configuration matrix B (tau = B T) of the vessel's thrusters."""
    from seafmu.components.thrusters import thruster_matrix

    return thruster_matrix(vessel.thrusters, vessel.dof)
