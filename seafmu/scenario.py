"""Scenario files: schema (pydantic), loading, and every check that can fail before a run.

A scenario names a vessel, the FMUs and their order (the stepping order of the master), its
coupling (``gauss-seidel`` or ``jacobi``, see ``seafmu.master``), the connections (by matching
names, or explicit), parameters, timed events, recorded outputs and acceptance checks. Every
mistake is reported as one line: ``file: field: what is wrong``.

Every number that sizes the run is bounded here, before anything is allocated, and ``seafmu
check`` runs exactly these checks: the file size (``seafmu.yamlfile``), the step (``MIN_STEP`` <=
step <= duration), the duration (``MAX_DURATION``), the number of master steps (``MAX_STEPS``), the
recorded results held in memory (``MAX_RESULT_BYTES``, estimated as samples x columns x 8 bytes),
step multiples and record intervals (within the run), the number of FMUs (``MAX_FMUS``), an FMU
file's unpacked size (``MAX_FMU_UNPACKED_BYTES``), event times (on the grid, inside the run) and
check windows (each must contain at least one recorded sample).
"""

from __future__ import annotations

import math
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from seafmu.components.names import did_you_mean
from seafmu.units import UnitError, to_si
from seafmu.yamlfile import load_value, read_mapping, validation_message

REPO = Path(__file__).resolve().parents[1]
SCENARIO_DIR = REPO / "scenarios"
DEFAULT_SCENARIO = "minerva2_dp"
KINDS = ("plant", "observer", "controller", "allocator")
Value = float | int | str | bool
Coupling = Literal["gauss-seidel", "jacobi"]
COUPLINGS: tuple[str, ...] = ("gauss-seidel", "jacobi")

MIN_STEP = 1e-6  # s: the smallest master step
MAX_DURATION = 1e7  # s: about 116 days
MAX_STEPS = 10_000_000  # master steps in one run (about an hour of wall time at 400 us per step)
MAX_RESULT_BYTES = 1_000_000_000  # recorded samples x (signals + time) x 8 bytes, held in memory
MAX_FMUS = 64  # FMUs (and hardware links) in one scenario
MAX_FMU_UNPACKED_BYTES = 2_000_000_000  # an FMU file's unpacked size (it is unpacked to run)
MAX_MODEL_DESCRIPTION_BYTES = 50_000_000


