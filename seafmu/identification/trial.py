"""Measured trials: a small YAML that says what experiment a CSV holds, loaded into SI arrays.

A trial names its kind (static table, 1st-order decay, step, 2nd-order decay, pendulum, maneuver),
the degree of freedom, which CSV columns are inputs and outputs (with units), the known constants
and the baseline model. Every mistake in the files is reported as one line naming file and field,
because a fit on a misread column is worse than no fit at all.
"""

from __future__ import annotations

import codecs
import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from seafmu.units import UnitError
from seafmu.yamlfile import read_mapping, validation_message


class TrialError(ValueError):
    """A trial that cannot be fitted; the message is one line naming the file and the field."""


KINDS = ("static", "decay", "step", "decay2", "pendulum", "maneuver")
TRANSLATIONAL = ("surge", "sway", "heave")
ROTATIONAL = ("roll", "pitch", "yaw")
DOFS = (*TRANSLATIONAL, *ROTATIONAL, "sway_yaw")
# Index of each DOF in a vessel's nu vector, for writing identified values back.
DOF_INDEX = {
    3: {"surge": 0, "sway": 1, "yaw": 2},
    6: {"surge": 0, "sway": 1, "heave": 2, "roll": 3, "pitch": 4, "yaw": 5},
}

# Minimum samples per kind: below this a fit has too few degrees of freedom to mean anything.
MIN_SAMPLES = {"static": 4, "pendulum": 10, "decay": 20, "step": 20, "decay2": 20, "maneuver": 20}

BASELINES = {
    ("static", "force_speed"): ("linear_quadratic", ("linear", "quadratic", "linear_quadratic")),
    ("static", "thrust_rpm"): ("linear", ("linear", "quadratic")),
    ("decay", None): ("linear", ("linear", "quadratic", "linear_quadratic")),
    ("step", None): ("linear", ("linear", "quadratic", "linear_quadratic")),
    ("decay2", None): ("linear", ("linear", "linear_quadratic")),
    ("pendulum", None): ("pendulum", ("pendulum",)),
    ("maneuver", None): ("ls", ("ls", "output_error")),
}

CONSTANTS = {
    "mass": "rigid-body mass or inertia of the DOF (kg or kg m^2); fixes the inertia of the model",
    "added_mass": "known added mass/inertia added to 'mass' in the baseline (default 0)",
    "thrust_coefficient": "known thrust gain k (N/rps, or N/rps^2 for a quadratic law); else fitted",
    "stiffness": "known restoring coefficient c (N/m or N m/rad) of a 2nd-order decay; else fitted",
    "mass_coupling": "sway-yaw inertia coupling m_26 (kg m) of a sway_yaw trial (default 0)",
    "inertia": "yaw inertia I_z + N_rdot (kg m^2) of a sway_yaw trial",
    "rod_length": "pendulum rod length r (m): gives K_Q from gamma",
    "buoyancy": "pendulum model buoyancy B (N)",
    "weight": "pendulum model weight M g (N); with buoyancy and rod_length gives the added mass",
}

# Units the shared table lacks (accelerations); name -> (SI unit, factor).
_EXTRA_UNITS = {
    "rad/s^2": ("rad/s^2", 1.0), "rad/s2": ("rad/s^2", 1.0),
    "deg/s^2": ("rad/s^2", math.pi / 180), "deg/s2": ("rad/s^2", math.pi / 180),
    "m/s^2": ("m/s^2", 1.0), "m/s2": ("m/s^2", 1.0),
}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ColumnSpec(_Strict):
    column: str = Field(description="header name in the CSV")
    unit: str = Field(description="unit of the values in the file, e.g. m/s, kn, deg, rpm, N")


class TrialModel(_Strict):
    name: str
    description: str = ""
    provenance: str | None = Field(None, description="where the data come from; default: CSV '#' header")
    kind: Literal["static", "decay", "step", "decay2", "pendulum", "maneuver"]
    dof: Literal["surge", "sway", "heave", "roll", "pitch", "yaw", "sway_yaw"] | None = None
    table: Literal["force_speed", "thrust_rpm"] | None = None
    files: list[str] = Field(min_length=1)
    validation_files: list[str] = Field(default_factory=list)
    columns: dict[str, ColumnSpec | str] = Field(default_factory=dict)
    constants: dict[str, float | str] = Field(default_factory=dict)
    baseline: str | None = None
    thrust_law: Literal["linear", "quadratic"] = "linear"
    restoring: Literal["linear", "sin"] = "linear"
    mirror: bool = Field(False, description="static: add (-x, -y) for every x != 0 (symmetric hull)")
    validation_fraction: float = Field(0.3, gt=0.0, lt=0.9)
    vessel: str | None = None


