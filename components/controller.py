"""Motion controllers: 6-DOF nonlinear PID with operating modes (Minerva 2), AMV OSF autopilot (3 DOF).

6 DOF (Fossen 2011, sec. 12.2.6, the thesis's controller):

    tau = -J(eta)^T (K_p eta_tilde + K_d (J(eta) nu - eta_d_dot) + K_i int eta_tilde dt)
          [+ M nu_d_dot + C(nu_d) nu_d + D(nu_d) nu_d  in waypoint mode]  [+ joystick forces]
    eta_tilde = eta_hat - eta_d   (angles wrapped),  eta_d from a 2nd-order reference model

The PID acts in NED (where a current or the net buoyancy is constant) and J^T maps it to the
body. Default gains come from pole placement per DOF on the diagonal of M (see
``pid_pole_placement`` and docs/gnc.md); anti-windup stops integration of the error components
that push an already saturated body DOF further out and clamps the integral force.

Modes (parameter ``mode``, tunable; the thesis's five operating modes):
0 DP (all six DOF held at ``<eta>_ref``); 1 waypoint tracking (``components.guidance``: north,
east and heading from a reference point running along a lawnmower or a waypoint list, model
feed-forward of its acceleration and velocity); 2 auto-depth; 3 auto-heading; 4 joystick;
5 auto-depth + auto-heading. Roll and pitch are held at their setpoints in every mode (the
thrusters' moments excite them; a pilot has no roll/pitch stick). A DOF that is not held is
"free": its PID terms are off, the body force of its joystick axis (``joy_surge`` ...) acts, its
reference model follows the estimate (position and velocity), and its integral force stays
applied as a trim (current, net buoyancy). Switching is bumpless: a newly held DOF starts its
reference at the vessel's position and velocity, and the difference between the last output and
the new mode's first output is added and decays with ``mode_blend_time``, so tau is continuous.

3 DOF (AMV OSF, thesis): heading autopilot on yaw only, open-loop surge force from the throttle;
``autopilot`` 0 = PID with yaw-rate feed-forward,

    tau_N = m66 r_d_dot + d(r_d) - K_p psi_tilde - K_d (r - r_d) - K_i int psi_tilde dt

``autopilot`` 1 = linear backstepping (thesis gains k1 = 8, k2 = 4) with integral action,

    z1 = psi_tilde,  alpha1 = r_d - k1 z1,  z2 = r - alpha1
    tau_N = m66 (r_d_dot - k1 (r - r_d)) + d(r) - z1 - k2 z2 - K_i,bs int z1 dt

(V = z1^2/2 + m66 z2^2/2 gives V_dot = -k1 z1^2 - k2 z2^2 without disturbance), where
m66 = I_z + A66 (the thesis printed I_z - A66: erratum), d(r) = D_L66 r + D_Q66 |r| r.

In course mode the joystick angle is a desired course chi_d; the heading reference becomes
psi_d = chi_d - beta with the crab angle beta = atan2(v, u), and the integral removes what the
model of beta misses (current). ``land_mode`` 1: the screws are driven open loop from the joystick,
n1 = S x (0.9 + 0.05 y), n2 = S x (0.9 - 0.05 y), S = land_n_scale * slider, output as the tau that
the two-screw allocator turns back into exactly these speeds; the heading autopilot idles with its
reference model on the vessel, so the return to water is bumpless. Joystick inputs that have no
function in the current mode (and unassigned button bits) are ignored: they never reset a state
(the original's bug).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from components.allocation import FORCE_UNIT, thrust_capability
from components.block import Block, Interface, Signal
from components.guidance import PathGuidance, lawnmower, parse_waypoints
from components.kinematics import J, rzyx, wrap_angle
from components.reference_model import ReferenceModel
from components.thrusters import speed_to_thrust, thruster_matrix
from components.vessel_spec import ANGLE_NAMES, VesselSpec, state_unit

# Closed-loop natural frequencies (rad/s) of the default 6-DOF gains; roll and pitch are placed
# at a multiple of their hydrostatic natural frequency (see pid_pole_placement).
DESIGN_OMEGA = {"north": 0.5, "east": 0.5, "down": 0.5, "yaw": 0.6}
DESIGN_OMEGA_MIN_ATTITUDE = 0.5
DESIGN_ATTITUDE_FACTOR = 1.5
DESIGN_ZETA = 1.0
BETA_MIN_SPEED = 0.1  # m/s: below this the crab angle atan2(v, u) is noise, course mode uses beta = 0


def restoring_stiffness(vessel: VesselSpec) -> np.ndarray:
    """Diagonal of dg/deta at eta = 0 (hydrostatic stiffness, only roll and pitch are non-zero)."""
    g = np.zeros(vessel.dof)
    rs = vessel.restoring
    if vessel.dof == 6 and rs is not None:
        zgb = rs.weight * rs.r_g[2] - rs.buoyancy * rs.r_b[2]
        g[3] = g[4] = zgb
    return g


def pid_pole_placement(vessel: VesselSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Default (K_p, K_d, K_i, omega_n) per DOF from a decoupled linear model of each DOF.

    m x_dd + (d + K_d) x_d + (g + K_p) x + K_i int x = 0 with m = M_jj, d = D_L_jj, g = hydrostatic
    stiffness: K_p = m w^2 - g, K_d = 2 zeta w m - d, K_i = K_p w / 10 (the integrator a decade
    below the bandwidth, so it removes offsets without eroding the phase margin). Roll and pitch
    use w = max(0.5, 1.5 x their hydrostatic frequency sqrt(g/m)): the metacentric height alone is
    too soft for the Munk moments of a depth change through a current (Minerva 2: about 80 N.m at
    0.15 m/s heave in 0.1 m/s current, 0.05 rad of roll); 1.5 x gives 2.25 x the stiffness and
    stays well inside the thrusters' roll/pitch capacity and their 0.2 s lag.
    """
    M = 0.5 * (vessel.M + vessel.M.T)
    m = np.diag(M)
    d = np.diag(vessel.D_L)
    g = restoring_stiffness(vessel)
    omega = np.zeros(vessel.dof)
    for j, name in enumerate(vessel.eta_names):
        if name in ("roll", "pitch"):
            hydrostatic = math.sqrt(max(g[j], 0.0) / m[j])
            omega[j] = max(DESIGN_OMEGA_MIN_ATTITUDE, DESIGN_ATTITUDE_FACTOR * hydrostatic)
        else:
            omega[j] = DESIGN_OMEGA[name]
    kp = np.maximum(m * omega**2 - g, 0.0)
    kd = np.maximum(2.0 * DESIGN_ZETA * omega * m - d, 0.0)
    ki = kp * omega / 10.0
    return kp, kd, ki, omega