class ScenarioError(ValueError):
    """A scenario that cannot run; the message is one line naming the file and field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _not_bool(v: Any) -> Any:
    """pydantic reads true as 1.0 where a number belongs: ``duration: true`` would be a 1 s run."""
    if isinstance(v, bool):
        raise PydanticCustomError("bool_number", "expected a number, not true or false")
    return v


Number = Annotated[float, BeforeValidator(_not_bool)]


class FmuEntry(_Strict):
    kind: Literal["plant", "observer", "controller", "allocator"] | None = None
    fmu: str | None = Field(None, description="path to any FMI 2.0 co-simulation FMU instead of a kind")
    hardware: str | None = Field(None, description="a hardware profile (hardware/profiles/NAME.yaml or a "
                                 "path): a real or emulated vessel behind serial NMEA and CAN")
    step_multiple: int = Field(1, ge=1, description="this FMU steps every N master steps")
    parameters: dict[str, Value] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _one_source(self) -> FmuEntry:
        if sum(x is not None for x in (self.kind, self.fmu, self.hardware)) != 1:
            raise ValueError("give exactly one of 'kind', 'fmu' or 'hardware'")
        return self


class Event(_Strict):
    time: Number = Field(ge=0)
    set: str = Field(description="instance.variable")
    value: Value


class Check(_Strict):
    name: str | None = None
    signal: str
    minus: str | None = Field(None, description="subtract this signal (e.g. a reference)")
    metric: Literal["max_abs", "final_abs", "rms", "max", "min", "mean"] = "max_abs"
    after: Number = 0.0
    before: Number | None = None
    angle: bool = Field(False, description="wrap the difference to (-pi, pi]")
    max: Number | None = None
    min: Number | None = None

    @model_validator(mode="after")
    def _bound(self) -> Check:
        if self.max is None and self.min is None:
            raise ValueError("a check needs 'max' or 'min'")
        if self.max is not None and self.min is not None and self.min > self.max:
            raise ValueError(f"min {self.min} is above max {self.max}")
        if self.before is not None and self.before <= self.after:
            raise ValueError(f"'before' ({self.before}) must be after 'after' ({self.after})")
        return self


_IDENT = r"^[A-Za-z_][A-Za-z0-9_-]*$"


class ScenarioModel(_Strict):
    name: str = Field(pattern=_IDENT, max_length=100, description="also the results folder name")
    description: str = ""
    vessel: str
    duration: Number = Field(gt=0)
    step: Number = Field(gt=0, description="master communication step, s")
    record_interval: Number | None = Field(None, gt=0)
    realtime: bool = Field(False, description="pace the run to the wall clock (always, with hardware)")
    coupling: Coupling = Field(
        "gauss-seidel", description="gauss-seidel: each FMU reads the newest outputs (scenario order); "
        "jacobi: every FMU steps with the outputs of the previous step, as libcosim and ecos do")
    fmus: dict[str, FmuEntry] | None = None
    connect: Literal["auto", "explicit"] = "auto"
    connections: list[str] = Field(default_factory=list)
    events: list[Event] = Field(default_factory=list)
    outputs: list[str] | None = None
    checks: list[Check] = Field(default_factory=list)


# -- resolved scenario -------------------------------------------------------------------------

@dataclass
class VarInfo:
    name: str
    causality: str  # input, output, parameter, local...
    type: str  # real, integer, boolean, string
    unit: str = ""
    variability: str = ""
    min: float | None = None
    max: float | None = None
    start: Any = None


@dataclass
class Instance:
    name: str
    kind: str | None
    fmu_file: Path | None
    step_multiple: int
    parameters: dict[str, Any]
    variables: dict[str, VarInfo]
    hardware: str | None = None  # hardware profile: the instance is a HardwareLink


@dataclass
class Scenario:
    name: str
    description: str
    source: Path
    vessel: str
    duration: float
    step: float
    record_every: int
    instances: list[Instance]
    connections: list[tuple[str, str, str, str]]  # src inst, src var, dst inst, dst var
    events: list[tuple[float, str, str, Any]]
    outputs: list[tuple[str, str]]
    checks: list[Check]
    realtime: bool = False
    coupling: Coupling = "gauss-seidel"
    overrides: tuple[str, ...] = ()  # the --set texts applied (for the record and a reproducing command)
    seed: int | None = None  # the --seed applied

    def instance(self, name: str) -> Instance:
        return next(i for i in self.instances if i.name == name)

    @property
    def n_steps(self) -> int:
        return round(self.duration / self.step)

    @property
    def n_samples(self) -> int:
        """Recorded rows, the initial one included."""
        return self.n_steps // self.record_every + 1

    @property
    def result_bytes(self) -> int:
        """Memory the recorded results take during the run (time column included)."""
        return result_bytes(self.n_samples, len(self.outputs))


def result_bytes(n_samples: int, n_signals: int) -> int:
    return 8 * n_samples * (n_signals + 1)


def _size(n: float) -> str:
    for unit, f in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n:.0f} bytes"


def scenario_path(name_or_path: str | Path | None) -> Path:
    if name_or_path is None:
        name_or_path = DEFAULT_SCENARIO
    p = Path(name_or_path)
    if p.is_file():
        return p
    candidate = SCENARIO_DIR / f"{name_or_path}.yaml"
    if p.suffix in ("", ) and candidate.is_file():
        return candidate
    if not str(name_or_path).strip():  # Path("") is the current folder
        raise ScenarioError("scenario '': empty name; give a scenario file or a shipped scenario's name")
    if p.exists():  # there, but not a file to read: say so rather than 'no such file'
        what = "a folder" if p.is_dir() else "not a regular file (a device, pipe or socket)"
        raise ScenarioError(f"{p}: is {what}, not a scenario file")
    names = sorted(q.stem for q in SCENARIO_DIR.glob("*.yaml"))
    raise ScenarioError(f"scenario '{name_or_path}': no such file or shipped scenario"
                        f"{did_you_mean(str(name_or_path), names)} (shipped: {', '.join(names)})")


@dataclass(frozen=True)
class Override:
    """One ``--set instance.variable=value`` (or ``instance.variable@TIME=value``: an event at TIME).

    ``value`` is the YAML reading of the text after ``=`` (``5`` a number, ``true`` a boolean,
    ``0.2 m/s`` a quantity), so an override is the same value the scenario file could hold, and it
    goes through the same validation (``load_scenario``).
    """

    instance: str
    variable: str
    value: Value
    text: str  # as given, for messages and the command line that reproduces a run
    time: float | None = None  # an event at this time instead of a parameter

    @property
    def label(self) -> str:
        return f"--set {self.text}"


_SET = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_-]*)\.([A-Za-z_][A-Za-z0-9_\[\].]*)"
                  r"\s*(?:@\s*([^=]+?))?\s*=(.*)$")


def parse_override(text: str) -> Override:
    """``plant.current_speed=0.2m/s`` -> Override; a malformed text is a one-line ScenarioError."""
    import yaml

    m = _SET.match(text)
    if not m:
        raise ScenarioError(f"--set {text!r}: must read instance.variable=value "
                            "(e.g. plant.current_speed=0.2m/s) or instance.variable@TIME=value")
    inst, var, at, raw = m.groups()
    if not raw.strip():
        raise ScenarioError(f"--set {text}: no value after '='")
    try:
        value = load_value(raw)  # numbers as the files read them: 010 is 10, 0x10 is text
    except (yaml.YAMLError, ValueError):  # ValueError: an integer of more than 4300 digits
        value = raw.strip()
    if isinstance(value, str):  # '0.2m/s' is the unit table's '0.2 m/s'
        value = value.strip()
    if value is None or isinstance(value, list | dict):
        raise ScenarioError(f"--set {text}: the value must be a number, a quantity, text or true/false")
    time = None
    if at is not None:
        try:
            time = to_si(at.strip(), "s")
        except UnitError as exc:
            raise ScenarioError(f"--set {text}: event time: {exc}") from None
        if not math.isfinite(time) or time < 0:
            raise ScenarioError(f"--set {text}: event time must be finite and >= 0")
    return Override(inst, var, value, text.strip(), time)


def _apply_overrides(doc: dict[str, Any], overrides: list[Override], path: Path) -> dict[str, str]:
    """Write the overrides into the scenario document (parameters, or events at a time) before
    validation; returns the labels that replace the file's field names in error messages."""
    labels: dict[str, str] = {}
    if not overrides:
        return labels
    fmus = doc.get("fmus")
    if fmus is None:  # the vessel's four FMUs by default: spelled out so a parameter can be set
        fmus = doc["fmus"] = {k: {"kind": k} for k in KINDS}
    if not isinstance(fmus, dict):
        return labels  # the schema reports the malformed field itself
    events = doc.setdefault("events", [])
    for o in overrides:
        if o.instance not in fmus:
            raise ScenarioError(f"{path}: {o.label}: unknown FMU '{o.instance}'"
                                f"{did_you_mean(o.instance, fmus)} (FMUs: {', '.join(map(str, fmus))})")
        if o.time is not None:
            if not isinstance(events, list):
                return labels
            labels[f"events.{len(events)}"] = o.label
            labels[f"events[{len(events)}]"] = o.label
            events.append({"time": o.time, "set": f"{o.instance}.{o.variable}", "value": o.value})
            continue
        entry = fmus[o.instance]
        if not isinstance(entry, dict):
            return labels
        params = entry.setdefault("parameters", {})
        if not isinstance(params, dict):
            return labels
        params[o.variable] = o.value
        labels[f"fmus.{o.instance}.parameters.{o.variable}"] = o.label
    return labels