@dataclass
class Run:
    """One measured record in SI units. y and u may have two columns (sway_yaw: v, r / Y, N)."""

    name: str
    y: np.ndarray
    t: np.ndarray | None = None
    u: np.ndarray | None = None
    rate: np.ndarray | None = None
    accel: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.y.shape[0])


@dataclass
class Trial:
    """A loaded, validated trial; everything in SI units (angles in rad, shaft speed in rev/s)."""

    name: str
    kind: str
    runs: list[Run]
    dof: str | None = None
    table: str | None = None
    validation_runs: list[Run] = field(default_factory=list)
    constants: dict[str, float] = field(default_factory=dict)
    baseline: str = ""
    input_kind: str | None = None  # "rpm" (shaft speed command) or "force" (force/moment) for step trials
    thrust_law: str = "linear"
    restoring: str = "linear"
    mirror: bool = False
    validation_fraction: float = 0.3
    vessel: str | None = None
    provenance: str = ""
    description: str = ""
    source: Path | None = None
    units: dict[str, str] = field(default_factory=dict)  # role -> unit in the file
    columns: dict[str, str] = field(default_factory=dict)  # role -> CSV column (maneuver mapping)
    files: list[Path] = field(default_factory=list)
    # what was done to the data before fitting (a hold before a release left out), said with the fit
    notes: list[str] = field(default_factory=list)

    @property
    def rotational(self) -> bool:
        return self.dof in ROTATIONAL or self.kind == "pendulum"

    @property
    def label(self) -> str:
        return f"{self.name} ({self.kind}{', ' + self.dof if self.dof else ''})"


def make_trial(
    kind: str,
    runs: list[Run],
    *,
    dof: str | None = None,
    table: str | None = None,
    baseline: str | None = None,
    constants: dict[str, float] | None = None,
    validation_runs: list[Run] | None = None,
    input_kind: str | None = None,
    thrust_law: str = "linear",
    restoring: str = "linear",
    mirror: bool = False,
    validation_fraction: float = 0.3,
    name: str = "synthetic",
    provenance: str = "synthetic data generated in code",
) -> Trial:
    """A trial from arrays already in SI units (tests, benchmarks, notebooks)."""
    if kind == "static" and table is None:
        table = "force_speed"
    key = (kind, table if kind == "static" else None)
    default, allowed = BASELINES[key]
    base = baseline or default
    if base not in allowed:
        raise TrialError(f"{name}: baseline '{base}' is not one of {', '.join(allowed)} for this kind")
    if kind == "step" and input_kind is None:
        input_kind = "force"
    notes: list[str] = []
    runs, vruns = released(runs, kind, notes), released(validation_runs or [], kind, notes)
    return Trial(
        name=name, kind=kind, runs=runs, dof=dof, table=table, validation_runs=vruns,
        constants=dict(constants or {}), baseline=base, input_kind=input_kind, thrust_law=thrust_law,
        restoring=restoring, mirror=mirror, validation_fraction=validation_fraction, provenance=provenance,
        notes=notes,
    )


def released(runs: list[Run], kind: str, notes: list[str]) -> list[Run]:
    """The runs of a decay or pendulum trial from their release on: a leading stretch where the body
    is still held (``release.held_samples``) is left out, and ``notes`` says so; a run left with too
    few samples is kept whole."""
    from seafmu.identification.release import held_samples

    out = []
    for r in runs:
        h = held_samples(r.t, r.y, kind) if r.t is not None else 0
        if h and r.y.shape[0] - h >= MIN_SAMPLES.get(kind, 0):
            notes.append(f"{r.name}: the first {h} samples ({r.t[h] - r.t[0]:.3g} s) left out: the output "
                         f"stays where it starts until a release at t = {r.t[h]:.6g} s (held before it)")
            r = Run(r.name, r.y[h:], r.t[h:], *(None if a is None else a[h:] for a in (r.u, r.rate, r.accel)))
        out.append(r)
    return out


# -- loading -----------------------------------------------------------------------------------

def _unit_si(unit: str) -> tuple[str, float]:
    """SI unit and factor of a unit name, from the shared table or the acceleration additions."""
    if unit in _EXTRA_UNITS:
        return _EXTRA_UNITS[unit]
    from seafmu.units import _UNITS

    if unit not in _UNITS:
        known = sorted({*_UNITS, *_EXTRA_UNITS})
        raise UnitError(f"unknown unit '{unit}' (known: {', '.join(known)})")
    return _UNITS[unit]


