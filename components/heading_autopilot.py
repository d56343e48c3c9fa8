"""Controller variant ``heading_autopilot``: heading/course autopilot with open-loop surge (AMV OSF).

The thesis's water controller: heading autopilot on yaw only, open-loop surge force from the
throttle (two fixed screws cannot make sway); ``autopilot`` 0 = PID with yaw-rate feed-forward,

    tau_N = m66 r_d_dot + d(r_d) - K_p psi_tilde - K_d (r - r_d) - K_i int psi_tilde dt

``autopilot`` 1 = linear backstepping (thesis gains k1 = 8, k2 = 4) with integral action,

    z1 = psi_tilde,  alpha1 = r_d - k1 z1,  z2 = r - alpha1
    tau_N = m66 (r_d_dot - k1 (r - r_d)) + d(r) - z1 - k2 z2 - K_i,bs int z1 dt

(V = z1^2/2 + m66 z2^2/2 gives V_dot = -k1 z1^2 - k2 z2^2 without disturbance), where
m66 = I_z + A66 (the thesis printed I_z - A66: erratum), d(r) = D_L66 r + D_Q66 |r| r. Default
gains and reference model are the vessel file's ``gnc.tuning`` (AMV: the thesis's published ones).

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

from .allocation import FORCE_UNIT, thrust_capability
from .block import Interface, Signal
from .controller import BETA_MIN_SPEED, ControllerBlock
from .dynamics import wrap_angle
from .thrusters import speed_to_thrust, thruster_matrix
from .vessel_spec import VesselSpec, state_unit

TURN_RADIUS_MAX = 1000.0  # m: turn_radius output when (nearly) straight
LAND_SIDEWAYS_BIT = 1  # joy_buttons bit 0: sideways mode while held (land); other bits are unassigned
# Defaults when a vessel file gives no gnc.tuning: the AMV thesis's published numbers.
DEFAULT_TUNING = {"kp": 5.0, "kd": 50.0, "ki": 1.5, "ref_omega": 0.5, "ref_zeta": 1.0, "bs_k1": 8.0,
                  "bs_k2": 4.0, "bs_ki": 1.5}


class HeadingAutopilot(ControllerBlock):
    """Heading (course) autopilot with open-loop surge, water joystick and land mode."""

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        # Long because it lists every signal and parameter in FMU order; no logic to split out.
        tun = {**DEFAULT_TUNING, **(vessel.gnc.tuning if vessel.gnc is not None else {})}
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
        i_n = vessel.tau_names.index("N")
        params = [
            Signal("kp", "N.m/rad", "proportional gain", min=0.0, start=float(tun["kp"]), tunable=True),
            Signal("kd", "N.m.s/rad", "derivative gain", min=0.0, start=float(tun["kd"]), tunable=True),
            Signal("ki", "N.m/(rad.s)", "integral gain", min=0.0, start=float(tun["ki"]), tunable=True),
            *cls._ref_params(omega=float(tun["ref_omega"]), zeta=float(tun["ref_zeta"])),
            Signal("course_mode", "", "0: yaw_ref is a heading; 1: a course (crab angle compensated)",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("tau_max_N", "N.m", "yaw moment saturation for anti-windup (default: both screws at "
                   "n_max in opposition)", min=0.0, start=float(round(cap[i_n], 3)), tunable=True),
            Signal("autopilot", "", "0 = PID with yaw-rate feed-forward, 1 = linear backstepping",
                   min=0, max=1, start=0, type="integer", tunable=True),
            Signal("bs_k1", "1/s", "backstepping gain k1", min=0.0, start=float(tun["bs_k1"]), tunable=True),
            Signal("bs_k2", "N.m.s/rad", "backstepping gain k2", min=0.0, start=float(tun["bs_k2"]),
                   tunable=True),
            Signal("bs_ki", "N.m/(rad.s)", "backstepping integral gain (removes the steady moment of a "
                   "current or crab; 0 = pure backstepping)", min=0.0, start=float(tun["bs_ki"]),
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
            cls._variant_param(vessel),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    # -- set-up --------------------------------------------------------------------------------
    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        self._setup(vessel, n_ref=1, ref_angles=[True])
        used = ("yaw_hat", "u_hat", "v_hat", "r_hat", "yaw_ref", "surge_force_ref", "joy_x", "joy_y",
                "joy_slider", "joy_buttons")
        self._iu = [self.inp[n] for n in used]
        self._i_yaw_ref = self.inp["yaw_ref"]
        out = self.out
        self._o_yaw_d = out["yaw_d"]
        self._o_ref = out.at(["yaw_d", "r_d", "turn_radius"])
        self._o_land = out.at(["n_joy_1", "n_joy_2", "sideways"])
        tn, nu = vessel.tau_names, vessel.nu_names
        self._iX, self._iY, self._iN = tn.index("X"), tn.index("Y"), tn.index("N")  # in tau (d values)
        self._oY, self._oN = out["tau_Y"], out["tau_N"]
        ir = nu.index("r")
        self._m66 = float(self._M[ir, ir])  # yaw inertia I_z + A66 (erratum: not I_z - A66)
        self._dl66 = float(vessel.D_L[ir, ir])
        self._dq66 = float(vessel.D_Q[ir, ir])
        self._joy_heading = 0.0  # water joystick: heading held while the stick is centred
        B = thruster_matrix(vessel.thrusters, vessel.dof)
        self._B_xn = B[[self._iX, self._iN], :]  # tau_X, tau_N of the thrusts (what the allocator inverts)
        self._check_all()

    def _check(self, name: str, value: Any) -> None:
        super()._check(name, value)
        if name == "land_mode" and float(value) == 1 and self.vessel.thrusters.count != 2:
            raise ValueError(f"controller: parameter 'land_mode': the land joystick drives two screws, "
                             f"vessel '{self.vessel.name}' has {self.vessel.thrusters.count} thrusters")

    def _apply_params(self) -> None:
        p = self.params
        self.kp = np.array([float(p["kp"])])
        self.kd = np.array([float(p["kd"])])
        self.ki = np.array([float(p["bs_ki"] if int(float(p["autopilot"])) == 1 else p["ki"])])
        self.tau_max = np.array([float(p["tau_max_N"])])
        self.course_mode = int(float(p["course_mode"])) == 1
        self.backstepping = int(float(p["autopilot"])) == 1
        self.land = int(float(p["land_mode"])) == 1
        self.joystick = int(float(p["joystick"])) == 1
        self._set_limits(self.tau_max, [math.inf])

    def _mode_key(self) -> tuple[int, ...]:
        return (int(self.land), int(self.backstepping), int(self.joystick))

    def _start_law(self, u: np.ndarray) -> None:
        yaw = u[self._iu[0]]
        self.ref.reset([yaw])
        self._y[self._o_yaw_d] = yaw
        self._joy_heading = float(yaw)

    def land_screws(self, x: float, y: float, slider: float) -> tuple[float, float]:
        """Thesis land joystick: n1 = S x (0.9 + 0.05 y), n2 = S x (0.9 - 0.05 y), S = scale * slider."""
        s = float(self.params["land_n_scale"]) * slider
        return s * x * (0.9 + 0.05 * y), s * x * (0.9 - 0.05 * y)

    # -- the law -------------------------------------------------------------------------------
    def _step_law(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        # Long because land and water modes share the blending, saturation and outputs; the two
        # halves are commented where they part.
        yaw, uu, vv, r, yaw_ref, surge, jx, jy, sl, bt = (u[i] for i in self._iu)
        jx, jy = (min(max(float(c), -1.0), 1.0) for c in (jx, jy))
        slider = min(max(float(sl), 0.0), 1.0)
        buttons = int(bt) if bt >= 0.0 else 0
        if not self._started:
            self.ref.reset([yaw])
            self._joy_heading = float(yaw)
            self._started = True
        d = self.dof
        out = np.zeros(self._n_out)
        tau_new = np.zeros(d)
        if self.land:
            n1, n2 = self.land_screws(jx, jy, slider)
            thrust = speed_to_thrust(self.vessel.thrusters, np.array([n1, n2]))
            tau_x, tau_n = (float(c) for c in self._B_xn @ thrust)
            # The heading loop idles on the vessel: back in water it starts from here (bumpless).
            self.ref.reset([yaw], [r])
            self._joy_heading = float(yaw)  # a centred stick back in water holds the heading it has
            e = np.zeros(1)
            yaw_d, rd = float(yaw), float(r)
            tau_new[self._iX], tau_new[self._iN] = tau_x, tau_n
            out[self._o_land] = [n1, n2, float(buttons & LAND_SIDEWAYS_BIT)]
        else:  # water: heading autopilot, open-loop surge
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
            tau_new[self._iX], tau_new[self._iN] = surge, tau_n
        if self.land:
            # No blending into land mode: the screws are the operator's direct command there, and
            # a decaying screw difference (e.g. the water crab's 8.8 N.m) would turn the vessel.
            self._offset[:] = 0.0
        else:
            self._blend(switched, h, tau_new)
        tau_unsat = tau_new + self._offset
        iN = self._iN
        tau_n_sat = min(max(float(tau_unsat[iN]), -float(self.tau_max[0])), float(self.tau_max[0]))
        if not self.land:
            self._integrate(h, e, np.array([tau_unsat[iN]]), np.array([tau_n_sat]), None)
        speed = math.hypot(uu, vv)
        radius = speed / abs(r) if abs(r) > speed / TURN_RADIUS_MAX else TURN_RADIUS_MAX
        out[self._o_tau] = tau_unsat
        out[self._oY] = 0.0  # no sway demand: two fixed screws cannot make it
        out[self._oN] = tau_n_sat
        out[self._o_ref] = [yaw_d, rd, radius]
        self._ref_seen = np.array([u[self._i_yaw_ref]])
        return out
