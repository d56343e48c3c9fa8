"""Controller variant ``dp_pid``: nonlinear PID dynamic positioning with operating modes, 3 or 6 DOF.

Fossen 2021, sec. 12.2 (the Minerva 2 thesis's controller; the usual DP controller of a ship):

    tau = -J(eta)^T (K_p eta_tilde + K_d (J(eta) nu - eta_d_dot) + K_i int eta_tilde dt)
          [+ M nu_d_dot + C(nu_d) nu_d + D(nu_d) nu_d  in waypoint mode]  [+ joystick forces]
    eta_tilde = eta_hat - eta_d   (angles wrapped),  eta_d from a 2nd-order reference model

The PID acts in NED (where a current or the net buoyancy is constant) and J^T maps it to the
body: J = diag(R(Theta), T(Theta)) for 6 DOF, R(psi) for 3 DOF (north, east, yaw). Default gains
come from pole placement per DOF on the diagonal of M with the vessel file's design data
(``gnc.tuning``: bandwidth ``omega`` per DOF, ``zeta``, ``integral_ratio``; see
``pid_pole_placement`` and docs/gnc.md); anti-windup stops integration of the error components
that push an already saturated body DOF further out and clamps the integral force.

Modes (parameter ``mode``, tunable; the Minerva 2 thesis's five operating modes):
0 DP (every DOF held at ``<eta>_ref``); 1 waypoint tracking (the vessel file's guidance variant,
``gnc.guidance``: north, east and heading from a reference point running along a lawnmower or a
waypoint list, model feed-forward of its acceleration and velocity); 2 auto-depth; 3
auto-heading; 4 joystick; 5 auto-depth + auto-heading. Roll and pitch (where the vessel has them)
are held in every mode (the thrusters' moments excite them; a pilot has no roll/pitch stick). A
DOF that is not held is "free": its PID terms are off, the body force of its joystick axis
(``joy_surge`` ...) acts, its reference model follows the estimate (position and velocity), and
its integral force stays applied as a trim (current, net buoyancy). For a 3-DOF vessel
auto-depth holds nothing (it has no depth) and is the joystick mode. Switching is bumpless: a
newly held DOF starts its reference at the vessel's position and velocity, and the difference
between the last output and the new mode's first output is added and decays with
``mode_blend_time``, so tau is continuous.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import numpy as np

from . import kernels, registry
from .allocation import FORCE_UNIT, thrust_capability
from .block import Interface, Signal
from .controller import ControllerBlock, restoring_stiffness
from .dynamics import coriolis_force, rpsi, rzyx, tzyx_inv
from .guidance import MAX_LINES, PathGuidance, lawnmower, parse_waypoints
from .vessel_spec import VesselSpec, state_unit

# Default design data (Minerva 2's, docs/gnc.md); a vessel file's gnc.tuning overrides each.
DESIGN_OMEGA = {"north": 0.5, "east": 0.5, "down": 0.5, "yaw": 0.6}  # rad/s, closed-loop bandwidth
DESIGN_OMEGA_MIN_ATTITUDE = 0.5
DESIGN_ATTITUDE_FACTOR = 1.5
DESIGN_ZETA = 1.0
DESIGN_INTEGRAL_RATIO = 10.0  # K_i = K_p omega / ratio
DESIGN_REF_OMEGA = 0.2
DESIGN_REF_ZETA = 1.0


def _tuning(vessel: VesselSpec) -> dict[str, Any]:
    return dict(vessel.gnc.tuning) if vessel.gnc is not None else {}


def pid_pole_placement(vessel: VesselSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Default (K_p, K_d, K_i, omega_n) per DOF from a decoupled linear model of each DOF.

    m x_dd + (d + K_d) x_d + (g + K_p) x + K_i int x = 0 with m = M_jj, d = D_L_jj, g = hydrostatic
    stiffness: K_p = m w^2 - g, K_d = 2 zeta w m - d, K_i = K_p w / ratio (default ratio 10: the
    integrator a decade below the bandwidth, so it removes offsets without eroding the phase
    margin). w per DOF is the vessel file's ``gnc.tuning.omega``. Roll and pitch use
    w = max(omega_min_attitude, attitude_factor x their hydrostatic frequency sqrt(g/m)): the
    metacentric height alone is too soft for the Munk moments of a depth change through a current
    (Minerva 2: about 80 N.m at 0.15 m/s heave in 0.1 m/s current, 0.05 rad of roll); 1.5 x gives
    2.25 x the stiffness and stays well inside the thrusters' roll/pitch capacity and their lag.
    """
    tuning = _tuning(vessel)
    design = {**DESIGN_OMEGA, **(tuning.get("omega") or {})}
    w_min = float(tuning.get("omega_min_attitude", DESIGN_OMEGA_MIN_ATTITUDE))
    factor = float(tuning.get("attitude_factor", DESIGN_ATTITUDE_FACTOR))
    zeta = float(tuning.get("zeta", DESIGN_ZETA))
    ratio = float(tuning.get("integral_ratio", DESIGN_INTEGRAL_RATIO))
    M = 0.5 * (vessel.M + vessel.M.T)
    m = np.diag(M)
    d = np.diag(vessel.D_L)
    g = restoring_stiffness(vessel)
    omega = np.zeros(vessel.dof)
    for j, name in enumerate(vessel.eta_names):
        if name in ("roll", "pitch"):
            hydrostatic = math.sqrt(max(g[j], 0.0) / m[j])
            omega[j] = max(w_min, factor * hydrostatic)
        else:
            omega[j] = float(design[name])
    kp = np.maximum(m * omega**2 - g, 0.0)
    kd = np.maximum(2.0 * zeta * omega * m - d, 0.0)
    ki = kp * omega / ratio
    return kp, kd, ki, omega