def _relabel(message: str, labels: dict[str, str]) -> str:
    """A message about a field an override wrote names the override instead."""
    for field, label in labels.items():
        if message.startswith(field + ":") or message.startswith(field + "."):
            rest = message.partition(":")[2]
            return f"{label}:{rest}"
    return message


def load_scenario(name_or_path: str | Path | None = None, overrides: list[Override] | None = None,
                  seed: int | None = None) -> Scenario:
    """Read, validate and resolve a scenario; ``overrides`` (``--set``) and ``seed`` (``--seed``:
    every parameter named ``seed`` or ``*_seed``, so it reaches every random source) are applied
    to the document first and validated by the same code as the file's own values."""
    import copy

    path = scenario_path(name_or_path)
    doc = read_mapping(path, "scenario", ScenarioError)
    if overrides:
        doc = copy.deepcopy(doc)
    labels = _apply_overrides(doc, list(overrides or []), path)
    try:
        model = ScenarioModel.model_validate(doc)
    except ValidationError as exc:
        raise ScenarioError(f"{path}: {_relabel(validation_message(exc), labels)}") from None
    sc = resolve(model, path, labels, seed)
    sc.overrides = tuple(o.text for o in overrides or [])
    sc.seed = seed
    return sc


def _fail(path: Path | None, where: str, msg: str) -> ScenarioError:
    """One line: the file (none for a value given outside one), the field, what is wrong."""
    return ScenarioError(f"{path}: {where}: {msg}" if path is not None else f"{where}: {msg}")


def _split(ref: str, path: Path, where: str) -> tuple[str, str]:
    if ref.count(".") < 1:
        raise _fail(path, where, f"'{ref}' must be 'instance.variable'")
    inst, var = ref.split(".", 1)
    return inst.strip(), var.strip()


