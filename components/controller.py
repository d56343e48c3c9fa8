"""The controller block: the FMU-facing ``ControllerBlock`` and what its variants share.

The control law is a named variant (``components.registry.CONTROLLERS``), chosen by the vessel
file (``gnc.controller``), never guessed from the number of DOFs or thrusters:

- ``dp_pid`` (``components/dp_pid.py``): nonlinear PID dynamic positioning in NED with a
  reference model and anti-windup, for 3 or 6 DOF, with the operating modes DP, waypoint
  tracking, auto-depth, auto-heading and joystick (Minerva 2; the offshore supply vessel);
- ``heading_autopilot`` (``components/heading_autopilot.py``): heading/course autopilot with an
  open-loop surge force, PID or linear backstepping, water joystick and land mode (AMV OSF).

``ControllerBlock(vessel, params)`` makes an instance of the variant class (a subclass), and
``ControllerBlock.interface(vessel)`` is that variant's interface, so the FMU, the in-process
master and the tests keep using ``ControllerBlock``. The string parameter ``controller_variant``
(fixed) names the variant too: by default the vessel file's; another registered variant is
accepted when its interface is the same (an FMU's variables cannot change with a parameter),
otherwise the error says to name it in the vessel file.

Shared here: the run skeleton (``start``, ``step``), bumpless transfer between modes
(``_blend``), conditional integration with clamping (``_integrate``) and setpoint latching
(``_latched``). Parameters are checked by ``Block`` from their Signals; a variant adds only
checks that involve the vessel or another value (``_check``).
"""

from __future__ import annotations

import math
from abc import abstractmethod
from typing import Any

import numpy as np

from . import registry
from .block import Block, Interface, Signal
from .dynamics import restoring_coefficients
from .dynamics import restoring_stiffness as _stiffness
from .guidance import parse_waypoints
from .reference_model import ReferenceModel
from .vessel_spec import ANGLE_NAMES, VesselSpec

BETA_MIN_SPEED = 0.1  # m/s: below this the crab angle atan2(v, u) is noise, course mode uses beta = 0

def restoring_stiffness(vessel: VesselSpec) -> np.ndarray:
    """Diagonal of dg/deta at eta = 0 (hydrostatic stiffness, only roll and pitch are non-zero)."""
    rs = vessel.restoring
    coeffs = None if rs is None else restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b)
    return _stiffness(coeffs, vessel.eta_names)


def declared_variant(vessel: VesselSpec) -> str:
    """The controller variant the vessel file names (``gnc.controller``)."""
    if vessel.gnc is None:
        raise ValueError(f"vessel '{vessel.name}' names no GNC variants (gnc section)")
    return vessel.gnc.controller


def variant_class(vessel: VesselSpec, name: Any = None) -> type[ControllerBlock]:
    """The class of variant ``name`` (default: the vessel's), checked to fit the vessel's interface."""
    declared = declared_variant(vessel)
    if name in (None, "", declared):
        return registry.controller_class(declared)
    try:
        cls = registry.controller_class(registry.check("controller", name))
    except ValueError as exc:
        raise ValueError(f"controller: parameter 'controller_variant': {exc}") from None
    mine = registry.controller_class(declared).interface(vessel)
    other = cls.interface(vessel)
    same = (mine.input_names() == other.input_names() and mine.output_names() == other.output_names()
            and [p.name for p in mine.parameters] == [p.name for p in other.parameters])
    if not same:
        raise ValueError(f"controller: parameter 'controller_variant': '{name}' has another interface than "
                         f"vessel '{vessel.name}''s '{declared}' (other inputs, outputs or parameters); "
                         "name it in the vessel file (gnc.controller) to build FMUs for it")
    return cls


