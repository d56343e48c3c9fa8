"""Vessel definitions: YAML data files with a provenance note per parameter, loaded into arrays.

Every physical parameter in a vessel file is written as ``{value: ..., source: "..."}`` so a user
can see where each number came from (measured, computed, assumed, corrected erratum). Bad files
fail with one line naming the file and the field.

Every key of a file is one the loader reads (a misspelled one would leave a default in its place
unnoticed), numbers are YAML 1.2's plain decimals (``010`` is 10, ``0x10`` is text), and each number
must be one a real vessel could have: finite, within ``MAX_MAGNITUDE``, thrusters with a direction,
a bounded force and a position on the hull.
"""

from __future__ import annotations

import hashlib
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from . import registry
from .names import did_you_mean
from .yaml_numbers import decimal_numbers

_Base: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

class _Loader(_Base):  # type: ignore[misc, valid-type]
    """libyaml (~9x faster than the pure-Python loader: every run and every sweep case reads a vessel
    file) with YAML 1.2 numbers (``yaml_numbers``: 0x10, 0b11, 1_0 and 1:30 stay text, 010 is 10)."""


decimal_numbers(_Loader)

VESSEL_DIR = Path(__file__).parent / "vessels"

# Names of the generalised coordinates per DOF set; sensors and FMU variables use these names.
ETA_NAMES = {3: ["north", "east", "yaw"], 6: ["north", "east", "down", "roll", "pitch", "yaw"]}
NU_NAMES = {3: ["u", "v", "r"], 6: ["u", "v", "w", "p", "q", "r"]}
TAU_NAMES = {3: ["X", "Y", "N"], 6: ["X", "Y", "Z", "K", "M", "N"]}
ANGLE_NAMES = {"roll", "pitch", "yaw"}
CORIOLIS_FORMS = ("full", "none")  # C_RB(nu) nu + C_A(nu_r) nu_r, or no Coriolis terms (linear models)
# What the inertia acts on in a current: M nu_dot (section 1 of the brief) or M nu_r_dot (Fossen's
# linear DP model, M nu_r_dot + D nu_r = tau; they differ by M (omega x nu_c) while turning).
CURRENT_INERTIA = ("absolute", "relative", "added")
# The inertia M in M nu_dot: the symmetric parts of the file's M_RB and M_A (default), or the file's
# matrices as published (Fossen's vehicle models: M = M_RB + M_A as given, its Coriolis from the
# symmetric parts), for comparing with a model written that way.
INERTIA_FORMS = ("symmetric", "published")
# Units a thruster's speed and thrust coefficient may be given in (``unit:`` beside value and
# source), with the conversion to what the model works in: shaft speeds in rev/s.
SPEED_UNITS: dict[str, Callable[[float], float]] = {
    "rev/s": lambda n: n, "rps": lambda n: n, "rpm": lambda n: n / 60.0,
}
K_UNITS: dict[str, dict[str, Callable[[float], float]]] = {
    "linear": {"N/(rev/s)": lambda k: k, "N/rps": lambda k: k, "N/rpm": lambda k: k * 60.0},
    "quadratic": {"N/(rev/s)^2": lambda k: k, "N/rps^2": lambda k: k, "N/rpm^2": lambda k: k * 3600.0},
}


# Plausibility bounds of vessel numbers, SI units. Far beyond any real vessel (the largest ships: 5e8 kg,
# a yaw inertia with added mass ~1e13 kg m^2, propellers of under 10 MN), so none is refused, yet far
# below where the model's products (M^-1 tau, k n^2, r x F) overflow or lose all meaning.
MAX_MAGNITUDE = 1e15  # any number of the file
MAX_THRUST = 1e8  # N: one thruster at n_max
MAX_SHAFT_SPEED = 1e3  # rev/s (60 000 rpm; small ROV thrusters turn at under 100 rev/s)
MAX_ARM = 1e3  # m: a thruster's position, each axis (ships are under 500 m long)
MAX_CONDITION = 1e12  # largest / smallest eigenvalue of the total mass matrix