def _quantity(raw: float | str) -> float:
    """A constant: a bare SI number or '<number> <unit>' in any known unit, converted to SI."""
    if isinstance(raw, int | float):
        return float(raw)
    from seafmu.units import _QUANTITY

    m = _QUANTITY.match(raw)
    if not m:
        try:
            return float(raw)
        except ValueError:
            raise UnitError(f"expected a number or '<number> <unit>', got {raw!r}") from None
    return float(m.group(1)) * _unit_si(m.group(2))[1]


def _expected_units(tm: TrialModel, table: str | None) -> dict[str, tuple[tuple[str, ...], str]]:
    """Required/optional column roles and the SI units each may have: role -> (allowed SI, meaning)."""
    rot = tm.dof in ROTATIONAL
    vel = ("rad/s",) if rot else ("m/s",)
    pos = ("rad",) if rot else ("m",)
    force = ("N.m",) if rot else ("N",)
    k = tm.kind
    if k == "static":
        if table == "thrust_rpm":
            return {"input": (("rev/s",), "shaft speed"), "output": (("N", "N.m"), "thrust")}
        return {"input": (vel, "speed"), "output": (force, "force")}
    if tm.dof == "sway_yaw":
        roles = {"time": (("s",), "time"), "output": (("m/s",), "sway velocity v"),
                 "output2": (("rad/s",), "yaw rate r")}
        if k == "step":
            roles |= {"input": (("N",), "sway force Y"), "input2": (("N.m",), "yaw moment N")}
        return roles
    if k in ("decay", "step"):
        roles = {"time": (("s",), "time"), "output": (vel, "velocity")}
        if k == "step":
            roles["input"] = (("rev/s", "N", "N.m"), "command (shaft speed or force)")
        return roles
    if k == "decay2":
        return {"time": (("s",), "time"), "output": (pos, "displacement/angle")}
    if k == "pendulum":
        return {"time": (("s",), "time"), "output": (("rad",), "angle"),
                "rate": (("rad/s",), "angular rate"), "accel": (("rad/s^2",), "angular acceleration")}
    return {}


_OPTIONAL = {"rate", "accel"}

# Why a constant output leaves nothing to fit, per kind (no excitation).
_STILL = {
    "static": "the output is the same at every input, nothing to fit",
    "decay": "nothing decays, no decay to fit",
    "step": "the output never responds, no response to fit",
    "decay2": "nothing moves, no oscillation to fit",
    "pendulum": "the angle never changes, no swing to fit",
}

# Maneuver column roles (names of load_maneuver_csv) and the SI unit each must convert to.
_M_POS, _M_ANG = ("north", "east", "down"), ("roll", "pitch", "yaw")
_M_LIN, _M_ROT = ("u", "v", "w"), ("p", "q", "r")
MANEUVER_ROLES = ("time, north, east, down, roll, pitch, yaw, u, v, w, p, q, r, thrust_<i>, "
                  "tau_X, tau_Y, tau_Z, tau_K, tau_M, tau_N, u_dot ... r_dot")


def _maneuver_role(role: str) -> tuple[tuple[str, ...], str] | None:
    """(allowed SI units, meaning) of a maneuver column role, or None if it is not one."""
    if role == "time":
        return ("s",), "time"
    if role in _M_POS:
        return ("m",), f"position {role}"
    if role in _M_ANG:
        return ("rad",), f"angle {role}"
    if role in _M_LIN:
        return ("m/s",), f"velocity {role}"
    if role in _M_ROT:
        return ("rad/s",), f"angular rate {role}"
    if role.startswith("thrust_") and role[7:].isdigit() and int(role[7:]) >= 1:
        return ("N",), f"thrust {role}"
    if role in ("tau_X", "tau_Y", "tau_Z"):
        return ("N",), f"force {role}"
    if role in ("tau_K", "tau_M", "tau_N"):
        return ("N.m",), f"moment {role}"
    if role.endswith("_dot") and role[:-4] in _M_LIN:
        return ("m/s^2",), f"acceleration {role}"
    if role.endswith("_dot") and role[:-4] in _M_ROT:
        return ("rad/s^2",), f"angular acceleration {role}"
    return None


def maneuver_factors(trial: Trial) -> dict[str, float]:
    """role -> factor to SI for the maneuver columns given with a unit (deg -> rad, kN -> N, ...)."""
    return {role: _unit_si(unit)[1] for role, unit in trial.units.items() if _unit_si(unit)[1] != 1.0}


# Largest magnitude accepted in a data column (after conversion to SI). No measured quantity
# comes near it, and squares and sums of squares over a long log stay far from overflow (1e308
# is a valid float whose square is not).
MAX_ABS = 1e15
# A time step longer than this many median sample intervals is a gap in the record: samples are
# missing there, and no fit integrates across it (the run must be split into separate files).
GAP_FACTOR = 5.0
TINY = 1e-100  # a column no larger than this is numerically zero (no motion)
_MAX_ECHO = 24  # longest cell text quoted in an error (the file is a valid table by then)


