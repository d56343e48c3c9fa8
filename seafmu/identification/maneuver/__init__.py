"""Multi-DOF maneuver identification: M, D_L and D_Q of the full 3- or 6-DOF model from one log.

Model (Fossen; the same one ``components.vessel_model`` simulates, without current):

    M nu_dot + C(nu) nu + D_L nu + D_Q (|nu| * nu) + g(eta) = tau,     C(nu) nu linear in M

Two methods, as the identification brief asks:

- ``"ls"`` — the Minerva 2 study's equation-error least squares. ``nu_dot`` is measured or
  differentiated (Savitzky–Golay, or central differences), then, per DOF row,

      Y = nu_dot + M0^-1 (C_M0(nu) nu + g(eta)) = Theta^T [tau, nu, |nu| nu]

  gives M^-1, -M^-1 D_L, -M^-1 D_Q (full matrices, 3d regressors per row), hence M, D_L, D_Q.
  ``coriolis="vessel"`` takes M0 from the vessel file (the thesis's variant), ``"iterate"``
  recomputes C from the estimated M until it settles, and ``"joint"`` regresses the force form
  tau - g = M nu_dot + C_M(nu) nu + D_L nu + D_Q |nu| nu directly, which is linear in the
  entries of a symmetric M, so no prior M is needed. ``"joint"`` is required when the thrusters
  span fewer DOFs than the model (the AMV's two screws: tau_Y is proportional to tau_N, so
  M^-1 cannot be separated from its action on tau in the acceleration form).
- ``"output_error"`` — simulate the model against the measured nu and adjust the diagonal of
  D_L and D_Q (optionally the added-mass diagonal) by MINPACK's Levenberg-Marquardt on the
  Jacobian's block structure (``arrowlm``: linear in the log length), started from the LS
  estimate. Differentiating noisy data biases equation error; output error only ever compares
  simulated with measured velocities, so white sensor noise does not bias it.

Every fit reports in ``FitResult`` (``fitting.py``): parameters with 95 % intervals, correlation
and non-identifiable pairs, NRMSE of simulated nu on the fitted part and on the held-out last
``validation_fraction`` of the log, AIC/BIC, residual whiteness and physical-sanity warnings.
Simulation NRMSE is computed the same way for both methods (restarted segments, see
``_simulate``), so LS and output-error numbers are comparable. Method notes and verified
numbers: docs/maneuver_identification.md.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import savgol_filter

from seafmu.components.allocation import allocation_matrix
from seafmu.components.plant import PlantBlock
from seafmu.components.thrusters import max_thrust, thrust_to_speed, thruster_matrix
from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import ETA_NAMES, NU_NAMES, TAU_NAMES, VesselSpec
from seafmu.identification import arrowlm, fitting
from seafmu.identification.fitting import FitResult
from seafmu.identification.trial import (
    GAP_FACTOR,
    MAX_ABS,
    TrialError,
    constant,
    echo_cell,
    is_number,
    read_text,
)

METHODS = ("ls", "output_error")
CORIOLIS = ("auto", "vessel", "iterate", "joint")
DERIVATIVES = ("auto", "savgol", "central", "measured")
# Fewest samples per regressor of one DOF row (3 d regressors): below this the LS is a guess.
SAMPLES_PER_REGRESSOR = 10
# The motion each velocity component stands for, in error messages.
DOF_WORDS = {"u": "surge", "v": "sway", "w": "heave", "p": "roll", "q": "pitch", "r": "yaw"}


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------

@dataclass
class ManeuverData:
    """One multi-DOF log: time, eta (NED pose), nu (body velocities), tau (generalised force).

    ``tau`` is the force acting on the vessel from its thrusters (B T), in the model's DOF order
    (X, Y, Z, K, M, N or X, Y, N). ``nu_dot`` is given only when accelerations were measured.
    ``source`` says where the data came from and, for CSVs, which columns gave tau.
    """

    t: np.ndarray
    eta: np.ndarray
    nu: np.ndarray
    tau: np.ndarray
    dof: int
    source: str
    nu_dot: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        n, d = self.t.size, self.dof
        if d not in (3, 6):
            raise TrialError(f"{self.source}: dof must be 3 or 6, got {d}")
        for name in ("eta", "nu", "tau", "nu_dot"):
            val = getattr(self, name)
            if val is None:
                continue
            arr = np.asarray(val, dtype=float)
            if arr.shape != (n, d):
                raise TrialError(f"{self.source}: {name} has shape {arr.shape}, expected ({n}, {d})")
            setattr(self, name, arr)

    @property
    def n(self) -> int:
        return int(self.t.size)

    def select(self, idx: slice | np.ndarray) -> ManeuverData:
        """A part of the log (e.g. the held-out segment), same source."""
        return ManeuverData(
            t=self.t[idx], eta=self.eta[idx], nu=self.nu[idx], tau=self.tau[idx], dof=self.dof,
            source=self.source, nu_dot=None if self.nu_dot is None else self.nu_dot[idx],
        )


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and a float array of a CSV; '#' lines are provenance comments; empty cells -> NaN.

    Nothing from the file appears in an error unless it looks like a data table (a header of at
    least two names and a first data row of as many cells with a number among them).
    """
    text = read_text(Path(path), "log")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise TrialError(f"{path}: empty file (no header line)")
    try:
        rows = list(csv.reader(lines))
    except csv.Error as exc:
        raise TrialError(f"{path}: not a CSV file ({exc})") from None
    header = [h.strip() for h in rows[0]]
    if len(header) < 2 or (len(rows) > 1 and (len(rows[1]) != len(header)
                                              or not any(is_number(c) for c in rows[1]))):
        raise TrialError(f"{path}: not a CSV data table (expected optional '#' lines, a header row of "
                         "column names, then rows of numbers separated by commas)")
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise TrialError(f"{path}: data row {r + 1} has {len(row)} cells, the header has {len(header)}")
        for c, cell in enumerate(row):
            cell = cell.strip()
            if cell:
                try:
                    data[r, c] = float(cell)
                except ValueError:
                    raise TrialError(
                        f"{path}: data row {r + 1}, column '{header[c]}': not a number ({echo_cell(cell)})"
                    ) from None
    return header, data


def load_maneuver_csv(path: Path, vessel: VesselSpec, columns: dict[str, str] | None = None,
                      factors: dict[str, float] | None = None) -> ManeuverData:
    """Read a maneuver log; with ``columns=None`` a ``seafmu run`` results.csv is recognised.

    ``columns`` maps logical names to CSV headers (only the ones that differ from the defaults):
    ``time``, the vessel's eta names (``north`` ... ``yaw``), nu names (``u`` ... ``r``),
    ``thrust_1`` ... ``thrust_m`` or ``tau_X`` ... ``tau_N``, and optionally ``u_dot`` ... .
    Defaults look for ``plant.<name>`` then ``<name>``. tau comes from the thrust columns through
    the vessel's thruster matrix (the true force on the hull) when they exist, else from
    ``allocator.tau_alloc_*`` (the allocated command: ignores thruster lag and saturation);
    ``ManeuverData.source`` says which. Every problem found is reported, one line each.
    ``factors`` (logical name -> factor) converts columns logged in other units to SI (deg -> rad);
    ``trial.maneuver_factors`` derives them from a trial's column units.
    """
    path = Path(path)
    header, table = _read_table(path)
    columns = dict(columns or {})
    d = vessel.dof
    index = {h: i for i, h in enumerate(header)}
    problems: list[str] = []
    found: dict[str, int] = {}

    def find(key: str, candidates: list[str], required: bool = True) -> int | None:
        if key in columns:
            if columns[key] in index:
                found[key] = index[columns[key]]
                return found[key]
            problems.append(f"column '{columns[key]}' (given for '{key}') is not in the file")
            return None
        for c in candidates:
            if c in index:
                found[key] = index[c]
                return found[key]
        if required:
            problems.append(f"missing column for '{key}' (looked for {', '.join(candidates)})")
        return None

    i_t = find("time", ["time", "t"])
    i_eta = [find(n, [f"plant.{n}", n]) for n in ETA_NAMES[d]]
    i_nu = [find(n, [f"plant.{n}", n]) for n in NU_NAMES[d]]
    m = vessel.thrusters.count
    thrust_keys = [f"thrust_{i + 1}" for i in range(m)]
    tau_keys = [f"tau_{n}" for n in TAU_NAMES[d]]
    want_tau = any(k in columns for k in tau_keys)
    i_thr = [find(k, [f"plant.{k}", k], required=False) for k in thrust_keys]
    i_tau = [find(k, [f"allocator.tau_alloc_{k[4:]}", k, f"plant.{k}"], required=False) for k in tau_keys]
    B = thruster_matrix(vessel.thrusters, d)
    if not want_tau and all(i is not None for i in i_thr):
        tau_cols = i_thr
        tau_note = f"tau = B T from {', '.join(header[i] for i in i_thr)} (thrust on the hull)"
    elif all(i is not None for i in i_tau):
        tau_cols = i_tau
        tau_note = f"tau from {', '.join(header[i] for i in i_tau)}"
        if header[i_tau[0]].startswith("allocator."):
            tau_note += " (allocated command: thruster lag and saturation are not in it)"
    else:
        tau_cols = []
        tau_note = ""
        problems.append(
            f"no generalised force: need thrust_1..thrust_{m} (plant.thrust_i) or "
            f"tau_{'/'.join(TAU_NAMES[d])} (allocator.tau_alloc_*) columns"
        )
    nu_dot_idx = [find(f"{n}_dot", [f"plant.{n}_dot", f"{n}_dot"], required=False) for n in NU_NAMES[d]]
    have_nu_dot = all(i is not None for i in nu_dot_idx)

    mismatch = _vessel_problems(index, columns, vessel)
    if mismatch:  # explains any missing columns: reported alone
        raise TrialError("\n".join(f"{path}: {p}" for p in mismatch))
    used = [i for i in [i_t, *i_eta, *i_nu, *tau_cols] if i is not None]
    if have_nu_dot:
        used += [i for i in nu_dot_idx if i is not None]
    for i in used:
        bad = np.flatnonzero(~np.isfinite(table[:, i]))
        if bad.size:
            problems.append(
                f"column '{header[i]}' has {bad.size} empty/NaN/inf value(s), first at data row {bad[0] + 1}"
            )
    min_n = SAMPLES_PER_REGRESSOR * 3 * d
    if table.shape[0] < min_n:
        problems.append(f"only {table.shape[0]} samples; a {d}-DOF maneuver fit needs at least {min_n}")
    if i_t is not None and table.shape[0] > 1:
        t = table[:, i_t]
        dt = np.diff(t)
        bad = np.flatnonzero(~(dt > 0))
        if bad.size:
            k = bad[0]
            problems.append(
                f"time is not strictly increasing at data row {k + 2} (t = {t[k + 1]:g} after {t[k]:g})"
            )
        elif np.all(np.isfinite(dt)):
            problems += _gap_problems(t, "data row ", 2)
    if problems:
        raise TrialError("\n".join(f"{path}: {p}" for p in problems))

    for key, factor in (factors or {}).items():  # to SI, before any column is combined
        if key in found:
            table[:, found[key]] *= factor
    for i in used:  # finite, but too large to square (e.g. 1e308)
        big = np.flatnonzero(~(np.abs(table[:, i]) <= MAX_ABS))
        if big.size:
            problems.append(f"column '{header[i]}' is {table[big[0], i]:.6g} at data row {big[0] + 1}: "
                            f"out of range (|value| > {MAX_ABS:g} in SI units; squares in the fit would "
                            "overflow)")
    if problems:
        raise TrialError("\n".join(f"{path}: {p}" for p in problems))
    tau_raw = table[:, tau_cols]
    problems += _excitation_problems(table[:, i_nu], tau_raw, [header[i] for i in i_nu],
                                     [header[i] for i in tau_cols], NU_NAMES[d])
    problems += _thrust_problems(tau_raw, [header[i] for i in tau_cols], vessel, tau_cols is i_thr)
    if problems:
        raise TrialError("\n".join(f"{path}: {p}" for p in problems))
    tau = tau_raw @ B.T if tau_cols is i_thr else tau_raw
    return ManeuverData(
        t=table[:, i_t],
        eta=table[:, i_eta],
        nu=table[:, i_nu],
        tau=tau,
        dof=d,
        source=f"{path} [{tau_note}]",
        nu_dot=table[:, nu_dot_idx] if have_nu_dot else None,
    )