# The keys the loader reads; any other is refused (``_Reader.fields``).
TOP_FIELDS = ("name", "title", "dof", "mass_matrix", "added_mass", "linear_damping", "quadratic_damping",
              "restoring", "coriolis", "current_inertia", "inertia", "thrusters", "sensors", "gnc",
              "extra")
RESTORING_FIELDS = ("weight", "buoyancy", "r_g", "r_b")  # 6 DOF only
THRUSTERS_FIELDS = ("law", "units")
THRUSTER_FIELDS = ("name", "position", "direction", "k_forward", "k_reverse", "n_max", "time_constant")
SENSOR_FIELDS = ("name", "channels", "rate_hz", "noise_std", "bias")
LEAF_FIELDS = ("value", "source", "unit")  # unit: only where a unit is converted (K_UNITS, SPEED_UNITS)
# extra: the sections something reads, with their fields (None: one value)
EXTRA_FIELDS: dict[str, tuple[str, ...] | None] = {
    "land": ("pitch", "effective_diameter", "track_width", "max_forward_speed", "max_sideways_speed",
             "on_the_spot_rotation"),  # amv_land.LandParams.from_vessel
    "bis": ("mass", "length", "gravity", "M_bis", "D_bis"),  # published bis data (test_supply_vessel.py)
    "variant_of": None,  # seafmu/build.py: a variant of a vessel gets no FMUs of its own
}


def state_unit(name: str) -> str:
    """SI unit of a state name (eta or nu), and of the course/SOG a plant also reports."""
    if name in ANGLE_NAMES or name == "course":
        return "rad"
    if name in ("p", "q", "r"):
        return "rad/s"
    if name in ("u", "v", "w", "sog"):
        return "m/s"
    return "m"


class VesselFileError(ValueError):
    """A vessel file is missing, unreadable or has a bad field (message names both)."""


@dataclass
class ThrusterSpec:
    names: list[str]
    positions: np.ndarray  # (m, 3) body frame, m
    directions: np.ndarray  # (m, 3) force per unit thrust (unit vectors unless documented otherwise)
    law: str  # "linear" (T = k n) or "quadratic" (T = k n|n|)
    k_forward: np.ndarray  # (m,) N/rps or N/rps^2
    k_reverse: np.ndarray  # (m,)
    n_max: np.ndarray  # (m,) rev/s
    time_constant: np.ndarray  # (m,) s, first-order lag of shaft speed

    @property
    def count(self) -> int:
        return len(self.names)


@dataclass
class SensorSpec:
    name: str
    channels: list[str]  # state names from ETA_NAMES/NU_NAMES
    rate_hz: float
    noise_std: np.ndarray  # (k,) in SI units of the channel (rad for angles)
    bias: np.ndarray  # (k,)


@dataclass
class RestoringSpec:
    weight: float  # N
    buoyancy: float  # N
    r_g: np.ndarray  # (3,) centre of gravity, body frame, m
    r_b: np.ndarray  # (3,) centre of buoyancy, body frame, m


@dataclass
class GncSpec:
    """The GNC variants a vessel uses, by name (``components.registry``), and their design data."""

    controller: str  # a name in registry.CONTROLLERS
    allocator: str  # a name in registry.ALLOCATORS
    guidance: str = "none"  # a name in registry.GUIDANCE
    camera_thrusters: list[int] = field(default_factory=list)  # 0-based: reverse jet hits the cameras
    tuning: dict[str, Any] = field(default_factory=dict)  # controller design data (keys per variant)


@dataclass
class VesselSpec:
    name: str
    title: str
    dof: int
    M_RB: np.ndarray
    M_A: np.ndarray
    D_L: np.ndarray  # damping force = D_L nu_r + D_Q (|nu_r| * nu_r); positive = dissipative
    D_Q: np.ndarray
    thrusters: ThrusterSpec
    sensors: list[SensorSpec]
    restoring: RestoringSpec | None = None
    source_file: str = ""
    provenance: dict[str, str] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)  # vessel-specific data (e.g. land-mode kinematics)
    gnc: GncSpec | None = None  # always set by the loader (the file's gnc section is required)
    coriolis: str = "full"  # one of CORIOLIS_FORMS
    current_inertia: str = "absolute"  # one of CURRENT_INERTIA
    inertia: str = "symmetric"  # one of INERTIA_FORMS

    @property
    def M(self) -> np.ndarray:
        return self.M_RB + self.M_A

    @property
    def eta_names(self) -> list[str]:
        return ETA_NAMES[self.dof]

    @property
    def nu_names(self) -> list[str]:
        return NU_NAMES[self.dof]

    @property
    def tau_names(self) -> list[str]:
        return TAU_NAMES[self.dof]