def read_text(path: Path, what: str = "file") -> str:
    """A text file's content, or one line saying why not (unreadable, not UTF-8, binary).

    Never quotes the file: a wrong path may point at anything.
    """
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise TrialError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if raw.startswith(codecs.BOM_UTF8):
        raw = raw[len(codecs.BOM_UTF8):]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise TrialError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}): "
                         f"save the {what} as UTF-8 or ASCII") from None
    nul = text.find("\x00")
    if nul >= 0:
        raise TrialError(f"{path}: not a text file (NUL byte on line {text.count(chr(10), 0, nul) + 1})")
    return text


def cell_float(cell: str) -> float:
    """float() of a CSV cell; ValueError also for '_' digit separators, which float() takes ('0_5'
    is 5, '3_3e-1' is 3.3) but are a typo in measured data (seafmu.units.is_number refuses them too)."""
    if "_" in cell:
        raise ValueError(cell)
    return float(cell)


def is_number(cell: str) -> bool:
    try:
        cell_float(cell)
    except ValueError:
        return False
    return True


def field_count_error(path: Path | str, where: str, fields: int, expected: int) -> TrialError:
    """A row with more or fewer fields than the header (a decimal comma '0,33', a stray value):
    reading it by position would shift the columns silently."""
    return TrialError(f"{path}: {where} has {fields} field{'s' if fields != 1 else ''}, the header has "
                      f"{expected}")


def echo_cell(cell: str) -> str:
    """A cell quoted in an error, shortened."""
    cell = cell if len(cell) <= _MAX_ECHO else cell[: _MAX_ECHO - 3] + "..."
    return repr(cell)


def _names(header: list[str]) -> str:
    """The header's column names for an error, shortened."""
    shown = [h if len(h) <= 40 else h[:37] + "..." for h in header[:20]]
    return ", ".join(shown) + (f", ... ({len(header)} columns)" if len(header) > 20 else "")


def read_table(path: Path) -> tuple[list[str], list[list[str]], list[int], list[str]]:
    """Header, rows, the file line number of each row, and the leading '#' comment lines of a CSV.

    The file must look like a data table — a header of at least two column names, then a first
    data row with as many cells, at least one of them a number — before anything from it (column
    names, cells) appears in an error message; anything else is one line quoting nothing.
    """
    text = read_text(path, "CSV file")
    comments: list[str] = []
    header: list[str] | None = None
    rows: list[list[str]] = []
    lines: list[int] = []
    try:
        for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
            if not row or all(not c.strip() for c in row):
                continue
            if row[0].lstrip().startswith("#"):
                if header is None:
                    comments.append(",".join(row).lstrip("# ").rstrip())
                continue
            if header is None:
                header = [c.strip() for c in row]
                continue
            rows.append(row)
            lines.append(lineno)
    except csv.Error as exc:
        raise TrialError(f"{path}: not a CSV file ({exc})") from None
    if header is None:
        raise TrialError(f"{path}: no header row (expected column names after the '#' comment lines)")
    if len(header) < 2 or (rows and not any(is_number(c) for c in rows[0])):
        raise TrialError(f"{path}: not a CSV data table (expected optional '#' lines, a header row of "
                         "column names, then rows of numbers separated by commas)")
    for row, lineno in zip(rows, lines, strict=True):  # every row, not just the first
        if len(row) != len(header):
            raise field_count_error(path, f"line {lineno}", len(row), len(header))
    return header, rows, lines, comments


def _column(path: Path, header: list[str], rows: list[list[str]], lines: list[int], name: str,
            role: str) -> np.ndarray:
    if name not in header:
        raise TrialError(f"{path}: column '{name}' ({role}) not found; the file has: {_names(header)}")
    twice = repeated(header, name)
    if twice:
        raise TrialError(f"{path}: {twice}")
    j = header.index(name)
    out = np.empty(len(rows))
    for i, row in enumerate(rows):
        cell = row[j].strip()  # every row has the header's fields (read_table)
        try:
            val = cell_float(cell)
        except ValueError:
            raise TrialError(f"{path}: line {lines[i]}: column '{name}' is not a number "
                             f"({echo_cell(cell)})") from None
        if not math.isfinite(val):
            raise TrialError(f"{path}: line {lines[i]}: column '{name}' is {echo_cell(cell)[1:-1]} "
                             f"(NaN/inf not allowed)")
        out[i] = val
    return out