def interface_variables(vessel: str, kind: str, spec: Any = None) -> dict[str, VarInfo]:
    """Variables of a seafmu FMU kind, from the Block interface (no build needed to validate);
    ``spec``: the vessel, loaded already (``load_vessel(vessel)``)."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.fmus.registry import BLOCKS

    iface = BLOCKS[kind].interface(spec if spec is not None else load_vessel(vessel))
    out: dict[str, VarInfo] = {}
    groups = (("input", iface.inputs), ("output", iface.outputs), ("parameter", iface.parameters))
    for causality, sigs in groups:
        for s in sigs:
            variability = ("tunable" if s.tunable else "fixed") if causality == "parameter" else "continuous"
            out[s.name] = VarInfo(s.name, causality, s.type, s.unit, variability, s.min, s.max, s.start)
    out["vessel_file"] = VarInfo("vessel_file", "parameter", "string", "", "fixed")
    return out


def _profile_path(profile: str, path: Path) -> str:
    p = Path(profile)
    if p.suffix in (".yaml", ".yml") and not p.is_absolute():
        p = (path.parent / p).resolve()
        return str(p)
    return profile


def hardware_variables(profile: str, vessel: str, path: Path, where: str) -> dict[str, VarInfo]:
    """The link's variables from its profile (no port opened), checked against the scenario's vessel."""
    from seafmu.hardware.link import HardwareLink
    from seafmu.hardware.profile import load_profile

    try:
        prof = load_profile(_profile_path(profile, path))
        iface = HardwareLink.interface(prof)
    except (ValueError, RuntimeError, OSError) as exc:
        raise _fail(path, where, " ".join(str(exc).split())) from None
    if prof.vessel != vessel:
        raise _fail(path, where,
                    f"profile '{profile}' is for vessel '{prof.vessel}', the scenario's is '{vessel}'")
    out: dict[str, VarInfo] = {}
    for causality, sigs in (("input", iface.inputs), ("output", iface.outputs)):
        for s in sigs:
            out[s.name] = VarInfo(s.name, causality, s.type, s.unit, "continuous", s.min, s.max, s.start)
    return out


def check_fmu_archive(fmu: Path) -> None:
    """Bound what running the FMU would unpack, from the zip directory alone (nothing extracted)."""
    with zipfile.ZipFile(fmu) as zf:
        infos = zf.infolist()
    md = next((i for i in infos if i.filename == "modelDescription.xml"), None)
    if md is None:
        raise ValueError("no modelDescription.xml in the archive")
    if md.file_size > MAX_MODEL_DESCRIPTION_BYTES:
        raise ValueError(f"modelDescription.xml unpacks to {_size(md.file_size)}; the limit is "
                         f"{_size(MAX_MODEL_DESCRIPTION_BYTES)}")
    total = sum(i.file_size for i in infos)
    if total > MAX_FMU_UNPACKED_BYTES:
        raise ValueError(f"unpacks to {_size(total)}; the limit is {_size(MAX_FMU_UNPACKED_BYTES)}")


def fmu_file_variables(fmu: Path) -> dict[str, VarInfo]:
    from fmpy import read_model_description

    check_fmu_archive(fmu)
    md = read_model_description(str(fmu))
    if md.fmiVersion != "2.0" or md.coSimulation is None:
        raise ValueError(f"seafmu runs FMI 2.0 co-simulation FMUs; this is FMI {md.fmiVersion}"
                         f"{'' if md.coSimulation else ' without co-simulation'}")
    units = {}
    out: dict[str, VarInfo] = {}
    for v in md.modelVariables:
        units[v.name] = v.unit or (v.declaredType.unit if v.declaredType is not None else "") or ""
        mn = float(v.min) if v.min is not None else None
        mx = float(v.max) if v.max is not None else None
        out[v.name] = VarInfo(v.name, v.causality, v.type.lower(), units[v.name], v.variability, mn, mx,
                              v.start)
    return out


def _check_vessel_file(value: str, vessel: str, kind: str, path: Path, where: str, spec: Any) -> str:
    """Resolve against the scenario's folder, load it, and demand the interface of the FMU."""
    from seafmu.components.vessel_spec import VesselFileError, load_vessel
    from seafmu.fmus.registry import BLOCKS

    p = Path(value)
    if not p.is_absolute():
        p = (path.parent / p).resolve()
    try:
        other = load_vessel(p)
    except VesselFileError as exc:
        raise _fail(path, where, str(exc)) from None
    a, b = BLOCKS[kind].interface(spec), BLOCKS[kind].interface(other)
    if a.input_names() != b.input_names() or a.output_names() != b.output_names():
        raise _fail(path, where, f"{p} has another interface than vessel '{vessel}' (thrusters, DOF and "
                    "sensors must match)")
    return str(p)