def vessel_path(name_or_path: str | Path) -> Path:
    """A bundled vessel name (``minerva2``) or a path to a vessel YAML file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        return p
    return VESSEL_DIR / f"{name_or_path}.yaml"


def bundled_vessels() -> list[str]:
    return sorted(p.stem for p in VESSEL_DIR.glob("*.yaml"))


_DOCUMENTS: dict[bytes, bytes] = {}  # the file's digest -> its YAML document, pickled
_MAX_DOCUMENTS = 32


def _document(text: bytes) -> Any:
    """The YAML document of a vessel file's text, parsed once per distinct text: a sweep validates
    every case's scenario, each loading the same vessel file, and parsing it is most of the time. Keyed
    by content (not the file's time, which can stay the same across a quick rewrite); each call gets
    its own copy (the spec keeps parts of the document)."""
    key = hashlib.blake2b(text, digest_size=20).digest()
    raw = _DOCUMENTS.get(key)
    if raw is not None:
        return pickle.loads(raw)
    doc = yaml.load(text, Loader=_Loader)
    if len(_DOCUMENTS) >= _MAX_DOCUMENTS:
        _DOCUMENTS.clear()
    _DOCUMENTS[key] = pickle.dumps(doc, protocol=pickle.HIGHEST_PROTOCOL)
    return doc


def load_vessel(name_or_path: str | Path) -> VesselSpec:
    path = vessel_path(name_or_path)
    if not path.is_file():
        given = Path(name_or_path)
        if path.is_dir() or (given.is_dir() and (given.is_absolute() or len(given.parts) > 1)):
            raise VesselFileError(f"{path if path.is_dir() else given}: is a folder, not a vessel file")
        bundled = bundled_vessels()
        raise VesselFileError(
            f"vessel '{name_or_path}': no such vessel file {path}{did_you_mean(str(name_or_path), bundled)} "
            f"(bundled: {', '.join(bundled)})"
        )
    try:
        doc = _document(path.read_bytes())
    except yaml.YAMLError as exc:
        raise VesselFileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    except ValueError as exc:  # an integer of more than 4300 digits (Python's int-from-text limit)
        raise VesselFileError(f"{path}: not valid YAML ({' '.join(str(exc).split())[:160]})") from None
    except OSError as exc:
        raise VesselFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not isinstance(doc, dict):
        raise VesselFileError(f"{path}: expected a mapping at the top level")
    return _parse(doc, path)


def _is_number(x: Any) -> bool:
    """A YAML number: text ("1_0", which float() reads as 10) and true/false are not."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def _all_numbers(x: Any) -> bool:
    return all(_all_numbers(v) for v in x) if isinstance(x, list) else _is_number(x)


class _Reader:
    """Reads ``{value, source}`` fields and records provenance; errors name file and field."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.provenance: dict[str, str] = {}

    def fail(self, key: str, msg: str) -> VesselFileError:
        return VesselFileError(f"{self.path}: field '{key}': {msg}")

    def too_big(self, key: str, value: float) -> VesselFileError:
        return self.fail(key, f"{value:g} is beyond any vessel's (|value| <= {MAX_MAGNITUDE:g} in SI units)")

    def fields(self, node: Any, where: str, known: tuple[str, ...]) -> None:
        """Refuse a key the loader does not read: misspelled, it would leave a default in its place."""
        if not isinstance(node, dict):
            return
        for key in node:
            if key not in known:
                hint = did_you_mean(str(key), known) or f" (known: {', '.join(known)})"
                raise self.fail(f"{where}.{key}" if where else str(key), f"unknown field{hint}")

    def get(self, node: dict, key: str, where: str, required: bool = True, leaf: bool = True,
            unit: bool = False) -> Any:
        """The field's value; a ``leaf`` (a value, not a section) may be ``{value, source}`` (and
        ``unit`` where the caller converts it), nothing else."""
        full = f"{where}.{key}" if where else key
        if not isinstance(node, dict) or key not in node:
            if required:
                raise self.fail(full, "missing")
            return None
        item = node[key]
        if isinstance(item, dict) and (leaf or "value" in item):
            self.fields(item, full, LEAF_FIELDS if unit else LEAF_FIELDS[:2])
            if "value" not in item:
                raise self.fail(full, "expected {value: ..., source: ...}; 'value' is missing")
            if "source" not in item:
                raise self.fail(full, "has a value but no 'source' (provenance is required)")
            self.provenance[full] = str(item["source"])
            return item["value"]
        return item

    def section(self, node: dict, key: str, where: str, known: tuple[str, ...],
                required: bool = True) -> dict | None:
        """A mapping of fields (``restoring``, ``thrusters``...), every key one of ``known``."""
        full = f"{where}.{key}" if where else key
        item = self.get(node, key, where, required=required, leaf=False)
        if item is None and not required:
            return None
        if not isinstance(item, dict):
            raise self.fail(full, f"expected a mapping of {', '.join(known)}")
        self.fields(item, full, known)
        return item

    def choice(self, node: dict, key: str, choices: tuple[str, ...]) -> str:
        """An optional top-level word, one of ``choices`` (the first is the default)."""
        value = self.get(node, key, "", required=False) or choices[0]
        if value not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def number(self, node: dict, key: str, where: str, positive: bool = False, default: Any = None,
               units: dict[str, Callable[[float], float]] | None = None) -> float:
        """A finite number within MAX_MAGNITUDE; with ``units``, an optional ``unit:`` beside value
        and source converts it."""
        full = f"{where}.{key}" if where else key
        raw = self.get(node, key, where, required=default is None, unit=units is not None)
        if raw is None:
            return float(default)
        if not _is_number(raw):
            raise self.fail(full, f"expected a number, got {raw!r}")
        try:
            val = float(raw)
        except OverflowError:
            raise self.fail(full, "too large for a floating-point number") from None
        if not np.isfinite(val):
            raise self.fail(full, "must be finite")
        if positive and val <= 0:
            raise self.fail(full, f"must be positive, got {val}")
        item = node[key]
        if units is not None and isinstance(item, dict) and "unit" in item:
            if item["unit"] not in units:
                raise self.fail(full, f"unknown unit {item['unit']!r}; known: {', '.join(units)}")
            val = units[item["unit"]](val)
        if abs(val) > MAX_MAGNITUDE:
            raise self.too_big(full, val)
        return val

    def name(self, node: dict, key: str, where: str, kind: str, default: str | None = None) -> str:
        """A registered variant name (``components.registry``), plain or as {value, source}."""
        raw = self.get(node, key, where, required=default is None)
        if raw is None:
            return str(default)
        try:
            return registry.check(kind, raw)
        except ValueError as exc:
            raise self.fail(f"{where}.{key}", str(exc)) from None

    def array(
        self, node: dict, key: str, where: str, shape: tuple[int, ...], default: Any = None
    ) -> np.ndarray:
        """A vector, or a matrix given in full or as its diagonal; finite, within MAX_MAGNITUDE."""
        full = f"{where}.{key}" if where else key
        raw = self.get(node, key, where, required=default is None)
        if raw is None:
            return np.array(default, dtype=float)
        try:
            if not _all_numbers(raw):
                raise ValueError
            arr = np.array(raw, dtype=float)
        except (TypeError, ValueError):
            raise self.fail(full, "expected numbers") from None
        except OverflowError:
            raise self.fail(full, "a number too large for a floating-point number") from None
        if len(shape) == 2 and arr.ndim == 1 and arr.shape == (shape[0],):
            arr = np.diag(arr)
        if arr.shape != shape:
            raise self.fail(full, f"expected shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise self.fail(full, "must be finite")
        if np.any(np.abs(arr) > MAX_MAGNITUDE):
            raise self.too_big(full, float(arr.flat[np.argmax(np.abs(arr))]))
        return arr


def _unwrap(r: _Reader, node: Any, where: str) -> Any:
    """Free-form ``extra`` data: ``{value, source}`` leaves become plain values, provenance recorded."""
    if isinstance(node, dict):
        if "value" in node:
            r.fields(node, where, LEAF_FIELDS[:2])
            if "source" not in node:
                raise r.fail(where, "has a value but no 'source' (provenance is required)")
            r.provenance[where] = str(node["source"])
            return node["value"]
        return {k: _unwrap(r, v, f"{where}.{k}") for k, v in node.items()}
    if isinstance(node, list):
        return [_unwrap(r, v, f"{where}[{i}]") for i, v in enumerate(node)]
    return node


def _parse(doc: dict, path: Path) -> VesselSpec:
    """The vessel of a file's document, section by section, each error naming its field."""
    r = _Reader(path)
    dof = r.get(doc, "dof", "")
    if isinstance(dof, bool) or dof not in (3, 6):
        raise r.fail("dof", f"must be 3 or 6, got {dof!r}")
    if dof == 3 and "restoring" in doc:  # read for 6 DOF only: given here, it would change nothing
        raise r.fail("restoring", "a 3-DOF model (surge, sway, yaw) has no restoring forces; remove it")
    r.fields(doc, "", TOP_FIELDS)
    name = str(r.get(doc, "name", ""))
    shape = (dof, dof)
    M_RB = r.array(doc, "mass_matrix", "", shape)
    M_A = r.array(doc, "added_mass", "", shape)
    D_L = r.array(doc, "linear_damping", "", shape)
    D_Q = r.array(doc, "quadratic_damping", "", shape)
    M = M_RB + M_A
    eig = np.linalg.eigvalsh(0.5 * (M + M.T))
    if np.any(eig <= 0):
        raise r.fail("mass_matrix + added_mass", "total mass matrix must be positive definite")
    if eig[0] * MAX_CONDITION < eig[-1]:  # M^-1 tau would amplify rounding beyond any meaning
        raise r.fail("mass_matrix + added_mass", f"total mass matrix is nearly singular (eigenvalues "
                     f"{eig[0]:.3g} to {eig[-1]:.3g}, more than {MAX_CONDITION:g} apart)")

    restoring = None
    if dof == 6:
        rs = r.section(doc, "restoring", "", RESTORING_FIELDS)
        restoring = RestoringSpec(
            weight=r.number(rs, "weight", "restoring", positive=True),
            buoyancy=r.number(rs, "buoyancy", "restoring", positive=True),
            r_g=r.array(rs, "r_g", "restoring", (3,)),
            r_b=r.array(rs, "r_b", "restoring", (3,)),
        )

    coriolis = r.choice(doc, "coriolis", CORIOLIS_FORMS)
    current_inertia = r.choice(doc, "current_inertia", CURRENT_INERTIA)
    inertia = r.choice(doc, "inertia", INERTIA_FORMS)

    thrusters = _parse_thrusters(r, doc, dof)
    sensors = _parse_sensors(r, doc, dof)
    gnc = _parse_gnc(r, doc, thrusters.count)
    title = r.get(doc, "title", "", required=False)

    return VesselSpec(
        name=name,
        title=str(name if title is None else title),
        dof=dof,
        M_RB=M_RB,
        M_A=M_A,
        D_L=D_L,
        D_Q=D_Q,
        thrusters=thrusters,
        sensors=sensors,
        restoring=restoring,
        source_file=str(path),
        provenance=r.provenance,
        extra=_parse_extra(r, doc),
        gnc=gnc,
        coriolis=coriolis,
        current_inertia=current_inertia,
        inertia=inertia,
    )