# -- operating modes ------------------------------------------------------------------------------

MODE_DP, MODE_WAYPOINT, MODE_DEPTH, MODE_HEADING, MODE_JOYSTICK, MODE_DEPTH_HEADING = range(6)
MODE_NAMES = ("DP", "waypoint tracking", "auto-depth", "auto-heading", "joystick",
              "auto-depth + auto-heading")
ALL = ("north", "east", "down", "roll", "pitch", "yaw")
# Held NED DOFs per mode, by name; roll and pitch are always held (a vessel without them: none).
HELD_NAMES = {
    MODE_DP: ALL,
    MODE_WAYPOINT: ALL,
    MODE_DEPTH: ("down", "roll", "pitch"),
    MODE_HEADING: ("roll", "pitch", "yaw"),
    MODE_JOYSTICK: ("roll", "pitch"),
    MODE_DEPTH_HEADING: ("down", "roll", "pitch", "yaw"),
}
GUIDED_NAMES = ("north", "east", "yaw")  # come from the guidance in waypoint mode
# Joystick axes: (axis, body tau, the NED DOF that must be free for the axis to act).
JOY_AXES = (("surge", "X", "north"), ("sway", "Y", "east"), ("heave", "Z", "down"), ("yaw", "N", "yaw"))
JOY_DEFAULT_FRACTION = 0.5  # full stick = half the pure-DOF capability: headroom for roll/pitch hold


def gain_unit(gain: str, dof: str) -> str:
    """The unit of a PID gain on one DOF: force (N, or N.m on an angle) per error (m or rad), per error
    rate (kd) or per integrated error (ki)."""
    force, error = ("N.m", "rad") if dof in ("roll", "pitch", "yaw") else ("N", "m")
    return {"kp": f"{force}/{error}", "kd": f"{force}.s/{error}", "ki": f"{force}/({error}.s)"}[gain]


class ModeTables(NamedTuple):
    """Per mode, for one set of eta names: free DOFs, DOFs from the setpoint inputs."""

    free: dict[int, np.ndarray]
    any_free: frozenset[int]
    from_input: dict[int, np.ndarray]
    guided: list[int]
    joy_axes: tuple[tuple[str, str, str], ...]  # the axes this vessel has
    joy_tau: tuple[int, ...]
    joy_dof: tuple[int, ...]


@functools.lru_cache(maxsize=8)
def mode_tables(eta_names: tuple[str, ...], tau_names: tuple[str, ...]) -> ModeTables:
    """The mode tables for a vessel's DOFs (shared, never mutated)."""
    held = {m: np.array([n in names for n in eta_names], dtype=bool) for m, names in HELD_NAMES.items()}
    free = {m: ~h for m, h in held.items()}
    from_input = {m: h.copy() for m, h in held.items()}
    guided = [eta_names.index(n) for n in GUIDED_NAMES]
    from_input[MODE_WAYPOINT][guided] = False
    axes = tuple(a for a in JOY_AXES if a[1] in tau_names and a[2] in eta_names)
    return ModeTables(free=free, any_free=frozenset(m for m, f in free.items() if f.any()),
                      from_input=from_input, guided=guided, joy_axes=axes,
                      joy_tau=tuple(tau_names.index(a[1]) for a in axes),
                      joy_dof=tuple(eta_names.index(a[2]) for a in axes))