def repeated(header: list[str], name: str) -> str | None:
    """Why a column the fit reads cannot be used when the header names it more than once (which
    one is meant is a guess), else None. Callers ask only for the columns they read: repeated
    names of unused columns change no result, and spreadsheet exports often repeat them (empty or
    note columns)."""
    k = header.count(name)
    if k < 2:
        return None
    return f"column '{name}' appears {'twice' if k == 2 else f'{k} times'} in the header"


def check_values(path: Path | str, name: str, x: np.ndarray, lines: list[int] | None = None) -> None:
    """Values too large to fit (SI units): one line naming the first."""
    big = np.flatnonzero(~(np.abs(x) <= MAX_ABS))
    if big.size:
        i = int(big[0])
        where = f"line {lines[i]}: " if lines is not None else f"sample {i + 1}: "
        raise TrialError(f"{path}: {where}column '{name}' is {x[i]:.6g}: out of range (|value| > "
                         f"{MAX_ABS:g} in SI units; squares in the fit would overflow)")


def constant(x: np.ndarray) -> bool:
    """True when a column does not change (to rounding), or is numerically zero (|x| < TINY:
    squares underflow, as those of MAX_ABS overflow)."""
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return True
    top = float(np.max(np.abs(x)))
    return bool(top < TINY or np.ptp(x) <= 1e-12 * top)


def check_time(path: Path | str, t: np.ndarray, lines: list[int] | None, name: str) -> None:
    """Time must increase strictly and without gaps (GAP_FACTOR median sample intervals)."""

    def at(i: int) -> str:
        return f"line {lines[i]}: " if lines is not None else f"sample {i + 1}: "

    d = np.diff(t)
    if d.size and np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        what = "repeats" if d[i] == 0 else "goes backwards to"
        raise TrialError(f"{path}: {at(i + 1)}time column '{name}' {what} {t[i + 1]:g} s "
                         f"(time must increase strictly)")
    if d.size >= 2:
        med = float(np.median(d))
        gaps = np.flatnonzero(d > GAP_FACTOR * med)
        if gaps.size:
            i = int(gaps[0])
            raise TrialError(
                f"{path}: {at(i + 1)}time column '{name}' jumps from {t[i]:g} s to {t[i + 1]:g} s, "
                f"{d[i] / med:.3g} sample intervals of {med:g} s ({gaps.size} gap(s) over {GAP_FACTOR:g} "
                f"intervals): samples are missing there; split the record into runs without gaps")


def data_file(trial_path: Path, entry: str, where: str) -> Path:
    """A data file named in a trial: relative to the trial's folder and inside it.

    Absolute paths, '..' escapes and symbolic links out of the folder are refused (a trial is a
    document that may come from anyone; only the command line names files anywhere).
    """
    base = trial_path.parent
    rel = Path(entry)
    if rel.is_absolute() or entry.startswith(("/", "\\")):
        raise TrialError(f"{trial_path}: {where}: '{entry}' is an absolute path; a trial names its files "
                         f"relative to its own folder (give a log elsewhere on the command line instead)")
    full = base / rel
    try:
        full.resolve().relative_to(base.resolve())
    except ValueError:
        raise TrialError(f"{trial_path}: {where}: '{entry}' lies outside the trial's folder "
                         f"({base.resolve()}); a trial may only name files in its folder or below") from None
    return full


def load_trial(path: str | Path) -> Trial:
    """Load and validate a trial YAML and its CSV files (paths relative to the YAML)."""
    path = Path(path)
    text = read_text(path, "trial")
    try:  # syntax first, with a message that names line and column but quotes nothing
        yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = " ".join(str(getattr(exc, "problem", None) or "syntax error").split())[:80]
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise TrialError(f"{path}: not valid YAML ({where}{problem})") from None
    doc = read_mapping(path, "trial", TrialError)  # duplicate keys, top-level mapping
    try:
        tm = TrialModel.model_validate(doc)
    except ValidationError as exc:
        raise TrialError(f"{path}: {validation_message(exc)}") from None
    return _resolve(tm, path)


def _check_name(path: Path, name: str) -> None:
    """The trial name becomes the default output folder results/<name>: a plain folder name."""
    if not name.strip() or name in (".", "..") or any(c in name for c in "/\\") or \
            any(ord(c) < 32 for c in name):
        raise TrialError(f"{path}: name: {name!r} is not a plain folder name (it names the output "
                         f"folder results/<name>: no '/', '\\', '..' or control characters)")


def _vessel_ref(path: Path, vessel: str | None) -> str | None:
    """A trial's vessel: a bundled name, or a vessel YAML inside the trial's folder (made absolute)."""
    if vessel is None:
        return None
    if Path(vessel).suffix in (".yaml", ".yml"):
        return str(data_file(path, vessel, "vessel"))
    if any(c in vessel for c in "/\\") or vessel in (".", ".."):
        raise TrialError(f"{path}: vessel: '{vessel}' is neither a bundled vessel name nor a .yaml file in "
                         f"the trial's folder")
    return vessel


