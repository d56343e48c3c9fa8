"""The plant block: vessel dynamics + thruster shafts + current + waves + sensors behind the Block contract.

Environment and sensor faults: JONSWAP waves (``components/waves.py``) enter the vessel model as
the external body force tau_ext, re-evaluated at the time midpoint of every RK4 sub-step (held
over the sub-step, position of the sub-step's start); a slowly varying current
(``components/environment.py``); a magnetometer calibration fault and position-fix
outliers/dropout (``components/sensors.py``).
Each random process has its own stream derived from ``seed`` (SeedSequence([seed, tag])), so
switching one on changes nothing in the others, and with every new parameter at its default the
run is bit-identical to the plant without them.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from . import kernels
from .allocation import FORCE_UNIT
from .block import Block, Interface, Signal
from .dynamics import wrap_angle
from .environment import GaussMarkovCurrent
from .sensors import SensorSuite, mag_heading_error
from .vessel_model import VesselModel
from .vessel_spec import VesselSpec, state_unit
from .waves import WaveField, WaveLoad

_MIN_SUBSTEP = 1e-6
FAIL_MODES = ("ok", "stuck at zero", "stuck at value")
WAVE_STREAM = 0x3A7E  # entropy tags: SeedSequence([seed, tag]) per random process of the plant
CURRENT_STREAM = 0xC0C0
FAULT_PARAMS = ("usbl_outlier_rate", "usbl_outlier_size", "usbl_dropout_start", "usbl_dropout_length")


class PlantBlock(Block):
    """Simulated vessel: inputs are shaft-speed commands, outputs true state, shafts, thrust, sensors."""

    kind = "plant"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        # Long because it lists every signal and parameter with its metadata (the FMU variables and
        # the checks of Block); there is no logic to split out.
        th = vessel.thrusters
        inputs = [
            Signal(f"n_cmd_{i + 1}", "rev/s", f"shaft speed command of thruster {i + 1} '{name}'",
                   min=-float(th.n_max[i]), max=float(th.n_max[i]))
            for i, name in enumerate(th.names)
        ]
        outputs = [Signal(n, state_unit(n), f"true position/attitude {n} (NED)") for n in vessel.eta_names]
        outputs += [Signal(n, state_unit(n), f"true body velocity {n}") for n in vessel.nu_names]
        outputs += [Signal(f"n_{i + 1}", "rev/s", f"actual shaft speed of thruster {i + 1} '{name}'")
                    for i, name in enumerate(th.names)]
        outputs += [Signal(f"thrust_{i + 1}", "N", f"thrust of thruster {i + 1} '{name}'")
                    for i, name in enumerate(th.names)]
        for s in vessel.sensors:
            outputs += [Signal(f"meas_{c}", state_unit(c),
                               f"{c} measured by {s.name} ({s.rate_hz:g} Hz), held") for c in s.channels]
            outputs.append(Signal(f"{s.name}_count", "", f"samples taken by {s.name}; +1 on each new sample"))
        outputs += [
            Signal("course", "rad", "true course over ground (heading when nearly at rest)"),
            Signal("sog", "m/s", "true speed over ground (horizontal)"),
        ]
        outputs.append(Signal("wave_elevation", "m", "wave elevation above the vessel's horizontal position"))
        outputs += [Signal(f"tau_wave_{t}", FORCE_UNIT[t], f"first-order wave force {t} (body frame)")
                    for t in vessel.tau_names]
        outputs += [
            Signal("current_north", "m/s", "current velocity, north (mean + slow variation)"),
            Signal("current_east", "m/s", "current velocity, east (mean + slow variation)"),
            Signal("mag_heading_error", "rad", "heading error of the magnetometer fault at the true "
                   "heading, A sin(yaw)"),
            Signal("pos_fix_outliers", "", "position-fix outliers injected so far"),
            Signal("pos_fix_dropout", "", "1 while the position-fix sensor is in its dropout"),
        ]
        params = [
            Signal("seed", "", "seed of the sensor noise (same seed, identical run)", min=0, start=0,
                   type="integer"),
            # max: 100 x the vessel file's noise (a 0.1 m fix with 10 m noise) is no sensor worth fusing
            Signal("noise_scale", "", "multiplies sensor noise std and bias (0 = perfect sensors)",
                   min=0.0, max=100.0, start=1.0),
            # max: the strongest tidal races (Saltstraumen, Moskstraumen) reach about 5 m/s
            Signal("current_speed", "m/s", "ocean current speed", min=0.0, max=10.0, start=0.0,
                   tunable=True),
            Signal("current_direction", "rad", "direction the current flows TOWARDS, from north",
                   start=0.0, tunable=True),
        ]
        params += [Signal(f"{n}_0", state_unit(n), f"initial {n}", start=0.0)
                   for n in vessel.eta_names + vessel.nu_names]
        params.append(Signal("substep", "s", "max RK4 step; a co-simulation step h is split into "
                             "ceil(h / substep) equal RK4 steps", min=_MIN_SUBSTEP, start=0.01))
        # A failed drive ignores its command; the shaft still follows the first-order lag to 0 or
        # to the value.
        for i, name in enumerate(th.names):
            params.append(Signal(f"fail_mode_{i + 1}", "", f"thruster {i + 1} '{name}': 0 = ok, 1 = failed, "
                                 "stuck at zero speed, 2 = failed, stuck at fail_value", min=0,
                                 max=len(FAIL_MODES) - 1, start=0, type="integer", tunable=True,
                                 choices=tuple(range(len(FAIL_MODES)))))
        for i, name in enumerate(th.names):
            n_max = float(th.n_max[i])
            params.append(Signal(f"fail_value_{i + 1}", "rev/s", f"thruster {i + 1} '{name}': shaft speed "
                                 "it is stuck at when fail_mode = 2", min=-n_max, max=n_max, start=0.0,
                                 tunable=True))
        # A fouled or damaged thruster: its drive follows the command, less force reaches the hull.
        for i, name in enumerate(th.names):
            params.append(Signal(f"thruster_efficiency_{i + 1}", "", f"thruster {i + 1} '{name}': fraction "
                                 "of its thrust law's force that reaches the hull (fouling, damage; 1 = "
                                 "nominal); thrust_i still reports the law's thrust at the shaft speed, as a "
                                 "log from the shaft speed would", min=0.0, max=1.5, start=1.0, tunable=True))
        # Environment and sensor faults (components/waves.py, environment.py, sensors.py).
        params += [
            Signal("wave_hs", "m", "significant wave height H_s of the JONSWAP sea (0 = no waves)",
                   min=0.0, max=20.0, start=0.0, tunable=True),
            Signal("wave_tp", "s", "peak period T_p", min=0.5, max=30.0, start=5.0),
            Signal("wave_direction", "rad", "direction the waves travel TOWARDS, from north", start=0.0),
            Signal("wave_gamma", "", "JONSWAP peak enhancement gamma (1 = Pierson-Moskowitz)",
                   min=1.0, max=7.0, start=3.3),
            Signal("wave_components", "", "number of regular wave components (random phases from seed)",
                   min=1, max=2000, start=40, type="integer"),
            # max: half the current speed's; a slow variation of 5 m/s std is no sea a vessel works in
            Signal("current_variation", "m/s", "std of the slow Gauss-Markov variation of each NED "
                   "current component (0 = constant current)", min=0.0, max=5.0, start=0.0),
            Signal("current_time_constant", "s", "time constant of the current variation", min=1e-3,
                   start=300.0),
            Signal("mag_fault_amplitude", "rad", "magnetometer calibration fault: heading error "
                   "A sin(yaw) (0 north/south, +A east, -A west); 0 = off", start=0.0, tunable=True),
            Signal("usbl_outlier_rate", "", "probability that a position fix is an outlier", min=0.0,
                   max=1.0, start=0.0, tunable=True),
            Signal("usbl_outlier_size", "m", "horizontal displacement of an outlier fix (random "
                   "direction)", min=0.0, start=5.0, tunable=True),
            Signal("usbl_dropout_start", "s", "start of the position-fix dropout", min=0.0, start=0.0,
                   tunable=True),
            Signal("usbl_dropout_length", "s", "length of the position-fix dropout (0 = none)", min=0.0,
                   start=0.0, tunable=True),
        ]
        if "land" in vessel.extra:  # the vessel file gives land kinematics (the amphibious AMV)
            params.append(Signal("land_mode", "", "0 = water, 1 = land (screws roll on the ground), "
                                 "2 = land sideways (button held)", min=0, max=2, start=0,
                                 type="integer", tunable=True, choices=(0, 1, 2)))
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        p = self.params
        self._seed = int(p["seed"])
        self._noise_scale = float(p["noise_scale"])
        self._substep = float(p["substep"])
        self._current = GaussMarkovCurrent(
            float(p["current_speed"]), float(p["current_direction"]),
            variation=float(p["current_variation"]), time_constant=float(p["current_time_constant"]),
            rng=np.random.default_rng(np.random.SeedSequence([self._seed, CURRENT_STREAM])),
        )
        field = WaveField(float(p["wave_hs"]), float(p["wave_tp"]), float(p["wave_direction"]),
                          float(p["wave_gamma"]), int(p["wave_components"]),
                          np.random.default_rng(np.random.SeedSequence([self._seed, WAVE_STREAM])))
        self._waves = WaveLoad(vessel, field)
        self._t = 0.0
        d = vessel.dof
        states = vessel.eta_names + vessel.nu_names
        x0 = [float(p[f"{n}_0"]) for n in states]

        self._model = VesselModel(vessel)
        self._land = None
        self._land_mode = 0
        if "land_mode" in self.params:
            from .amv_land import LandModel

            self._land = LandModel(vessel)
            self._land_mode = int(self.params["land_mode"])
        # Where each group of outputs goes, looked up by name once (see Block, Slots).
        th = range(vessel.thrusters.count)
        o = self.out
        self._n_out = len(o)
        self._o_x = o.at(states + [f"n_{i + 1}" for i in th])
        self._o_thrust = o.at([f"thrust_{i + 1}" for i in th])
        self._thrust_buf = np.empty(vessel.thrusters.count)  # the thrust law's output, reused
        self._o_sensors = o.at(SensorSuite.output_names(vessel.sensors))
        self._o_course_sog = o.at(["course", "sog"])
        self._o_env = o.at(["wave_elevation", *(f"tau_wave_{t}" for t in vessel.tau_names), "current_north",
                            "current_east", "mag_heading_error", "pos_fix_outliers", "pos_fix_dropout"])
        # the same positions for the compiled step, in its order (kernels/plant.write_outputs)
        self._layout = np.concatenate([np.arange(self._n_out)[s] for s in (
            self._o_x, self._o_thrust, self._o_course_sog, self._o_env, self._o_sensors)]).astype(np.int64)
        # n_max and the speed a failed drive is stuck at (NaN: not failed), for the compiled step
        self._drive = np.vstack([np.asarray(vessel.thrusters.n_max, dtype=float),
                                 np.full(vessel.thrusters.count, np.nan)])
        self._x = self._model.initial_state(np.array(x0[:d]), np.array(x0[d:]))
        for i in self._model.angle_index:
            self._x[i] = wrap_angle(self._x[i])
        self._sensors = SensorSuite(vessel.sensors, states, self._seed, self._noise_scale)
        self._sensors.set_mag_fault(float(p["mag_fault_amplitude"]))
        self._set_pos_faults()
        self._sensors.initialise(self._x[: 2 * d])
        self._sensor_out: list[float] = []
        self._stuck: list[tuple[int, float]] = []  # (thruster index, speed command it is stuck at)
        self._apply_failures()
        self._K: np.ndarray | None = None  # the model's K with the thruster efficiencies (None: nominal)
        self._apply_efficiency()
        self._y = self._outputs()

    def _set_pos_faults(self) -> None:
        p = self.params
        self._sensors.set_pos_faults(float(p["usbl_outlier_rate"]), float(p["usbl_outlier_size"]),
                                     float(p["usbl_dropout_start"]), float(p["usbl_dropout_length"]))

    def __deepcopy__(self, memo: dict) -> PlantBlock:
        """Copy the state; share the vessel spec and model, which never change after __init__."""
        new = object.__new__(type(self))
        memo[id(self)] = new
        shared = {"vessel", "_model", "iface", "inp", "out"}
        for k, v in self.__dict__.items():
            new.__dict__[k] = v if k in shared else copy.deepcopy(v, memo)
        return new

    def _outputs(self, sensors_changed: bool = True) -> np.ndarray:
        x = self._x
        if sensors_changed:
            self._sensor_out = self._sensors.output()
            y = np.empty(self._n_out)
            y[self._o_sensors] = self._sensor_out
        else:  # the held samples are the last outputs' (most steps take no sample)
            y = self._y.copy()
        y[self._o_x] = x
        self._model.thrust_into(x[2 * self.vessel.dof :], self._thrust_buf)
        y[self._o_thrust] = self._thrust_buf
        y[self._o_course_sog] = self._course_sog()
        y[self._o_env] = self._env_out()
        return y

    def _env_out(self) -> list[float]:
        """wave_elevation, tau_wave_*, current_north/east, mag_heading_error, outliers, dropout."""
        d = self.vessel.dof
        x = self._x
        field = self._waves.field
        if field.hs > 0.0:
            elev = field.elevation(self._t, float(x[0]), float(x[1]))
            tau = self._waves.force(self._t, x[:d])
        else:
            elev, tau = 0.0, [0.0] * d
        s = self._sensors
        return [elev, *tau, *self._current.ned(), mag_heading_error(float(x[d - 1]), s.mag_fault),
                s.outliers, float(s.in_dropout)]

    def _course_sog(self) -> list[float]:
        """Course and speed over ground: what a surface vessel's crab-angle compensation aims at."""
        d = self.vessel.dof
        vn, ve = self._model.horizontal_velocity(self._x)
        sog = float(np.hypot(vn, ve))  # libm's hypot, as the compiled step (math.hypot may differ by 1 ulp)
        course = math.atan2(ve, vn) if sog > 1e-6 else float(self._x[d - 1])
        return [course, sog]

    def output(self) -> np.ndarray:
        return self._y.copy()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """One compiled call (``kernels/plant.step``) on water; the reference form on land."""
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"step size h must be finite and > 0, got {h!r}")
        if self._land_mode and self._land is not None:
            return self._step_reference(t, h, u)
        if type(u) is not np.ndarray or u.shape != self._in_shape or u.dtype != np.float64:
            u = np.array(self._inputs(u), dtype=float)
        cur = self._current
        vcn, vce = cur.ned()
        if cur.variation != 0.0:  # the deviation draws: only once the inputs are known to be good
            if not math.isfinite(sum(u.tolist())):
                self._inputs(u)
            cur.step(h)
            vcn1, vce1 = cur.ned()
        else:
            vcn1, vce1 = vcn, vce
        p = self._model.kernel_params
        f = self._waves.field
        s = self._sensors
        res = kernels.plant.step(
            t, h, u, self._drive, self._x, max(1, math.ceil(h / self._substep - 1e-9)), vcn, vce, vcn1, vce1,
            p.K if self._K is None else self._K, p.MS, p.MAL, p.ML, p.g6, p.th, p.flags, p.angle_index,
            f.hs > 0.0, f.omega, f.k, f.phase, f.amp, f._acc_amp, f._cd, f._sd, self._waves.W, s.s_int,
            s.s_conf, s.s_int_mut, s.s_float_mut, s.noise, s.uniform, self._layout, self._y)
        if res < 0:
            self._inputs(u)  # raises, naming the input
        self._t = t + h
        if res & kernels.plant.REFILL:
            s.refill()
        return self._y.copy()

    def check_restored(self) -> None:
        """The sub-step must be the parameter's: a crafted 1e-12 s would make one step loop for hours."""
        from .state import StateError

        super().check_restored()
        if self._substep != float(self.params["substep"]):
            raise StateError(f"state: plant sub-step {self._substep!r} s is not its parameter substep = "
                             f"{self.params['substep']!r} s")

    def _inputs(self, u: np.ndarray | list[float]) -> list[float]:
        """``u`` as a list of floats; ValueError naming what is wrong (count, a non-finite value)."""
        ul = u.tolist() if isinstance(u, np.ndarray) else [float(c) for c in u]
        names = self.inp.names
        if len(ul) != len(names) or (ul and isinstance(ul[0], list)):
            raise ValueError(f"expected {len(names)} inputs {names}, got {np.shape(u)}")
        if not math.isfinite(sum(ul)):  # one check on the hot path; inf - inf and nan propagate
            bad = [f"{n}={v}" for n, v in zip(names, ul, strict=True) if not math.isfinite(v)]
            if bad:
                raise ValueError(f"non-finite input {', '.join(bad)}")
        return ul

    def _step_reference(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """The step in Python and NumPy around ``VesselModel.rk4``: what ``kernels/plant.step``
        computes, and the land mode's step (``tests/test_kernels.py`` holds them bit-identical)."""
        ul = self._inputs(u)
        model = self._model
        steps = max(1, math.ceil(h / self._substep - 1e-9))
        vcn, vce = self._current.ned()
        for i, value in self._stuck:  # failed drives ignore their command
            ul[i] = value
        cmd = model.clip(ul)
        waves = self._waves
        if self._land_mode and self._land is not None:  # on land: kinematics of the screws, no water
            self._x = self._land.step(self._x, cmd, h, steps, sideways=self._land_mode == 2)
        elif waves.field.hs > 0.0:  # wave force re-evaluated per sub-step, at its time midpoint
            dt = h / steps
            x = self._x
            d = self.vessel.dof
            for j in range(steps):
                x = model.rk4(x, cmd, dt, 1, vcn, vce, waves.force(t + (j + 0.5) * dt, x[:d]), self._K)
            self._x = x
        else:
            self._x = model.rk4(self._x, cmd, h / steps, steps, vcn, vce, None, self._K)
        self._current.step(h)
        self._t = t + h
        changed = self._sensors.update(t, h, self._x[: 2 * self.vessel.dof])
        self._y[:] = self._outputs(changed)
        return self._y.copy()

    # -- thruster failures -----------------------------------------------------------------------
    def _apply_failures(self) -> None:
        stuck = []
        for i in range(self.vessel.thrusters.count):
            mode = int(float(self.params[f"fail_mode_{i + 1}"]))
            if mode == 1:
                stuck.append((i, 0.0))
            elif mode == 2:
                stuck.append((i, float(self.params[f"fail_value_{i + 1}"])))
        self._stuck = stuck
        self._drive[1] = np.nan
        for i, value in stuck:
            self._drive[1, i] = value

    def _apply_efficiency(self) -> None:
        """Fold the thruster efficiencies into the model's K (None when all are 1: the nominal K)."""
        eff = self.efficiency
        self._K = None if all(e == 1.0 for e in eff) else self._model.k_matrix(eff)

    @property
    def efficiency(self) -> list[float]:
        """Per thruster, the fraction of its thrust law that reaches the hull."""
        p, m = self.params, self.vessel.thrusters.count
        return [float(p[f"thruster_efficiency_{i + 1}"]) for i in range(m)]

    @property
    def failed(self) -> list[int]:
        """0-based indices of the thrusters whose drive has failed."""
        return [i for i, _ in self._stuck]

    def set_parameter(self, name: str, value: Any) -> None:
        """Checked by Block (range, type), then applied to the part of the plant it belongs to."""
        super().set_parameter(name, value)
        if name == "land_mode" and self._land is not None:
            self._land_mode = int(float(value))
        elif name.startswith(("fail_mode_", "fail_value_")):
            self._apply_failures()
        elif name.startswith("thruster_efficiency_"):
            self._apply_efficiency()
        elif name == "current_speed":
            self._current.speed = float(value)
        elif name == "current_direction":
            self._current.direction = float(value)
        elif name == "wave_hs":
            self._waves.field.set_hs(float(value))
        elif name == "mag_fault_amplitude":
            self._sensors.set_mag_fault(float(value))
        elif name in FAULT_PARAMS:
            self._set_pos_faults()

    # -- conveniences for tests and analysis ---------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """[eta, nu, n] (copy)."""
        return self._x.copy()

    @property
    def model(self) -> VesselModel:
        return self._model

    @property
    def waves(self) -> WaveLoad:
        return self._waves