def _parse_thrusters(r: _Reader, doc: dict, dof: int) -> ThrusterSpec:
    """The ``thrusters`` section: the law and one entry per thruster, each one a real thruster could be."""
    th = r.section(doc, "thrusters", "", THRUSTERS_FIELDS)
    law = r.get(th, "law", "thrusters")
    if law not in K_UNITS:  # the laws of kernels/laws.py (tests/test_kernels.py holds them equal)
        raise r.fail("thrusters.law", f"must be {' or '.join(repr(k) for k in K_UNITS)}, got {law!r}")
    units = r.get(th, "units", "thrusters", leaf=False)
    if not isinstance(units, list) or not units:
        raise r.fail("thrusters.units", "expected a non-empty list of thrusters")
    names, pos, dirs, kf, kr, nmax, tc = [], [], [], [], [], [], []
    for i, unit in enumerate(units):
        where = f"thrusters.units[{i}]"
        if not isinstance(unit, dict):
            raise r.fail(where, f"expected a mapping of {', '.join(THRUSTER_FIELDS)}")
        r.fields(unit, where, THRUSTER_FIELDS)
        names.append(str(r.get(unit, "name", where)))
        pos.append(r.array(unit, "position", where, (3,)))
        dirs.append(r.array(unit, "direction", where, (3,)))
        kf.append(r.number(unit, "k_forward", where, positive=True, units=K_UNITS[law]))
        kr.append(r.number(unit, "k_reverse", where, positive=True, units=K_UNITS[law]))
        nmax.append(r.number(unit, "n_max", where, positive=True, units=SPEED_UNITS))
        tc.append(r.number(unit, "time_constant", where, positive=True))
        _check_thruster(r, where, law, dof, pos[-1], dirs[-1], kf[-1], kr[-1], nmax[-1])
    return ThrusterSpec(
        names=names,
        positions=np.array(pos),
        directions=np.array(dirs),
        law=law,
        k_forward=np.array(kf),
        k_reverse=np.array(kr),
        n_max=np.array(nmax),
        time_constant=np.array(tc),
    )


