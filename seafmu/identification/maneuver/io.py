"""Maneuver logs: ``ManeuverData``, reading a CSV log (with every problem reported, one line
each) and writing one.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seafmu.components.thrusters import max_thrust, thruster_matrix
from seafmu.components.vessel_spec import ETA_NAMES, NU_NAMES, TAU_NAMES, VesselSpec
from seafmu.identification.trial import (
    GAP_FACTOR,
    MAX_ABS,
    TrialError,
    cell_float,
    constant,
    echo_cell,
    field_count_error,
    is_number,
    read_text,
    repeated,
)

# Fewest samples per regressor of one DOF row (3 d regressors): below this the LS is a guess.
SAMPLES_PER_REGRESSOR = 10
# The motion each velocity component stands for, in error messages.
DOF_WORDS = {"u": "surge", "v": "sway", "w": "heave", "p": "roll", "q": "pitch", "r": "yaw"}


@dataclass
class ManeuverData:
    """One multi-DOF log: time, eta (NED pose), nu (body velocities), tau (generalised force).

    ``tau`` is the force acting on the vessel from its thrusters (B T), in the model's DOF order
    (X, Y, Z, K, M, N or X, Y, N). ``nu_dot`` is given only when accelerations were measured.
    ``source`` says where the data came from and, for CSVs, which columns gave tau.

    ``thrust`` (n, m), when the log has one column per thruster, is each thruster's thrust as
    logged (from its shaft speed through the thrust law: what it should deliver), and
    ``efficiency`` (m,) the fraction of it the vessel file says reaches the hull, so that
    tau = B diag(efficiency) thrust. A thruster that delivers less than the file says
    (``effects/thruster_loss.py``) is found from these two.
    """

    t: np.ndarray
    eta: np.ndarray
    nu: np.ndarray
    tau: np.ndarray
    dof: int
    source: str
    nu_dot: np.ndarray | None = None
    thrust: np.ndarray | None = None
    efficiency: np.ndarray | None = None

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
        if self.thrust is not None:
            thr = np.asarray(self.thrust, dtype=float)
            if thr.ndim != 2 or thr.shape[0] != n:
                raise TrialError(f"{self.source}: thrust has shape {thr.shape}, expected ({n}, thrusters)")
            self.thrust = thr
            m = thr.shape[1]
            eff = np.ones(m) if self.efficiency is None else np.asarray(self.efficiency, dtype=float)
            if eff.shape != (m,):
                raise TrialError(f"{self.source}: efficiency has shape {eff.shape}, expected ({m},)")
            self.efficiency = eff

    @property
    def thrust_on_hull(self) -> np.ndarray | None:
        """Per-thruster thrust reaching the hull as the vessel file says (thrust x efficiency)."""
        if self.thrust is None or self.efficiency is None:
            return None
        return self.thrust * self.efficiency

    @property
    def n(self) -> int:
        return int(self.t.size)

    def select(self, idx: slice | np.ndarray) -> ManeuverData:
        """A part of the log (e.g. the held-out segment), same source."""
        return ManeuverData(
            t=self.t[idx], eta=self.eta[idx], nu=self.nu[idx], tau=self.tau[idx], dof=self.dof,
            source=self.source, nu_dot=None if self.nu_dot is None else self.nu_dot[idx],
            thrust=None if self.thrust is None else self.thrust[idx], efficiency=self.efficiency,
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
        rows = list(csv.reader(lines[:2]))
    except csv.Error as exc:
        raise TrialError(f"{path}: not a CSV file ({exc})") from None
    header = [h.strip() for h in rows[0]]
    if len(header) < 2 or (len(rows) > 1 and not any(is_number(c) for c in rows[1])):
        raise TrialError(f"{path}: not a CSV data table (expected optional '#' lines, a header row of "
                         "column names, then rows of numbers separated by commas)")
    fast = _numbers(lines[1:], len(header))
    if fast is not None:
        return header, fast
    try:
        rows = list(csv.reader(lines))
    except csv.Error as exc:
        raise TrialError(f"{path}: not a CSV file ({exc})") from None
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise field_count_error(path, f"data row {r + 1}", len(row), len(header))
        for c, cell in enumerate(row):
            cell = cell.strip()
            if cell:
                try:
                    data[r, c] = cell_float(cell)
                except ValueError:
                    raise TrialError(
                        f"{path}: data row {r + 1}, column '{header[c]}': not a number ({echo_cell(cell)})"
                    ) from None
    return header, data


def _numbers(lines: list[str], n_cols: int) -> np.ndarray | None:
    """The data rows as floats by numpy's compiled reader (a 10 000-row log: ~5 ms, where the cell
    by cell reading takes ~100 ms); None for anything it does not read as a full table of numbers
    (empty cells, a row of another length, a cell that is not a number), which ``_read_table``
    then reads cell by cell and reports."""
    if not lines:
        return None
    # numpy's reader refuses '_' digit separators today, but an older one parsed cells with
    # Python's float(), which takes '0_5' as 5; the cell-by-cell reader reports them. One memchr
    # per line: ~10 ms for 100 000 rows of 133 columns, which numpy reads in ~2.7 s.
    if any("_" in ln for ln in lines):
        return None
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=float, ndmin=2, quotechar='"', comments=None)
    except ValueError:
        return None
    return data if data.shape == (len(lines), n_cols) else None


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
    # Over 80 lines: it collects every problem of the log before raising (one line each), in the
    # order a user fixes them (columns, then values, then units and ranges, then excitation); the
    # checks share the column lookup ``find`` and the list ``problems``.
    path = Path(path)
    header, table = _read_table(path)
    columns = dict(columns or {})
    d = vessel.dof
    index = {h: i for i, h in enumerate(header)}
    problems: list[str] = []
    found: dict[str, int] = {}

    def use(key: str, name: str) -> int:
        twice = repeated(header, name)
        if twice:
            problems.append(twice)
        found[key] = index[name]
        return found[key]

    def find(key: str, candidates: list[str], required: bool = True) -> int | None:
        if key in columns:
            if columns[key] in index:
                return use(key, columns[key])
            problems.append(f"column '{columns[key]}' (given for '{key}') is not in the file")
            return None
        for c in candidates:
            if c in index:
                return use(key, c)
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
    per_thruster = tau_cols is i_thr
    eff = thruster_efficiency(vessel)
    tau = (tau_raw * eff) @ B.T if per_thruster else tau_raw
    if per_thruster and np.any(eff != 1.0):
        tau_note += f", efficiencies {', '.join(f'{e:.3g}' for e in eff)} from the vessel file"
    return ManeuverData(
        t=table[:, i_t],
        eta=table[:, i_eta],
        nu=table[:, i_nu],
        tau=tau,
        dof=d,
        source=f"{path} [{tau_note}]",
        nu_dot=table[:, nu_dot_idx] if have_nu_dot else None,
        thrust=tau_raw if per_thruster else None,
        efficiency=eff if per_thruster else None,
    )


def thruster_efficiency(vessel: VesselSpec) -> np.ndarray:
    """The fraction of each thruster's nominal thrust that reaches the hull, from the vessel file
    (thrusters' ``efficiency``; 1 where the file gives none)."""
    m = vessel.thrusters.count
    eff = getattr(vessel.thrusters, "efficiency", None)
    return np.ones(m) if eff is None else np.broadcast_to(np.asarray(eff, dtype=float), (m,)).copy()


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



def write_maneuver_csv(data: ManeuverData, path: Path, provenance: str = "",
                       per_thruster: bool = False) -> Path:
    """The log as a CSV that ``load_maneuver_csv`` reads without a column map (SI units):
    time, eta names, nu names, tau_X ... (one '#' provenance line first). ``per_thruster`` also
    writes thrust_1 ... (the log's per-thruster thrust, as logged): the reader then takes tau from
    them through the vessel file, and a lost thruster can be located (``thruster_loss``)."""
    d = data.dof
    names = ["time", *ETA_NAMES[d], *NU_NAMES[d], *(f"tau_{n}" for n in TAU_NAMES[d])]
    cols = [data.t, data.eta, data.nu, data.tau]
    if per_thruster and data.thrust is not None:
        names += [f"thrust_{i + 1}" for i in range(data.thrust.shape[1])]
        cols.append(data.thrust)
    table = np.column_stack(cols)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        fh.write(f"# {provenance or data.source}\n")
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.10g")
    return path
