"""The plant block: vessel dynamics + thruster shafts + current + sensors behind the Block contract."""

from __future__ import annotations

import copy
import math
import numbers
from typing import Any

import numpy as np

from components.block import Block, Interface, Signal, full_params
from components.environment import Current
from components.kinematics import J, wrap_angle
from components.sensors import SensorSuite
from components.vessel_model import VesselModel
from components.vessel_spec import ANGLE_NAMES, VesselSpec

_MIN_SUBSTEP = 1e-6
FAIL_MODES = ("ok", "stuck at zero", "stuck at value")


def _units(vessel: VesselSpec) -> dict[str, str]:
    u = {n: ("rad" if n in ANGLE_NAMES else "m") for n in vessel.eta_names}
    u.update({n: ("rad/s" if n in ("p", "q", "r") else "m/s") for n in vessel.nu_names})
    return u


class PlantBlock(Block):
    """Simulated vessel: inputs are shaft-speed commands, outputs true state, shafts, thrust, sensors."""

    kind = "plant"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        th = vessel.thrusters
        units = _units(vessel)
        inputs = [
            Signal(f"n_cmd_{i + 1}", "rev/s", f"shaft speed command of thruster {i + 1} '{name}'",
                   min=-float(th.n_max[i]), max=float(th.n_max[i]))
            for i, name in enumerate(th.names)
        ]
        outputs = [Signal(n, units[n], f"true position/attitude {n} (NED)") for n in vessel.eta_names]
        outputs += [Signal(n, units[n], f"true body velocity {n}") for n in vessel.nu_names]
        outputs += [Signal(f"n_{i + 1}", "rev/s", f"actual shaft speed of thruster {i + 1} '{name}'")
                    for i, name in enumerate(th.names)]
        outputs += [Signal(f"thrust_{i + 1}", "N", f"thrust of thruster {i + 1} '{name}'")
                    for i, name in enumerate(th.names)]
        for s in vessel.sensors:
            outputs += [Signal(f"meas_{c}", units[c], f"{c} measured by {s.name} ({s.rate_hz:g} Hz), held")
                        for c in s.channels]
            outputs.append(Signal(f"{s.name}_count", "", f"samples taken by {s.name}; +1 on each new sample"))
        outputs += [
            Signal("course", "rad", "true course over ground (heading when nearly at rest)"),
            Signal("sog", "m/s", "true speed over ground (horizontal)"),
        ]
        params = [
            Signal("seed", "", "seed of the sensor noise (same seed, identical run)", min=0, start=0,
                   type="integer"),
            Signal("noise_scale", "", "multiplies sensor noise std and bias (0 = perfect sensors)",
                   min=0.0, start=1.0),
            Signal("current_speed", "m/s", "ocean current speed", min=0.0, start=0.0, tunable=True),
            Signal("current_direction", "rad", "direction the current flows TOWARDS, from north",
                   start=0.0, tunable=True),
        ]
        params += [Signal(f"{n}_0", units[n], f"initial {n}", start=0.0)
                   for n in vessel.eta_names + vessel.nu_names]
        params.append(Signal("substep", "s", "max RK4 step; a co-simulation step h is split into "
                             "ceil(h / substep) equal RK4 steps", min=_MIN_SUBSTEP, start=0.01))
        # Thruster failures (appended: the earlier parameters keep their order). A failed drive
        # ignores its command; the shaft still follows the first-order lag to 0 or to the value.
        for i, name in enumerate(th.names):
            params.append(Signal(f"fail_mode_{i + 1}", "", f"thruster {i + 1} '{name}': 0 = ok, 1 = failed, "
                                 "stuck at zero speed, 2 = failed, stuck at fail_value", min=0,
                                 max=len(FAIL_MODES) - 1, start=0, type="integer", tunable=True))
        for i, name in enumerate(th.names):
            n_max = float(th.n_max[i])
            params.append(Signal(f"fail_value_{i + 1}", "rev/s", f"thruster {i + 1} '{name}': shaft speed "
                                 "it is stuck at when fail_mode = 2", min=-n_max, max=n_max, start=0.0,
                                 tunable=True))
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        iface = self.interface(vessel)
        super().__init__(vessel, full_params(iface, params))
        p = self.params
        seed = p["seed"]
        if isinstance(seed, bool) or not isinstance(seed, numbers.Real) or not float(seed).is_integer():
            raise ValueError(f"seed must be an integer, got {seed!r}")
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self._seed = int(seed)
        self._noise_scale = self._real("noise_scale", lo=0.0)
        self._substep = self._real("substep", lo=_MIN_SUBSTEP)
        self._current = Current(self._real("current_speed", lo=0.0), self._real("current_direction"))
        d = vessel.dof
        x0 = [self._real(f"{n}_0") for n in vessel.eta_names + vessel.nu_names]

        self._model = VesselModel(vessel)
        self._input_names = iface.input_names()
        self._x = self._model.initial_state(np.array(x0[:d]), np.array(x0[d:]))
        for i in self._model.angle_index:
            self._x[i] = wrap_angle(self._x[i])
        self._sensors = SensorSuite(vessel.sensors, vessel.eta_names + vessel.nu_names, self._seed,
                                    self._noise_scale)
        self._sensors.initialise(self._x[: 2 * d])
        self._sensor_out: list[float] = []
        self._stuck: list[tuple[int, float]] = []  # (thruster index, speed command it is stuck at)
        for i in range(vessel.thrusters.count):
            self._check_failure(f"fail_mode_{i + 1}", self.params[f"fail_mode_{i + 1}"])
            self._check_failure(f"fail_value_{i + 1}", self.params[f"fail_value_{i + 1}"])
        self._apply_failures()
        self._y = self._outputs()

    def _real(self, name: str, lo: float | None = None) -> float:
        """A finite real parameter, optionally >= lo; ValueError names it."""
        v = self.params[name]
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number, got {v!r}") from None
        if not math.isfinite(f):
            raise ValueError(f"{name} must be finite, got {v!r}")
        if lo is not None and f < lo:
            raise ValueError(f"{name} must be >= {lo:g}, got {v!r}")
        return f

    def __deepcopy__(self, memo: dict) -> PlantBlock:
        """Copy the state; share the vessel spec and model, which never change after __init__."""
        new = object.__new__(type(self))
        memo[id(self)] = new
        shared = {"vessel", "_model", "_input_names"}
        for k, v in self.__dict__.items():
            new.__dict__[k] = v if k in shared else copy.deepcopy(v, memo)
        return new

    def _outputs(self, sensors_changed: bool = True) -> np.ndarray:
        if sensors_changed:
            self._sensor_out = self._sensors.output()
        x = self._x.tolist()
        thrust = self._model.thrust_list(x[2 * self.vessel.dof :])
        return np.array(x + thrust + self._sensor_out + self._course_sog())

    def _course_sog(self) -> list[float]:
        """Course and speed over ground: what a surface vessel's crab-angle compensation aims at."""
        d = self.vessel.dof
        eta_dot = J(self._x[:d]) @ self._x[d : 2 * d]
        vn, ve = float(eta_dot[0]), float(eta_dot[1])
        sog = math.hypot(vn, ve)
        course = math.atan2(ve, vn) if sog > 1e-6 else float(self._x[d - 1])
        return [course, sog]

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"step size h must be finite and > 0, got {h!r}")
        ul = u.tolist() if isinstance(u, np.ndarray) else [float(c) for c in u]
        names = self._input_names
        if len(ul) != len(names) or (ul and isinstance(ul[0], list)):
            raise ValueError(f"expected {len(names)} inputs {names}, got {np.shape(u)}")
        if not math.isfinite(sum(ul)):  # one check on the hot path; inf - inf and nan propagate
            bad = [f"{n}={v}" for n, v in zip(names, ul, strict=True) if not math.isfinite(v)]
            if bad:
                raise ValueError(f"non-finite input {', '.join(bad)}")
        model = self._model
        steps = max(1, math.ceil(h / self._substep - 1e-9))
        vcn, vce = self._current.ned()
        for i, value in self._stuck:  # failed drives ignore their command
            ul[i] = value
        self._x = model.rk4(self._x, model.clip(ul), h / steps, steps, vcn, vce)
        changed = self._sensors.update(t, h, self._x[: 2 * self.vessel.dof])
        self._y = self._outputs(changed)
        return self._y.copy()

    # -- thruster failures -----------------------------------------------------------------------
    def _check_failure(self, name: str, value: Any) -> None:
        """ValueError naming the parameter unless it is a valid fail_mode_i / fail_value_i."""
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number, got {value!r}") from None
        i = int(name.rsplit("_", 1)[1]) - 1
        if name.startswith("fail_mode_") and f not in range(len(FAIL_MODES)):
            modes = ", ".join(f"{k} = {m}" for k, m in enumerate(FAIL_MODES))
            raise ValueError(f"{name} must be one of {modes}; got {value!r}")
        n_max = float(self.vessel.thrusters.n_max[i])
        if name.startswith("fail_value_") and not (math.isfinite(f) and abs(f) <= n_max):
            raise ValueError(f"{name} must be within +-{n_max:g} rev/s, got {value!r}")

    def _apply_failures(self) -> None:
        stuck = []
        for i in range(self.vessel.thrusters.count):
            mode = int(float(self.params[f"fail_mode_{i + 1}"]))
            if mode == 1:
                stuck.append((i, 0.0))
            elif mode == 2:
                stuck.append((i, float(self.params[f"fail_value_{i + 1}"])))
        self._stuck = stuck

    @property
    def failed(self) -> list[int]:
        """0-based indices of the thrusters whose drive has failed."""
        return [i for i, _ in self._stuck]

    def set_parameter(self, name: str, value: Any) -> None:
        if name.startswith(("fail_mode_", "fail_value_")):
            if name not in self.params:
                raise ValueError(f"{type(self).__name__}: unknown parameter '{name}'")
            self._check_failure(name, value)
            self.params[name] = value
            self._apply_failures()
            return
        if name in ("current_speed", "current_direction"):
            old = self.params[name]
            self.params[name] = value
            try:
                f = self._real(name, lo=0.0 if name == "current_speed" else None)
            except ValueError:
                self.params[name] = old
                raise
            if name == "current_speed":
                self._current.speed = f
            else:
                self._current.direction = f
            return
        super().set_parameter(name, value)

    # -- conveniences for tests and analysis ---------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """[eta, nu, n] (copy)."""
        return self._x.copy()

    @property
    def model(self) -> VesselModel:
        return self._model