def _check_thruster(r: _Reader, where: str, law: str, dof: int, position: np.ndarray, direction: np.ndarray,
                    k_forward: float, k_reverse: float, n_max: float) -> None:
    """Refuse a thruster no vessel has: one that gives no force, more force than any propeller, turns
    faster than any shaft or sits off any hull (each would run, and give a meaningless result)."""
    length = float(np.linalg.norm(direction))
    if length < 1e-6:
        shown = f" (length {length:g})" if length else ""
        raise r.fail(f"{where}.direction", f"must be a non-zero vector{shown}")
    if dof == 3 and np.hypot(direction[0], direction[1]) < 1e-6 * length:  # 3 DOF: rows X, Y, N
        raise r.fail(f"{where}.direction", f"{direction.tolist()} has no horizontal component: in a 3-DOF "
                     "model (surge, sway, yaw) this thruster gives no force")
    if np.any(np.abs(position) > MAX_ARM):
        raise r.fail(f"{where}.position", f"{position.tolist()} m is more than {MAX_ARM:g} m from the body "
                     "origin (no vessel is that long)")
    if n_max > MAX_SHAFT_SPEED:
        raise r.fail(f"{where}.n_max", f"{n_max:g} rev/s is above {MAX_SHAFT_SPEED:g} rev/s "
                     f"({MAX_SHAFT_SPEED * 60:g} rpm); no thruster shaft turns that fast")
    for key, k in (("k_forward", k_forward), ("k_reverse", k_reverse)):
        force = k * (n_max if law == "linear" else n_max**2) * length
        if force > MAX_THRUST:
            raise r.fail(f"{where}.{key}", f"gives {force:.3g} N at n_max; one thruster gives at most "
                         f"{MAX_THRUST:g} N (the largest ship propellers give under 10 MN)")