_SIX_ONLY = ("down", "roll", "pitch", "w", "p", "q")  # eta/nu names a 3-DOF vessel lacks
_THRUSTER_FAMILIES = ("plant.thrust_{}", "thrust_{}", "plant.n_{}", "n_{}", "allocator.n_cmd_{}", "n_cmd_{}")


def _vessel_problems(index: dict[str, int], columns: dict[str, str], vessel: VesselSpec) -> list[str]:
    """Signs that the log was recorded on another vessel: other DOFs, more thrusters, or column
    roles this vessel does not have. One line each; empty when the log fits the vessel."""
    d, m, name = vessel.dof, vessel.thrusters.count, vessel.name
    hint = "a log of another vessel? (name its vessel with --vessel or the trial's 'vessel')"
    out = []
    six = set(_SIX_ONLY) | {"tau_Z", "tau_K", "tau_M"} | {f"{n}_dot" for n in ("w", "p", "q")}
    for role in columns:
        if d == 3 and role in six:
            out.append(f"columns.{role}: vessel '{name}' has 3 DOF (no {role}): {hint}")
        elif role.startswith("thrust_") and role[7:].isdigit() and int(role[7:]) > m:
            out.append(f"columns.{role}: vessel '{name}' has {m} thruster(s): {hint}")
    if d == 3:
        for prefix in ("plant.", ""):
            hits = [prefix + n for n in _SIX_ONLY if prefix + n in index]
            if len(hits) == len(_SIX_ONLY):
                out.append(f"the log has 6-DOF columns ({', '.join(hits)}), vessel '{name}' has 3 DOF: "
                           f"{hint}")
                break
    else:
        mapped = set(columns)
        six_found = [n for n in _SIX_ONLY if n in mapped or f"plant.{n}" in index or n in index]
        three_found = [n for n in ("north", "east", "yaw", "u", "v", "r")
                       if n in mapped or f"plant.{n}" in index or n in index]
        if not six_found and len(three_found) == 6:
            out.append(f"the log has 3-DOF columns only (north, east, yaw, u, v, r), vessel '{name}' has "
                       f"6 DOF: {hint}")
    for family in _THRUSTER_FAMILIES:
        k = m
        while family.format(k + 1) in index:
            k += 1
        if k > m:
            out.append(f"the log has columns for {k} thrusters ({family.format(1)} ... {family.format(k)}), "
                       f"vessel '{name}' has {m}: {hint}")
            break
    return out


def _gap_problems(t: np.ndarray, unit: str, offset: int) -> list[str]:
    """A time step over GAP_FACTOR median sample intervals: samples are missing (one line)."""
    dt = np.diff(t)
    if dt.size < 2:
        return []
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > GAP_FACTOR * med)
    if not gaps.size:
        return []
    k = int(gaps[0])
    return [f"time jumps from {t[k]:g} s to {t[k + 1]:g} s at {unit}{k + offset} ({dt[k] / med:.3g} sample "
            f"intervals of {med:g} s; {gaps.size} gap(s) over {GAP_FACTOR:g} intervals): samples are missing "
            "there; split the log into parts without gaps"]


def _excitation_problems(nu: np.ndarray, tau: np.ndarray, nu_cols: list[str], tau_cols: list[str],
                         nu_names: tuple[str, ...]) -> list[str]:
    """Columns that never change: a DOF that does not move, or forces that never vary, leave
    nothing to identify (instead of a singular matrix later)."""
    out = []
    still = [j for j in range(nu.shape[1]) if constant(nu[:, j])]
    for j in still:
        out.append(f"column '{nu_cols[j]}' ({nu_names[j]}) is constant ({nu[0, j]:g} throughout): "
                   f"{DOF_WORDS.get(nu_names[j], nu_names[j])} is not excited, its damping cannot be "
                   "identified")
    if tau.shape[1] and all(constant(tau[:, j]) for j in range(tau.shape[1])):
        out.append(f"the forces ({', '.join(tau_cols)}) are constant: nothing excites the vessel")
    if len(still) == nu.shape[1] and out:
        out = [f"no motion: every velocity column ({', '.join(nu_cols)}) is constant, nothing to identify"]
    return out


def _thrust_problems(tau_raw: np.ndarray, cols: list[str], vessel: VesselSpec,
                     per_thruster: bool) -> list[str]:
    """Forces far beyond what the vessel's thrusters can give (3x): another vessel or a unit error."""
    t_min, t_max = max_thrust(vessel.thrusters)
    cap_t = np.maximum(np.abs(t_min), np.abs(t_max))
    if per_thruster:
        caps = cap_t
    else:
        B = thruster_matrix(vessel.thrusters, vessel.dof)
        caps = np.abs(B) @ cap_t
    out = []
    for j, c in enumerate(cols):
        peak = float(np.max(np.abs(tau_raw[:, j]))) if tau_raw.shape[0] else 0.0
        if caps[j] > 0 and peak > 3.0 * caps[j]:
            out.append(f"column '{c}' reaches {peak:.4g}, over 3x what vessel '{vessel.name}' can give "
                       f"({caps[j]:.4g}): a log of another vessel, or a unit error?")
    return out


# ---------------------------------------------------------------------------------------------
# simulated trials (tests, benchmark, experiment design, replay)
# ---------------------------------------------------------------------------------------------