def convert_parameter(value: Any, info: VarInfo, where: str) -> Any:
    """A parameter's value as a scenario file's is read (a quantity in its unit, its range, its
    type); a bad one is a one-line ScenarioError ``{where}: ...``. For tools that set one parameter
    outside a scenario (``seafmu emulate --set``)."""
    return _convert(value, info, None, where)


def _convert(value: Any, info: VarInfo, path: Path | None, where: str) -> Any:
    if info.type == "string":
        if not isinstance(value, str):
            raise _fail(path, where, f"expected text, got {value!r}")
        return value
    if info.type == "boolean":
        if not isinstance(value, bool):
            raise _fail(path, where, f"expected true or false, got {value!r}")
        return value
    if info.type == "integer":
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(path, where, f"expected a whole number, got {value!r}")
        if not -(2**31) <= value < 2**31:
            raise _fail(path, where, f"{value} does not fit an FMI Integer (32 bits)")
        if info.min is not None and value < info.min:
            raise _fail(path, where, f"{value} is below the minimum {info.min:g}")
        if info.max is not None and value > info.max:
            raise _fail(path, where, f"{value} is above the maximum {info.max:g}")
        return value
    try:
        x = to_si(value, info.unit)
    except UnitError as exc:
        raise _fail(path, where, str(exc)) from None
    if not math.isfinite(x):
        raise _fail(path, where, f"must be finite, got {value!r}")
    shown = f"{x:g} {info.unit}".strip()
    if info.min is not None and x < info.min - 1e-12:
        raise _fail(path, where, f"{shown} is below the minimum {info.min:g}")
    if info.max is not None and x > info.max + 1e-12:
        raise _fail(path, where, f"{shown} is above the maximum {info.max:g}")
    return x


def _check_text(kind: str | None, name: str, value: Any, path: Path, where: str, spec: Any) -> None:
    """A text parameter of seafmu's own FMUs checked as its block will check it (components.registry),
    for the scenario's vessel ``spec``; an FMU from elsewhere (no kind) is the judge of its own."""
    if kind is None or not isinstance(value, str):
        return
    from seafmu.components.registry import check_text_parameter

    try:
        check_text_parameter(name, value, spec)
    except ValueError as exc:
        raise _fail(path, where, str(exc)) from None


def _units_differ(a: VarInfo, b: VarInfo, both_ours: bool) -> bool:
    """Between two of seafmu's own FMUs, which give every physical variable its unit, a variable
    without one (a count, a flag) meets only another without one; an FMU from elsewhere may leave
    units out, so there only two given units count."""
    if both_ours:
        return (a.unit or "") != (b.unit or "")
    return bool(a.unit and b.unit and a.unit != b.unit)


def _unit_text(v: VarInfo) -> str:
    return f"in {v.unit}" if v.unit else "without a unit"


def _check_link(src: VarInfo, dst: VarInfo, left: str, right: str, path: Path, where: str,
                both_ours: bool = False) -> None:
    """Types and units must match (``_units_differ``)."""
    if src.type != "real" or dst.type != "real":
        raise _fail(path, where,
                    f"only Real variables can be connected: {left} is {src.type}, {right} is {dst.type}")
    if _units_differ(src, dst, both_ours):
        raise _fail(path, where, f"unit mismatch: {left} is {_unit_text(src)}, {right} {_unit_text(dst)}")


def _window(c: Check) -> str:
    return f"t >= {c.after:g} s" + (f", t <= {c.before:g} s" if c.before is not None else "")


def time_slack(t: float) -> float:
    """How far a sample time may miss a window edge and still count as on it: 1e-9 relative (1e-9 s
    below 1 s). Above float rounding at any time, and far below the step (at most 1e7 steps)."""
    return 1e-9 * max(1.0, abs(t))


def _window_has_samples(after: float, before: float | None, dt_rec: float, last: int) -> bool:
    """Whether a recorded sample t_i = i dt_rec, i = 0..last, lies in [after, before] (with
    ``time_slack``, as the checks evaluate it)."""
    i0 = max(0, math.ceil((after - time_slack(after)) / dt_rec))
    if i0 > last:
        return False
    return before is None or i0 * dt_rec <= before + time_slack(before)