def _parse_sensors(r: _Reader, doc: dict, dof: int) -> list[SensorSpec]:
    """The ``sensors`` list: each channel a state of the vessel, measured by one sensor only."""
    listed = r.get(doc, "sensors", "", leaf=False)
    if listed is None:
        return []
    if not isinstance(listed, list):
        raise r.fail("sensors", "expected a list of sensors")
    known = set(ETA_NAMES[dof]) | set(NU_NAMES[dof])
    sensors = []
    seen: set[str] = set()
    for i, s in enumerate(listed):
        where = f"sensors[{i}]"
        if not isinstance(s, dict):
            raise r.fail(where, f"expected a mapping of {', '.join(SENSOR_FIELDS)}")
        r.fields(s, where, SENSOR_FIELDS)
        sname = str(r.get(s, "name", where))
        channels = r.get(s, "channels", where)
        if not isinstance(channels, list) or not channels:
            raise r.fail(f"{where}.channels", "expected a non-empty list")
        bad = [c for c in channels if c not in known]
        if bad:
            raise r.fail(f"{where}.channels", f"unknown channel(s) {bad}; known: {sorted(known)}")
        dup = [c for c in channels if c in seen]
        if dup:
            raise r.fail(f"{where}.channels", f"channel(s) {dup} already measured by another sensor")
        seen.update(channels)
        k = len(channels)
        sensors.append(
            SensorSpec(
                name=sname,
                channels=list(channels),
                rate_hz=r.number(s, "rate_hz", where, positive=True),
                noise_std=r.array(s, "noise_std", where, (k,)),
                bias=r.array(s, "bias", where, (k,), default=np.zeros(k)),
            )
        )
        if np.any(sensors[-1].noise_std < 0):
            raise r.fail(f"{where}.noise_std", "must be non-negative")
    return sensors


