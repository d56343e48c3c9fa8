"""Observer: discrete extended Kalman filter on position/attitude, body velocity and a bias force.

State x = [eta, nu, b] (3 x dof values) with the vessel's own model and an unknown force b:

    eta_dot = J(eta) nu
    M nu_dot = tau + b - C(nu) nu - D_L nu - D_Q (|nu| * nu) - g(eta) + w_nu
    b_dot   = -b / T_b + w_b

The current is not known to the observer, so what it changes in the damping (and anything else
the model misses: waves, thruster lag, the net buoyancy if the file is off) ends up in b, which the
controller's integral action then removes. ``tau`` is the allocator's ``tau_alloc`` (achieved
after thrust limits), not the controller's demand.

Each co-simulation step: (1) prediction to t + h with the model linearised once per sub-step:
x+ = x + h f + h^2/2 A f and Phi = I + h A + h^2/2 A^2 (second order in h, like the state);
(2) for every sensor whose ``{sensor}_count`` input changed since the last step, a measurement
update with that sensor's channels (sequential per sensor, Joseph form, angle innovations
wrapped); the first sample of a position/attitude channel initialises that state directly.
Predict-then-update because the plant time-stamps a sample at the END of the step it was taken in
(sensors.py) and seafmu's master steps the plant before the observer (Gauss-Seidel), so the
measurements an observer step sees belong to t + h; tau_alloc (from the allocator, stepped last)
belongs to t and is held over the step, as the thrusters hold it.

Acoustic position fixes (the sensor measuring north and east: USBL; the AMV's GNSS) get two more
things: a chi-square gate at a chosen probability (``gate_probability`` p: a fix whose normalised
innovation squared y^T S^-1 y exceeds the chi-square quantile chi2_m(p), m = number of channels, is
rejected; a consistent filter then rejects a fraction 1 - p of good fixes), and dead reckoning:
without an accepted fix for more than ``dr_timeout`` seconds (dropout or rejections) the filter
runs on DVL/gyro/AHRS and the model alone, says so in ``dead_reckoning`` = 1, and its
``position_std`` grows. So that a filter that has drifted cannot lock itself out, more than
``gate_max_rejections`` consecutive rejected fixes reset the horizontal position to the next
failing fix (its covariance to the sensor's).

Every sensor's samples pass an innovation gate (``innovation_gate``, a NIS threshold; by default
only gross errors, 100 sigma: ``INNOVATION_GATE``) and are counted in ``samples_rejected``; more
than ``gate_max_rejections`` consecutive rejected samples of any sensor reset the states it
measures to the next failing sample, as for position fixes.

Wave filter (``wave_filter`` = 1, fixed at initialisation): DP must not chase first-order wave
motion (the thrusters cannot follow it, saturate, and the allocation error spills into roll and
yaw). The state is extended by a linear wave model per horizontal position (and depth) in NED,

    xi_dot = zeta,   zeta_dot = -omega_0^2 xi - 2 lambda omega_0 zeta + w_wave

(Fossen's second-order wave model, resonance at ``wave_filter_omega``, relative damping
``wave_filter_damping``, white noise of intensity ``wave_filter_q``); positions are measured as
eta + xi, body velocities (DVL) as nu + R(Theta)^T zeta. The estimates given to the controller,
``<eta>_hat`` and ``<nu>_hat``, are then the low-frequency motion; ``wave_<eta>_hat`` report xi.
The model is the classical DP observer structure (Fossen 2011, ch. 11; Sørensen 2011).

Why hand-written: filterpy/pykalman would need the Jacobian from us anyway and add a Python call
layer per step; the Jacobian is analytic (kinematics, restoring, damping) and the Coriolis term
uses a precomputed tensor (C(nu) nu is quadratic in nu, so one tensor-vector product gives both the
Jacobian G(nu) and C(nu) nu = G(nu) nu / 2). The numerics run compiled
(``components/kernels/ekf.py``, numba): model and Jacobian, prediction, and the updates, which
solve with the Cholesky factor of S instead of forming S^-1 (Joseph form kept).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import kernels
from .allocation import FORCE_UNIT
from .block import Block, Interface, Signal
from .dynamics import coriolis_tensor, restoring_coefficients, rzyx, wrap_angle
from .vessel_spec import ANGLE_NAMES, VesselSpec, state_unit

PREDICT_DT_MAX = 0.05  # s: largest prediction sub-step
Q_ETA = 1e-8  # (m or rad)^2/s: tiny kinematic process noise, keeps P positive definite
P0_POSITION = 100.0**2  # m^2 (and rad^2 for angles): before the first fix nothing is known
P0_VELOCITY = 1.0  # (m/s)^2, (rad/s)^2
P0_BIAS_ACCEL = 0.1  # m/s^2: initial bias std, as an acceleration (scaled by M_jj into a force)
R_FLOOR = 1e-12  # smallest measurement variance (a noise-free sensor file must not make S singular)
# Default innovation gate: NIS above (100 sigma)^2 is a gross error (a corrupt sentence with a good
# checksum, a depth of 500 m for 5 m), never noise, even from a filter whose model is off by a lot;
# without it one such sample drags the estimate by metres, or diverges it (hardware-in-the-loop).
INNOVATION_GATE = 1.0e4


@dataclass(frozen=True)
class _Channels:
    """The states one sensor measures (H is a selection), with what the update needs precomputed."""

    idx: np.ndarray  # state indices
    sel: slice | np.ndarray  # the same as a slice when contiguous: views beat fancy indexing
    angle: np.ndarray  # bool per channel: wrap the innovation
    has_angle: bool
    is_eta: np.ndarray  # bool per channel: position/attitude (initialised by the first sample)
    has_eta: bool
    eta_idx: np.ndarray
    diag: tuple[np.ndarray, np.ndarray]
    var: np.ndarray  # noise variance from the vessel file (before r_scale)
    pos_fix: bool = False  # a position-fix sensor (north and east): chi-square gate, dead reckoning
    wave: bool = False  # measures a state the wave filter adds to (position, body velocity)

    @classmethod
    def build(cls, idx: np.ndarray, angle: np.ndarray, is_eta: np.ndarray, var: np.ndarray,
              pos_fix: bool = False, wave: bool = False) -> _Channels:
        contiguous = bool(np.all(np.diff(idx) == 1))
        return cls(idx=idx, sel=slice(int(idx[0]), int(idx[-1]) + 1) if contiguous else idx, angle=angle,
                   has_angle=bool(angle.any()), is_eta=is_eta, has_eta=bool(is_eta.any()),
                   eta_idx=idx[is_eta], diag=np.diag_indices(len(idx)), var=var, pos_fix=pos_fix,
                   wave=wave)


def chi2_quantile(p: float, m: int) -> float:
    """x with P(chi2_m <= x) = p (scipy.special, not scipy.stats: the FMU loads faster). Imported
    here, not with the module: a scenario's validation imports this module for its interface
    alone (the registry), and scipy.special is ~0.06 s of a sweep's or a run's start-up."""
    from scipy.special import chdtri

    return float(chdtri(m, 1.0 - p))


class ObserverBlock(Block):
    """EKF on [eta, nu, bias]; updates only on new sensor samples; reports its position std."""

    kind = "observer"

    @classmethod
    def interface(cls, vessel: VesselSpec) -> Interface:
        inputs: list[Signal] = []
        for s in vessel.sensors:
            inputs += [Signal(f"meas_{c}", state_unit(c), f"{s.name}: measured {c} (held between samples)")
                       for c in s.channels]
            inputs.append(Signal(f"{s.name}_count", "", f"{s.name}: sample counter (a change = new sample)"))
        inputs += [Signal(f"tau_alloc_{t}", FORCE_UNIT[t], f"allocated generalised force {t}")
                   for t in vessel.tau_names]
        outputs = [Signal(f"{n}_hat", state_unit(n), f"estimated {n}") for n in vessel.eta_names]
        outputs += [Signal(f"{n}_hat", state_unit(n), f"estimated {n}") for n in vessel.nu_names]
        outputs += [Signal(f"bias_{t}_hat", FORCE_UNIT[t], f"estimated bias force {t} (body)")
                    for t in vessel.tau_names]
        outputs.append(Signal("position_std", "m", "sqrt(var north + var east) of the estimate"))
        outputs += [
            Signal("pos_fixes_rejected", "", "position fixes rejected by a gate so far"),
            Signal("dead_reckoning", "", "1 while no position fix was accepted for more than dr_timeout"),
            Signal("samples_rejected", "", "samples of any sensor rejected by a gate so far (position "
                   "fixes included)"),
        ]
        outputs += [Signal(f"wave_{nm}_hat", "m", f"estimated wave-frequency displacement {nm} (NED; "
                           "0 without wave filter)")
                    for nm in vessel.eta_names if nm in ("north", "east", "down")]
        params = [
            Signal("q_velocity", "m/s^2/sqrt(Hz)", "process noise on the body accelerations (model "
                   "error), same number used for rad/s^2", min=0.0, start=0.02, tunable=True),
            Signal("q_bias", "m/s^2/sqrt(s)", "random-walk intensity of the bias, as an acceleration "
                   "(times M_jj gives N/sqrt(s))", min=0.0, start=0.002, tunable=True),
            Signal("bias_time_constant", "s", "T_b of the bias model b_dot = -b/T_b + w", min=0.0,
                   min_open=True, start=500.0, tunable=True),
            Signal("r_scale", "", "measurement variance = r_scale * noise_std^2 from the vessel file",
                   min=0.0, min_open=True, start=1.0, tunable=True),
            Signal("innovation_gate", "", "reject a sample whose normalised innovation squared exceeds "
                   "this (chi-square; 0 = accept all; default: gross errors only, 100 sigma)", min=0.0,
                   start=INNOVATION_GATE, tunable=True),
            Signal("gate_probability", "", "chi-square gate on position fixes: accept a fix whose "
                   "NIS is below the chi2_m quantile at this probability (e.g. 0.999; 0 = off)",
                   min=0.0, max=0.999999, start=0.0, tunable=True),
            Signal("gate_max_rejections", "", "after this many consecutive rejected samples of a sensor "
                   "the next failing one resets the states it measures (0 = never)", min=0, start=5,
                   type="integer", tunable=True),
            Signal("dr_timeout", "s", "dead reckoning is declared after this long without an "
                   "accepted position fix", min=0.0, start=3.0, tunable=True),
            Signal("wave_filter", "", "1 = estimate first-order wave motion separately and give the "
                   "controller the low-frequency motion; 0 = off (fixed at initialisation)", min=0.0,
                   max=1.0, start=0.0),
            Signal("wave_filter_omega", "rad/s", "resonance of the wave model (about 2 pi / T_p)",
                   min=0.0, start=1.2566, tunable=True),
            Signal("wave_filter_damping", "", "relative damping lambda of the wave model", min=0.0,
                   start=0.1, tunable=True),
            Signal("wave_filter_q", "m/s^2/sqrt(Hz)", "white-noise intensity driving the wave model "
                   "(stationary std of xi = q / sqrt(4 lambda omega^3))", min=0.0, start=0.05,
                   tunable=True),
        ]
        return Interface(inputs=inputs, outputs=outputs, parameters=params)

    def __init__(self, vessel: VesselSpec, params: dict[str, Any]) -> None:
        super().__init__(vessel, params)
        d = self.d = vessel.dof
        # Wave filter states: xi and zeta for each translational position (north, east[, down]).
        self._wave_on = float(self.params.get("wave_filter", 0.0)) > 0.0
        self._wdof = [i for i, nm in enumerate(vessel.eta_names) if nm in ("north", "east", "down")]
        nw = self.nw = len(self._wdof) if self._wave_on else 0
        n = self.n = 3 * d + 2 * nw
        self._w0 = 3 * d  # index of xi_1; zeta_1 at 3 d + nw
        # state index -> (kind, k): a position with wave state xi_k, or body velocity component k
        self._wave_map: dict[int, tuple[str, int]] = {}
        if nw:
            self._wave_map.update({i: ("pos", k) for k, i in enumerate(self._wdof)})
            self._wave_map.update({d + k: ("vel", k) for k in range(nw)})
        M = 0.5 * (vessel.M + vessel.M.T)
        self.Minv = np.linalg.inv(M)
        self._m_diag = np.diag(M).copy()
        G = coriolis_tensor(M) if vessel.coriolis != "none" else np.zeros((d, d, d))
        self._MinvG = np.einsum("ij,jkl->ikl", self.Minv, G)
        self._MinvDL = self.Minv @ np.asarray(vessel.D_L, dtype=float)
        self._MinvDQ = self.Minv @ np.asarray(vessel.D_Q, dtype=float)
        if d == 6:
            rs = vessel.restoring
            if rs is None:
                raise ValueError(f"observer: 6-DOF vessel '{vessel.name}' has no restoring section")
            self._g6 = restoring_coefficients(rs.weight, rs.buoyancy, rs.r_g, rs.r_b)
        state_names = vessel.eta_names + vessel.nu_names
        self._angle_list = [i for i, nm in enumerate(vessel.eta_names) if nm in ANGLE_NAMES]
        self._angle_arr = np.array(self._angle_list, dtype=np.int64)
        # what the compiled kernels take: contiguous float64, zeros where a part does not apply
        self._MinvG = np.ascontiguousarray(self._MinvG)
        self._g6_arr = np.array(self._g6 if d == 6 else (0.0, 0.0, 0.0, 0.0), dtype=float)
        self._Aw = np.zeros((0, 0))

        # Sensors: where their inputs are, which states they measure.
        inp = self.inp
        self._sensors: list[tuple[slice | list[int], int, _Channels]] = []  # (meas inputs, count, channels)
        for s in vessel.sensors:
            ch = _Channels.build(
                np.array([state_names.index(c) for c in s.channels]),
                np.array([c in ANGLE_NAMES for c in s.channels]),
                np.array([c in vessel.eta_names for c in s.channels]),
                np.maximum(np.asarray(s.noise_std, dtype=float) ** 2, R_FLOOR),
                pos_fix="north" in s.channels and "east" in s.channels,
                wave=any(state_names.index(c) in self._wave_map for c in s.channels),
            )
            self._sensors.append((inp.at(f"meas_{c}" for c in s.channels), inp[f"{s.name}_count"], ch))
        self._tau_in = inp.at(f"tau_alloc_{t}" for t in vessel.tau_names)
        self._sens, self._sens_var = self._sensor_table()
        self._tau_idx = np.arange(len(inp))[self._tau_in].astype(np.int64)
        o = self.out
        self._n_out = len(o)
        self._o_state = o.at([f"{n}_hat" for n in vessel.eta_names + vessel.nu_names]
                             + [f"bias_{t}_hat" for t in vessel.tau_names])
        self._o_std, self._o_rej, self._o_dr = o["position_std"], o["pos_fixes_rejected"], o["dead_reckoning"]
        self._o_all_rej = o["samples_rejected"]
        self._o_wave = o.at(f"wave_{vessel.eta_names[i]}_hat" for i in self._wdof)
        pos = np.arange(self._n_out)
        self._layout = np.concatenate([pos[self._o_state], [self._o_std], pos[self._o_wave]]).astype(np.int64)
        self._y = np.zeros(self._n_out)

        # Constant parts of the Jacobian A = df/dx.
        self._A = np.zeros((n, n))
        self._A[d : 2 * d, 2 * d : 3 * d] = self.Minv
        self._diag = np.diag_indices(n)
        self.x = np.zeros(n)
        p0 = np.concatenate([np.full(d, P0_POSITION), np.full(d, P0_VELOCITY),
                             (P0_BIAS_ACCEL * self._m_diag) ** 2, self._wave_p0()])
        self.P = np.diag(p0)
        self._last_count = np.zeros(len(self._sensors))
        self._initialised = np.zeros(d, dtype=bool)  # eta states set from a first sample
        self._all_initialised = False  # every eta state set (the usual case: one test per update)
        self.n_rejected = 0  # rejections by either gate, any sensor
        self.pos_rejected = 0  # rejected position fixes
        self.pos_resets, self.resets = 0, 0  # resets after too many rejections: position, other sensors
        self._consecutive = 0  # consecutive rejected position fixes
        # other sensors' (consecutive rejections, counter of the last) (a run: the counter moved by one)
        self._runs: dict[int, tuple[int, float]] = {}
        self._since_fix = 0.0  # s since the last accepted position fix
        self._apply_params()

    def _sensor_table(self) -> tuple[np.ndarray, np.ndarray]:
        """The sensors for the compiled step (``kernels/ekf.step``): one row per sensor padded to the
        widest (count input, channels, flags, measurement inputs, state indices, angle flags), and
        the noise variances."""
        W = max((len(ch.idx) for _, _, ch in self._sensors), default=0)
        sens = np.zeros((len(self._sensors), 3 + 3 * W), dtype=np.int64)
        var = np.ones((len(self._sensors), W))
        pos = np.arange(len(self.inp))
        for i, (meas, count, ch) in enumerate(self._sensors):
            m = len(ch.idx)
            row = sens[i]
            row[:3] = count, m, int(ch.pos_fix) | 2 * int(ch.wave) | 4 * int(ch.has_eta)
            row[3 : 3 + m] = pos[meas]
            row[3 + W : 3 + W + m] = ch.idx
            row[3 + 2 * W : 3 + 2 * W + m] = ch.angle
            var[i, :m] = ch.var
        return sens, var

    def _wave_p0(self) -> np.ndarray:
        """Stationary covariance of the wave model: var xi = q^2 / (4 lambda w^3), var zeta = w^2 var xi."""
        if not self.nw:
            return np.zeros(0)
        p = self.params
        q, lam, w = float(p["wave_filter_q"]), float(p["wave_filter_damping"]), float(p["wave_filter_omega"])
        var = q * q / max(4.0 * lam * w**3, 1e-12)
        return np.concatenate([np.full(self.nw, var), np.full(self.nw, w * w * var)])

    # -- parameters ----------------------------------------------------------------------------
    def set_parameter(self, name: str, value: Any) -> None:
        super().set_parameter(name, value)
        self._apply_params()

    def _apply_params(self) -> None:
        p, d = self.params, self.d
        self._inv_tb = 1.0 / float(p["bias_time_constant"])
        self._A[2 * d : 3 * d, 2 * d : 3 * d] = -self._inv_tb * np.eye(d)
        qv = float(p["q_velocity"]) ** 2
        qb = (float(p["q_bias"]) * self._m_diag) ** 2
        nw = self.nw
        qw = float(p["wave_filter_q"]) ** 2
        self._Qc = np.concatenate([np.full(d, Q_ETA), np.full(d, qv), qb,
                                   np.full(nw, Q_ETA), np.full(nw, qw)])
        if nw:
            w0, lam = float(p["wave_filter_omega"]), float(p["wave_filter_damping"])
            Aw = np.block([[np.zeros((nw, nw)), np.eye(nw)],
                           [-(w0**2) * np.eye(nw), -2.0 * lam * w0 * np.eye(nw)]])
            self._A[3 * d :, 3 * d :] = Aw
            self._Aw = Aw
        self._r_scale = float(p["r_scale"])
        self._gate = float(p["innovation_gate"])
        self._gate_p = float(p["gate_probability"])
        self._pos_thr = {m: chi2_quantile(self._gate_p, m) for m in (1, 2, 3)} if self._gate_p > 0 else {}
        self._thr = np.array([self._threshold(ch, len(ch.idx)) for _, _, ch in self._sensors])
        self._max_rej = int(float(p["gate_max_rejections"]))
        self._dr_timeout = float(p["dr_timeout"])

    # -- model ---------------------------------------------------------------------------------
    def _model(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(x) and A = df/dx at x (A is self._A, updated in place).

        With S(nu) = M^-1 (G(nu) + D_Q diag(2|nu|)) (both terms are homogeneous of degree 2, so
        their force is S nu / 2): A_nu,nu = -(S + M^-1 D_L) and
        nu_dot = M^-1 (tau + b - g) - (S/2 + M^-1 D_L) nu.
        """
        A = self._A
        f = np.empty(self.n)
        kernels.ekf.model(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(tau, dtype=float),
                          self.d, self.nw, self._inv_tb, self.Minv, self._MinvG, self._MinvDL, self._MinvDQ,
                          self._g6_arr, self._Aw, A, f)
        return f, A

    # -- filter --------------------------------------------------------------------------------
    def predict(self, h: float, tau: np.ndarray) -> None:
        k = max(1, math.ceil(h / PREDICT_DT_MAX - 1e-9))
        # x and P in place
        kernels.ekf.predict(self.x, self.P, np.ascontiguousarray(tau, dtype=float), k, h / k, self._Qc,
                            self.d, self.nw, self._inv_tb, self.Minv, self._MinvG, self._MinvDL, self._MinvDQ,
                            self._g6_arr, self._Aw, self._A, self._angle_arr)

    def _update(self, z: np.ndarray, ch: _Channels, sensor: int = -1, count: float = 0.0) -> bool:
        """Measurement update with one sensor's channels (sample ``count`` of sensor ``sensor``); False
        if rejected by the gate."""
        if ch.has_eta and not self._all_initialised and not self._initialised[ch.eta_idx].all():
            return self._first_fix(z, ch, sensor, count)
        if ch.wave and self.nw:
            return self._update_wave(z, ch, sensor, count)
        ok, _ = kernels.ekf.update_measured(self.x, self.P, ch.idx, z, ch.angle, ch.var, self._r_scale,
                                            self._threshold(ch, len(z)), self._angle_arr)  # x, P in place
        if not ok:
            return self._rejected(z, ch, sensor, count)
        if ch.pos_fix:
            self._consecutive = 0
        return True

    def _threshold(self, ch: _Channels, m: int) -> float:
        """The largest NIS y^T S^-1 y a sample of m channels may have (inf: no gate applies): the
        innovation gate, and the chi-square gate on position fixes."""
        thr = self._gate if self._gate > 0.0 else math.inf
        if ch.pos_fix and self._gate_p > 0.0:
            thr = min(thr, self._pos_thr.get(m) or chi2_quantile(self._gate_p, m))
        return thr

    def _rejected(self, z: np.ndarray, ch: _Channels, sensor: int = -1, count: float = 0.0) -> bool:
        """Count a gated sample; too many consecutive rejected samples of a sensor reset the states it
        measures (True: the sample was taken that way). Why for every sensor: a gate alone would
        lock a filter that has drifted (or a sensor re-zeroed) out of that sensor for good."""
        if ch.pos_fix:
            self._consecutive += 1
            if 0 < self._max_rej < self._consecutive:
                self._reset_position(z, ch)
                return True
            self.pos_rejected += 1
        elif sensor >= 0:
            run, last = self._runs.get(sensor, (0, -math.inf))
            run = run + 1 if count == last + 1.0 else 1
            self._runs[sensor] = (run, count)
            if 0 < self._max_rej < run:
                self._reset_channels(z, ch)
                self._runs[sensor] = (0, count)
                self.resets += 1
                return True
        self.n_rejected += 1
        return False

    def _update_wave(self, z: np.ndarray, ch: _Channels, sensor: int = -1, count: float = 0.0) -> bool:
        """Update with a sensor the wave filter adds to: positions eta + xi, body velocities nu + R^T zeta.

        General H (one or two non-zeros per row for positions; R^T and its derivative in the angles
        for velocities), Joseph form.
        """
        x, nw, n = self.x, self.nw, self.n
        m = len(z)
        H = np.zeros((m, n))
        H[np.arange(m), ch.idx] = 1.0
        zhat = x[ch.idx].copy()
        vel_rows: list[tuple[int, int]] = []
        for r, i in enumerate(ch.idx.tolist()):
            kind, k = self._wave_map.get(i, ("", -1))
            if kind == "pos":
                H[r, self._w0 + k] = 1.0
                zhat[r] += x[self._w0 + k]
            elif kind == "vel":
                vel_rows.append((r, k))
        if vel_rows:
            zeta = x[self._w0 + nw : self._w0 + 2 * nw]
            v_b, dv, Rt = self._body_wave_velocity(x, zeta)
            zi = self._w0 + nw
            for r, k in vel_rows:
                zhat[r] += v_b[k]
                H[r, zi : zi + nw] = Rt[k]
                for a, col in dv:
                    H[r, a] = col[k]
        y = z - zhat
        if ch.has_angle:
            y[ch.angle] = (y[ch.angle] + math.pi) % (2.0 * math.pi) - math.pi
        ok, _ = kernels.ekf.update_general(self.x, self.P, H, y, ch.var * self._r_scale,
                                           self._threshold(ch, m), self._angle_arr)  # x, P in place
        if not ok:
            return self._rejected(z, ch, sensor, count)
        if ch.pos_fix:
            self._consecutive = 0
        return True

    def _body_wave_velocity(self, x: np.ndarray, zeta: np.ndarray) -> tuple[np.ndarray, list, np.ndarray]:
        """R^T zeta (body frame), its derivatives in the angles as [(state index, column)], and
        d(R^T zeta)/d zeta (rows: body velocity components, columns: the wave states' NED axes).
        With R = Rz Ry Rx: d(R^T z)/dphi = -e_x x (R^T z), d/dtheta = -Rx^T (e_y x (Ry^T Rz^T z)),
        d/dpsi = -R^T (e_z x z).
        """
        if self.d == 6:
            phi, th, psi = x[3:6].tolist()
            z3 = np.zeros(3)
            z3[: len(zeta)] = zeta
            R = rzyx(phi, th, psi)
            Rt = R.T
            v = Rt @ z3
            cf, sf = math.cos(phi), math.sin(phi)
            ct, st = math.cos(th), math.sin(th)
            cp, sp = math.cos(psi), math.sin(psi)
            Rxt = np.array([[1.0, 0.0, 0.0], [0.0, cf, sf], [0.0, -sf, cf]])
            a = np.array([[ct, 0.0, -st], [0.0, 1.0, 0.0], [st, 0.0, ct]]) @ (
                np.array([[cp, sp, 0.0], [-sp, cp, 0.0], [0.0, 0.0, 1.0]]) @ z3)
            d_phi = -np.cross([1.0, 0.0, 0.0], v)
            d_th = -(Rxt @ np.cross([0.0, 1.0, 0.0], a))
            d_psi = -(Rt @ np.cross([0.0, 0.0, 1.0], z3))
            return v, [(3, d_phi), (4, d_th), (5, d_psi)], Rt[:, : len(zeta)]
        psi = float(x[2])
        c, s_ = math.cos(psi), math.sin(psi)
        Rt = np.array([[c, s_], [-s_, c]])
        v = Rt @ zeta[:2]
        d_psi = np.array([-s_ * zeta[0] + c * zeta[1], -c * zeta[0] - s_ * zeta[1], 0.0])
        return np.append(v, 0.0), [(2, d_psi)], np.vstack([Rt, np.zeros((1, 2))])

    def _reset_position(self, z: np.ndarray, ch: _Channels) -> None:
        """Take the fix as the position (the filter had drifted beyond its own covariance)."""
        self._reset_channels(z, ch)
        self._consecutive = 0
        self.pos_resets += 1

    def _reset_channels(self, z: np.ndarray, ch: _Channels) -> None:
        """Take the sample as the states it measures, with the sensor's variance and no correlation."""
        idx = ch.idx
        self.x[idx] = z
        self.P[idx, :] = 0.0
        self.P[:, idx] = 0.0
        self.P[idx, idx] = ch.var * self._r_scale
        for i in idx.tolist():  # the sample is the whole position: no wave displacement on top
            kind, k = self._wave_map.get(i, ("", -1))
            if kind == "pos":
                self.x[self._w0 + k] = 0.0
        self._wrap()

    def _first_fix(self, z: np.ndarray, ch: _Channels, sensor: int = -1, count: float = 0.0) -> bool:
        """First sample of a position/attitude channel: take it as the state, with its noise."""
        fresh = ch.is_eta.copy()
        fresh[fresh] = ~self._initialised[ch.idx[fresh]]
        fi = ch.idx[fresh]
        self.x[fi] = z[fresh]
        self.P[fi, :] = 0.0
        self.P[:, fi] = 0.0
        self.P[fi, fi] = ch.var[fresh] * self._r_scale
        self._initialised[fi] = True
        self._all_initialised = bool(self._initialised.all())
        self._wrap()
        rest = ~fresh
        if rest.any():  # channels of the same sensor already initialised, or velocities
            sub = _Channels.build(ch.idx[rest], ch.angle[rest], np.zeros(int(rest.sum()), bool), ch.var[rest],
                                  ch.pos_fix, any(int(i) in self._wave_map for i in ch.idx[rest]))
            return self._update(z[rest], sub, sensor, count)
        return True

    def _wrap(self) -> None:
        x = self.x
        for i in self._angle_list:
            a = x[i]
            if a > math.pi or a <= -math.pi:
                x[i] = wrap_angle(a)

    # -- block ---------------------------------------------------------------------------------
    def output(self) -> np.ndarray:
        d = self.d
        P = self.P
        y = np.empty(self._n_out)
        y[self._o_state] = self.x[: 3 * d]
        y[self._o_std] = math.sqrt(P[0, 0] + P[1, 1])
        y[self._o_rej] = self.pos_rejected
        y[self._o_dr] = 1.0 if self._since_fix > self._dr_timeout else 0.0
        y[self._o_all_rej] = self.n_rejected
        y[self._o_wave] = self.x[3 * d : 3 * d + self.nw] if self.nw else 0.0
        return y

    def _checked(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != self._in_shape:
            raise ValueError(f"observer: expected {len(self.inp)} inputs, got {u.shape}")
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(self.inp.names, u.tolist(), strict=True) if not math.isfinite(v)]
            raise ValueError(f"observer: input '{bad[0]}' is not finite")
        return u

    def start(self, u: np.ndarray) -> np.ndarray:
        """Start from the samples the sensors already hold at t = 0 (no prediction yet)."""
        self._update_sensors(self._checked(u))
        return self.output()

    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """One compiled call (``kernels/ekf.step``: prediction, the plain updates, the outputs);
        what it leaves (a first fix, the wave filter's updates, a gated sample) goes on here."""
        if type(u) is not np.ndarray or u.shape != self._in_shape or u.dtype != np.float64:
            u = self._checked(u)
        k = max(1, math.ceil(h / PREDICT_DT_MAX - 1e-9))
        y = self._y
        res = kernels.ekf.step(
            u, self.x, self.P, self._tau_idx, k, h / k, self._Qc, self.d, self.nw, self._inv_tb,
            self.Minv, self._MinvG, self._MinvDL, self._MinvDQ, self._g6_arr, self._Aw, self._A,
            self._angle_arr, self._sens, self._sens_var, self._thr, self._r_scale, self._last_count,
            self._all_initialised, self._layout, y)
        if res < 0:
            self._checked(u)  # raises, naming the input
        self._since_fix += h
        if res & kernels.ekf.POS_ACCEPTED:
            self._consecutive = 0
            self._since_fix = 0.0
        i = res >> 2
        if i < len(self._sensors):  # the kernel stopped at sensor i
            if res & kernels.ekf.REJECTED:
                meas, count, ch = self._sensors[i]
                if self._rejected(u[meas].copy(), ch, i, float(u[count])) and ch.pos_fix:
                    self._since_fix = 0.0
                i += 1
            self._update_sensors(u, i)
            return self.output()
        y[self._o_rej] = self.pos_rejected
        y[self._o_dr] = 1.0 if self._since_fix > self._dr_timeout else 0.0
        y[self._o_all_rej] = self.n_rejected
        return y.copy()

    def _step_reference(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """The step as separate calls (``predict``, ``_update`` per sensor, ``output``): what
        ``kernels/ekf.step`` computes (``tests/test_kernels.py``: bit-identical)."""
        u = self._checked(u)
        self._since_fix += h
        self.predict(h, u[self._tau_in])
        self._update_sensors(u)
        return self.output()

    def _update_sensors(self, u: np.ndarray, first: int = 0) -> None:
        """Sequential update with every sensor (from ``first`` on) whose sample counter moved."""
        for i, (meas, count, ch) in enumerate(self._sensors):
            if i < first:
                continue
            c = u[count]
            if c != self._last_count[i]:
                self._last_count[i] = c
                if self._update(u[meas].copy(), ch, i, float(c)) and ch.pos_fix:
                    self._since_fix = 0.0