def multisine(t: np.ndarray, channels: int, fmax: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean multisines, one per channel on interleaved frequency grids (mutually orthogonal
    over the record), peak-normalised to 1; amplitudes fall as 1/sqrt(k) so slow DOFs move."""
    duration = float(t[-1] - t[0]) if t.size > 1 else 1.0
    f0 = 1.0 / duration
    ks = np.arange(1, max(int(fmax / f0), channels + 1) + 1)
    out = np.zeros((t.size, channels))
    for i in range(channels):
        k = ks[(ks % channels) == i]
        phase = rng.uniform(0.0, 2.0 * np.pi, k.size)
        s = (np.sin(2.0 * np.pi * f0 * np.outer(t - t[0], k) + phase) / np.sqrt(k)).sum(axis=1)
        out[:, i] = s / max(float(np.max(np.abs(s))), 1e-12)
    return out


def default_amplitude(vessel: VesselSpec) -> np.ndarray:
    """Generalised-force amplitudes of the excitation: large in the DOFs the thrusters push
    well, small in roll/pitch (weak restoring: 0.05 m metacentric height on Minerva 2)."""
    if vessel.dof == 6:
        return np.array([250.0, 250.0, 150.0, 80.0, 100.0, 80.0])
    return np.array([25.0, 8.0, 2.0])


def simulate_maneuver(
    vessel: VesselSpec,
    duration: float = 300.0,
    dt: float = 0.01,
    seed: int = 0,
    amplitude: np.ndarray | None = None,
    fmax: float = 0.25,
    attitude_gains: tuple[float, float] = (1000.0, 800.0),
    commands: np.ndarray | None = None,
    substep: float = 0.01,
    plant_params: dict[str, float] | None = None,
) -> tuple[ManeuverData, np.ndarray]:
    """A noise-free maneuver trial from seafmu's own plant (``PlantBlock``, noise_scale = 0).

    Excitation: a multisine generalised force per DOF (``amplitude``, up to ``fmax`` Hz),
    allocated to the thrusters by the pseudo-inverse; for 6 DOF a PD term on roll and pitch
    (``attitude_gains`` = (K_p, K_d) in N m/rad, N m s/rad) keeps the angles moderate, as an
    ROV's attitude control would in a sea trial. ``commands`` (n, m) replays given shaft-speed
    commands open loop instead (the close-the-loop check). ``plant_params`` are further
    PlantBlock parameters (e.g. ``current_speed``, ``current_direction``: an environment the
    identified model may lack). Returns the log (tau = B T from the plant's true thrusts) and the
    commands used, one row per step.
    """
    d, m = vessel.dof, vessel.thrusters.count
    steps = round(duration / dt)
    t = np.arange(steps + 1) * dt
    B = thruster_matrix(vessel.thrusters, d)
    if commands is not None:
        commands = np.asarray(commands, dtype=float)
        if commands.shape != (steps, m):
            raise ValueError(f"commands must have shape ({steps}, {m}), got {commands.shape}")
        tau_d = None
    else:
        amp = default_amplitude(vessel) if amplitude is None else np.asarray(amplitude, dtype=float)
        tau_d = multisine(t, d, fmax, np.random.default_rng(seed)) * amp
        P = allocation_matrix(B)
    plant = PlantBlock(vessel, {**(plant_params or {}), "noise_scale": 0.0, "substep": min(substep, dt)})
    names = PlantBlock.interface(vessel).output_names()  # outputs located by name, not position
    i_eta = [names.index(n) for n in vessel.eta_names]
    i_nu = [names.index(n) for n in vessel.nu_names]
    i_thr = [names.index(f"thrust_{i + 1}") for i in range(m)]
    i_roll, i_pitch, i_p, i_q = (names.index(n) for n in ("roll", "pitch", "p", "q")) if d == 6 else (0,) * 4
    y = plant.output()
    out = np.empty((steps + 1, y.size))
    out[0] = y
    cmds = np.empty((steps, m)) if commands is None else commands
    kp, kd = attitude_gains
    for k in range(steps):
        if tau_d is not None:
            demand = tau_d[k].copy()
            if d == 6:
                demand[3] -= kp * y[i_roll] + kd * y[i_p]
                demand[4] -= kp * y[i_pitch] + kd * y[i_q]
            cmds[k] = thrust_to_speed(vessel.thrusters, P @ demand)
        y = plant.step(float(t[k]), dt, cmds[k])
        out[k + 1] = y
    data = ManeuverData(
        t=t, eta=out[:, i_eta], nu=out[:, i_nu], tau=out[:, i_thr] @ B.T, dof=d,
        source=f"simulated by PlantBlock ({vessel.name}, {duration:g} s, dt {dt:g} s, seed {seed})",
    )
    return data, cmds


def write_maneuver_csv(data: ManeuverData, path: Path, provenance: str = "") -> Path:
    """The log as a CSV that ``load_maneuver_csv`` reads without a column map (SI units):
    time, eta names, nu names, tau_X ... (one '#' provenance line first)."""
    d = data.dof
    names = ["time", *ETA_NAMES[d], *NU_NAMES[d], *(f"tau_{n}" for n in TAU_NAMES[d])]
    table = np.column_stack([data.t, data.eta, data.nu, data.tau])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        fh.write(f"# {provenance or data.source}\n")
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.10g")
    return path


def add_sensor_noise(data: ManeuverData, vessel: VesselSpec, scale: float, seed: int = 0) -> ManeuverData:
    """White Gaussian noise on eta and nu, std = ``scale`` x the vessel file's sensor noise_std
    (0 for channels no sensor measures); tau stays exact (thrust from measured shaft speed)."""
    rng = np.random.default_rng(seed)
    std = {c: float(s) for sen in vessel.sensors for c, s in zip(sen.channels, sen.noise_std, strict=True)}
    d = data.dof
    s_eta = np.array([std.get(n, 0.0) for n in ETA_NAMES[d]]) * scale
    s_nu = np.array([std.get(n, 0.0) for n in NU_NAMES[d]]) * scale
    return replace(
        data,
        eta=data.eta + rng.standard_normal(data.eta.shape) * s_eta,
        nu=data.nu + rng.standard_normal(data.nu.shape) * s_nu,
        source=f"{data.source} + sensor noise x{scale:g} (seed {seed})",
        nu_dot=None,
    )


# ---------------------------------------------------------------------------------------------
# model pieces, vectorised over samples (and over parameter sets in the simulator)
# ---------------------------------------------------------------------------------------------

def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def coriolis_force(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C_M(nu) nu for every row of ``nu`` (..., d) with the symmetric part of M (..., d, d).

    Same formula as ``kinematics.m2c`` / ``VesselModel``: [nu2 x a; nu1 x a + nu2 x b] with
    [a; b] = M nu (6 DOF), [-r a_y, r a_x, u a_y - v a_x] (3 DOF). Linear in M.
    """
    a = np.einsum("...ij,...j->...i", _sym(M), nu)
    if nu.shape[-1] == 6:
        u, v, w, p, q, r = (nu[..., i] for i in range(6))
        a1, a2, a3, b1, b2, b3 = (a[..., i] for i in range(6))
        return np.stack([
            q * a3 - r * a2, r * a1 - p * a3, p * a2 - q * a1,
            v * a3 - w * a2 + q * b3 - r * b2,
            w * a1 - u * a3 + r * b1 - p * b3,
            u * a2 - v * a1 + p * b2 - q * b1,
        ], axis=-1)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    ax, ay = a[..., 0], a[..., 1]
    return np.stack([-r * ay, r * ax, u * ay - v * ax], axis=-1)


def coriolis_tensor(M: np.ndarray) -> np.ndarray:
    """T (d, d*d) with C_M(nu) nu = T (nu kron nu): the quadratic form by polarisation."""
    d = M.shape[0]
    eye = np.eye(d)
    q = coriolis_force(M, eye)  # row j: Q(e_j)
    T = np.zeros((d, d, d))
    for j in range(d):
        T[:, j, j] = q[j]
        for k in range(j + 1, d):
            T[:, j, k] = T[:, k, j] = 0.5 * (coriolis_force(M, eye[j] + eye[k]) - q[j] - q[k])
    return T.reshape(d, d * d)


class _Restoring:
    """g(eta) of the vessel file (roll and pitch enter; zero for 3 DOF), vectorised."""

    def __init__(self, vessel: VesselSpec) -> None:
        self.dof = vessel.dof
        rs = vessel.restoring
        if self.dof == 6 and rs is not None:
            W, Bu = rs.weight, rs.buoyancy
            self.wb = W - Bu
            self.gx, self.gy, self.gz = (W * np.asarray(rs.r_g) - Bu * np.asarray(rs.r_b)).tolist()
        else:
            self.wb = self.gx = self.gy = self.gz = 0.0

    def __call__(self, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
        if self.dof == 3:
            return np.zeros((*np.shape(phi), 3))
        sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
        wb, gx, gy, gz = self.wb, self.gx, self.gy, self.gz
        return np.stack([
            wb * st,
            -wb * ct * sp,
            -wb * ct * cp,
            -gy * ct * cp + gz * ct * sp,
            gz * st + gx * ct * cp,
            -gx * ct * sp - gy * st,
        ], axis=-1)


def plant_matrices(vessel: VesselSpec) -> dict[str, np.ndarray]:
    """M, D_L, D_Q as the plant simulates them (symmetric parts of M_RB and M_A)."""
    vm = VesselModel(vessel)
    return {"M": vm.M.copy(), "D_L": vm.D_L.copy(), "D_Q": vm.D_Q.copy(), "M_RB": vm.M_RB.copy()}


# ---------------------------------------------------------------------------------------------
# preprocessing: derivative and consistent smoothing
# ---------------------------------------------------------------------------------------------

@dataclass
class _Prepared:
    t: np.ndarray
    dt: float
    eta: np.ndarray  # smoothed like nu
    nu: np.ndarray
    nu_dot: np.ndarray
    tau: np.ndarray
    nu_raw: np.ndarray
    edge: int  # samples at each end where the derivative filter is one-sided
    note: str


def _uniform(data: ManeuverData, warnings: list[str]) -> ManeuverData:
    """Resample onto a uniform grid when the log's sampling jitters (> 1 % of the median step)."""
    dt = np.diff(data.t)
    med = float(np.median(dt))
    if np.max(np.abs(dt - med)) <= 0.01 * med:
        return data
    t = np.arange(data.t[0], data.t[-1] + 0.5 * med, med)
    t = t[t <= data.t[-1] + 1e-12]

    def interp(a: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, data.t, a[:, j]) for j in range(a.shape[1])])

    warnings.append(f"non-uniform sampling: resampled linearly onto a {med:g} s grid")
    return ManeuverData(t=t, eta=interp(data.eta), nu=interp(data.nu), tau=interp(data.tau), dof=data.dof,
                        source=data.source, nu_dot=None if data.nu_dot is None else interp(data.nu_dot))


def noise_ratio(nu: np.ndarray) -> float:
    """Largest per-DOF ratio of white-noise std to signal std, from second differences
    (robust MAD; a smooth signal's second difference is O(dt^2) and does not count)."""
    d2 = np.diff(nu, n=2, axis=0)
    sigma = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / math.sqrt(6.0)
    return float(np.max(sigma / np.maximum(nu.std(axis=0), 1e-300)))


def _prepare(data: ManeuverData, derivative: str, smoothing: float | None, polyorder: int) -> _Prepared:
    """nu_dot and the regressor signals, all filtered by the same smoother.

    Savitzky–Golay (default): a local polynomial of order ``polyorder`` over a window of
    ``smoothing`` seconds (None: the shortest window, polyorder + 3 samples, for clean logs)
    gives nu_dot as its derivative and smoothed nu, eta and tau as its value — the same filter on
    both sides of the equation, so smoothing adds no lag between regressors and output.
    Central differences: ``np.gradient`` (second order), no smoothing.
    """
    dt = float(np.median(np.diff(data.t)))
    if derivative == "measured":
        if data.nu_dot is None:
            raise TrialError(f"{data.source}: derivative='measured' but the log has no nu_dot")
        return _Prepared(data.t, dt, data.eta, data.nu, data.nu_dot, data.tau, data.nu, 0,
                         "nu_dot measured (from the log)")
    if derivative == "central":
        return _Prepared(data.t, dt, data.eta, data.nu, np.gradient(data.nu, dt, axis=0), data.tau,
                         data.nu, 1, "nu_dot by central differences (np.gradient), no smoothing")
    if derivative != "savgol":
        raise ValueError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {derivative!r}")
    min_win = polyorder + 3 if polyorder % 2 == 0 else polyorder + 2
    win = min_win if smoothing is None else max(min_win, 2 * round(0.5 * smoothing / dt) + 1)
    if win >= data.n:
        raise TrialError(f"{data.source}: smoothing window of {win} samples exceeds the {data.n}-sample log")

    def sg(a: np.ndarray, deriv: int = 0) -> np.ndarray:
        return savgol_filter(a, win, polyorder, deriv=deriv, delta=dt, axis=0, mode="interp")

    eta = data.eta.copy()
    if data.dof == 6:  # roll and pitch enter the restoring force
        eta[:, 3:5] = sg(data.eta[:, 3:5])
    return _Prepared(
        data.t, dt, eta, sg(data.nu), sg(data.nu, 1), sg(data.tau), data.nu, win // 2,
        f"nu_dot by Savitzky-Golay (order {polyorder}, window {win} samples = {win * dt:.3g} s); "
        "nu, roll/pitch and tau smoothed by the same filter",
    )


# ---------------------------------------------------------------------------------------------
# equation error (LS)
# ---------------------------------------------------------------------------------------------

@dataclass
class _LSResult:
    M: np.ndarray
    D_L: np.ndarray
    D_Q: np.ndarray
    names: list[str]
    values: np.ndarray
    cov: np.ndarray
    residual: np.ndarray  # (n, d) equation error
    n_rows: int
    note: str
    iterations: int = 1


def _names(prefix: str, d: int, entries: str) -> list[tuple[str, int, int]]:
    if entries == "diag":
        return [(f"{prefix}[{i},{i}]", i, i) for i in range(d)]
    if entries == "upper":
        return [(f"{prefix}[{i},{j}]", i, j) for i in range(d) for j in range(i, d)]
    return [(f"{prefix}[{i},{j}]", i, j) for i in range(d) for j in range(d)]


def _ls_acceleration(prep: _Prepared, rows: np.ndarray, g: np.ndarray, M0: np.ndarray,
                     iterate: bool = False, warnings: list[str] | None = None) -> _LSResult:
    """Thesis form: Y = nu_dot + M0^-1 (C_M0 nu + g) = Theta^T [tau, nu, |nu| nu], per row.

    ``iterate``: replace M0 by the symmetric part of the estimated M and refit until Theta
    settles (only Y changes, so the normal equations are factored once).
    """
    d = prep.nu.shape[1]
    nu, tau = prep.nu[rows], prep.tau[rows]
    Phi = np.hstack([tau, nu, np.abs(nu) * nu])
    # normal equations with unit-scaled columns (condition ~20 on a rich trial; an SVD of the
    # tall regressor matrix is what makes numpy slow on a busy multi-threaded BLAS)
    A = Phi.T @ Phi
    cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
    G = np.linalg.pinv(A / np.outer(cs, cs), hermitian=True) / np.outer(cs, cs)
    P = G @ Phi.T

    def fit(Mc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Y = prep.nu_dot[rows] + np.linalg.solve(Mc, (coriolis_force(Mc, nu) + g[rows]).T).T
        return Y, P @ Y

    Y, Theta = fit(M0)
    iterations = 1
    if iterate:
        for iterations in range(2, 201):  # noqa: B007 - the count is reported
            M_new = _sym(np.linalg.inv(Theta[:d].T))
            if np.any(np.linalg.eigvalsh(M_new) <= 0):
                if warnings is not None:
                    warnings.append("Coriolis iteration stopped: the estimated M is not positive definite")
                break
            Y, nxt = fit(M_new)
            change = float(np.max(np.abs(nxt - Theta)) / max(float(np.max(np.abs(Theta))), 1e-300))
            Theta = nxt
            if change < 1e-10:
                break
        else:
            if warnings is not None:
                warnings.append("Coriolis iteration did not settle in 200 iterations")
    E = Y - Phi @ Theta
    n, p = Phi.shape
    Sigma = E.T @ E / max(n - p, 1)
    cov_theta = np.kron(Sigma, G)  # vec by output row: theta_i = Theta[:, i]

    A, BL, BQ = Theta[:d].T, Theta[d : 2 * d].T, Theta[2 * d :].T
    M = np.linalg.inv(A)
    D_L, D_Q = -M @ BL, -M @ BQ
    # delta method: d[M, D_L, D_Q] = -M dA [M, D_L, D_Q] - M [0, dB_L, dB_Q]
    out_idx = _names("M", d, "full") + _names("D_L", d, "full") + _names("D_Q", d, "full")
    values = np.concatenate([M.ravel(), D_L.ravel(), D_Q.ravel()])
    Jd = np.zeros((3 * d * d, p * d))
    for i in range(d):  # output row i of Theta^T
        for k in range(p):
            dA, dBL, dBQ = np.zeros((d, d)), np.zeros((d, d)), np.zeros((d, d))
            blk, col = divmod(k, d)
            (dA, dBL, dBQ)[blk][i, col] = 1.0
            dM = -M @ dA @ M
            dDL = -M @ dA @ D_L - M @ dBL
            dDQ = -M @ dA @ D_Q - M @ dBQ
            Jd[:, i * p + k] = np.concatenate([dM.ravel(), dDL.ravel(), dDQ.ravel()])
    cov = Jd @ cov_theta @ Jd.T
    return _LSResult(M, D_L, D_Q, [nm for nm, _, _ in out_idx], values, cov, E, n * d,
                     "acceleration form (Minerva 2 study)", iterations)


def _ls_joint(prep: _Prepared, rows: np.ndarray, g: np.ndarray, damping: str) -> _LSResult:
    """Force form, linear in a symmetric M (incl. its Coriolis terms), D_L and D_Q:
    tau - g = M nu_dot + C_M(nu) nu + D_L nu + D_Q |nu| nu, all DOF rows in one weighted LS."""
    d = prep.nu.shape[1]
    nu, nud = prep.nu[rows], prep.nu_dot[rows]
    y = prep.tau[rows] - g[rows]
    n = nu.shape[0]
    entries = "full" if damping == "full" else "diag"
    m_idx = _names("M", d, "upper")
    l_idx = _names("D_L", d, entries)
    q_idx = _names("D_Q", d, entries)
    P = len(m_idx) + len(l_idx) + len(q_idx)
    X = np.zeros((n, d, P))  # regressors, filled in place (no list of columns beside it)
    for k, (_, i, j) in enumerate(m_idx):
        E = np.zeros((d, d))
        E[i, j] = E[j, i] = 1.0
        X[:, :, k] = nud @ E.T + coriolis_force(E, nu)
    nq = np.abs(nu) * nu
    k = len(m_idx)
    for src, idx in ((nu, l_idx), (nq, q_idx)):
        for _, i, j in idx:
            X[:, i, k] = src[:, j]
            k += 1
    # per-DOF Gram matrices once (the weights only scale them): few, large BLAS calls, which a
    # busy shared machine serves far better than many
    grams = [X[:, i, :].T @ X[:, i, :] for i in range(d)]
    cross = [X[:, i, :].T @ y[:, i] for i in range(d)]

    def solve(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted normal equations (column-scaled): theta and (X^T W X)^-1."""
        A = sum(w[i] ** 2 * grams[i] for i in range(d))
        b = sum(w[i] ** 2 * cross[i] for i in range(d))
        cs = np.sqrt(np.maximum(np.diag(A), 1e-300))
        G = np.linalg.pinv(A / np.outer(cs, cs), hermitian=True) / np.outer(cs, cs)
        return G @ b, G

    w = 1.0 / np.maximum(y.std(axis=0), 1e-12)  # first pass: each DOF row scaled to unit spread
    theta, G = solve(w)
    E = y - np.einsum("ndp,p->nd", X, theta)
    sd = np.sqrt(np.sum(E**2, axis=0) / max(n - P / d, 1))
    w = 1.0 / np.maximum(sd, 1e-12 * max(float(np.max(sd)), 1e-300))
    theta, G = solve(w)  # second pass: weights from the residual spread per DOF (feasible GLS)
    E = y - np.einsum("ndp,p->nd", X, theta)
    s2 = float(np.sum((E * w) ** 2)) / max(n * d - P, 1)
    cov = s2 * G
    M = np.zeros((d, d))
    for k, (_, i, j) in enumerate(m_idx):
        M[i, j] = M[j, i] = theta[k]
    D_L, D_Q = np.zeros((d, d)), np.zeros((d, d))
    off = len(m_idx)
    for k, (_, i, j) in enumerate(l_idx):
        D_L[i, j] = theta[off + k]
    off += len(l_idx)
    for k, (_, i, j) in enumerate(q_idx):
        D_Q[i, j] = theta[off + k]
    names = [nm for nm, _, _ in m_idx + l_idx + q_idx]
    # residual as acceleration-equivalent for reporting (force residual / M row scale)
    return _LSResult(M, D_L, D_Q, names, theta, cov, E, n * d,
                     f"force form, symmetric M with its Coriolis terms solved jointly ({damping} damping)")


# ---------------------------------------------------------------------------------------------
# simulation (output error, NRMSE): batched RK4 over parameter sets and restarted segments
# ---------------------------------------------------------------------------------------------

class _Simulator:
    """RK4 of the model for many (M, D_L, D_Q) and many segments at once.

    State: nu (3 DOF) or [roll, pitch, nu] (6 DOF: restoring needs the attitude). tau is linear
    between samples (RK4 stages use tau at t, the midpoint and t + h). Each segment restarts
    from the measured (smoothed) state, so a fit is not dominated by drift from one start.
    Same equations as ``VesselModel.derivative`` without current (checked by a test).

    Diagnosis extensions (``run(..., F0=, vc=)``): a constant generalised force F0 added to tau,
    and a constant NED current vc = (north, east): damping and the added-mass Coriolis terms then
    act on nu_r = nu - R^T [vc; 0] as in the plant (C_RB(nu) nu + C_A(nu_r) nu_r), with R from the
    simulated roll/pitch and the *measured* heading (``psi``, set by ``_sim_setup``).
    """

    def __init__(self, vessel: VesselSpec, t: np.ndarray, tau: np.ndarray, x_meas: np.ndarray,
                 starts: np.ndarray, length: int) -> None:
        self.d = vessel.dof
        self.g = _Restoring(vessel)
        self.length = length
        self.h = float(t[1] - t[0])
        n = t.size
        idx = starts[:, None] + np.arange(length + 1)[None, :]
        self.valid = idx < n
        idx = np.minimum(idx, n - 1)
        self.tau = tau[idx]  # (S, L+1, d)
        self.tau_mid = 0.5 * (self.tau[:, :-1] + self.tau[:, 1:])
        self.x0 = x_meas[starts]  # (S, nx)
        self.idx = idx
        self.M_RB = _sym(np.asarray(vessel.M_RB, dtype=float))
        self.psi: np.ndarray | None = None  # (S, L+1) measured heading (unwrapped), for a current
        self.psi_mid: np.ndarray | None = None  # (S, L)

    def _current(self, vc: np.ndarray, psi: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Body-frame current nu_c (K, S, d) from the NED current vc (K, 2) at heading psi (1, S)."""
        vn, ve = vc[:, 0, None], vc[:, 1, None]
        cs, sn = np.cos(psi), np.sin(psi)
        out = np.zeros((*x.shape[:-1], self.d))
        if self.d == 3:
            out[..., 0] = cs * vn + sn * ve
            out[..., 1] = -sn * vn + cs * ve
            return out
        phi, th = x[..., 0], x[..., 1]
        cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th)
        out[..., 0] = cs * ct * vn + sn * ct * ve
        out[..., 1] = (-sn * cp + cs * st * sp) * vn + (cs * cp + sp * st * sn) * ve
        out[..., 2] = (sn * sp + cs * cp * st) * vn + (-cs * sp + st * sn * cp) * ve
        return out

    def _f(self, x: np.ndarray, tau: np.ndarray, W: np.ndarray, vc: np.ndarray | None = None,
           psi: np.ndarray | None = None) -> np.ndarray:
        """x_dot; nu_dot = [tau - g, nu (x) nu, nu, |nu| nu] @ W (one matmul per parameter set).

        With a current: [tau - g, nu (x) nu, nu_r (x) nu_r, nu_r, |nu_r| nu_r] @ W (split Coriolis).
        """
        if self.d == 6:
            phi, th, nu = x[..., 0], x[..., 1], x[..., 2:]
            force = tau - self.g(phi, th)
        else:
            nu, force = x, np.broadcast_to(tau, x.shape)
        nn = (nu[..., :, None] * nu[..., None, :]).reshape(*nu.shape[:-1], -1)
        if vc is None or psi is None:
            nu_dot = np.matmul(np.concatenate([force, nn, nu, np.abs(nu) * nu], axis=-1), W)
        else:
            nur = nu - self._current(vc, psi, x)
            nnr = (nur[..., :, None] * nur[..., None, :]).reshape(*nur.shape[:-1], -1)
            nu_dot = np.matmul(np.concatenate([np.broadcast_to(force, nu.shape), nn, nnr, nur,
                                               np.abs(nur) * nur], axis=-1), W)
        if self.d == 3:
            return nu_dot
        p, q, r = nu[..., 3], nu[..., 4], nu[..., 5]
        sp, cp = np.sin(phi), np.cos(phi)
        phi_dot = p + (sp * q + cp * r) * np.tan(th)
        th_dot = cp * q - sp * r
        return np.concatenate([phi_dot[..., None], th_dot[..., None], nu_dot], axis=-1)

    def run(self, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, x0: np.ndarray | None = None,
            F0: np.ndarray | None = None, vc: np.ndarray | None = None) -> np.ndarray:
        """Simulated states (K, S, L+1, nx) for K parameter sets (M, DL, DQ each (K, d, d));
        ``x0`` (K, S, nx) replaces the measured segment starts; ``F0`` (K, d) constant force,
        ``vc`` (K, 2) NED current (see the class docstring)."""
        K = M.shape[0]
        cur = vc is not None and self.psi is not None and self.psi_mid is not None
        d = self.d
        W = np.empty((K, d + (2 if cur else 1) * d**2 + 2 * d, d))
        T_RB = coriolis_tensor(self.M_RB) if cur else None
        for k in range(K):
            Ms = _sym(M[k])
            Minv = np.linalg.inv(Ms)
            if T_RB is not None:  # C_RB(nu) nu + C_A(nu_r) nu_r: Coriolis is linear in M
                cor = [-Minv @ T_RB, -Minv @ coriolis_tensor(Ms - self.M_RB)]
            else:
                cor = [-Minv @ coriolis_tensor(Ms)]
            W[k] = np.hstack([Minv, *cor, -Minv @ DL[k], -Minv @ DQ[k]]).T
        x = np.broadcast_to(self.x0 if x0 is None else x0, (K, *self.x0.shape)).copy()
        out = np.empty((K, *self.x0.shape[:1], self.length + 1, self.x0.shape[-1]))
        out[:, :, 0] = x
        h = self.h
        f0 = 0.0 if F0 is None else np.asarray(F0, dtype=float)[:, None, :]
        vck = np.asarray(vc, dtype=float) if cur and vc is not None else None
        no_psi = (None, None, None)
        with np.errstate(all="ignore"):
            for k in range(self.length):
                t0, tm, t1 = (self.tau[None, :, k] + f0, self.tau_mid[None, :, k] + f0,
                              self.tau[None, :, k + 1] + f0)
                p0, pm, p1 = no_psi if vck is None else (
                    self.psi[None, :, k], self.psi_mid[None, :, k], self.psi[None, :, k + 1])  # type: ignore[index]
                k1 = self._f(x, t0, W, vck, p0)
                k2 = self._f(x + 0.5 * h * k1, tm, W, vck, pm)
                k3 = self._f(x + 0.5 * h * k2, tm, W, vck, pm)
                k4 = self._f(x + h * k3, t1, W, vck, p1)
                x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
                x = np.where(np.abs(x) < 1e6, x, np.nan)  # a diverging model stays NaN
                out[:, :, k + 1] = x
        return out


def _state(prep_eta: np.ndarray, nu: np.ndarray, d: int) -> np.ndarray:
    return nu if d == 3 else np.hstack([prep_eta[:, 3:5], nu])


@dataclass
class _SimSetup:
    sim: _Simulator
    meas: np.ndarray  # (S, L+1, d) measured nu on the simulation grid
    mask: np.ndarray  # (S, L+1) samples that exist and are compared (not the start)
    scale: np.ndarray  # (d,) spread of measured nu, normalises residuals per DOF
    t: np.ndarray | None = None  # (n_grid,) times of the simulation grid (for plots)


def _sim_setup(vessel: VesselSpec, prep: _Prepared, i0: int, i1: int, segment: float, sim_dt: float,
               scale: np.ndarray | None = None) -> _SimSetup | None:
    """Segments of ``segment`` seconds covering samples [i0, i1), on a grid of about ``sim_dt``."""
    if i1 - i0 < 3:
        return None
    stride = max(1, round(sim_dt / prep.dt))
    sel = np.arange(i0, i1, stride)
    t = prep.t[sel]
    d = prep.nu.shape[1]
    x_meas = _state(prep.eta[sel], prep.nu[sel], d)
    L = max(1, min(sel.size - 1, round(segment / (stride * prep.dt))))
    starts = np.arange(0, sel.size - 1, L)
    sim = _Simulator(vessel, t, prep.tau[sel], x_meas, starts, L)
    # tau at the RK4 midpoints from the full-rate log (a logged sample when the stride is even)
    t_mid = 0.5 * (t[sim.idx[:, :-1]] + t[sim.idx[:, 1:]])
    sim.tau_mid = np.stack([np.interp(t_mid, prep.t, prep.tau[:, j]) for j in range(d)], axis=-1)
    psi = np.unwrap(prep.eta[:, d - 1])  # yaw: last eta entry (3 and 6 DOF)
    sim.psi = psi[sel][sim.idx]
    sim.psi_mid = np.interp(t_mid, prep.t, psi)
    meas = prep.nu_raw[sel][sim.idx]
    mask = sim.valid.copy()
    mask[:, 0] = False
    if scale is None:
        scale = np.maximum(prep.nu_raw[i0:i1].std(axis=0), 1e-9)
    return _SimSetup(sim, meas, mask, scale, t)


def _one(effect: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """Effect terms of one parameter set as the batched simulator takes them (K = 1)."""
    return {k: np.asarray(v, dtype=float)[None] for k, v in (effect or {}).items()}


def _trace(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray, run: str,
           effect: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Measured and simulated nu on the simulation grid, every sample once, for the overlay and
    residual plots; ``restarts`` are the segment starts (the simulation restarts there)."""
    x = setup.sim.run(M[None], DL[None], DQ[None], **_one(effect))[0]
    d = setup.meas.shape[-1]
    mask = setup.mask
    assert setup.t is not None
    return {"run": run, "t": setup.t[setup.sim.idx][mask], "y": setup.meas[mask], "yhat": x[..., -d:][mask],
            "restarts": setup.t[setup.sim.idx[:, 0]]}


def _sim_residual(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                  x0: np.ndarray | None = None, **effect: np.ndarray) -> np.ndarray:
    """Normalised nu residuals (K, S, L+1, d); NaN where a simulation diverged."""
    x = setup.sim.run(M, DL, DQ, x0, **effect)
    d = setup.meas.shape[-1]
    return (x[..., -d:] - setup.meas[None]) / setup.scale


def _nrmse_per_dof(setup: _SimSetup, M: np.ndarray, DL: np.ndarray, DQ: np.ndarray,
                   effect: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-DOF NRMSE ‖y − ŷ‖/‖y − ȳ‖ of simulated nu, and the flat normalised residual."""
    r = _sim_residual(setup, M[None], DL[None], DQ[None], **_one(effect))[0]
    mask = setup.mask
    y = setup.meas[mask]
    res = r[mask] * setup.scale
    out = np.array([fitting.nrmse(y[:, j], y[:, j] - res[:, j]) if np.all(np.isfinite(res[:, j]))
                    else math.inf for j in range(y.shape[1])])
    return out, r[mask]


# ---------------------------------------------------------------------------------------------
# statistics helpers
# ---------------------------------------------------------------------------------------------

def _autocorr_inflation(residual: np.ndarray, max_lag: int = 2000) -> float:
    """1 + 2 sum(rho_k) up to the first non-positive lag, averaged over columns: the factor by
    which correlated residuals shrink the effective sample size (and widen honest CIs)."""
    r = residual.reshape(residual.shape[0], -1)
    factors = []
    for j in range(r.shape[1]):
        x = r[:, j][np.isfinite(r[:, j])]
        if x.size < 8:
            continue
        x = x - x.mean()
        nfft = 1 << int(np.ceil(np.log2(2 * x.size)))
        f = np.fft.rfft(x, nfft)
        acf = np.fft.irfft(f * np.conj(f), nfft)[: min(max_lag, x.size // 4)]
        if acf[0] <= 0.0:
            continue
        rho = acf[1:] / acf[0]
        stop = np.flatnonzero(rho <= 0.0)
        rho = rho[: stop[0]] if stop.size else rho
        factors.append(1.0 + 2.0 * float(np.sum(rho)))
    return float(np.mean(factors)) if factors else 1.0


def _whiteness(residual: np.ndarray, names: list[str]) -> dict[str, Any]:
    per = {n: fitting.whiteness_test(residual[:, j]) for j, n in enumerate(names)}
    finite = [v for v in per.values() if v["lags"] > 0]
    return {
        "lags": max((v["lags"] for v in finite), default=0),
        "fraction_outside": max((v["fraction_outside"] for v in finite), default=float("nan")),
        "ljung_box_p": min((v["ljung_box_p"] for v in finite), default=float("nan")),
        "white": bool(finite) and all(v["white"] for v in finite),
        "per_dof": per,
    }


def _sanity(M: np.ndarray, D_L: np.ndarray, D_Q: np.ndarray, M_RB: np.ndarray,
            ci: dict[str, tuple[float, float]], nu_rms: np.ndarray, names: list[str],
            fitted: set[str]) -> list[str]:
    """Physical sanity of an identified model, one warning per problem (brief section 2)."""
    out = []
    d = M.shape[0]

    def below(key: str, value: float, bound: float, what: str) -> str | None:
        """A warning when value < bound; 'significant' only if the whole CI is below it."""
        if value >= bound:
            return None
        lo, hi = ci.get(key, (value, value))
        if hi < bound:
            return f"{what}: unphysical (significant: 95 % CI [{lo:.4g}, {hi:.4g}] below {bound:.4g})"
        return (f"{what}, but not significantly (95 % CI [{lo:.4g}, {hi:.4g}] reaches {bound:.4g}): "
                "consistent with the physical bound")

    for i in range(d):
        for label, mat in (("linear", D_L), ("quadratic", D_Q)):
            key = f"D_{'L' if label == 'linear' else 'Q'}[{i},{i}]"
            if key in fitted:
                w = below(key, mat[i, i], 0.0, f"negative {label} damping {key} = {mat[i, i]:.4g} in "
                          f"{names[i]} (the force pushes along the motion)")
                if w:
                    out.append(w)
        key = f"M[{i},{i}]"
        if key in fitted:
            w = below(key, M[i, i], M_RB[i, i], f"negative added mass in {names[i]}: {key} = {M[i, i]:.4g} "
                      f"< rigid-body {M_RB[i, i]:.4g}")
            if w:
                out.append(w)
    ev = np.linalg.eigvalsh(_sym(M))
    if np.any(ev <= 0):
        out.append(f"identified mass matrix is not positive definite (smallest eigenvalue {ev.min():.4g}): "
                   "the model cannot be simulated")
    D_eq = _sym(D_L + 2.0 * D_Q * np.abs(nu_rms)[None, :])
    evd = np.linalg.eigvalsh(D_eq)
    if np.any(evd < 0):
        out.append(f"damping linearised at the trial's rms speeds has a negative eigenvalue "
                   f"({evd.min():.4g}): the fitted model injects energy in some direction (unstable drift)")
    return out


# ---------------------------------------------------------------------------------------------
# the public fit
# ---------------------------------------------------------------------------------------------

def _run_ls(prep: _Prepared, rows: np.ndarray, vessel: VesselSpec, plant: dict[str, np.ndarray],
            coriolis: str, damping: str, warnings: list[str]) -> _LSResult:
    """The equation-error fit in the requested form."""
    d = vessel.dof
    n = prep.t.size
    g_all = _Restoring(vessel)(prep.eta[:, 3], prep.eta[:, 4]) if d == 6 else np.zeros((n, 3))
    if coriolis == "joint":
        return _ls_joint(prep, rows, g_all, damping)
    ls = _ls_acceleration(prep, rows, g_all, plant["M"], coriolis == "iterate", warnings)
    if coriolis == "iterate":
        ls.note += f", Coriolis from the estimated M ({ls.iterations} iterations)"
    else:
        ls.note += ", Coriolis and restoring from the vessel file's M"
    return ls


def identify_maneuver(
    data: ManeuverData,
    vessel: VesselSpec,
    method: str = "ls",
    validation_fraction: float = 0.3,
    *,
    coriolis: str = "auto",
    damping: str = "full",
    derivative: str = "auto",
    smoothing: float | None = None,
    polyorder: int = 4,
    oe_added_mass: bool = False,
    oe_base: str = "vessel",
    segment: float = 30.0,
    sim_dt: float = 0.05,
    max_nfev: int = 40,
    effect: str | None = None,
    oe_start: dict[str, float] | None = None,
) -> FitResult:
    """Identify M, D_L, D_Q from a maneuver log (see the module docstring for the methods).

    The first 1 − ``validation_fraction`` of the log is fitted, the rest held out.
    ``coriolis``: "vessel" (C and g from the vessel file's M, the thesis's variant), "iterate"
    (C from the estimated M until it settles), "joint" (force form, M solved with its own
    Coriolis terms; ``damping="diagonal"`` restricts D_L, D_Q to diagonals), "auto" (= "vessel"
    when the thrusters span all DOFs, else "joint"). ``derivative``/``smoothing``: how nu_dot is
    obtained (``_prepare``). Output error: ``oe_added_mass`` also fits the added-mass diagonal;
    ``oe_base`` = "vessel" keeps every other entry from the vessel file, "ls" from the LS fit.
    ``segment`` s: restart length of the simulations, on a grid of about ``sim_dt`` s.
    ``effect`` (output error only): a diagnosis extension, "current" (NED current fitted, damping
    on nu - nu_c) or "constant_force" (a force per DOF); ``oe_start``: start values by name.
    """
    if effect is not None:
        effect_names(effect, vessel.dof)  # validates the name
        if method != "output_error":
            raise ValueError("an effect extension is fitted by output error (method='output_error')")
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if coriolis not in CORIOLIS:
        raise ValueError(f"coriolis must be one of {', '.join(CORIOLIS)}, got {coriolis!r}")
    if damping not in ("full", "diagonal"):
        raise ValueError(f"damping must be 'full' or 'diagonal', got {damping!r}")
    if oe_base not in ("vessel", "ls"):
        raise ValueError(f"oe_base must be 'vessel' or 'ls', got {oe_base!r}")
    if not 0.0 <= validation_fraction < 0.9:
        raise ValueError(f"validation_fraction must be in [0, 0.9), got {validation_fraction}")
    if data.dof != vessel.dof:
        raise TrialError(
            f"{data.source}: the log has {data.dof} DOF, vessel '{vessel.name}' has {vessel.dof}"
        )
    d = vessel.dof
    min_n = SAMPLES_PER_REGRESSOR * 3 * d
    if data.n < min_n:
        raise TrialError(
            f"{data.source}: only {data.n} samples; a {d}-DOF maneuver fit needs at least {min_n}"
        )
    for name in ("t", "eta", "nu", "tau"):
        arr = getattr(data, name)
        if not np.all(np.isfinite(arr)):
            raise TrialError(f"{data.source}: {name} contains NaN or inf")
        if np.any(np.abs(arr) > MAX_ABS):
            raise TrialError(f"{data.source}: {name} has values out of range (|value| > {MAX_ABS:g}; "
                             "squares in the fit would overflow)")
    if np.any(np.diff(data.t) <= 0):
        raise TrialError(f"{data.source}: time is not strictly increasing")
    problems = _gap_problems(data.t, "sample ", 2) + _excitation_problems(
        data.nu, data.tau, list(NU_NAMES[d]), [f"tau_{n}" for n in TAU_NAMES[d]], NU_NAMES[d])
    if problems:
        raise TrialError("\n".join(f"{data.source}: {p}" for p in problems))

    warnings: list[str] = []
    data = _uniform(data, warnings)
    if derivative not in DERIVATIVES:
        raise ValueError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {derivative!r}")
    if derivative == "auto":
        derivative = "measured" if data.nu_dot is not None else "savgol"
    n = data.n
    i_split = n if validation_fraction == 0 else round(n * (1.0 - validation_fraction))

    plant = plant_matrices(vessel)
    M_RB = plant["M_RB"]
    B = thruster_matrix(vessel.thrusters, d)
    rank = int(np.sum(np.linalg.eigvalsh(B @ B.T) > 1e-10 * np.max(np.linalg.eigvalsh(B @ B.T))))
    if coriolis == "auto":
        coriolis = "vessel" if rank == d else "joint"
    if coriolis != "joint" and damping != "full":
        raise ValueError("damping='diagonal' needs coriolis='joint' (the acceleration form is per row, full)")
    if coriolis != "joint" and rank < d:
        warnings.append(f"the thrusters span only {rank} of {d} DOFs: in the acceleration form M^-1 is not "
                        "identifiable from tau (use coriolis='joint')")

    # Smoothing: a clean log needs none; on a noisy one (second-difference noise estimate) the
    # window is chosen among a few by the LS model's simulated NRMSE on the fitted part.
    candidates: list[float | None] = [smoothing]
    ratio = noise_ratio(data.nu)
    if derivative == "savgol" and smoothing is None and ratio > 2e-3:
        dt = float(np.median(np.diff(data.t)))
        candidates = [None] + [s for s in (0.25, 0.5, 1.0, 2.0) if s / dt < 0.05 * n and s > 8 * dt]
    best: tuple | None = None
    scores: dict[str, float] = {}
    for sm in candidates:
        prep = _prepare(data, derivative, sm, polyorder)
        rows = np.arange(prep.edge, min(i_split, n - prep.edge))
        if rows.size < min_n:
            raise TrialError(
                f"{data.source}: {rows.size} samples left to fit after the hold-out; need {min_n}"
            )
        ls = _run_ls(prep, rows, vessel, plant, coriolis, damping, warnings if len(candidates) == 1 else [])
        fit_setup = _sim_setup(vessel, prep, 0, i_split, segment, sim_dt)
        if fit_setup is None:
            raise TrialError(f"{data.source}: too few samples to simulate the fitted part")
        score = float("nan")
        if len(candidates) > 1:
            sc, _ = _nrmse_per_dof(fit_setup, _sym(ls.M), ls.D_L, ls.D_Q)
            score = float(np.mean(sc))
            scores["none" if sm is None else f"{sm:g} s"] = score
        if best is None or (np.isfinite(score) and not score >= best[0]):
            best = (score, sm, prep, rows, ls, fit_setup)
    assert best is not None
    _, smoothing, prep, rows, ls, fit_setup = best
    if len(candidates) > 1:  # rerun to collect the chosen fit's warnings
        ls = _run_ls(prep, rows, vessel, plant, coriolis, damping, warnings)
    tau_cov = np.cov((prep.tau[rows] / np.maximum(prep.tau[rows].std(axis=0), 1e-12)).T)
    tau_rank = int(np.sum(np.linalg.eigvalsh(tau_cov) > 1e-8))
    if tau_rank < d:
        warnings.append(f"the logged forces excite only {tau_rank} of {d} independent directions")
    if prep.dt > 0.05 and derivative != "measured" and method == "ls":
        warnings.append(f"coarse sampling ({prep.dt:g} s): differentiation bias grows as dt^2; "
                        "prefer method='output_error' for final numbers")

    nu_names = NU_NAMES[d]
    nu_rms = np.sqrt(np.mean(prep.nu_raw[rows] ** 2, axis=0))
    val_setup = _sim_setup(vessel, prep, i_split, n, segment, sim_dt, scale=fit_setup.scale)
    extras: dict[str, Any] = {
        "preprocessing": prep.note,
        "noise_ratio": ratio,
        "smoothing_s": smoothing,
        "smoothing_scores": scores,
        "source": data.source,
        "coriolis": coriolis,
        "ls_form": ls.note,
        "segment_s": segment,
        "sim_dt_s": fit_setup.sim.h,
        "ls_matrices": {"M": ls.M.tolist(), "D_L": ls.D_L.tolist(), "D_Q": ls.D_Q.tolist()},
        "vessel_matrices": {k: v.tolist() for k, v in plant.items()},
        "equation_error_rms": np.sqrt(np.mean(ls.residual**2, axis=0)).tolist(),
        "fit_samples": [0, i_split],
        "validation_samples": [i_split, n],
    }

    if method == "ls":
        M, D_L, D_Q = ls.M, ls.D_L, ls.D_Q
        names, values = ls.names, ls.values
        infl = _autocorr_inflation(ls.residual)
        cov = ls.cov * infl
        n_res = ls.n_rows
        ci = fitting.confidence_intervals(names, values, cov, n_res)
        corr = fitting.correlation_matrix(cov)
        fitted = set(names)
        extras["ci_inflation"] = infl
        method_label = f"maneuver LS ({ls.note})"
    else:
        (M, D_L, D_Q, names, values, cov, ci, corr, n_res, oe_info) = _output_error(
            vessel, prep, fit_setup, ls, plant, oe_added_mass, oe_base, max_nfev, warnings, effect, oe_start)
        fitted = set(names)
        extras.update(oe_info)
        method_label = (f"maneuver output error (diagonal D_L, D_Q{', added mass' if oe_added_mass else ''}; "
                        f"start: {ls.note}; other entries from the "
                        f"{'vessel file' if oe_base == 'vessel' else 'LS fit'})")

    # simulation NRMSE (same for both methods)
    eff = extras.get("effect_terms") if method != "ls" else None
    nr_fit, res_fit = _nrmse_per_dof(fit_setup, M, D_L, D_Q, eff)
    if val_setup is not None and validation_fraction > 0:
        nr_val, _ = _nrmse_per_dof(val_setup, M, D_L, D_Q, eff)
        extras["n_validation"] = int(val_setup.mask.sum() * d)
        nrmse_validation = float(np.mean(nr_val))
        extras["nrmse_validation_per_dof"] = dict(zip(nu_names, nr_val.tolist(), strict=True))
    else:
        nrmse_validation = float("nan")
    nrmse_fit = float(np.mean(nr_fit))
    extras["nrmse_fit_per_dof"] = dict(zip(nu_names, nr_fit.tolist(), strict=True))
    extras["nu_names"] = list(nu_names)
    extras["predictions"] = [_trace(fit_setup, M, D_L, D_Q, "fit", eff)]
    if val_setup is not None and validation_fraction > 0:
        extras["predictions"].append(_trace(val_setup, M, D_L, D_Q, "validation", eff))
    if not np.all(np.isfinite(res_fit)):
        warnings.append("the fitted model diverges when simulated against the trial (unstable)")
        res_ok = np.nan_to_num(res_fit, nan=1e3)
    else:
        res_ok = res_fit
    rss = float(np.sum(res_ok**2))
    aic, bic = fitting.aic_bic(rss, res_ok.size, len(names))
    whiteness = _whiteness(res_ok, nu_names)

    warnings += _sanity(M, D_L, D_Q, M_RB, ci, nu_rms, nu_names, fitted)
    nonid = fitting.nonidentifiable_pairs(names, corr)
    if nonid:
        warnings.append(f"{len(nonid)} parameter pair(s) with |correlation| > "
                        f"{fitting.NONIDENTIFIABLE_CORR}: not separately identifiable from this trial "
                        "(see nonidentifiable)")
    wide = [k for k in names if _is_diag(k) and _rel_halfwidth(ci[k], values[names.index(k)]) > 0.5]
    if wide:
        warnings.append(f"{len(wide)} diagonal parameter(s) with a 95 % CI wider than +-50 % of the value "
                        f"(poorly excited): {', '.join(wide[:8])}{' ...' if len(wide) > 8 else ''}")
    if SAMPLES_PER_REGRESSOR * len(names) > n_res:
        warnings.append(f"{len(names)} parameters from {n_res} equations: too few data per parameter")
    extras["matrices"] = {"M": M.tolist(), "D_L": D_L.tolist(), "D_Q": D_Q.tolist()}
    return FitResult(
        params=dict(zip(names, (float(v) for v in values), strict=True)),
        ci95=ci,
        correlation=corr,
        param_names=list(names),
        nonidentifiable=nonid,
        nrmse_fit=nrmse_fit,
        nrmse_validation=nrmse_validation,
        aic=aic,
        bic=bic,
        whiteness=whiteness,
        warnings=warnings,
        n_samples=int(rows.size),
        method=method_label,
        extras=extras,
    )


def _is_diag(name: str) -> bool:
    """True for a diagonal matrix entry 'X[i,i]' (effect parameters are not matrix entries)."""
    if "[" not in name or "," not in name:
        return False
    i, j = name[name.index("[") + 1 : -1].split(",")
    return i == j


def _rel_halfwidth(ci: tuple[float, float], value: float) -> float:
    return 0.5 * (ci[1] - ci[0]) / max(abs(value), 1e-300)


def _output_error(vessel: VesselSpec, prep: _Prepared, setup: _SimSetup | None, ls: _LSResult,
                  plant: dict[str, np.ndarray], added_mass: bool, base: str, max_nfev: int,
                  warnings: list[str], effect: str | None = None,
                  start: dict[str, float] | None = None) -> tuple:
    """Diagonal D_L, D_Q (and added mass) by simulation error, started from the LS estimate.

    ``effect`` adds a diagnosis extension's parameters (``effect_names``), started at "absent";
    ``start`` (name -> value, e.g. a baseline fit's) replaces the LS start where it has a value.
    """
    if setup is None:
        raise TrialError("too few samples for an output-error fit")
    d = vessel.dof
    if base == "ls":
        M0, DL0, DQ0 = _sym(ls.M), ls.D_L.copy(), ls.D_Q.copy()
    else:
        M0, DL0, DQ0 = plant["M"].copy(), plant["D_L"].copy(), plant["D_Q"].copy()
    # start: LS diagonal (falls back to the vessel file where LS is unusable)
    ls_ok_M = np.all(np.linalg.eigvalsh(_sym(ls.M)) > 0)
    start_L = np.where(np.isfinite(np.diag(ls.D_L)), np.diag(ls.D_L), np.diag(plant["D_L"]))
    start_Q = np.where(np.diag(ls.D_Q) > 0, np.diag(ls.D_Q), np.diag(plant["D_Q"]))
    names = [f"D_L[{i},{i}]" for i in range(d)] + [f"D_Q[{i},{i}]" for i in range(d)]
    p0 = [*start_L, *start_Q]
    if added_mass:
        names += [f"M[{i},{i}]" for i in range(d)]
        mdiag = np.diag(ls.M) if ls_ok_M else np.diag(plant["M"])
        p0 += list(np.where(mdiag > 0, mdiag, np.diag(plant["M"])))
    if start:
        p0 = [float(start.get(nm, v)) for nm, v in zip(names, p0, strict=True)]
    e0 = len(names)  # effect parameters follow the model's
    enames = effect_names(effect, d)
    names += enames
    p0 = np.array([*p0, *([0.0] * len(enames))], dtype=float)
    nu_abs = np.sqrt(np.mean(prep.nu_raw**2, axis=0))
    # parameter scales: a linear coefficient is worth its quadratic one times the rms speed
    sQ = np.maximum(np.abs(p0[d : 2 * d]), 1e-3 * np.diag(plant["M"]))
    sL = np.maximum(np.abs(p0[:d]), sQ * nu_abs + 1e-6)
    scales = [*sL, *sQ] + ([*np.abs(p0[2 * d : 3 * d])] if added_mass else [])
    if effect == "constant_force":  # a few % of the force each DOF sees
        scales += list(0.05 * np.maximum(prep.tau.std(axis=0), 1e-3))
    elif effect == "current":
        scales += [0.1, 0.1]  # m/s
    scales = np.maximum(np.array(scales), 1e-9)
    # initial state of every segment is estimated too (multiple shooting without continuity):
    # restarting from a noisy measured state biases the damping (measured: -7 % in sway)
    x0_meas = setup.sim.x0
    S, nx = x0_meas.shape
    x_scale = np.maximum(np.sqrt(np.mean(x0_meas**2, axis=0)), 1e-6)
    npar = p0.size
    mask = setup.mask
    maskd = np.broadcast_to(mask[:, :, None], (*mask.shape, d))  # residuals that count

    def mats(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        K = P.shape[0]
        M = np.broadcast_to(M0, (K, d, d)).copy()
        DL = np.broadcast_to(DL0, (K, d, d)).copy()
        DQ = np.broadcast_to(DQ0, (K, d, d)).copy()
        ii = np.arange(d)
        DL[:, ii, ii] = P[:, :d]
        DQ[:, ii, ii] = P[:, d : 2 * d]
        if added_mass:
            M[:, ii, ii] = P[:, 2 * d : 3 * d]
        return M, DL, DQ

    def terms(P: np.ndarray) -> dict[str, np.ndarray]:
        """The effect's terms for the simulator: F0 (K, d) or vc (K, 2)."""
        if effect == "constant_force":
            return {"F0": P[:, e0 : e0 + d]}
        if effect == "current":
            return {"vc": P[:, e0 : e0 + 2]}
        return {}

    def residuals(Z: np.ndarray) -> np.ndarray:
        """Residuals per segment (K, S, R) for several scaled parameter sets, R = (L + 1) d rows
        per segment, zero where no sample is compared (the segment start, past the log's end)."""
        P = Z[:, :npar] * scales
        X0 = Z[:, npar:].reshape(-1, S, nx) * x_scale
        r = _sim_residual(setup, *mats(P), X0, **terms(P))
        r = np.where(maskd, np.where(np.isfinite(r), r, 1e3), 0.0)
        return r.reshape(P.shape[0], S, -1)

    def fun(z: np.ndarray) -> np.ndarray:
        return residuals(z[None])[0]

    def jac(z: np.ndarray) -> arrowlm.ArrowJacobian:
        """Finite differences in one batched simulation: one run per model parameter, and one
        per state component (it perturbs that component in every segment at once; segments
        are independent, so segment s's rows give its own state's column). Kept by blocks
        (arrowlm): a dense matrix would have one column per segment and state, rows x columns
        growing as the square of the log length."""
        step = 1e-6 * np.maximum(1.0, np.abs(z))
        Z = np.repeat(z[None], 1 + npar + nx, axis=0)
        Z[1 + np.arange(npar), np.arange(npar)] += step[:npar]
        hx = 1e-6
        for j in range(nx):
            Z[1 + npar + j, npar + j :: nx] += hx
        R = residuals(Z)
        Jp = ((R[1 : 1 + npar] - R[0]) / step[:npar, None, None]).transpose(1, 2, 0)
        Jx = ((R[1 + npar :] - R[0]) / hx).transpose(1, 2, 0)
        return arrowlm.ArrowJacobian(np.ascontiguousarray(Jp), np.ascontiguousarray(Jx))

    # start from the LS diagonal, unless the vessel file's values simulate the trial better
    # (a poorly exciting log gives an LS model that may not even be stable)
    p_file = np.concatenate([np.diag(plant["D_L"]), np.diag(plant["D_Q"])]
                            + ([np.diag(plant["M"])] if added_mass else []) + [np.zeros(len(enames))])
    x0z = (x0_meas / x_scale).ravel()
    z_ls, z_file = np.concatenate([p0 / scales, x0z]), np.concatenate([p_file / scales, x0z])
    costs = np.sum(residuals(np.vstack([z_ls, z_file])) ** 2, axis=(1, 2))
    z0 = z_ls if costs[0] <= costs[1] else z_file
    first = "given start" if start else "LS estimate"
    start_from = first if costs[0] <= costs[1] else f"vessel file ({first} simulated worse)"
    p0 = z0[:npar] * scales
    # MINPACK's Levenberg-Marquardt (as least_squares(method="lm", x_scale=1.0)) on the block
    # structure: time and memory linear in the log length (arrowlm)
    sol = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=max_nfev)
    p = sol.x[:npar] * scales
    if not sol.success:
        warnings.append(f"output-error optimiser stopped: {sol.message}")
    r = sol.fun[maskd.reshape(S, -1)]  # the compared residuals, in time order
    infl = _autocorr_inflation(r.reshape(-1, d))
    # s^2 (J^T J)^-1 over model and initial-state parameters (column-scaled pseudo-inverse), model block
    n_cols = npar + S * nx
    cov = float(r @ r) / max(r.size - n_cols, 1) * sol.jac.scaled(scales).normal().inverse_pp() * infl
    ci = fitting.confidence_intervals(names, p, cov, r.size)
    corr = fitting.correlation_matrix(cov)
    M, DL, DQ = (a[0] for a in mats(p[None]))
    info = {"oe_nfev": int(sol.nfev), "oe_cost": float(sol.cost), "oe_start_from": start_from,
            "oe_start": dict(zip(names, p0.tolist(), strict=True)), "ci_inflation": infl,
            "oe_status": sol.message, "effect": effect,
            "effect_terms": {k: v[0] for k, v in terms(p[None]).items()}}
    return M, DL, DQ, names, p, cov, ci, corr, r.size, info


# Diagnosis extensions of a maneuver fit (catalogue names; docs/maneuver_identification.md).
MANEUVER_EFFECTS = ("current", "constant_force")


def effect_names(effect: str | None, d: int) -> list[str]:
    """Parameter names a maneuver extension adds: the NED current, or a force per DOF."""
    if effect is None:
        return []
    if effect == "current":
        return ["v_c_north", "v_c_east"]
    if effect == "constant_force":
        return [f"F_0[{n}]" for n in TAU_NAMES[d]]
    raise ValueError(f"maneuver effect must be one of {', '.join(MANEUVER_EFFECTS)}, got {effect!r}")
