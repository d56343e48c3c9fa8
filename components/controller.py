"""Motion controllers: 6-DOF nonlinear PID for DP (Minerva 2), heading autopilot (AMV OSF, 3 DOF).

6 DOF (Fossen 2011, sec. 12.2.6, the thesis's controller):

    tau = -J(eta)^T (K_p eta_tilde + K_d (J(eta) nu - eta_d_dot) + K_i int eta_tilde dt)
    eta_tilde = eta_hat - eta_d   (angles wrapped),  eta_d from a 2nd-order reference model

The PID acts in NED (where a current or the net buoyancy is constant) and J^T maps it to the
body. Default gains come from pole placement per DOF on the diagonal of M (see
``pid_pole_placement`` and docs/gnc.md); anti-windup stops integration of the error components
that push an already saturated body DOF further out and clamps the integral force.

3 DOF (AMV OSF, thesis): heading autopilot on yaw only, open-loop surge force from the throttle

    tau_N = m66 r_d_dot + d(r_d) - K_p psi_tilde - K_d (r - r_d) - K_i int psi_tilde dt
    m66 = I_z + A66 (the thesis printed I_z - A66: erratum), d(r) = D_L66 r + D_Q66 |r| r

In course mode the joystick angle is a desired course chi_d; the heading reference becomes
psi_d = chi_d - beta with the crab angle beta = atan2(v, u), and the integral removes what the
model of beta misses (current).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from components.allocation import FORCE_UNIT, thrust_capability
from components.block import Block, Interface, Signal
from components.kinematics import J, wrap_angle
from components.observer import state_unit
from components.reference_model import ReferenceModel
from components.vessel_spec import ANGLE_NAMES, VesselSpec

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


class ControllerBlock(Block):
    """DP nonlinear PID (6 DOF) or heading autopilot with open-loop surge (3 DOF)."""

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
        outputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"commanded generalised force {t} (body)") for t in tn]
        outputs += [Signal(f"{n}_d", state_unit(n), f"reference-model trajectory {n}") for n in eta]
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
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    @classmethod
    def _interface3(cls, vessel: VesselSpec) -> Interface:
        inputs = [Signal(f"{n}_hat", state_unit(n), f"estimated {n}")
                  for n in vessel.eta_names + vessel.nu_names]
        inputs.append(Signal("yaw_ref", "rad", "desired heading (course when course_mode = 1)"))
        inputs.append(Signal("surge_force_ref", "N", "throttle: open-loop surge force"))
        outputs = [Signal(f"tau_{t}", FORCE_UNIT[t], f"commanded generalised force {t} (body)")
                   for t in vessel.tau_names]
        outputs += [Signal("yaw_d", "rad", "reference-model heading"),
                    Signal("r_d", "rad/s", "reference-model yaw rate")]
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
        self._n_out = len(iface.outputs)
        d = self.dof = vessel.dof
        self._angles = [n in ANGLE_NAMES for n in vessel.eta_names]
        self._angle_idx = np.flatnonzero(self._angles)
        M = 0.5 * (vessel.M + vessel.M.T)
        self._m66 = float(M[d - 1, d - 1])  # yaw inertia I_z + A66 (erratum: not I_z - A66)
        self._dl66 = float(vessel.D_L[d - 1, d - 1])
        self._dq66 = float(vessel.D_Q[d - 1, d - 1])
        n_ref = 6 if d == 6 else 1
        self.ref = ReferenceModel(n_ref, 1.0, 1.0, angles=self._angles if d == 6 else [True])
        self.z = np.zeros(n_ref)  # integral of the (wrapped) error
        self._started = False
        self._y = np.zeros(self._n_out)
        for name, value in self.params.items():
            self._check(name, value)
        self._apply_params()

    def _check(self, name: str, value: Any) -> None:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"controller: parameter '{name}' must be a number, got {value!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"controller: parameter '{name}' must be finite, got {value!r}")
        if name in ("ref_omega", "ref_zeta") or name.startswith("tau_max_"):
            if v <= 0.0:
                raise ValueError(f"controller: parameter '{name}' must be positive, got {value!r}")
        elif name == "course_mode":
            if v not in (0.0, 1.0):
                raise ValueError(f"controller: parameter 'course_mode' must be 0 or 1, got {value!r}")
        elif v < 0.0:
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
        else:
            self.kp = np.array([float(p["kp"])])
            self.kd = np.array([float(p["kd"])])
            self.ki = np.array([float(p["ki"])])
            self.tau_max = np.array([float(p["tau_max_N"])])
            z_force_max = self.tau_max
            self.course_mode = int(float(p["course_mode"])) == 1
            v_lim = [math.inf]
        safe_ki = np.where(self.ki > 0.0, self.ki, 1.0)
        self._z_max = np.where(self.ki > 0.0, z_force_max / safe_ki, np.inf)
        self.ref.set_dynamics(float(p["ref_omega"]), float(p["ref_zeta"]), v_max=v_lim)

    # -- run -----------------------------------------------------------------------------------
    def start(self, u: np.ndarray) -> np.ndarray:
        """Bumpless start: the reference model begins at the initial estimate, no force yet."""
        u = np.asarray(u, dtype=float)
        if u.shape == (len(self._in_names),) and np.isfinite(u).all():
            if self.dof == 6:
                self.ref.reset(u[:6])
                self._y[6:] = u[:6]
            else:
                self.ref.reset([u[2]])
                self._y[3] = u[2]
            self._started = True
        return self.output()

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != (len(self._in_names),):
            raise ValueError(f"controller: expected {len(self._in_names)} inputs, got {u.shape}")
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(self._in_names, u.tolist(), strict=True) if not math.isfinite(v)]
            raise ValueError(f"controller: input '{bad[0]}' is not finite")
        y = self._step6(h, u) if self.dof == 6 else self._step3(h, u)
        self._y = y
        return y.copy()

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

    def _step6(self, h: float, u: np.ndarray) -> np.ndarray:
        eta, nu, eta_ref = u[:6], u[6:12], u[12:18]
        if not self._started:
            self.ref.reset(eta)  # bumpless start from the current estimate
            self._started = True
        eta_d, eta_d_dot, _ = self.ref.step(h, eta_ref)
        e = eta - eta_d
        ai = self._angle_idx
        e[ai] = (e[ai] + math.pi) % (2.0 * math.pi) - math.pi
        Jm = J(eta)
        Jt = Jm.T
        edot = Jm @ nu - eta_d_dot
        tau_unsat = -(Jt @ (self.kp * e + self.kd * edot + self.ki * self.z))
        tau = np.minimum(np.maximum(tau_unsat, -self.tau_max), self.tau_max)
        self._integrate(h, e, tau_unsat, tau, Jt)
        y = np.empty(self._n_out)
        y[:6] = tau
        y[6:] = eta_d
        return y

    def _step3(self, h: float, u: np.ndarray) -> np.ndarray:
        yaw, uu, vv, r, yaw_ref, surge = u[2], u[3], u[4], u[5], u[6], u[7]
        if self.course_mode and math.hypot(uu, vv) > BETA_MIN_SPEED:
            yaw_ref = yaw_ref - math.atan2(vv, uu)  # psi_d = chi_d - beta
        if not self._started:
            self.ref.reset([yaw])
            self._started = True
        yaw_d, r_d, a_d = self.ref.step(h, [yaw_ref])
        e = np.array([wrap_angle(yaw - yaw_d[0])])
        rd = float(r_d[0])
        ff = self._m66 * float(a_d[0]) + self._dl66 * rd + self._dq66 * abs(rd) * rd
        tau_unsat = ff - self.kp * e - self.kd * (r - rd) - self.ki * self.z
        tau = np.minimum(np.maximum(tau_unsat, -self.tau_max), self.tau_max)
        self._integrate(h, e, tau_unsat, tau, None)
        return np.array([surge, 0.0, float(tau[0]), float(yaw_d[0]), rd])