class ControllerBlock(Block):
    """Generalised force from estimates and setpoints; the law is the vessel's named variant."""

    kind = "controller"

    def __new__(cls, vessel: VesselSpec | None = None, params: dict[str, Any] | None = None) -> Any:
        if cls is ControllerBlock and vessel is not None:
            cls = variant_class(vessel, (params or {}).get("controller_variant"))
        return super().__new__(cls)

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        if cls is ControllerBlock:
            return variant_class(vessel).interface(vessel)
        raise TypeError(f"controller variant {cls.__name__} defines no interface()")  # pragma: no cover

    # -- interface helpers -----------------------------------------------------------------------
    @staticmethod
    def _ref_params(omega: float, zeta: float = 1.0) -> list[Signal]:
        return [
            Signal("ref_omega", "rad/s", "reference-model natural frequency", min=0.0, min_open=True,
                   start=omega, tunable=True),
            Signal("ref_zeta", "", "reference-model damping ratio (1 = critically damped)", min=0.0,
                   min_open=True, start=zeta, tunable=True),
        ]

    @staticmethod
    def _variant_param(vessel: VesselSpec) -> Signal:
        return Signal("controller_variant", "", f"control law ({', '.join(registry.CONTROLLERS)}); default: "
                      "the vessel file's gnc.controller; another variant only if its interface is the same",
                      start=declared_variant(vessel), type="string")

    # -- set-up shared by the variants -----------------------------------------------------------
    def _setup(self, vessel: VesselSpec, n_ref: int, ref_angles: list[bool]) -> None:
        """State every variant has; call from the variant's ``__init__`` before its own."""
        self._n_out = len(self.out)
        self._o_tau = self.out.at(f"tau_{t}" for t in vessel.tau_names)
        d = self.dof = vessel.dof
        self._angles = [n in ANGLE_NAMES for n in vessel.eta_names]
        self._angle_idx = np.flatnonzero(self._angles)
        self._angle_mask = np.array(self._angles, dtype=bool)
        self._M = 0.5 * (vessel.M + vessel.M.T)
        self.ref = ReferenceModel(n_ref, 1.0, 1.0, angles=ref_angles)
        self.z = np.zeros(n_ref)  # integral of the (wrapped) error
        self._started = False
        self._stepped = False
        self._y = np.zeros(self._n_out)
        self._offset = np.zeros(d)  # bumpless transfer: decaying output offset after a mode switch
        self._offset_on = False  # _offset has a non-zero entry (set by _blend)
        self._active: tuple[int, ...] | None = None  # the mode key the last step ran in
        # Setpoints latched at a mode switch (NaN = none; see _latched) and the last setpoint
        # inputs seen (a change releases the latch).
        self._latch = np.full(n_ref, np.nan)
        self._latch_any = False
        self._ref_seen = np.full(n_ref, np.nan)

    def _check(self, name: str, value: Any) -> None:
        """What the Signal metadata cannot say (Block checks type and range first)."""
        if name == "waypoints" and value.strip():
            parse_waypoints(value)

    def _check_all(self) -> None:
        for name, value in self.params.items():
            self._check(name, value)
        self._apply_params()

    def check_parameter(self, name: str, value: Any) -> None:
        super().check_parameter(name, value)
        self._check(name, value)

    def set_parameter(self, name: str, value: Any) -> None:
        super().set_parameter(name, value)
        self._apply_params()

    def _set_limits(self, z_force_max: np.ndarray, v_lim: list[float]) -> None:
        """Integral clamp from the force bound, mode blending time, reference-model dynamics."""
        p = self.params
        safe_ki = np.where(self.ki > 0.0, self.ki, 1.0)
        self._z_max = np.where(self.ki > 0.0, z_force_max / safe_ki, np.inf)
        self._blend_time = float(p["mode_blend_time"])
        self.ref.set_dynamics(float(p["ref_omega"]), float(p["ref_zeta"]), v_max=v_lim)

    # -- what a variant defines ------------------------------------------------------------------
    @abstractmethod
    def _apply_params(self) -> None:
        """Derive the law's gains from the parameters (every variant has its own)."""

    @abstractmethod
    def _mode_key(self) -> tuple[int, ...]:
        """What decides the control law; a change is a mode switch (bumpless transfer)."""

    @abstractmethod
    def _start_law(self, u: np.ndarray) -> None:
        """Bumpless start from the initial inputs (reference model at the estimate)."""

    @abstractmethod
    def _step_law(self, h: float, u: np.ndarray, switched: bool) -> np.ndarray:
        """One step of the law: the outputs at t + h."""

    # -- run -----------------------------------------------------------------------------------
    def start(self, u: np.ndarray) -> np.ndarray:
        """Bumpless start: the reference model begins at the initial estimate, no force yet."""
        u = np.asarray(u, dtype=float)
        if u.shape == self._in_shape and np.isfinite(u).all():
            self._start_law(u)
            self._started = True
        return self.output()

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != self._in_shape:
            raise ValueError(f"controller: expected {len(self.inp)} inputs, got {u.shape}")
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(self.inp.names, u.tolist(), strict=True) if not math.isfinite(v)]
            raise ValueError(f"controller: input '{bad[0]}' is not finite")
        key = self._mode_key()
        switched = key != self._active
        y = self._step_law(h, u, switched)
        self._active = key
        self._stepped = True
        self._y = y
        return y.copy()

    def _blend(self, switched: bool, h: float, tau_new: np.ndarray) -> None:
        """Bumpless transfer: at a switch, offset = last output - new law's output, then it decays."""
        if switched and self._stepped and self._blend_time > 0.0:
            self._offset = self._y[self._o_tau] - tau_new
        elif self._blend_time > 0.0 and self._offset.any():
            self._offset *= math.exp(-h / self._blend_time)
            if np.abs(self._offset).max() < 1e-9:  # gone: skip the arithmetic from now on
                self._offset[:] = 0.0
        else:
            self._offset[:] = 0.0
        self._offset_on = bool(self._offset.any())

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
            sat = (over != 0.0) & (self.tau_max > 0.0)  # tau_max 0: a DOF the thrusters cannot make
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

    def _latched(self, eta_ref: np.ndarray) -> np.ndarray:
        """Setpoint inputs with latched setpoints; a changed input releases its latch."""
        changed = eta_ref != self._ref_seen
        if changed.any():
            self._latch[changed] = np.nan
            self._latch_any = bool(np.isfinite(self._latch).any())
        latch = self._latch
        return np.where(np.isfinite(latch), latch, eta_ref)