def _resolve(tm: TrialModel, path: Path) -> Trial:
    # Over 80 lines: it resolves the fields of the trial YAML in the order they depend on each other
    # (files, kind, dof, table, input kind, columns and units), each error naming its field; one
    # flat sequence reads like the format's documentation (docs/identification.md).
    def fail(where: str, msg: str) -> TrialError:
        return TrialError(f"{path}: {where}: {msg}")

    _check_name(path, tm.name)
    tm.vessel = _vessel_ref(path, tm.vessel)
    files = [data_file(path, f, f"files[{i}]") for i, f in enumerate(tm.files)]
    vfiles = [data_file(path, f, f"validation_files[{i}]") for i, f in enumerate(tm.validation_files)]
    for i, f in enumerate(files + vfiles):
        if not f.is_file():
            where = f"files[{i}]" if i < len(files) else f"validation_files[{i - len(files)}]"
            raise fail(where, f"no such file {f}")

    if tm.kind == "maneuver":
        cols: dict[str, str] = {}
        m_units: dict[str, str] = {}
        for role, spec in tm.columns.items():
            allowed_m = _maneuver_role(role)
            if allowed_m is None:
                raise fail(f"columns.{role}",
                           f"not a column role of a maneuver trial (roles: {MANEUVER_ROLES})")
            if isinstance(spec, str):  # a bare column name: SI units (as seafmu run logs are)
                cols[role] = spec
                continue
            si_units, meaning = allowed_m
            try:
                si, _ = _unit_si(spec.unit)
            except UnitError as exc:
                raise fail(f"columns.{role}.unit", str(exc)) from None
            if si not in si_units:
                raise fail(f"columns.{role}.unit", f"'{spec.unit}' is {si}, but the {meaning} of a maneuver "
                                                   f"trial needs {' or '.join(si_units)}")
            cols[role], m_units[role] = spec.column, spec.unit
        if not tm.vessel:
            raise fail("vessel", "a maneuver trial needs the vessel whose model is fitted")
        base = tm.baseline or "ls"
        if base not in BASELINES[("maneuver", None)][1]:
            raise fail("baseline", f"'{base}' is not one of ls, output_error for a maneuver trial")
        return Trial(name=tm.name, kind="maneuver", runs=[], dof=tm.dof, baseline=base, vessel=tm.vessel,
                     provenance=tm.provenance or _header_provenance(files[0]), description=tm.description,
                     source=path, columns=cols, files=files + vfiles, units=m_units,
                     validation_fraction=tm.validation_fraction)

    if tm.dof is None:
        raise fail("dof", f"required for a {tm.kind} trial (one of {', '.join(DOFS)})")
    if tm.kind == "pendulum" and tm.dof == "sway_yaw":
        raise fail("dof", "a pendulum trial has one DOF")
    if tm.dof == "sway_yaw" and tm.kind not in ("step", "decay"):
        raise fail("dof", "sway_yaw (coupled sway-yaw) is a step or decay trial")
    if tm.kind != "static" and tm.table is not None:
        raise fail("table", "only a static trial has a table type")
    if tm.mirror and tm.kind != "static":
        raise fail("mirror", "only a static table can be mirrored")

    # Table type: stated, or inferred from the input unit (rev/s -> thrust table).
    table = tm.table
    if tm.kind == "static" and table is None:
        spec = tm.columns.get("input")
        unit = spec.unit if isinstance(spec, ColumnSpec) else ""
        try:
            table = "thrust_rpm" if unit and _unit_si(unit)[0] == "rev/s" else "force_speed"
        except UnitError:
            table = "force_speed"

    expected = _expected_units(tm, table)
    units: dict[str, str] = {}
    factors: dict[str, float] = {}
    colnames: dict[str, str] = {}
    for role, spec in tm.columns.items():
        if role not in expected:
            raise fail(f"columns.{role}", f"not a column role of a {tm.kind} trial "
                                          f"(roles: {', '.join(expected)})")
        if isinstance(spec, str):
            raise fail(f"columns.{role}", "give {column: NAME, unit: UNIT}")
        allowed, meaning = expected[role]
        try:
            si, factor = _unit_si(spec.unit)
        except UnitError as exc:
            raise fail(f"columns.{role}.unit", str(exc)) from None
        if si not in allowed:
            raise fail(f"columns.{role}.unit", f"'{spec.unit}' is {si}, but the {meaning} of a "
                                               f"{tm.dof} {tm.kind} trial needs {' or '.join(allowed)}")
        units[role], factors[role], colnames[role] = spec.unit, factor, spec.column
    for role in expected:
        if role not in tm.columns and role not in _OPTIONAL:
            raise fail("columns", f"the {expected[role][1]} column ('{role}') is missing")

    input_kind = None
    if tm.kind == "step":
        input_kind = "rpm" if _unit_si(units["input"])[0] == "rev/s" else "force"

    constants: dict[str, float] = {}
    for key, raw in tm.constants.items():
        if key not in CONSTANTS:
            raise fail(f"constants.{key}", f"unknown constant (known: {', '.join(CONSTANTS)})")
        try:
            val = _quantity(raw)
        except UnitError as exc:
            raise fail(f"constants.{key}", str(exc)) from None
        if not math.isfinite(val) or (val <= 0 and key not in ("added_mass", "mass_coupling")):
            raise fail(f"constants.{key}", f"must be a positive number, got {raw!r}")
        constants[key] = val

    key = (tm.kind, table if tm.kind == "static" else None)
    default, allowed_b = BASELINES[key]
    baseline = tm.baseline or default
    if baseline not in allowed_b:
        raise fail("baseline", f"'{baseline}' is not one of {', '.join(allowed_b)} for a {tm.kind} trial")

    def read(f: Path) -> Run:
        header, rows, lines, _ = read_table(f)
        minimum = MIN_SAMPLES[tm.kind]
        if len(rows) < minimum:
            raise TrialError(f"{f}: {len(rows)} samples; a {tm.kind} trial needs at least {minimum}")
        data: dict[str, np.ndarray] = {}
        for role in colnames:
            data[role] = _column(f, header, rows, lines, colnames[role], role) * factors[role]
            check_values(f, colnames[role], data[role], lines)
        if "time" in data:
            check_time(f, data["time"], lines, colnames["time"])
        if tm.kind == "static" and constant(data["input"]):
            raise TrialError(f"{f}: column '{colnames['input']}' has one value only: nothing to fit")
        for role in ("output", "output2"):
            if role in data and constant(data[role]):
                raise TrialError(f"{f}: column '{colnames[role]}' ({role}) is constant "
                                 f"({data[role][0] / factors[role]:g} throughout): {_STILL[tm.kind]}")
        if tm.kind == "step" and not any(np.any(data[r] != 0) for r in ("input", "input2") if r in data):
            raise TrialError(f"{f}: column '{colnames['input']}' (input) is zero throughout: the command "
                             "never acts, no response to identify (a run without input is a decay trial)")
        y = data["output"] if "output2" not in data else np.column_stack([data["output"], data["output2"]])
        u = data.get("input")
        if "input2" in data:
            u = np.column_stack([data["input"], data["input2"]])
        return Run(name=f.stem, y=y, t=data.get("time"), u=u, rate=data.get("rate"), accel=data.get("accel"))

    notes: list[str] = []
    runs = released([read(f) for f in files], tm.kind, notes)
    vruns = released([read(f) for f in vfiles], tm.kind, notes)
    if tm.kind == "static" and vruns:
        raise fail("validation_files", "a static table is validated by leave-one-out, not by files")
    return Trial(
        name=tm.name, kind=tm.kind, runs=runs, dof=tm.dof, table=table, validation_runs=vruns,
        constants=constants, baseline=baseline, input_kind=input_kind, thrust_law=tm.thrust_law,
        restoring=tm.restoring, mirror=tm.mirror, validation_fraction=tm.validation_fraction,
        vessel=tm.vessel, provenance=tm.provenance or _header_provenance(files[0]),
        description=tm.description, source=path, units=units, columns=colnames, files=files + vfiles,
        notes=notes,
    )


