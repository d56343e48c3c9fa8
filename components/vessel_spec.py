"""Vessel definitions: YAML data files with a provenance note per parameter, loaded into arrays.

Every physical parameter in a vessel file is written as ``{value: ..., source: "..."}`` so a user
can see where each number came from (measured, computed, assumed, corrected erratum). Bad files
fail with one line naming the file and the field.
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

# libyaml (~9x faster than the pure-Python loader): every run and every sweep case reads a vessel file
_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

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
# Units a thruster's speed and thrust coefficient may be given in (``unit:`` beside value and
# source), with the conversion to what the model works in: shaft speeds in rev/s.
SPEED_UNITS: dict[str, Callable[[float], float]] = {
    "rev/s": lambda n: n, "rps": lambda n: n, "rpm": lambda n: n / 60.0,
}
K_UNITS: dict[str, dict[str, Callable[[float], float]]] = {
    "linear": {"N/(rev/s)": lambda k: k, "N/rps": lambda k: k, "N/rpm": lambda k: k * 60.0},
    "quadratic": {"N/(rev/s)^2": lambda k: k, "N/rps^2": lambda k: k, "N/rpm^2": lambda k: k * 3600.0},
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
    doc = yaml.load(text, Loader=_LOADER)
    if len(_DOCUMENTS) >= _MAX_DOCUMENTS:
        _DOCUMENTS.clear()
    _DOCUMENTS[key] = pickle.dumps(doc, protocol=pickle.HIGHEST_PROTOCOL)
    return doc


def load_vessel(name_or_path: str | Path) -> VesselSpec:
    path = vessel_path(name_or_path)
    if not path.is_file():
        from .names import did_you_mean

        bundled = bundled_vessels()
        raise VesselFileError(
            f"vessel '{name_or_path}': no such vessel file {path}{did_you_mean(str(name_or_path), bundled)} "
            f"(bundled: {', '.join(bundled)})"
        )
    try:
        doc = _document(path.read_bytes())
    except yaml.YAMLError as exc:
        raise VesselFileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise VesselFileError(f"{path}: expected a mapping at the top level")
    return _parse(doc, path)


class _Reader:
    """Reads ``{value, source}`` fields and records provenance; errors name file and field."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.provenance: dict[str, str] = {}

    def fail(self, key: str, msg: str) -> VesselFileError:
        return VesselFileError(f"{self.path}: field '{key}': {msg}")

    def get(self, node: dict, key: str, where: str, required: bool = True) -> Any:
        full = f"{where}.{key}" if where else key
        if not isinstance(node, dict) or key not in node:
            if required:
                raise self.fail(full, "missing")
            return None
        item = node[key]
        if isinstance(item, dict) and "value" in item:
            if "source" not in item:
                raise self.fail(full, "has a value but no 'source' (provenance is required)")
            self.provenance[full] = str(item["source"])
            return item["value"]
        return item

    def number(self, node: dict, key: str, where: str, positive: bool = False, default: Any = None,
               units: dict[str, Callable[[float], float]] | None = None) -> float:
        """A finite number; with ``units``, an optional ``unit:`` beside value/source converts it."""
        full = f"{where}.{key}" if where else key
        raw = self.get(node, key, where, required=default is None)
        if raw is None:
            return float(default)
        try:
            val = float(raw)
        except (TypeError, ValueError):
            raise self.fail(full, f"expected a number, got {raw!r}") from None
        if not np.isfinite(val):
            raise self.fail(full, "must be finite")
        if positive and val <= 0:
            raise self.fail(full, f"must be positive, got {val}")
        item = node[key]
        if isinstance(item, dict) and "unit" in item:
            if units is None or item["unit"] not in units:
                known = ", ".join(units) if units else "none (SI only)"
                raise self.fail(full, f"unknown unit {item['unit']!r}; known: {known}")
            val = units[item["unit"]](val)
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
        """A vector, or a matrix given in full or as its diagonal."""
        full = f"{where}.{key}" if where else key
        raw = self.get(node, key, where, required=default is None)
        if raw is None:
            return np.array(default, dtype=float)
        try:
            arr = np.array(raw, dtype=float)
        except (TypeError, ValueError):
            raise self.fail(full, "expected numbers") from None
        if len(shape) == 2 and arr.ndim == 1 and arr.shape == (shape[0],):
            arr = np.diag(arr)
        if arr.shape != shape:
            raise self.fail(full, f"expected shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise self.fail(full, "must be finite")
        return arr


def _unwrap(r: _Reader, node: Any, where: str) -> Any:
    """Free-form ``extra`` data: ``{value, source}`` leaves become plain values, provenance recorded."""
    if isinstance(node, dict):
        if "value" in node:
            if "source" not in node:
                raise r.fail(where, "has a value but no 'source' (provenance is required)")
            r.provenance[where] = str(node["source"])
            return node["value"]
        return {k: _unwrap(r, v, f"{where}.{k}") for k, v in node.items()}
    if isinstance(node, list):
        return [_unwrap(r, v, f"{where}[{i}]") for i, v in enumerate(node)]
    return node


def _parse(doc: dict, path: Path) -> VesselSpec:
    # Long because it reads every section of the file in order with its own one-line error
    # messages; each section is a few lines and the GNC section is already split out.
    r = _Reader(path)
    name = str(r.get(doc, "name", ""))
    dof = r.get(doc, "dof", "")
    if dof not in (3, 6):
        raise r.fail("dof", f"must be 3 or 6, got {dof!r}")
    shape = (dof, dof)
    M_RB = r.array(doc, "mass_matrix", "", shape)
    M_A = r.array(doc, "added_mass", "", shape)
    D_L = r.array(doc, "linear_damping", "", shape)
    D_Q = r.array(doc, "quadratic_damping", "", shape)
    M = M_RB + M_A
    if np.any(np.linalg.eigvalsh(0.5 * (M + M.T)) <= 0):
        raise r.fail("mass_matrix + added_mass", "total mass matrix must be positive definite")

    restoring = None
    if dof == 6:
        rs = r.get(doc, "restoring", "")
        restoring = RestoringSpec(
            weight=r.number(rs, "weight", "restoring", positive=True),
            buoyancy=r.number(rs, "buoyancy", "restoring", positive=True),
            r_g=r.array(rs, "r_g", "restoring", (3,)),
            r_b=r.array(rs, "r_b", "restoring", (3,)),
        )

    coriolis = r.get(doc, "coriolis", "", required=False) or "full"
    if coriolis not in CORIOLIS_FORMS:
        raise r.fail("coriolis", f"must be one of {', '.join(CORIOLIS_FORMS)}, got {coriolis!r}")
    current_inertia = r.get(doc, "current_inertia", "", required=False) or "absolute"
    if current_inertia not in CURRENT_INERTIA:
        raise r.fail("current_inertia", f"must be one of {', '.join(CURRENT_INERTIA)}, "
                     f"got {current_inertia!r}")

    th = r.get(doc, "thrusters", "")
    law = r.get(th, "law", "thrusters")
    if law not in K_UNITS:  # the laws of kernels/laws.py (tests/test_kernels.py holds them equal)
        raise r.fail("thrusters.law", f"must be {' or '.join(repr(k) for k in K_UNITS)}, got {law!r}")
    units = r.get(th, "units", "thrusters")
    if not isinstance(units, list) or not units:
        raise r.fail("thrusters.units", "expected a non-empty list of thrusters")
    names, pos, dirs, kf, kr, nmax, tc = [], [], [], [], [], [], []
    for i, unit in enumerate(units):
        where = f"thrusters.units[{i}]"
        names.append(str(r.get(unit, "name", where)))
        pos.append(r.array(unit, "position", where, (3,)))
        dirs.append(r.array(unit, "direction", where, (3,)))
        kf.append(r.number(unit, "k_forward", where, positive=True, units=K_UNITS[law]))
        kr.append(r.number(unit, "k_reverse", where, positive=True, units=K_UNITS[law]))
        nmax.append(r.number(unit, "n_max", where, positive=True, units=SPEED_UNITS))
        tc.append(r.number(unit, "time_constant", where, positive=True))
    thrusters = ThrusterSpec(
        names=names,
        positions=np.array(pos),
        directions=np.array(dirs),
        law=law,
        k_forward=np.array(kf),
        k_reverse=np.array(kr),
        n_max=np.array(nmax),
        time_constant=np.array(tc),
    )

    known = set(ETA_NAMES[dof]) | set(NU_NAMES[dof])
    sensors = []
    seen: set[str] = set()
    for i, s in enumerate(r.get(doc, "sensors", "") or []):
        where = f"sensors[{i}]"
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

    gnc = _parse_gnc(r, doc, thrusters.count)

    return VesselSpec(
        name=name,
        title=str(doc.get("title", name)),
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
        extra=_unwrap(r, dict(doc.get("extra", {}) or {}), "extra"),
        gnc=gnc,
        coriolis=coriolis,
        current_inertia=current_inertia,
    )


GNC_FIELDS = ("controller", "allocator", "guidance", "camera_thrusters", "tuning")


def _parse_gnc(r: _Reader, doc: dict, n_thrusters: int) -> GncSpec:
    """The ``gnc`` section: variant names (required: controller, allocator) and their data."""
    g = r.get(doc, "gnc", "")
    if not isinstance(g, dict):
        raise r.fail("gnc", "expected a mapping (controller, allocator, guidance, camera_thrusters, tuning)")
    unknown = sorted(set(g) - set(GNC_FIELDS))
    if unknown:
        raise r.fail("gnc", f"unknown field(s) {', '.join(unknown)}; known: {', '.join(GNC_FIELDS)}")
    controller = r.name(g, "controller", "gnc", "controller")
    camera = r.get(g, "camera_thrusters", "gnc", required=False) or []
    if not isinstance(camera, list) or any(
            isinstance(i, bool) or not isinstance(i, int) or not 1 <= i <= n_thrusters for i in camera):
        raise r.fail("gnc.camera_thrusters", f"expected a list of thruster numbers 1..{n_thrusters}")
    tuning = _unwrap(r, dict(g.get("tuning", {}) or {}), "gnc.tuning")
    allowed = registry.CONTROLLERS[controller].tuning
    bad = sorted(set(tuning) - set(allowed))
    if bad:
        raise r.fail("gnc.tuning", f"unknown key(s) {', '.join(bad)} for controller '{controller}'; "
                     f"known: {', '.join(allowed)}")
    return GncSpec(
        controller=controller,
        allocator=r.name(g, "allocator", "gnc", "allocator"),
        guidance=r.name(g, "guidance", "gnc", "guidance", default="none"),
        camera_thrusters=[int(i) - 1 for i in camera],
        tuning=tuning,
    )
