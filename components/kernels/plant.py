"""The plant's whole co-simulation step in one compiled call (``PlantBlock.step``).

One call does what the plant block did around ``rigid_body.rk4`` in Python: the input check, the
failed drives' stuck commands, the clip to +-n_max, the RK4 sub-steps (with the first-order wave
force re-evaluated at each sub-step's time midpoint when there are waves), the sensors'
sampling (``sensors_update``) and every output (state, thrusts, course and speed over ground,
sensors, wave elevation and force, current, fault indicators). At these sizes the Python around
the kernel cost more than the kernel (issue 13).

Reference forms: ``PlantBlock._step_reference`` (``components/plant.py``) for the step and
``SensorSuite.update`` (``components/sensors.py``) for the sampling; the same operations in the
same order, so the results are bit-identical (``tests/test_kernels.py``).

What stays in Python: the slowly varying current (its Gauss-Markov deviation draws from a NumPy
generator; the kernel gets the NED current before and after the step), drawing the sensors'
noise ahead (``SensorSuite.refill``, when the kernel reports a stream's rows used up), the error
message of a bad input (the kernel only reports it) and the land kinematics of the amphibious AMV.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel
from .rigid_body import rk4, wrap
from .thrust_law import thrust_of
from .waves import elevation, force

BAD_INPUT = -1  # step's return value for a non-finite input (nothing changed)
CHANGED = 1  # a sensor took a new sample
REFILL = 2  # a noise stream's rows are used up: SensorSuite.refill before the next step
CHUNK = 256  # rows of noise drawn ahead (sensors.CHUNK)
_EPS = 1e-6  # sensors._EPS
_PI = math.pi


@kernel
def sensors_update(
    t: float,
    h: float,
    state: np.ndarray,
    s_int: np.ndarray,
    s_conf: np.ndarray,
    s_int_mut: np.ndarray,
    s_float_mut: np.ndarray,
    noise: np.ndarray,
    uniform: np.ndarray,
) -> int:
    """Sample every group with a sample instant in (t, t + h] (``SensorSuite.update``); returns
    CHANGED | REFILL flags. Layout of the packed arrays: ``SensorSuite``."""
    # Long because it is SensorSuite.update and _take in one loop, on the packed arrays.
    G, C = s_int[0], s_int[1]
    o_idx, o_ang, o_yaw, o_ys = 3 + G, 3 + G + C, 3 + G + 2 * C, 3 + 2 * G + 2 * C
    pg, pn, pe = s_int[3 + 3 * G + 2 * C], s_int[4 + 3 * G + 2 * C], s_int[5 + 3 * G + 2 * C]
    kf = C + G
    mag = s_float_mut[kf]
    flags = 0
    for g in range(G):
        rate = s_conf[g]
        last = s_int_mut[G + 1 + g]
        if last == -(2**62):
            last = math.floor(t * rate + _EPS)
            s_int_mut[G + 1 + g] = last
        k = math.floor((t + h) * rate + _EPS)
        if k <= last:
            continue
        s_int_mut[G + 1 + g] = k
        if g == pg:
            start, length = s_float_mut[kf + 3], s_float_mut[kf + 4]
            ts = k / rate
            dropout = length > 0.0 and start - _EPS <= ts < start + length - _EPS
            s_float_mut[kf + 6] = 1.0 if dropout else 0.0
            if dropout:
                continue
        a, b = s_int[2 + g], s_int[3 + g]
        row = s_int_mut[g]
        s_int_mut[g] = row + 1
        if row + 1 >= CHUNK:
            flags |= REFILL
        for i in range(a, b):
            s_float_mut[i] = (state[s_int[o_idx + i]] + s_conf[G + C + i]) + s_conf[G + i] * noise[row, i]
        yaw = s_int[o_yaw + g]
        if mag != 0.0 and yaw >= 0:
            s_float_mut[yaw] += mag * math.sin(state[s_int[o_ys + g]])
        if g == pg:
            j = s_int_mut[G]
            s_int_mut[G] = j + 1
            if j + 1 >= CHUNK:
                flags |= REFILL
            x, ang = uniform[j, 0], uniform[j, 1]
            if x < s_float_mut[kf + 1]:
                size = s_float_mut[kf + 2]
                s_float_mut[pn] += size * math.cos(2.0 * math.pi * ang)
                s_float_mut[pe] += size * math.sin(2.0 * math.pi * ang)
                s_float_mut[kf + 5] += 1.0
        for i in range(a, b):
            if s_int[o_ang + i]:
                v = s_float_mut[i]
                if v > _PI or v <= -_PI:
                    s_float_mut[i] = wrap(v)
        s_float_mut[C + g] += 1.0
        flags |= CHANGED
    return flags


@kernel
def write_outputs(
    t: float,
    x: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    vcn: float,
    vce: float,
    wave_on: bool,
    omega: np.ndarray,
    k: np.ndarray,
    phase: np.ndarray,
    amp: np.ndarray,
    acc_amp: np.ndarray,
    cd: float,
    sd: float,
    W: np.ndarray,
    s_int: np.ndarray,
    s_float_mut: np.ndarray,
    layout: np.ndarray,
    y: np.ndarray,
) -> None:
    """Every output at time t into y (``PlantBlock._outputs``); ``layout`` = positions in y of
    x (n), thrust (m), course and sog (2), the environment (1 + dof + 5), the sensors (C + G)."""
    # Long because it writes each group of outputs in turn (state, thrusts, course and speed over
    # ground unrolled in scalars, environment, sensors); splitting adds calls, not clarity.
    n, m, d = x.shape[0], th.shape[1], flags[0]
    law = flags[1]
    for i in range(n):
        y[layout[i]] = x[i]
    o = n
    for i in range(m):
        ni = x[2 * d + i]
        y[layout[o + i]] = thrust_of(th[0, i] if ni >= 0.0 else th[1, i], ni, law)
    o += m
    if d == 6:  # the first two rows of J(eta) nu (VesselModel.horizontal_velocity)
        phi, theta, psi, u, v, w = x[3], x[4], x[5], x[6], x[7], x[8]
        cphi, sphi = math.cos(phi), math.sin(phi)
        cth, sth = math.cos(theta), math.sin(theta)
        cpsi, spsi = math.cos(psi), math.sin(psi)
        vn = (cpsi * cth * u + (-spsi * cphi + cpsi * sth * sphi) * v
              + (spsi * sphi + cpsi * cphi * sth) * w)
        ve = (spsi * cth * u + (cpsi * cphi + sphi * sth * spsi) * v
              + (-cpsi * sphi + sth * spsi * cphi) * w)
    else:
        psi, u, v = x[2], x[3], x[4]
        c, s = math.cos(psi), math.sin(psi)
        vn, ve = c * u - s * v, s * u + c * v
    sog = math.hypot(vn, ve)
    y[layout[o]] = math.atan2(ve, vn) if sog > 1e-6 else x[d - 1]
    y[layout[o + 1]] = sog
    o += 2
    if wave_on:
        y[layout[o]] = elevation(t, x[0], x[1], omega, k, phase, amp, cd, sd)
        tau = np.empty(d)
        force(t, x, d, omega, k, phase, acc_amp, cd, sd, W, tau)
        for i in range(d):
            y[layout[o + 1 + i]] = tau[i]
    else:
        for i in range(d + 1):
            y[layout[o + i]] = 0.0
    o += 1 + d
    G, C = s_int[0], s_int[1]
    kf = C + G
    y[layout[o]] = vcn
    y[layout[o + 1]] = vce
    y[layout[o + 2]] = s_float_mut[kf] * math.sin(x[d - 1])
    y[layout[o + 3]] = s_float_mut[kf + 5]
    y[layout[o + 4]] = s_float_mut[kf + 6]
    o += 5
    j = 0
    for g in range(G):
        for i in range(s_int[2 + g], s_int[3 + g]):
            y[layout[o + j]] = s_float_mut[i]
            j += 1
        y[layout[o + j]] = s_float_mut[C + g]
        j += 1


@kernel
def step(
    t: float,
    h: float,
    u: np.ndarray,
    drive: np.ndarray,
    x: np.ndarray,
    steps: int,
    vcn: float,
    vce: float,
    vcn1: float,
    vce1: float,
    K: np.ndarray,
    MS: np.ndarray,
    MAL: np.ndarray,
    ML: np.ndarray,
    g6: np.ndarray,
    th: np.ndarray,
    flags: np.ndarray,
    angle_index: np.ndarray,
    wave_on: bool,
    omega: np.ndarray,
    k: np.ndarray,
    phase: np.ndarray,
    amp: np.ndarray,
    acc_amp: np.ndarray,
    cd: float,
    sd: float,
    W: np.ndarray,
    s_int: np.ndarray,
    s_conf: np.ndarray,
    s_int_mut: np.ndarray,
    s_float_mut: np.ndarray,
    noise: np.ndarray,
    uniform: np.ndarray,
    layout: np.ndarray,
    y: np.ndarray,
) -> int:
    """One plant step from t to t + h: x (the state) and y (the outputs) in place.

    ``u``: shaft-speed commands; ``drive`` (2, m): n_max and the speed a failed drive is stuck at
    (NaN: not failed); ``steps`` RK4 sub-steps of h / steps with the current (vcn, vce) of the
    step's start; (vcn1, vce1) is the current reported at t + h. Returns ``BAD_INPUT`` (nothing
    changed) or the CHANGED | REFILL flags of ``sensors_update``.
    """
    m = th.shape[1]
    for i in range(m):
        if not math.isfinite(u[i]):
            return BAD_INPUT
    d = flags[0]
    ncmd = np.empty(m)
    for i in range(m):
        c = u[i]
        stuck = drive[1, i]
        if stuck == stuck:  # failed drives ignore their command
            c = stuck
        nm = drive[0, i]
        if -nm > c:
            c = -nm
        if nm < c:
            c = nm
        ncmd[i] = c
    dt = h / steps
    tau = np.zeros(d)
    if wave_on:  # wave force re-evaluated per sub-step, at its time midpoint
        for j in range(steps):
            force(t + (j + 0.5) * dt, x, d, omega, k, phase, acc_amp, cd, sd, W, tau)
            rk4(x, ncmd, dt, 1, vcn, vce, tau, True, K, MS, MAL, ML, g6, th, flags, angle_index, x)
    else:
        rk4(x, ncmd, dt, steps, vcn, vce, tau, False, K, MS, MAL, ML, g6, th, flags, angle_index, x)
    res = sensors_update(t, h, x, s_int, s_conf, s_int_mut, s_float_mut, noise, uniform)
    write_outputs(t + h, x, th, flags, vcn1, vce1, wave_on, omega, k, phase, amp, acc_amp, cd, sd, W,
                  s_int, s_float_mut, layout, y)
    return res