# -- operating modes ------------------------------------------------------------------------------

MODE_DP, MODE_WAYPOINT, MODE_DEPTH, MODE_HEADING, MODE_JOYSTICK, MODE_DEPTH_HEADING = range(6)
MODE_NAMES = ("DP", "waypoint tracking", "auto-depth", "auto-heading", "joystick",
              "auto-depth + auto-heading")
# Held NED DOFs (north, east, down, roll, pitch, yaw) per mode; roll and pitch are always held.
HELD = {
    MODE_DP: (1, 1, 1, 1, 1, 1),
    MODE_WAYPOINT: (1, 1, 1, 1, 1, 1),
    MODE_DEPTH: (0, 0, 1, 1, 1, 0),
    MODE_HEADING: (0, 0, 0, 1, 1, 1),
    MODE_JOYSTICK: (0, 0, 0, 1, 1, 0),
    MODE_DEPTH_HEADING: (0, 0, 1, 1, 1, 1),
}
FREE = {m: ~np.array(h, dtype=bool) for m, h in HELD.items()}
ANY_FREE = {m for m, f in FREE.items() if f.any()}
# DOFs whose reference comes from the <eta>_ref inputs (held, not guided) per mode.
FROM_INPUT = {m: np.array(h, dtype=bool) for m, h in HELD.items()}
FROM_INPUT[MODE_WAYPOINT] = np.array([0, 0, 1, 1, 1, 0], dtype=bool)
GUIDED = [0, 1, 5]  # north, east, yaw come from the guidance in waypoint mode
JOY6 = ("surge", "sway", "heave", "yaw")  # joystick axes -> body tau X, Y, Z, N
JOY6_TAU = (0, 1, 2, 5)
JOY6_DOF = (0, 1, 2, 5)  # the NED DOF that must be free for the axis to act (north/east for X and Y)
JOY6_DEFAULT_FRACTION = 0.5  # full stick = half the pure-DOF capability: headroom for roll/pitch hold
TURN_RADIUS_MAX = 1000.0  # m: turn_radius output when (nearly) straight
LAND_SIDEWAYS_BIT = 1  # joy_buttons bit 0: sideways mode while held (land); other bits are unassigned

INT_CHOICES = {
    "mode": tuple(range(6)), "guide_yaw_mode": (0, 1), "lm_side": (-1, 1), "course_mode": (0, 1),
    "autopilot": (0, 1), "land_mode": (0, 1), "joystick": (0, 1),
}
SIGNED = {"lm_heading", "lm_north", "lm_east"}
POSITIVE = {"ref_omega", "ref_zeta", "guide_speed", "guide_accel", "guide_acceptance", "guide_yaw_rate",
            "lm_length"}