def _check_time_grid(model: ScenarioModel, path: Path) -> float:
    """Duration and step within their bounds, a bounded whole number of steps: duration / step."""
    d, h = model.duration, model.step
    if d > MAX_DURATION:
        raise _fail(path, "duration", f"{d:g} s is above the limit of {MAX_DURATION:g} s "
                    f"({MAX_DURATION / 86400:.0f} days)")
    if h < MIN_STEP:
        raise _fail(path, "step", f"{h:g} s is below the smallest step, {MIN_STEP:g} s")
    if h > d:
        raise _fail(path, "step", f"{h:g} s is longer than the duration {d:g} s")
    ratio = d / h
    if ratio > MAX_STEPS + 0.5:
        raise _fail(path, "step", f"{d:g} s in steps of {h:g} s is {ratio:.3g} steps; a run is limited "
                    f"to {MAX_STEPS:.0e} steps (a longer step or a shorter run)")
    if abs(ratio - round(ratio)) > 1e-6 * max(1.0, ratio):
        raise _fail(path, "step",
                    f"duration {model.duration} s is not a whole number of steps of {model.step} s")
    return ratio


def resolve(model: ScenarioModel, path: Path, labels: dict[str, str] | None = None,
            seed: int | None = None) -> Scenario:
    """The validated model made into a runnable Scenario; ``labels`` name the ``--set`` that wrote
    a field in its messages; ``seed`` goes to every seed parameter."""
    # Long because it resolves the scenario's fields in the order they depend on each other
    # (vessel, FMUs, parameters with units and ranges, connections, events, checks, limits), each
    # error naming its field; one flat sequence reads like the format's documentation.
    labels = labels or {}
    from seafmu.build import VESSELS
    from seafmu.components.vessel_spec import VesselFileError, bundled_vessels, load_vessel

    try:
        spec = load_vessel(model.vessel)  # once: each FMU kind's interface is made from it
    except VesselFileError as exc:
        known = "" if "bundled:" in str(exc) else f" (bundled: {', '.join(bundled_vessels())})"
        raise _fail(path, "vessel", f"{exc}{known}") from None
    if model.vessel not in VESSELS:
        raise _fail(path, "vessel", f"'{model.vessel}' has no FMUs (FMUs are built for "
                    f"{', '.join(VESSELS)}); load another vessel file of the same interface with "
                    "the plant parameter vessel_file")

    ratio = _check_time_grid(model, path)
    n_steps = round(ratio)
    if model.fmus is not None and not model.fmus:
        raise _fail(path, "fmus", "lists no FMU (leave the field out for the vessel's four FMUs)")
    if model.fmus is not None and len(model.fmus) > MAX_FMUS:
        raise _fail(path, "fmus", f"{len(model.fmus)} FMUs; a scenario is limited to {MAX_FMUS}")
    entries = model.fmus if model.fmus is not None else {k: FmuEntry(kind=k) for k in KINDS}
    instances: list[Instance] = []
    seeded: list[str] = []
    for name, e in entries.items():
        where = f"fmus.{name}"
        if not re.match(_IDENT, name):
            raise _fail(path, where, "an FMU name must be a plain identifier (letters, digits, _ or -)")
        if e.kind is not None:
            variables = interface_variables(model.vessel, e.kind, spec)
            fmu_file = None
        elif e.hardware is not None:
            variables = hardware_variables(e.hardware, model.vessel, path, f"{where}.hardware")
            fmu_file = None
        else:
            fmu_file = (path.parent / e.fmu).resolve() if not Path(e.fmu).is_absolute() else Path(e.fmu)
            if fmu_file.is_dir():  # an unpacked FMU's folder, say: it is run from its .fmu archive
                raise _fail(path, f"{where}.fmu", f"{fmu_file} is a folder, not an FMU file")
            if not fmu_file.is_file():
                raise _fail(path, f"{where}.fmu", f"no such FMU file {fmu_file}")
            try:
                variables = fmu_file_variables(fmu_file)
            except Exception as exc:  # fmpy raises many types for broken archives
                first = " ".join(str(exc).split())[:200]
                raise _fail(path, f"{where}.fmu", f"not a readable FMU ({first})") from None
        params = {}
        for pname, value in e.parameters.items():
            field = f"{where}.parameters.{pname}"
            field = labels.get(field, field)
            info = variables.get(pname)
            if info is None:
                raise _fail(path, field, f"no such variable in FMU '{name}'{did_you_mean(pname, variables)}")
            if info.causality not in ("parameter", "input"):
                raise _fail(path, field, f"is an {info.causality}; it cannot be set")
            params[pname] = _convert(value, info, path, field)
            _check_text(e.kind, pname, params[pname], path, field, spec)
        if seed is not None:
            for v in variables.values():
                if v.causality == "parameter" and (v.name == "seed" or v.name.endswith("_seed")):
                    given = labels.get(f"{where}.parameters.{v.name}")
                    if given is not None:  # both name its value: neither may silently win
                        raise _fail(path, "--seed", f"{seed} and {given} both set {name}.{v.name}; "
                                    "give one of them")
                    params[v.name] = _convert(seed, v, path, f"--seed (fmus.{name}.{v.name})")
                    seeded.append(f"{name}.{v.name}")
        if e.kind is not None and params.get("vessel_file"):
            params["vessel_file"] = _check_vessel_file(params["vessel_file"], model.vessel, e.kind, path,
                                                       f"{where}.parameters.vessel_file", spec)
        instances.append(Instance(name, e.kind, fmu_file, e.step_multiple, params, variables,
                                  hardware=_profile_path(e.hardware, path) if e.hardware else None))
    if seed is not None and not seeded:
        raise _fail(path, "--seed", "no FMU of this scenario has a seed parameter (nothing random to seed)")
    by_name = {i.name: i for i in instances}

    def lookup(ref: str, where: str, causality: tuple[str, ...]) -> tuple[str, str, VarInfo]:
        inst, var = _split(ref, path, where)
        if inst not in by_name:
            raise _fail(path, where, f"unknown FMU '{inst}' in '{ref}'{did_you_mean(inst, by_name)} "
                        f"(FMUs: {', '.join(by_name)})")
        info = by_name[inst].variables.get(var)
        if info is None:
            raise _fail(path, where, f"FMU '{inst}' has no variable '{var}'"
                        f"{did_you_mean(var, by_name[inst].variables)}")
        if info.causality not in causality:
            raise _fail(path, where, f"'{ref}' is an {info.causality}, expected {' or '.join(causality)}")
        return inst, var, info

    connections: dict[tuple[str, str], tuple[str, str]] = {}
    if model.connect == "auto":
        producers: dict[str, list[str]] = {}
        for inst in instances:
            for v in inst.variables.values():
                if v.causality == "output":
                    producers.setdefault(v.name, []).append(inst.name)
        for inst in instances:
            for v in inst.variables.values():
                if v.causality != "input":
                    continue
                src = [p for p in producers.get(v.name, []) if p != inst.name]
                if len(src) > 1:
                    raise _fail(path, "connect", f"input {inst.name}.{v.name} matches outputs of several "
                                f"FMUs ({', '.join(src)}): connect it explicitly")
                if src:
                    sinfo = by_name[src[0]].variables[v.name]
                    _check_link(sinfo, v, f"{src[0]}.{v.name}", f"{inst.name}.{v.name}", path, "connect",
                                both_ours=by_name[src[0]].kind is not None and inst.kind is not None)
                    connections[(inst.name, v.name)] = (src[0], v.name)
    explicit: set[tuple[str, str]] = set()
    for k, text in enumerate(model.connections):
        where = f"connections[{k}]"
        if "->" not in text:
            raise _fail(path, where, f"'{text}' must read 'instance.output -> instance.input'")
        left, right = (s.strip() for s in text.split("->", 1))
        si, sv, sinfo = lookup(left, where, ("output",))
        di, dv, dinfo = lookup(right, where, ("input",))
        if (di, dv) in explicit:
            raise _fail(path, where, f"{right} is already connected by an earlier line")
        explicit.add((di, dv))
        _check_link(sinfo, dinfo, left, right, path, where,
                    both_ours=by_name[si].kind is not None and by_name[di].kind is not None)
        connections[(di, dv)] = (si, sv)

    for inst in instances:  # a start value on a connected input: the connection overwrites it at once
        for pname in inst.parameters:
            if (inst.name, pname) in connections and inst.variables[pname].causality == "input":
                field = f"fmus.{inst.name}.parameters.{pname}"
                src = ".".join(connections[(inst.name, pname)])
                raise _fail(path, labels.get(field, field), f"{inst.name}.{pname} is an input driven by "
                            f"{src}; a value given here would be overwritten (disconnect it to set it)")

    events = []
    first_set: dict[tuple[int, str, str], int] = {}  # (step, instance, variable) -> the event setting it
    for k, ev in enumerate(model.events):
        where = labels.get(f"events[{k}]", f"events[{k}]")
        inst, var, info = lookup(ev.set, where, ("input", "parameter"))
        if (inst, var) in connections:
            raise _fail(path, where, f"{ev.set} is driven by a connection; an event cannot set it")
        if info.causality == "parameter" and info.variability != "tunable":
            raise _fail(path, where, f"{ev.set} is a fixed parameter; only tunable ones change during a run")
        if ev.time >= model.duration:
            raise _fail(path, where, f"time {ev.time} is not before the end of the run ({model.duration} s)")
        k_ev = ev.time / model.step
        if abs(k_ev - round(k_ev)) > 1e-6:
            raise _fail(path, where, f"time {ev.time} s is not on the step grid ({model.step} s)")
        earlier = first_set.setdefault((round(k_ev), inst, var), k)
        if earlier != k:  # both apply at the same step: one of them would be lost without a word
            raise _fail(path, where, f"sets {inst}.{var} at {ev.time:g} s, as "
                        f"{labels.get(f'events[{earlier}]', f'events[{earlier}]')} does")
        value_field = where if where.startswith("--set") else f"{where}.value"
        value = _convert(ev.value, info, path, value_field)
        _check_text(by_name[inst].kind, var, value, path, value_field, spec)
        events.append((ev.time, inst, var, value))
    events.sort(key=lambda e: e[0])

    record_every = 1
    if model.record_interval is not None:
        if model.record_interval > model.duration:
            raise _fail(path, "record_interval", f"{model.record_interval:g} s is longer than the duration "
                        f"{model.duration:g} s")
        r = model.record_interval / model.step
        if r < 1 - 1e-9 or abs(r - round(r)) > 1e-6:
            raise _fail(path, "record_interval", f"{model.record_interval} s must be a whole multiple of "
                        f"the step {model.step} s")
        record_every = round(r)
        if n_steps % record_every:
            raise _fail(path, "record_interval", f"{model.record_interval} s does not divide the duration "
                        f"{model.duration} s (the last sample would be lost)")
    for inst in instances:
        if inst.step_multiple > n_steps:
            raise _fail(path, f"fmus.{inst.name}.step_multiple", f"{inst.step_multiple} is more than the "
                        f"run's {n_steps} steps")
        if n_steps % inst.step_multiple:
            raise _fail(path, f"fmus.{inst.name}.step_multiple", f"{inst.step_multiple} steps of "
                        f"{model.step} s do not divide the duration {model.duration} s")

    def recordable(ref: str, where: str) -> tuple[str, str]:
        inst, var, info = lookup(ref, where, ("output", "input", "parameter"))
        if info.type != "real" and not (info.type == "integer" and info.causality == "parameter"):
            raise _fail(path, where, f"'{ref}' is {info.type}; only Real signals can be recorded")
        return inst, var

    if model.outputs is None:
        outputs = [(i.name, v.name) for i in instances for v in i.variables.values()
                   if v.causality == "output" and v.type == "real"]
    else:
        outputs = [recordable(ref, f"outputs[{k}]") for k, ref in enumerate(model.outputs)]
    recorded = set(outputs)
    for _, inst, var, _ in events:  # setpoints and other event targets belong in the results
        if (inst, var) not in recorded:
            outputs.append((inst, var))
            recorded.add((inst, var))
    for k, c in enumerate(model.checks):
        pair = []
        for attr in ("signal", "minus"):
            ref = getattr(c, attr)
            if ref is None:
                continue
            inst, var = recordable(ref, f"checks[{k}].{attr}")
            pair.append((inst, var))
            if (inst, var) not in recorded:
                outputs.append((inst, var))
                recorded.add((inst, var))
        if len(pair) == 2:  # metres minus radians measures nothing
            (i1, v1), (i2, v2) = pair
            a, b = by_name[i1].variables[v1], by_name[i2].variables[v2]
            ours = by_name[i1].kind is not None and by_name[i2].kind is not None
            if _units_differ(a, b, ours):
                raise _fail(path, f"checks[{k}].minus", f"unit mismatch: {c.signal} is {_unit_text(a)}, "
                            f"{c.minus} {_unit_text(b)}")
        if c.after >= model.duration:
            raise _fail(path, f"checks[{k}].after", f"{c.after} s is not before the end of the run")
        dt_rec = model.step * record_every
        if not _window_has_samples(c.after, c.before, dt_rec, n_steps // record_every):
            raise _fail(path, f"checks[{k}]", f"the window {_window(c)} contains no recorded sample "
                        f"(samples every {dt_rec:g} s)")

    n_samples = n_steps // record_every + 1
    need = result_bytes(n_samples, len(outputs))
    if need > MAX_RESULT_BYTES:
        raise _fail(path, "record_interval" if model.record_interval is not None else "step",
                    f"{n_samples} samples x {len(outputs) + 1} columns = {_size(need)} of results in memory; "
                    f"the limit is {_size(MAX_RESULT_BYTES)} (record less often with record_interval, "
                    "or fewer outputs)")

    return Scenario(
        name=model.name,
        description=model.description,
        source=path,
        vessel=model.vessel,
        duration=model.duration,
        step=model.step,
        record_every=record_every,
        instances=instances,
        connections=[(s[0], s[1], d[0], d[1]) for d, s in connections.items()],
        events=events,
        outputs=outputs,
        checks=model.checks,
        realtime=model.realtime or any(i.hardware for i in instances),
        coupling=model.coupling,
    )
