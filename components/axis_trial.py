"""Controller variant ``axis_trial``: hold every DOF but the trial's axis, push that one open loop.

The hydrodynamic test plan (AAUSHIP method one; ``seafmu testplan``) needs a vessel that moves in
one body DOF only: a surge, sway or yaw record is only a 1-DOF record when the other DOFs stay
still. This variant keeps ``dp_pid``'s interface (inputs, outputs, parameters), so a scenario
chooses it with ``controller_variant: axis_trial`` for any vessel whose file names ``dp_pid``, in
FMUs, in-process and against the hardware link alike. Its law differs:

- the setpoint is the pose where the run starts (latched from the first estimate; ``<eta>_ref``
  and the reference model are not used), so holding means "stay where you were";
- translations are held in the frame of the latched heading: the gains ``kp_north``/``kd_north``/
  ``ki_north`` act along the latched surge direction and ``*_east`` along the latched sway
  direction (the same axes as north/east for a trial started at heading 0), ``*_down``, the
  angles as in ``dp_pid``;
- a DOF whose three gains are zero is **free** (no PID force at all), and the joystick force of
  its axis, ``joy_<axis> * joy_max_<tau>``, is the open-loop force profile on it (the scenario's
  events set ``joy_<axis>``); a surge/sway/yaw trial zeroes the gains of exactly one DOF, a
  roll/pitch release also those of the DOFs its inertia couples to (they swing with it);
- ``mode`` is ignored (there is one law).

tau = -J(eta)^T [R(psi_0) (K_p e + K_d e_dot + K_i z)_translation ; (K_p e + K_d e_dot + K_i z)_angles]
      + joystick forces, with e the error in the latched frame, then saturation and anti-windup as
``dp_pid``.
"""

from __future__ import annotations

import math

import numpy as np

from .dp_pid import DPPidController
from .dynamics import J, rpsi


class AxisTrialController(DPPidController):
    """One free DOF with an open-loop force (joystick), the others held at the starting pose."""

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """The block's generic step, which calls ``_step_law`` below: a shortcut ``dp_pid`` takes for
        its own law (a compiled held step) would skip this variant's."""
        return super(DPPidController, self).step(t, h, u)

    def _start_law(self, u: np.ndarray) -> None:
        super()._start_law(u)
        self._hold = u[self._in_eta].copy()

    def _mode_key(self) -> tuple[int, ...]:
        return (0,)  # one law: a mode change is no switch

    def _frame(self) -> np.ndarray:
        """Rotation from the latched horizontal frame to NED (3 x 3, identity on down)."""
        R = np.eye(3)
        R[:2, :2] = rpsi(float(self._hold[self._yaw]))[:2, :2]
        return R

    def _step_law(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        d = self.dof
        eta, nu = u[self._in_eta], u[self._in_nu]
        if not self._started or not hasattr(self, "_hold"):
            self._hold = eta.copy()
            self._started = True
        Jm = J(eta)
        Jt = Jm.T
        eta_dot = Jm @ nu
        e = eta - self._hold
        ai = self._angle_idx
        e[ai] = (e[ai] + math.pi) % (2.0 * math.pi) - math.pi
        edot = eta_dot.copy()
        # translations in the latched frame: 3 DOF (north, east), 6 DOF (north, east, down)
        nt = 2 if d == 3 else 3
        R = self._frame()[:nt, :nt]
        e[:nt] = R.T @ e[:nt]
        edot[:nt] = R.T @ edot[:nt]
        force = self.kp * e + self.kd * edot + self.ki * self.z
        force[:nt] = R @ force[:nt]
        tau_new = -(Jt @ force)
        tab = self._tab
        joy = np.clip(u[self._in_joy], -1.0, 1.0)
        for kk, ti in enumerate(tab.joy_tau):
            tau_new[ti] += joy[kk] * self._joy_max[kk]
        tau = np.minimum(np.maximum(tau_new, -self.tau_max), self.tau_max)
        # anti-windup on the latched-frame errors: the coupling of a latched component to the body
        # DOFs is J^T R (R = identity on the angles)
        Rfull = np.eye(d)
        Rfull[:nt, :nt] = R
        free = (self.kp == 0.0) & (self.kd == 0.0) & (self.ki == 0.0)
        self._integrate(h, np.where(free, 0.0, e), tau_new, tau, Jt @ Rfull)
        y = np.zeros(self._n_out)
        y[self._o_tau] = tau
        y[self._o_eta_d] = self._hold
        return y