def _cross(a: list[float], b: list[float]) -> list[float]:
    """a x b on 3-lists (a NumPy call costs more than the arithmetic here)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


class ControllerBlock(Block):
    """DP / waypoint / auto-depth / auto-heading / joystick (6 DOF) or AMV autopilot and land mode (3 DOF)."""

    kind = "controller"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        if vessel.dof == 6:
            return cls._interface6(vessel)
        return cls._interface3(vessel)

    @classmethod
    def _interface6(cls, vessel: VesselSpec) -> Interface:
        eta, nu, tn = vessel.eta_names, vessel.nu_names, vessel.tau_names
        inputs = [Signal(f"{n}_hat", state_unit(n), f"estimated {n}") for n in eta + nu]
        inputs += [Signal(f"{n}_ref", state_unit(n), f"setpoint {n}") for n in eta]
        inputs += [Signal(f"joy_{a}", "", f"joystick {a} axis in [-1, 1] (body force; acts in the modes "
                          "where that DOF is free)", min=-1.0, max=1.0) for a in JOY6]
        outputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"commanded generalised force {t} (body)") for t in tn]
        outputs += [Signal(f"{n}_d", state_unit(n), f"reference-model trajectory {n}") for n in eta]
        outputs += [
            Signal("cross_track_error", "m", "waypoint mode: signed distance of the estimate to the active "
                   "leg (+ = starboard of the leg direction); 0 in the other modes"),
            Signal("corner_error", "m", "waypoint mode: closest approach of the estimate to the last corner "
                   "waypoint passed (held until the next one)"),
            Signal("leg", "", "waypoint mode: active leg, 1-based (legs + 1 when the path is done); "
                   "0 otherwise"),
            Signal("speed_d", "m/s", "waypoint mode: speed of the reference point along the path"),
        ]
        kp, kd, ki, omega = pid_pole_placement(vessel)
        cap = thrust_capability(vessel)
        params: list[Signal] = []
        for g, vals, what in (("kp", kp, "proportional"), ("kd", kd, "derivative"), ("ki", ki, "integral")):
            for n, v in zip(eta, vals, strict=True):
                params.append(Signal(f"{g}_{n}", "", f"{what} gain {n} (default: pole placement, "
                                     f"omega_n = {omega[eta.index(n)]:.3g} rad/s, zeta = 1)",
                                     min=0.0, start=float(round(v, 6)), tunable=True))
        params += cls._ref_params(omega=0.2)
        params.append(Signal("ref_v_max", "m/s", "reference-model speed limit, translations (0 = none)",
                             min=0.0, start=0.0, tunable=True))
        params.append(Signal("ref_rate_max", "rad/s", "reference-model rate limit, angles (0 = none)",
                             min=0.0, start=0.0, tunable=True))
        for t, c in zip(tn, cap, strict=True):
            params.append(Signal(f"tau_max_{t}", FORCE_UNIT[t], f"saturation of tau_{t} for anti-windup "
                                 "(default: pure-DOF thruster capability through the allocator)",
                                 min=0.0, start=float(round(c, 3)), tunable=True))
        # -- appended with the operating modes (earlier parameters keep their order) --
        params.append(Signal("mode", "", "0 = DP, 1 = waypoint tracking, 2 = auto-depth, 3 = auto-heading, "
                             "4 = joystick, 5 = auto-depth + auto-heading (roll/pitch held in all)",
                             min=0, max=5, start=0, type="integer", tunable=True))
        for a, ti in zip(JOY6, JOY6_TAU, strict=True):
            t = tn[ti]
            params.append(Signal(f"joy_max_{t}", FORCE_UNIT[t], f"force of a full joystick {a} deflection "
                                 "(default: half the pure-DOF capability)", min=0.0,
                                 start=float(round(JOY6_DEFAULT_FRACTION * cap[ti], 3)), tunable=True))
        params += [
            Signal("waypoints", "", "waypoint list 'n1, e1; n2, e2; ...' (m); empty = the lawnmower below. "
                   "Read when waypoint mode is engaged", start="", type="string", tunable=True),
            Signal("lm_lines", "", "lawnmower: number of lines", min=1, start=6, type="integer",
                   tunable=True),
            Signal("lm_spacing", "m", "lawnmower: distance between lines", min=0.0, start=4.0, tunable=True),
            Signal("lm_length", "m", "lawnmower: length of a line", min=0.0, start=20.0, tunable=True),
            Signal("lm_heading", "rad", "lawnmower: direction of the first line", start=0.0, tunable=True),
            Signal("lm_north", "m", "lawnmower: start of the first line, north", start=0.0, tunable=True),
            Signal("lm_east", "m", "lawnmower: start of the first line, east", start=0.0, tunable=True),
            Signal("lm_side", "", "lawnmower: 1 = next line to starboard, -1 = to port", min=-1, max=1,
                   start=1, type="integer", tunable=True),
            Signal("guide_speed", "m/s", "guidance: speed limit of the reference point", min=0.0, start=0.3,
                   tunable=True),
            Signal("guide_accel", "m/s^2", "guidance: acceleration limit of the reference point", min=0.0,
                   start=0.05, tunable=True),
            Signal("guide_acceptance", "m", "guidance: radius of the circle of acceptance around a waypoint",
                   min=0.0, start=0.5, tunable=True),
            Signal("guide_yaw_mode", "", "guidance: 0 = heading along the leg, 1 = heading from yaw_ref",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("guide_yaw_rate", "rad/s", "guidance: heading rate limit at corners", min=0.0, start=0.2,
                   tunable=True),
            Signal("ff_gain", "", "waypoint mode: weight of the model feed-forward "
                   "M nu_d_dot + C nu_d + D nu_d (0 = PID only)", min=0.0, max=1.0, start=1.0, tunable=True),
            Signal("mode_blend_time", "s", "bumpless switching: time constant of the decaying output offset "
                   "(0 = none)", min=0.0, start=2.0, tunable=True),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    @classmethod
    def _interface3(cls, vessel: VesselSpec) -> Interface:
        inputs = [Signal(f"{n}_hat", state_unit(n), f"estimated {n}")
                  for n in vessel.eta_names + vessel.nu_names]
        inputs.append(Signal("yaw_ref", "rad", "desired heading (course when course_mode = 1)"))
        inputs.append(Signal("surge_force_ref", "N", "throttle: open-loop surge force"))
        inputs += [
            Signal("joy_x", "", "joystick stick forward axis in [-1, 1]", min=-1.0, max=1.0),
            Signal("joy_y", "", "joystick stick starboard axis in [-1, 1]", min=-1.0, max=1.0),
            Signal("joy_slider", "", "joystick slider (throttle) in [0, 1]", min=0.0, max=1.0),
            Signal("joy_buttons", "", "joystick buttons as a bit mask: bit 0 = sideways mode while held "
                   "(land); the other bits are unassigned and ignored", min=0.0),
        ]
        outputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"commanded generalised force {t} (body)")
                   for t in vessel.tau_names]
        outputs += [Signal("yaw_d", "rad", "reference-model heading"),
                    Signal("r_d", "rad/s", "reference-model yaw rate")]
        outputs += [
            Signal("turn_radius", "m", f"radius of the current turn, sqrt(u^2 + v^2) / |r| from the inputs "
                   f"(capped at {TURN_RADIUS_MAX:g} m)"),
            Signal("n_joy_1", "rev/s", "land mode: joystick screw speed command, port screw (0 in water)"),
            Signal("n_joy_2", "rev/s", "land mode: joystick screw speed command, starboard screw "
                   "(0 in water)"),
            Signal("sideways", "", "land mode: 1 while the sideways button is held"),
        ]
        cap = thrust_capability(vessel)
        params = [
            Signal("kp", "N.m/rad", "proportional gain (thesis)", min=0.0, start=5.0, tunable=True),
            Signal("kd", "N.m.s/rad", "derivative gain (thesis)", min=0.0, start=50.0, tunable=True),
            Signal("ki", "N.m/(rad.s)", "integral gain (thesis)", min=0.0, start=1.5, tunable=True),
            *cls._ref_params(omega=0.5),
            Signal("course_mode", "", "0: yaw_ref is a heading; 1: a course (crab angle compensated)",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("tau_max_N", "N.m", "yaw moment saturation for anti-windup (default: both screws at "
                   "n_max in opposition)", min=0.0, start=float(round(cap[2], 3)), tunable=True),
            # -- appended: backstepping, land mode, joystick (earlier parameters keep their order) --
            Signal("autopilot", "", "0 = PID with yaw-rate feed-forward, 1 = linear backstepping",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("bs_k1", "1/s", "backstepping gain k1 (thesis)", min=0.0, start=8.0, tunable=True),
            Signal("bs_k2", "N.m.s/rad", "backstepping gain k2 (thesis)", min=0.0, start=4.0, tunable=True),
            Signal("bs_ki", "N.m/(rad.s)", "backstepping integral gain (not in the thesis: removes the "
                   "steady moment of a current or crab; 0 = pure backstepping)", min=0.0, start=1.5,
                   tunable=True),
            Signal("land_mode", "", "0 = water (heading autopilot), 1 = land (open-loop joystick screws)",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("joystick", "", "water: 0 = yaw_ref and surge_force_ref inputs, 1 = the joystick (stick "
                   "angle = heading, slider = surge force)", min=0, max=1, start=0, type="integer",
                   tunable=True),
            Signal("joy_surge_max", "N", "water joystick: surge force at full slider", min=0.0, start=50.0,
                   tunable=True),
            Signal("joy_deadband", "", "water joystick: stick deflection below which the heading is held",
                   min=0.0, max=1.0, start=0.2, tunable=True),
            Signal("land_n_scale", "rev/s", "land joystick: S = land_n_scale * slider in "
                   "n = S x (0.9 +- 0.05 y)",
                   min=0.0, start=float(np.max(vessel.thrusters.n_max)), tunable=True),
            Signal("mode_blend_time", "s", "bumpless switching: time constant of the decaying output offset "
                   "(0 = none)", min=0.0, start=1.0, tunable=True),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    @staticmethod
    def _ref_params(omega: float) -> list[Signal]:
        return [
            Signal("ref_omega", "rad/s", "reference-model natural frequency", min=0.0, start=omega,
                   tunable=True),
            Signal("ref_zeta", "", "reference-model damping ratio (1 = critically damped)", min=0.0,
                   start=1.0, tunable=True),
        ]

    # -- set-up --------------------------------------------------------------------------------
    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        iface = self.interface(vessel)
        self._in_names = iface.input_names()
        self._in_start = np.array([float(s.start) for s in iface.inputs])
        self._n_legacy_in = 18 if vessel.dof == 6 else 8  # the inputs before the joystick was added
        self._n_out = len(iface.outputs)
        d = self.dof = vessel.dof
        self._angles = [n in ANGLE_NAMES for n in vessel.eta_names]
        self._angle_idx = np.flatnonzero(self._angles)
        M = 0.5 * (vessel.M + vessel.M.T)
        self._M = M
        self._m66 = float(M[d - 1, d - 1])  # yaw inertia I_z + A66 (erratum: not I_z - A66)
        self._dl66 = float(vessel.D_L[d - 1, d - 1])
        self._dq66 = float(vessel.D_Q[d - 1, d - 1])
        n_ref = 6 if d == 6 else 1
        self.ref = ReferenceModel(n_ref, 1.0, 1.0, angles=self._angles if d == 6 else [True])
        self.z = np.zeros(n_ref)  # integral of the (wrapped) error
        self._started = False
        self._stepped = False
        self._y = np.zeros(self._n_out)
        self._offset = np.zeros(d)  # bumpless transfer: decaying output offset after a mode switch
        self._active: tuple[int, ...] | None = None  # the mode key the last step ran in
        self.guidance: PathGuidance | None = None
        self._joy_heading = 0.0  # AMV water joystick: heading held while the stick is centred
        # Setpoints latched at a mode switch (NaN = none; see _latch_setpoints) and the last
        # <eta>_ref inputs seen (a change releases the latch).
        self._latch = np.full(n_ref, np.nan)
        self._latch_any = False
        self._ref_seen = np.full(n_ref, np.nan)
        if d == 3:
            B = thruster_matrix(vessel.thrusters, 3)
            self._B_xn = B[[0, 2], :]  # tau_X, tau_N of the screw thrusts (what the allocator inverts)
        for name, value in self.params.items():
            self._check(name, value)
        self._apply_params()

    def _check(self, name: str, value: Any) -> None:
        if name == "waypoints":
            if not isinstance(value, str):
                raise ValueError(f"controller: parameter 'waypoints' must be text, got {value!r}")
            if value.strip():
                parse_waypoints(value)
            return
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"controller: parameter '{name}' must be a number, got {value!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"controller: parameter '{name}' must be finite, got {value!r}")
        if name in INT_CHOICES:
            if v not in INT_CHOICES[name]:
                allowed = ", ".join(str(c) for c in INT_CHOICES[name])
                raise ValueError(f"controller: parameter '{name}' must be one of {allowed}, got {value!r}")
        elif name == "lm_lines":
            if v < 1 or not v.is_integer():
                raise ValueError(f"controller: parameter 'lm_lines' must be a whole number >= 1, "
                                 f"got {value!r}")
        elif name in POSITIVE or name.startswith("tau_max_"):
            if v <= 0.0:
                raise ValueError(f"controller: parameter '{name}' must be positive, got {value!r}")
        elif name in ("ff_gain", "joy_deadband"):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"controller: parameter '{name}' must be within [0, 1], got {value!r}")
        elif name not in SIGNED and v < 0.0:
            raise ValueError(f"controller: parameter '{name}' must be >= 0, got {value!r}")

    def set_parameter(self, name: str, value: Any) -> None:
        self._check(name, value)
        super().set_parameter(name, value)
        self._apply_params()

    def _apply_params(self) -> None:
        p = self.params
        if self.dof == 6:
            eta = self.vessel.eta_names
            self.kp = np.array([float(p[f"kp_{n}"]) for n in eta])
            self.kd = np.array([float(p[f"kd_{n}"]) for n in eta])
            self.ki = np.array([float(p[f"ki_{n}"]) for n in eta])
            self.tau_max = np.array([float(p[f"tau_max_{t}"]) for t in self.vessel.tau_names])
            # Integral force bound per NED component: north and east share the horizontal body
            # forces (rotated by the heading); the others map one-to-one for small roll/pitch.
            z_force_max = self.tau_max.copy()
            z_force_max[:2] = self.tau_max[:2].max()
            vmax = float(p["ref_v_max"]) or math.inf
            rmax = float(p["ref_rate_max"]) or math.inf
            v_lim = [rmax if a else vmax for a in self._angles]
            self.mode = int(float(p["mode"]))
            self._joy_max = np.array([float(p[f"joy_max_{self.vessel.tau_names[i]}"]) for i in JOY6_TAU])
            self._ff_gain = float(p["ff_gain"])
        else:
            self.kp = np.array([float(p["kp"])])
            self.kd = np.array([float(p["kd"])])
            self.ki = np.array([float(p["bs_ki"] if int(float(p["autopilot"])) == 1 else p["ki"])])
            self.tau_max = np.array([float(p["tau_max_N"])])
            z_force_max = self.tau_max
            self.course_mode = int(float(p["course_mode"])) == 1
            self.backstepping = int(float(p["autopilot"])) == 1
            self.land = int(float(p["land_mode"])) == 1
            self.joystick = int(float(p["joystick"])) == 1
            v_lim = [math.inf]
        safe_ki = np.where(self.ki > 0.0, self.ki, 1.0)
        self._z_max = np.where(self.ki > 0.0, z_force_max / safe_ki, np.inf)
        self._blend_time = float(p["mode_blend_time"])
        self.ref.set_dynamics(float(p["ref_omega"]), float(p["ref_zeta"]), v_max=v_lim)

    def _mode_key(self) -> tuple[int, ...]:
        """What decides the control law; a change is a mode switch (bumpless transfer)."""
        if self.dof == 6:
            return (self.mode,)
        return (int(self.land), int(self.backstepping), int(self.joystick))

    # -- run -----------------------------------------------------------------------------------
    def start(self, u: np.ndarray) -> np.ndarray:
        """Bumpless start: the reference model begins at the initial estimate, no force yet."""
        u = self._full_inputs(np.asarray(u, dtype=float), strict=False)
        if u is not None and np.isfinite(u).all():
            if self.dof == 6:
                self.ref.reset(u[:6])
                self._y[6:12] = u[:6]
            else:
                self.ref.reset([u[2]])
                self._y[3] = u[2]
                self._joy_heading = float(u[2])
            self._started = True
        return self.output()

    def output(self) -> np.ndarray:
        return self._y.copy()

    def _full_inputs(self, u: np.ndarray, strict: bool = True) -> np.ndarray | None:
        """Inputs aligned with the interface; the pre-joystick prefix is accepted (start values added)."""
        n = len(self._in_names)
        if u.shape == (n,):
            return u
        if u.shape == (self._n_legacy_in,):
            return np.concatenate([u, self._in_start[self._n_legacy_in:]])
        if strict:
            raise ValueError(f"controller: expected {n} inputs, got {u.shape}")
        return None

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        u = self._full_inputs(np.asarray(u, dtype=float))
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(self._in_names, u.tolist(), strict=True) if not math.isfinite(v)]
            raise ValueError(f"controller: input '{bad[0]}' is not finite")
        key = self._mode_key()
        switched = key != self._active
        y = self._step6(h, u, switched) if self.dof == 6 else self._step3(h, u, switched)
        self._active = key
        self._stepped = True
        self._y = y
        return y.copy()

    def _blend(self, switched: bool, h: float, tau_new: np.ndarray) -> None:
        """Bumpless transfer: at a switch, offset = last output - new law's output, then it decays."""
        if switched and self._stepped and self._blend_time > 0.0:
            self._offset = self._y[: self.dof] - tau_new
        elif self._blend_time > 0.0 and self._offset.any():
            self._offset *= math.exp(-h / self._blend_time)
            if np.abs(self._offset).max() < 1e-9:  # gone: skip the arithmetic from now on
                self._offset[:] = 0.0
        else:
            self._offset[:] = 0.0

    def _integrate(self, h: float, e: np.ndarray, tau_unsat: np.ndarray, tau: np.ndarray,
                   Jt: np.ndarray | None) -> None:
        """Conditional integration + clamping (anti-windup).

        While a body DOF saturates, the error components coupled to it (|J^T| > 0.1) are not
        integrated, with one exception: unwinding, i.e. the integral force already pushes into
        that saturation and the increment reduces it (otherwise an integral that saturates the
        output could never come back). Integrating in the other direction is blocked too: during a
        saturated transient the error is large for reasons the integral cannot fix (the vessel is
        at full thrust), and what it stores there becomes overshoot later. The integral force
        K_i z is also clamped to the saturation level of its DOF.
        """
        dz = h * e
        over = tau_unsat - tau  # non-zero only where saturated; sign = direction of the excess
        if over.any():
            sat = over != 0.0
            sig = np.sign(over[sat])[:, None]
            if Jt is None:
                coupling = np.ones((1, 1))
            else:
                coupling = Jt[sat]
            # Body effect of each NED component: d tau_j = -(J^T)_ji K_i,i dz_i (same for z_i).
            effect = -(coupling * (self.ki * dz)) * sig
            current = -(coupling * (self.ki * self.z)) * sig
            unwinding = (effect < 0.0) & (current > 0.0)
            blocked = ((np.abs(coupling) > 0.1) & ~unwinding).any(axis=0)
            dz[blocked] = 0.0
        z = self.z + dz
        self.z = np.minimum(np.maximum(z, -self._z_max), self._z_max)

    # -- 6 DOF ---------------------------------------------------------------------------------
    def _start_guidance(self) -> None:
        """Waypoint mode engaged: path from the current reference point through the waypoints."""
        p = self.params
        text = str(p["waypoints"])
        if text.strip():
            wps = parse_waypoints(text)
        else:
            wps = lawnmower(int(float(p["lm_lines"])), float(p["lm_spacing"]), float(p["lm_length"]),
                            float(p["lm_heading"]), (float(p["lm_north"]), float(p["lm_east"])),
                            int(float(p["lm_side"])))
        self.guidance = PathGuidance(float(p["guide_speed"]), float(p["guide_accel"]),
                                     float(p["guide_acceptance"]), float(p["guide_yaw_rate"]),
                                     yaw_mode=int(float(p["guide_yaw_mode"])))
        self.guidance.start(wps, self.ref.x[:2], float(self.ref.x[5]), float(self.ref.v[5]))

    def _latch_setpoints(self, dofs: np.ndarray) -> None:
        """Newly held DOFs hold where the vessel glides to a stop, not the old ``<eta>_ref``.

        A DOF whose reference did not come from ``<eta>_ref`` in the previous mode (free, or
        guided) and does now gets the setpoint x0 + v0 / omega_ref: from (x0, v0) the critically
        damped reference model then approaches it monotonically, with the vessel's velocity at
        the start (no reversing). The latch holds until the operator changes that ``<eta>_ref``.
        """
        if not dofs.any():
            return
        target = self.ref.x + self.ref.v / self.ref.omega
        ai = self._angle_idx
        target[ai] = (target[ai] + math.pi) % (2.0 * math.pi) - math.pi
        self._latch = np.where(dofs, target, self._latch)
        self._latch_any = bool(np.isfinite(self._latch).any())

    def _latched(self, eta_ref: np.ndarray) -> np.ndarray:
        """``<eta>_ref`` with latched setpoints; a changed input releases its latch."""
        changed = eta_ref != self._ref_seen
        if changed.any():
            self._latch[changed] = np.nan
            self._latch_any = bool(np.isfinite(self._latch).any())
        latch = self._latch
        return np.where(np.isfinite(latch), latch, eta_ref)

    def _feedforward(self, eta: np.ndarray, eta_d_dot: np.ndarray, eta_d_dd: np.ndarray) -> np.ndarray:
        """M nu_d_dot + C(nu_d) nu_d + D(nu_d) nu_d in the body, nu_d from the NED reference.

        nu_d = J^-1 eta_d_dot (J^-1 = diag(R^T, T^-1), written out); nu_d_dot = J^-1 eta_d_dd minus
        omega_d x v_d in the linear part (the body turns under a velocity fixed in NED; small
        roll and pitch). C(nu) nu = [w x a; v x a + w x b] with [a; b] = M nu (Fossen's m2c) holds
        the Munk moments of the anisotropic added mass.
        """
        R = rzyx(eta[3], eta[4], eta[5])
        cphi, sphi = math.cos(eta[3]), math.sin(eta[3])
        cth, sth = math.cos(eta[4]), math.sin(eta[4])
        Tinv = np.array([[1.0, 0.0, -sth], [0.0, cphi, cth * sphi], [0.0, -sphi, cth * cphi]])
        nu_d = np.concatenate([R.T @ eta_d_dot[:3], Tinv @ eta_d_dot[3:]])
        nu_dd = np.concatenate([R.T @ eta_d_dd[:3], Tinv @ eta_d_dd[3:]])
        v1, w1 = nu_d[:3].tolist(), nu_d[3:].tolist()
        nu_dd[:3] -= _cross(w1, v1)
        ab = (self._M @ nu_d).tolist()
        a, b = ab[:3], ab[3:]
        cor = _cross(w1, a) + [x + y for x, y in zip(_cross(v1, a), _cross(w1, b), strict=True)]
        vs = self.vessel
        return self._M @ nu_dd + np.array(cor) + vs.D_L @ nu_d + vs.D_Q @ (np.abs(nu_d) * nu_d)

    def _step6(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        eta, nu, eta_ref = u[:6], u[6:12], u[12:18]
        if not self._started:
            self.ref.reset(eta)  # bumpless start from the current estimate
            self._started = True
        mode = self.mode
        if switched and self._stepped:
            self._latch_setpoints(FROM_INPUT[mode] & ~FROM_INPUT[self._active[0]])
        if switched and mode == MODE_WAYPOINT:
            self._start_guidance()
        if self._latch_any:
            eta_ref = self._latched(eta_ref)
        free = FREE[mode]
        any_free = mode in ANY_FREE
        Jm = J(eta)
        Jt = Jm.T
        eta_dot = Jm @ nu
        eta_d, eta_d_dot, eta_d_dd = self.ref.step(h, eta_ref)
        y = np.zeros(self._n_out)
        if mode == MODE_WAYPOINT or any_free:
            eta_d, eta_d_dot, eta_d_dd = eta_d.copy(), eta_d_dot.copy(), eta_d_dd.copy()
            if mode == MODE_WAYPOINT and self.guidance is not None:
                g = self.guidance.step(h, eta[:2], float(eta_ref[5]))
                eta_d[GUIDED] = [g.pos[0], g.pos[1], g.yaw]
                eta_d_dot[GUIDED] = [g.vel[0], g.vel[1], g.yaw_rate]
                eta_d_dd[GUIDED] = [g.acc[0], g.acc[1], g.yaw_acc]
                y[12:16] = [g.cross_track, g.corner_error, g.leg, g.speed]
            if any_free:
                # A free DOF's reference follows the vessel: engaging it later starts from here.
                eta_d[free], eta_d_dot[free], eta_d_dd[free] = eta[free], eta_dot[free], 0.0
            self.ref.x, self.ref.v, self.ref.a = eta_d.copy(), eta_d_dot.copy(), eta_d_dd.copy()
        if self.guidance is not None and mode != MODE_WAYPOINT:
            y[13] = self.guidance.corner_error
        e = eta - eta_d
        ai = self._angle_idx
        e[ai] = (e[ai] + math.pi) % (2.0 * math.pi) - math.pi
        edot = eta_dot - eta_d_dot
        tau_new = -(Jt @ (self.kp * e + self.kd * edot + self.ki * self.z))
        if mode == MODE_WAYPOINT and self._ff_gain > 0.0:
            tau_new += self._ff_gain * self._feedforward(eta, eta_d_dot, eta_d_dd)
        if any_free:
            joy = np.clip(u[18:22], -1.0, 1.0)
            for k, (ti, di) in enumerate(zip(JOY6_TAU, JOY6_DOF, strict=True)):
                if free[di]:
                    tau_new[ti] += joy[k] * self._joy_max[k]
        self._blend(switched, h, tau_new)
        tau_unsat = tau_new + self._offset if self._offset.any() else tau_new
        tau = np.minimum(np.maximum(tau_unsat, -self.tau_max), self.tau_max)
        self._integrate(h, e, tau_unsat, tau, Jt)  # e = 0 on free DOFs: their integral is held
        self._ref_seen = u[12:18].copy()
        y[:6] = tau
        y[6:12] = eta_d
        return y

    # -- 3 DOF (AMV) ---------------------------------------------------------------------------
    def land_screws(self, x: float, y: float, slider: float) -> tuple[float, float]:
        """Thesis land joystick: n1 = S x (0.9 + 0.05 y), n2 = S x (0.9 - 0.05 y), S = scale * slider."""
        s = float(self.params["land_n_scale"]) * slider
        return s * x * (0.9 + 0.05 * y), s * x * (0.9 - 0.05 * y)

    def _step3(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        yaw, uu, vv, r, yaw_ref, surge = u[2], u[3], u[4], u[5], u[6], u[7]
        jx, jy = (min(max(float(c), -1.0), 1.0) for c in u[8:10])
        slider = min(max(float(u[10]), 0.0), 1.0)
        buttons = int(u[11]) if u[11] >= 0.0 else 0
        if not self._started:
            self.ref.reset([yaw])
            self._joy_heading = float(yaw)
            self._started = True
        out = np.zeros(self._n_out)
        if self.land:
            n1, n2 = self.land_screws(jx, jy, slider)
            thrust = speed_to_thrust(self.vessel.thrusters, np.array([n1, n2]))
            tau_x, tau_n = (float(c) for c in self._B_xn @ thrust)
            # The heading loop idles on the vessel: back in water it starts from here (bumpless).
            self.ref.reset([yaw], [r])
            self._joy_heading = float(yaw)  # a centred stick back in water holds the heading it has
            e = np.zeros(1)
            yaw_d, rd = float(yaw), float(r)
            tau_new = np.array([tau_x, 0.0, tau_n])
            out[6:9] = [n1, n2, float(buttons & LAND_SIDEWAYS_BIT)]
        else:
            if switched and self._stepped and self._active[0] == 1 and not self.joystick:
                # Back from land: hold the heading (course) it glides to until yaw_ref changes.
                chi = yaw + (math.atan2(vv, uu) if self.course_mode and math.hypot(uu, vv) > BETA_MIN_SPEED
                             else 0.0)
                self._latch[0] = wrap_angle(chi + r / float(self.ref.omega[0]))
                self._latch_any = True
            if self._latch_any:
                yaw_ref = float(self._latched(np.array([yaw_ref]))[0])
            if self.joystick:  # stick angle = desired heading, slider = surge force
                if math.hypot(jx, jy) > float(self.params["joy_deadband"]):
                    self._joy_heading = math.atan2(jy, jx)
                yaw_ref = self._joy_heading
                surge = slider * float(self.params["joy_surge_max"])
            if self.course_mode and math.hypot(uu, vv) > BETA_MIN_SPEED:
                yaw_ref = yaw_ref - math.atan2(vv, uu)  # psi_d = chi_d - beta
            yd, r_d, a_d = self.ref.step(h, [yaw_ref])
            yaw_d, rd, ad = float(yd[0]), float(r_d[0]), float(a_d[0])
            e = np.array([wrap_angle(yaw - yaw_d)])
            if self.backstepping:
                k1, k2 = float(self.params["bs_k1"]), float(self.params["bs_k2"])
                z1 = float(e[0])
                z2 = r - (rd - k1 * z1)
                alpha1_dot = ad - k1 * (r - rd)
                tau_n = (self._m66 * alpha1_dot + self._dl66 * r + self._dq66 * abs(r) * r - z1 - k2 * z2
                         - float(self.ki[0] * self.z[0]))
            else:
                ff = self._m66 * ad + self._dl66 * rd + self._dq66 * abs(rd) * rd
                tau_n = float(ff - self.kp[0] * e[0] - self.kd[0] * (r - rd) - self.ki[0] * self.z[0])
            tau_new = np.array([surge, 0.0, tau_n])
        if self.land:
            # No blending into land mode: the screws are the operator's direct command there, and
            # a decaying screw difference (e.g. the water crab's 8.8 N.m) would turn the vessel.
            self._offset[:] = 0.0
        else:
            self._blend(switched, h, tau_new)
        tau_unsat = tau_new + self._offset
        tau_n_sat = min(max(float(tau_unsat[2]), -float(self.tau_max[0])), float(self.tau_max[0]))
        if not self.land:
            self._integrate(h, e, np.array([tau_unsat[2]]), np.array([tau_n_sat]), None)
        speed = math.hypot(uu, vv)
        radius = speed / abs(r) if abs(r) > speed / TURN_RADIUS_MAX else TURN_RADIUS_MAX
        out[:6] = [float(tau_unsat[0]), 0.0, tau_n_sat, yaw_d, rd, radius]
        self._ref_seen = u[6:7].copy()
        return out