def _cross(a: list[float], b: list[float]) -> list[float]:
    """a x b on 3-lists (a NumPy call costs more than the arithmetic here)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _tables(vessel: VesselSpec) -> ModeTables:
    return mode_tables(tuple(vessel.eta_names), tuple(vessel.tau_names))


class DPPidController(ControllerBlock):
    """DP / waypoint / auto-depth / auto-heading / joystick with a nonlinear PID (3 or 6 DOF)."""

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        # Long because it lists every signal and parameter with its metadata (the FMU variables and
        # the checks of Block); there is no logic to split out.
        eta, nu, tn = vessel.eta_names, vessel.nu_names, vessel.tau_names
        axes = _tables(vessel).joy_axes
        inputs = [Signal(f"{n}_hat", state_unit(n), f"estimated {n}") for n in eta + nu]
        inputs += [Signal(f"{n}_ref", state_unit(n), f"setpoint {n}") for n in eta]
        inputs += [Signal(f"joy_{a}", "", f"joystick {a} axis in [-1, 1] (body force; acts in the modes "
                          "where that DOF is free)", min=-1.0, max=1.0) for a, _, _ in axes]
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
        zeta = float(_tuning(vessel).get("zeta", DESIGN_ZETA))
        cap = thrust_capability(vessel)
        params: list[Signal] = []
        for g, vals, what in (("kp", kp, "proportional"), ("kd", kd, "derivative"), ("ki", ki, "integral")):
            for n, v in zip(eta, vals, strict=True):
                params.append(Signal(f"{g}_{n}", gain_unit(g, n),
                                     f"{what} gain {n} (default: pole placement, "
                                     f"omega_n = {omega[eta.index(n)]:.3g} rad/s, zeta = {zeta:g})",
                                     min=0.0, start=float(round(v, 6)), tunable=True))
        tuning = _tuning(vessel)
        params += cls._ref_params(omega=float(tuning.get("ref_omega", DESIGN_REF_OMEGA)),
                                  zeta=float(tuning.get("ref_zeta", DESIGN_REF_ZETA)))
        params.append(Signal("ref_v_max", "m/s", "reference-model speed limit, translations (0 = none)",
                             min=0.0, start=0.0, tunable=True))
        params.append(Signal("ref_rate_max", "rad/s", "reference-model rate limit, angles (0 = none)",
                             min=0.0, start=0.0, tunable=True))
        for t, c in zip(tn, cap, strict=True):
            params.append(Signal(f"tau_max_{t}", FORCE_UNIT[t], f"saturation of tau_{t} for anti-windup "
                                 "(default: pure-DOF thruster capability through the allocator)",
                                 min=0.0, start=float(round(c, 3)), tunable=True))
        params.append(Signal("mode", "", "0 = DP, 1 = waypoint tracking, 2 = auto-depth, 3 = auto-heading, "
                             "4 = joystick, 5 = auto-depth + auto-heading (roll/pitch held in all)",
                             min=0, max=5, start=0, type="integer", tunable=True))
        for a, t, _ in axes:
            ti = tn.index(t)
            params.append(Signal(f"joy_max_{t}", FORCE_UNIT[t], f"force of a full joystick {a} deflection "
                                 "(default: half the pure-DOF capability)", min=0.0,
                                 start=float(round(JOY_DEFAULT_FRACTION * cap[ti], 3)), tunable=True))
        params += [
            Signal("waypoints", "", "waypoint list 'n1, e1; n2, e2; ...' (m); empty = the lawnmower below. "
                   "Read when waypoint mode is engaged", start="", type="string", tunable=True),
            Signal("lm_lines", "", "lawnmower: number of lines", min=1, max=MAX_LINES, start=6,
                   type="integer", tunable=True),
            Signal("lm_spacing", "m", "lawnmower: distance between lines", min=0.0, start=4.0, tunable=True),
            Signal("lm_length", "m", "lawnmower: length of a line", min=0.0, min_open=True, start=20.0,
                   tunable=True),
            Signal("lm_heading", "rad", "lawnmower: direction of the first line", start=0.0, tunable=True),
            Signal("lm_north", "m", "lawnmower: start of the first line, north", start=0.0, tunable=True),
            Signal("lm_east", "m", "lawnmower: start of the first line, east", start=0.0, tunable=True),
            Signal("lm_side", "", "lawnmower: 1 = next line to starboard, -1 = to port", min=-1, max=1,
                   start=1, type="integer", tunable=True, choices=(-1, 1)),
            Signal("guide_speed", "m/s", "guidance: speed limit of the reference point", min=0.0,
                   min_open=True, start=0.3, tunable=True),
            Signal("guide_accel", "m/s^2", "guidance: acceleration limit of the reference point", min=0.0,
                   min_open=True, start=0.05, tunable=True),
            Signal("guide_acceptance", "m", "guidance: radius of the circle of acceptance around a waypoint",
                   min=0.0, min_open=True, start=0.5, tunable=True),
            Signal("guide_yaw_mode", "", "guidance: 0 = heading along the leg, 1 = heading from yaw_ref",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("guide_yaw_rate", "rad/s", "guidance: heading rate limit at corners", min=0.0,
                   min_open=True, start=0.2, tunable=True),
            Signal("ff_gain", "", "waypoint mode: weight of the model feed-forward "
                   "M nu_d_dot + C nu_d + D nu_d (0 = PID only)", min=0.0, max=1.0, start=1.0, tunable=True),
            Signal("mode_blend_time", "s", "bumpless switching: time constant of the decaying output offset "
                   "(0 = none)", min=0.0, start=2.0, tunable=True),
            cls._variant_param(vessel),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    # -- set-up --------------------------------------------------------------------------------
    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        d = vessel.dof
        self._setup(vessel, n_ref=d, ref_angles=[n in ("roll", "pitch", "yaw") for n in vessel.eta_names])
        self._tab = _tables(vessel)
        eta, inp, out = vessel.eta_names, self.inp, self.out
        self._in_eta = inp.at(f"{n}_hat" for n in eta)
        self._in_nu = inp.at(f"{n}_hat" for n in vessel.nu_names)
        self._in_ref = inp.at(f"{n}_ref" for n in eta)
        self._in_joy = inp.at(f"joy_{a}" for a, _, _ in self._tab.joy_axes)
        self._o_eta_d = out.at(f"{n}_d" for n in eta)
        self._o_guid = out.at(["cross_track_error", "corner_error", "leg", "speed_d"])
        self._o_corner = out["corner_error"]
        self._guided = list(self._tab.guided)
        self._yaw = vessel.eta_names.index("yaw")
        self._coriolis = vessel.coriolis != "none"
        self._guidance_name = vessel.gnc.guidance if vessel.gnc is not None else "none"
        self.guidance: PathGuidance | None = None
        # the same positions as index arrays, for the compiled held step (kernels/control.dp_block_step)
        pos_in, pos_out = np.arange(len(inp)), np.arange(len(out))
        self._k_in = tuple(pos_in[s].astype(np.int64) for s in (self._in_eta, self._in_nu, self._in_ref))
        self._k_out = tuple(pos_out[s].astype(np.int64) for s in (self._o_tau, self._o_eta_d))
        self._check_all()

    def _apply_params(self) -> None:
        p = self.params
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
        self._joy_max = np.array([float(p[f"joy_max_{t}"]) for _, t, _ in self._tab.joy_axes])
        self._ff_gain = float(p["ff_gain"])
        self._set_limits(z_force_max, v_lim)

    def _check(self, name: str, value: Any) -> None:
        super()._check(name, value)
        if name == "mode" and float(value) == MODE_WAYPOINT and registry.guidance_class(
                self._guidance_name) is None:
            raise ValueError("controller: parameter 'mode': waypoint tracking needs a guidance variant; "
                             f"vessel '{self.vessel.name}' names none (gnc.guidance)")

    def _mode_key(self) -> tuple[int, ...]:
        return (self.mode,)

    def _start_law(self, u: np.ndarray) -> None:
        eta = u[self._in_eta]
        self.ref.reset(eta)
        self._y[self._o_eta_d] = eta

    # -- modes ---------------------------------------------------------------------------------
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
        cls = registry.guidance_class(self._guidance_name)
        self.guidance = cls(float(p["guide_speed"]), float(p["guide_accel"]),
                            float(p["guide_acceptance"]), float(p["guide_yaw_rate"]),
                            yaw_mode=int(float(p["guide_yaw_mode"])))
        y = self._yaw
        self.guidance.start(wps, self.ref.x[:2], float(self.ref.x[y]), float(self.ref.v[y]))

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

    def _feedforward(self, eta: np.ndarray, eta_d_dot: np.ndarray, eta_d_dd: np.ndarray) -> np.ndarray:
        """M nu_d_dot + C(nu_d) nu_d + D(nu_d) nu_d in the body, nu_d from the NED reference.

        nu_d = J^-1 eta_d_dot (J^-1 = diag(R^T, T^-1), written out); nu_d_dot = J^-1 eta_d_dd minus
        omega_d x v_d in the linear part (the body turns under a velocity fixed in NED; small
        roll and pitch). C(nu) nu = [w x a; v x a + w x b] with [a; b] = M nu (Fossen's m2c) holds
        the Munk moments of the anisotropic added mass (none for a vessel file with coriolis: none).
        """
        vs = self.vessel
        if self.dof == 3:
            Rt = rpsi(float(eta[2])).T
            nu_d, nu_dd = Rt @ eta_d_dot, Rt @ eta_d_dd
            r, u, v = float(nu_d[2]), float(nu_d[0]), float(nu_d[1])
            nu_dd[0] += r * v  # minus (0, 0, r) x (u, v, 0)
            nu_dd[1] -= r * u
            cor = coriolis_force(self._M, nu_d) if self._coriolis else 0.0
            return self._M @ nu_dd + cor + vs.D_L @ nu_d + vs.D_Q @ (np.abs(nu_d) * nu_d)
        R = rzyx(eta[3], eta[4], eta[5])
        Tinv = tzyx_inv(eta[3], eta[4])
        nu_d = np.concatenate([R.T @ eta_d_dot[:3], Tinv @ eta_d_dot[3:]])
        nu_dd = np.concatenate([R.T @ eta_d_dd[:3], Tinv @ eta_d_dd[3:]])
        v1, w1 = nu_d[:3].tolist(), nu_d[3:].tolist()
        nu_dd[:3] -= _cross(w1, v1)
        if self._coriolis:
            ab = (self._M @ nu_d).tolist()
            a, b = ab[:3], ab[3:]
            cor = np.array(_cross(w1, a) + [x + y for x, y in zip(_cross(v1, a), _cross(w1, b), strict=True)])
        else:
            cor = np.zeros(6)
        return self._M @ nu_dd + cor + vs.D_L @ nu_d + vs.D_Q @ (np.abs(nu_d) * nu_d)

    # -- the law -------------------------------------------------------------------------------
    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """The usual step (``_held_step``'s conditions, no switch) in one compiled call from the input
        vector to the output vector; anything else, and a bad input, through ``ControllerBlock.step``."""
        ref, mode = self.ref, self.mode
        if (type(u) is np.ndarray and u.shape == self._in_shape and u.dtype == np.float64
                and self._active is not None and self._active[0] == mode and self._started
                and not (self._latch_any or self._offset_on) and ref.exact and mode != MODE_WAYPOINT
                and mode not in self._tab.any_free):
            d = self.dof
            x, v, a, seen = np.empty(d), np.empty(d), np.empty(d), np.empty(d)
            y = np.zeros(self._n_out)
            w2, two_zw = ref.rates()
            in_eta, in_nu, in_ref = self._k_in
            o_tau, o_eta_d = self._k_out
            if kernels.control.dp_block_step(
                    u, in_eta, in_nu, in_ref, h, ref.x, ref.v, ref.coefficients(h), w2, two_zw, ref.angles,
                    x, v, a, self.z, self.kp, self.kd, self.ki, self._angle_mask, self.tau_max, self._z_max,
                    seen, o_tau, o_eta_d, y):
                ref.x, ref.v, ref.a = x, v, a
                self._ref_seen = seen
                if self.guidance is not None:
                    y[self._o_corner] = self.guidance.corner_error
                self._stepped = True
                self._y = y
                return y.copy()
        return super().step(t, h, u)

    def _held_step(self, h: float, u: np.ndarray, eta: np.ndarray, nu: np.ndarray,
                   eta_ref: np.ndarray) -> np.ndarray:
        """The usual step: every DOF held at its setpoint, no switch, no latch, no blend offset, an
        unlimited reference model. The general path's operations in one compiled call (reference
        model, PID, saturation and conditional integration; z in place)."""
        ref, d = self.ref, self.dof
        x, v, a, tau = np.empty(d), np.empty(d), np.empty(d), np.empty(d)
        w2, two_zw = ref.rates()
        kernels.control.dp_step(h, eta, nu, np.ascontiguousarray(eta_ref), ref.x, ref.v, ref.coefficients(h),
                                w2, two_zw, ref.angles, x, v, a, self.z, self.kp, self.kd, self.ki,
                                self._angle_mask, self.tau_max, self._z_max, tau)
        ref.x, ref.v, ref.a = x, v, a
        y = np.zeros(self._n_out)
        if self.guidance is not None:
            y[self._o_corner] = self.guidance.corner_error
        self._ref_seen = u[self._in_ref].copy()
        y[self._o_tau] = tau
        y[self._o_eta_d] = x
        return y

    def _step_law(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        tab = self._tab
        eta, nu, eta_ref = u[self._in_eta], u[self._in_nu], u[self._in_ref]
        if not self._started:
            self.ref.reset(eta)  # bumpless start from the current estimate
            self._started = True
        mode = self.mode
        if switched and self._stepped:
            self._latch_setpoints(tab.from_input[mode] & ~tab.from_input[self._active[0]])
        if switched and mode == MODE_WAYPOINT:
            self._start_guidance()
        if self._latch_any:
            eta_ref = self._latched(eta_ref)
        free = tab.free[mode]
        any_free = mode in tab.any_free
        if not (switched or any_free or mode == MODE_WAYPOINT or self._latch_any or self._offset_on) \
                and self.ref.exact:
            return self._held_step(h, u, eta, nu, eta_ref)
        d = self.dof
        Jm, eta_dot, e, tau_new = np.empty((d, d)), np.empty(d), np.empty(d), np.empty(d)
        eta_d, eta_d_dot, eta_d_dd = self.ref.step(h, eta_ref)
        y = np.zeros(self._n_out)
        if mode == MODE_WAYPOINT or any_free:
            kernels.control.eta_rate(eta, nu, Jm, eta_dot)
            eta_d, eta_d_dot, eta_d_dd = eta_d.copy(), eta_d_dot.copy(), eta_d_dd.copy()
            if mode == MODE_WAYPOINT and self.guidance is not None:
                g = self.guidance.step(h, eta[:2], float(eta_ref[self._yaw]))
                gi = self._guided
                eta_d[gi] = [g.pos[0], g.pos[1], g.yaw]
                eta_d_dot[gi] = [g.vel[0], g.vel[1], g.yaw_rate]
                eta_d_dd[gi] = [g.acc[0], g.acc[1], g.yaw_acc]
                y[self._o_guid] = [g.cross_track, g.corner_error, g.leg, g.speed]
            if any_free:
                # A free DOF's reference follows the vessel: engaging it later starts from here.
                eta_d[free], eta_d_dot[free], eta_d_dd[free] = eta[free], eta_dot[free], 0.0
            self.ref.x, self.ref.v, self.ref.a = eta_d.copy(), eta_d_dot.copy(), eta_d_dd.copy()
        if self.guidance is not None and mode != MODE_WAYPOINT:
            y[self._o_corner] = self.guidance.corner_error
        # J, eta_dot = J nu, e = eta - eta_d (angles wrapped), tau = -J^T (Kp e + Kd edot + Ki z), compiled
        kernels.control.pid_force(eta, nu, eta_d, eta_d_dot, self.z, self.kp, self.kd, self.ki,
                                  self._angle_mask, Jm, eta_dot, e, tau_new)
        if mode == MODE_WAYPOINT and self._ff_gain > 0.0:
            tau_new += self._ff_gain * self._feedforward(eta, eta_d_dot, eta_d_dd)
        if any_free:
            joy = np.clip(u[self._in_joy], -1.0, 1.0)
            for kk, (ti, di) in enumerate(zip(tab.joy_tau, tab.joy_dof, strict=True)):
                if free[di]:
                    tau_new[ti] += joy[kk] * self._joy_max[kk]
        self._blend(switched, h, tau_new)
        tau_unsat = tau_new + self._offset if self._offset.any() else tau_new
        # tau = clip(tau_unsat) and the conditional integration (ControllerBlock._integrate with
        # J^T = Jm.T), compiled; e = 0 on free DOFs: their integral is held
        tau = np.empty(d)
        kernels.control.saturate_integrate(h, e, tau_unsat, self.tau_max, self.ki, self.z, self._z_max, Jm,
                                           tau)
        self._ref_seen = u[self._in_ref].copy()
        y[self._o_tau] = tau
        y[self._o_eta_d] = eta_d
        return y