def _parse_extra(r: _Reader, doc: dict) -> dict[str, Any]:
    """The ``extra`` section: only the sections something reads (EXTRA_FIELDS), as plain values."""
    extra = r.section(doc, "extra", "", tuple(EXTRA_FIELDS), required=False)
    if extra is None:
        return {}
    for sec, known in EXTRA_FIELDS.items():
        if known is not None and sec in extra:
            r.section(extra, sec, "extra", known)
    out = _unwrap(r, dict(extra), "extra")
    spot = (out.get("land") or {}).get("on_the_spot_rotation", False)
    if spot is not False:  # documents the thesis; the land model (amv_land.py) has no such mode
        raise r.fail("extra.land.on_the_spot_rotation", f"must be false (the land model turns about a "
                     f"screw at most), got {spot!r}")
    return out


GNC_FIELDS = ("controller", "allocator", "guidance", "camera_thrusters", "tuning")


def _parse_gnc(r: _Reader, doc: dict, n_thrusters: int) -> GncSpec:
    """The ``gnc`` section: variant names (required: controller, allocator) and their data."""
    g = r.get(doc, "gnc", "", leaf=False)
    if not isinstance(g, dict):
        raise r.fail("gnc", "expected a mapping (controller, allocator, guidance, camera_thrusters, tuning)")
    unknown = sorted(set(g) - set(GNC_FIELDS), key=str)
    if unknown:
        raise r.fail("gnc", f"unknown field(s) {', '.join(map(str, unknown))}; known: {', '.join(GNC_FIELDS)}"
                     f"{did_you_mean(str(unknown[0]), GNC_FIELDS)}")
    controller = r.name(g, "controller", "gnc", "controller")
    camera = r.get(g, "camera_thrusters", "gnc", required=False) or []
    if not isinstance(camera, list) or any(
            isinstance(i, bool) or not isinstance(i, int) or not 1 <= i <= n_thrusters for i in camera):
        raise r.fail("gnc.camera_thrusters", f"expected a list of thruster numbers 1..{n_thrusters}")
    tuning_doc = g.get("tuning") or {}
    if not isinstance(tuning_doc, dict):
        raise r.fail("gnc.tuning", "expected a mapping of the controller's design data")
    tuning = _unwrap(r, dict(tuning_doc), "gnc.tuning")
    allowed = registry.CONTROLLERS[controller].tuning
    bad = sorted(set(tuning) - set(allowed), key=str)
    if bad:
        raise r.fail("gnc.tuning", f"unknown key(s) {', '.join(map(str, bad))} for controller "
                     f"'{controller}'; known: {', '.join(allowed)}{did_you_mean(str(bad[0]), allowed)}")
    return GncSpec(
        controller=controller,
        allocator=r.name(g, "allocator", "gnc", "allocator"),
        guidance=r.name(g, "guidance", "gnc", "guidance", default="none"),
        camera_thrusters=[int(i) - 1 for i in camera],
        tuning=tuning,
    )