def _header_provenance(path: Path) -> str:
    try:
        return " ".join(read_table(path)[3][:3])
    except TrialError:
        return ""


def check_vessel(trial: Trial, spec: Any) -> None:
    """A 1-2 DOF trial and the vessel named for it must belong together: the vessel has the
    trial's DOF, and a stated 'mass' (or 'inertia') lies within a factor 3 of the vessel's
    rigid-body value or its total with the added mass (trials state either). One line if not."""
    if trial.kind in ("static", "pendulum", "maneuver") or not trial.dof:
        return
    idx = DOF_INDEX.get(spec.dof, {})
    dofs = ["sway", "yaw"] if trial.dof == "sway_yaw" else [trial.dof]
    missing = [x for x in dofs if x not in idx]
    name = getattr(spec, "name", "?")
    if missing:
        raise TrialError(f"{trial.source or trial.name}: vessel '{name}' has no {missing[0]} DOF "
                         f"({spec.dof}-DOF vessel) for this {trial.dof} {trial.kind} trial: a trial of "
                         "another vessel?")
    checks = [("mass", dofs[0])] + ([("inertia", "yaw")] if trial.dof == "sway_yaw" else [])
    for key, dof in checks:
        if key not in trial.constants:
            continue
        i = idx[dof]
        rb = float(spec.M_RB[i, i])
        total = rb + float(spec.M_A[i, i])
        val = trial.constants[key]
        lo, hi = min(rb, total) / 3.0, max(rb, total) * 3.0
        if rb > 0 and not lo <= val <= hi:
            unit = "kg m^2" if dof in ROTATIONAL else "kg"
            raise TrialError(f"{trial.source or trial.name}: constants.{key} = {val:g} {unit}, but vessel "
                             f"'{name}' has {rb:g} {unit} rigid-body ({total:g} with added mass) in {dof}: "
                             "a trial of another vessel? (name its vessel with --vessel or the trial's "
                             "'vessel')")


def csv_trial(path: str | Path, vessel: str) -> Trial:
    """A bare CSV (e.g. a `seafmu run` results.csv) taken as a maneuver trial of this vessel, named
    after its run's folder (results/minerva2_dp/results.csv: minerva2_dp), any other CSV after its
    own name: logs/a.csv and logs/b.csv must not share the default output folder."""
    path = Path(path)
    if not path.is_file():
        raise TrialError(f"{path}: no such file")
    name = (path.parent.name or path.stem) if path.stem == "results" else path.stem
    return Trial(name=name, kind="maneuver", runs=[], baseline="ls", vessel=vessel,
                 provenance=_header_provenance(path) or f"log {path}", source=path, files=[path])


def write_trial(trial: Trial, folder: Path) -> Path:
    """Write a trial (SI arrays) as CSV files plus the trial YAML; returns the YAML path.

    Used to ship synthetic examples and by the tests that exercise the file format end to end.
    """
    folder.mkdir(parents=True, exist_ok=True)
    rot = trial.dof in ROTATIONAL or trial.kind == "pendulum"
    if trial.kind == "static":
        rpm = trial.table == "thrust_rpm"
        roles = {"input": ("input", "rev/s" if rpm else ("rad/s" if rot else "m/s")),
                 "output": ("output", "N.m" if rot and not rpm else "N")}
    elif trial.dof == "sway_yaw":
        roles = {"time": ("t", "s"), "output": ("v", "m/s"), "output2": ("r", "rad/s")}
        if trial.kind == "step":
            roles |= {"input": ("Y", "N"), "input2": ("N", "N.m")}
    else:
        out_unit = ("rad" if rot else "m") if trial.kind in ("decay2", "pendulum") else (
            "rad/s" if rot else "m/s")
        roles = {"time": ("t", "s"), "output": ("y", out_unit)}
        if trial.kind == "step":
            roles["input"] = ("u", "rev/s" if trial.input_kind == "rpm" else ("N.m" if rot else "N"))
    files = []
    for i, run in enumerate([*trial.runs, *trial.validation_runs]):
        cols: dict[str, np.ndarray] = {}
        for role, (cname, _) in roles.items():
            if role == "time":
                cols[cname] = np.asarray(run.t)
            elif role in ("output", "output2"):
                y = np.asarray(run.y)
                cols[cname] = y if y.ndim == 1 else y[:, 0 if role == "output" else 1]
            else:
                u = np.asarray(run.u)
                cols[cname] = u if u.ndim == 1 else u[:, 0 if role == "input" else 1]
        name = f"{trial.name}_{i + 1}_{run.name}.csv"
        with open(folder / name, "w", newline="") as fh:
            fh.write(f"# {trial.provenance}\n")
            w = csv.writer(fh)
            w.writerow(list(cols))
            for row in np.column_stack(list(cols.values())):
                w.writerow([f"{x:.9g}" for x in row])
        files.append(name)
    nfit = len(trial.runs)
    doc: dict[str, Any] = {
        "name": trial.name, "provenance": trial.provenance, "kind": trial.kind, "dof": trial.dof,
        "files": files[:nfit],
        "columns": {role: {"column": c, "unit": u} for role, (c, u) in roles.items()},
        "baseline": trial.baseline,
    }
    if files[nfit:]:
        doc["validation_files"] = files[nfit:]
    if trial.kind == "static":
        doc["table"] = trial.table
        doc["mirror"] = trial.mirror
    if trial.constants:
        doc["constants"] = {k: float(v) for k, v in trial.constants.items()}
    if trial.thrust_law != "linear":
        doc["thrust_law"] = trial.thrust_law
    if trial.restoring != "linear":
        doc["restoring"] = trial.restoring
    out = folder / f"{trial.name}.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out
