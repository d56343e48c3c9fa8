"""Study files: what varies over a base scenario, and the cases that makes.

A study names a base scenario and

- ``vary``: inputs, each an ``instance.variable`` (a parameter; ``instance.variable@TIME`` an event
  at TIME) or a free name with ``set:`` templates (``{"plant.fail_mode_{value}@60": 1}``), given as
  a list (``values``), a grid (``grid: {start, stop, num}``) or a distribution (``uniform: [lo, hi]``,
  ``normal: {mean, std[, min, max]}``, ``lognormal: {median, sigma}``, ``choice: [a, b, ...]``);
  quantities carry units (``"0.1 m/s"``) or a ``unit:``;
- ``sampling``: how distributions are sampled (``lhs``, ``sobol``: ``scipy.stats.qmc``; ``saltelli``:
  SALib's design for Sobol indices; ``random``), ``samples`` points;
- ``seeds``: a count (1..N), a list, or ``{start, count}``; ``pair_seeds: true`` gives the i-th
  sample the i-th seed (Monte Carlo: one random environment per seed) instead of crossing them;
- ``set``: overrides every case shares; ``metrics``: extra summary values (``settling_time`` or a
  check metric, no bound); ``keep``: signals to save per case as Parquet time series.

Lists and grids are crossed (full factorial), with the samples, and with the seeds. Each case is
the list of ``--set`` texts plus a seed: exactly what ``seafmu run BASE --set ... --seed S`` takes,
so every case is validated by ``seafmu.scenario.load_scenario`` before anything runs, and the
command printed for a case reproduces it bit for bit (values written with ``repr``: no rounding).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from seafmu.scenario import Override, ScenarioError, load_scenario, parse_override, scenario_path
from seafmu.units import is_number, split_quantity
from seafmu.yamlfile import read_mapping, validation_message

Scalar = float | int | str | bool
MAX_CASES = 100_000  # a study larger than this is a mistake more often than a plan
# Validated scenarios kept for the workers (so a case is validated once, not again in its worker) up to
# this many cases: about 30 kB each, held by this process and the scheduler until the case runs.
KEEP_SCENARIOS = 2_000
SAMPLING_METHODS = ("lhs", "sobol", "saltelli", "random")
_TARGET = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*\.[A-Za-z_][A-Za-z0-9_\[\].]*(@.+)?$")


# A row's own columns in cases.parquet (seafmu.sweep.worker.run_case, execute.cases_frame), and the
# prefixes of its check, pass and metric columns: an input named so would overwrite one of them
# (an input "key" would make every rerun miss its finished cases).
ROW_COLUMNS = frozenset({"case", "key", "seed", "status", "error", "worker", "run_time_s", "simulated_s",
                         "loop_time_s", "realtime_factor", "wall_time_s", "started", "finished", "cpu_time_s",
                         "sample", "overrides", "command", "timeseries"})
ROW_PREFIXES = ("check: ", "pass: ", "metric: ", "_")


class StudyError(ValueError):
    """A study that cannot run; one line naming the file and the field or case."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Grid(_Strict):
    start: float | str
    stop: float | str
    num: int = Field(ge=1, le=10_000)


class Normal(_Strict):
    mean: float | str
    std: float | str
    min: float | str | None = None
    max: float | str | None = None


class LogNormal(_Strict):
    median: float | str = Field(description="exp(mu): the median of the value")
    sigma: float = Field(gt=0, description="standard deviation of ln(value)")


class Input(_Strict):
    values: list[Scalar] | None = Field(None, min_length=1)
    grid: Grid | None = None
    uniform: list[float | str] | None = Field(None, min_length=2, max_length=2)
    normal: Normal | None = None
    lognormal: LogNormal | None = None
    choice: list[Scalar] | None = Field(None, min_length=1)
    unit: str | None = None
    set: dict[str, Scalar] | None = Field(None, description="overrides templated with {value}")

    @model_validator(mode="after")
    def _one(self) -> Input:
        given = [k for k in ("values", "grid", "uniform", "normal", "lognormal", "choice")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of values, grid, uniform, normal, lognormal, choice"
                             + (f" (got {', '.join(given)})" if given else ""))
        return self

    @property
    def sampled(self) -> bool:
        return self.values is None and self.grid is None


class Sampling(_Strict):
    method: Literal["lhs", "sobol", "saltelli", "random"] = "lhs"
    samples: int = Field(16, ge=1, le=MAX_CASES)
    seed: int = Field(0, ge=0)


class Seeds(_Strict):
    start: int = Field(1, ge=0)
    count: int = Field(ge=1, le=MAX_CASES)


class Metric(_Strict):
    name: str = Field(min_length=1, max_length=200)
    signal: str
    minus: str | None = None
    metric: Literal["settling_time", "max_abs", "final_abs", "rms", "max", "min", "mean"] = "max_abs"
    angle: bool = False
    after: float = 0.0
    before: float | None = None
    tolerance: float | None = Field(None, gt=0, description="settling_time: the band, in SI")

    @model_validator(mode="after")
    def _tol(self) -> Metric:
        if self.metric == "settling_time" and self.tolerance is None:
            raise ValueError("a settling_time metric needs 'tolerance'")
        if self.before is not None and not self.before > self.after:
            raise ValueError(f"the window ends (before: {self.before:g}) before it starts "
                             f"(after: {self.after:g})")
        return self


class StudyModel(_Strict):
    name: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_-]*$", max_length=100)
    description: str = ""
    scenario: str
    set: dict[str, Scalar] | list[str] = Field(default_factory=dict)
    vary: dict[str, Input] = Field(default_factory=dict)
    sampling: Sampling = Field(default_factory=Sampling)
    seeds: int | list[int] | Seeds | None = None
    pair_seeds: bool = False
    metrics: list[Metric] = Field(default_factory=list)
    keep: list[str] = Field(default_factory=list)
    worst: int = Field(5, ge=0, le=100)

    @field_validator("metrics")
    @classmethod
    def _metric_names(cls, v: list[Metric]) -> list[Metric]:
        names = [m.name for m in v]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"metric names repeat ({', '.join(dup)}): each is one column")
        return v

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: Any) -> Any:
        if isinstance(v, int) and not 1 <= v <= MAX_CASES:
            raise ValueError(f"a seed count must be 1..{MAX_CASES}")
        if isinstance(v, list):
            if not v or any(s < 0 for s in v):
                raise ValueError("seeds must be a non-empty list of integers >= 0")
            if len(set(v)) != len(v):
                raise ValueError("seeds repeat")
        return v


@dataclass
class Case:
    """One run: the ``--set`` texts and the seed; ``inputs`` are the varied values (by input name)."""

    index: int
    overrides: list[str]
    seed: int | None
    inputs: dict[str, Scalar]
    sample: int | None = None  # row of the sampling design (Sobol analysis needs the order)
    key: str = ""

    def command(self, scenario: str) -> str:
        parts = ["seafmu", "run", scenario]
        for o in self.overrides:
            parts += ["--set", o]
        if self.seed is not None:
            parts += ["--seed", str(self.seed)]
        return shlex.join(parts)


@dataclass
class Study:
    name: str
    description: str
    source: Path
    scenario: str  # as written in the study (a shipped name or a path relative to the study file)
    scenario_file: Path
    model: StudyModel
    cases: list[Case]
    inputs: dict[str, Input]
    units: dict[str, str]  # input -> the unit its values are written in ("" if none)
    design: np.ndarray | None = None  # unit-cube design of the sampled inputs (saltelli: for SALib)
    sampled_names: list[str] = field(default_factory=list)
    # filled by validate_cases: each case's resolved scenario (up to KEEP_SCENARIOS cases) and the
    # first one validated, which stands for the base scenario's checks and variables (overrides set
    # parameters and events, never checks or units)
    scenarios: dict[int, Any] = field(default_factory=dict)
    base: Any = None

    def base_scenario(self) -> Any:
        """The base scenario as validated (loaded once here if the cases were not validated)."""
        if self.base is None:
            self.base = load_scenario(self.scenario_file)
        return self.base

    @property
    def scenario_arg(self) -> str:
        """The base scenario as ``seafmu run`` takes it from the current folder."""
        if not Path(self.scenario).suffix:  # a shipped name
            return self.scenario
        try:
            return str(self.scenario_file.resolve().relative_to(Path.cwd()))
        except ValueError:
            return str(self.scenario_file.resolve())


def _fail(path: Path, where: str, msg: str) -> StudyError:
    return StudyError(f"{path}: {where}: {msg}")


def _quantity(x: float | str, unit: str | None, path: Path, where: str) -> tuple[float, str]:
    """A bound or grid point as (number, unit): "0.2 m/s" -> (0.2, "m/s"); 5 -> (5.0, unit or "")."""
    if isinstance(x, int | float) and not isinstance(x, bool):
        return float(x), unit or ""
    if isinstance(x, str):
        q = split_quantity(x)
        if q is not None:
            number, u = q
            if unit and u != unit:
                raise _fail(path, where, f"'{x}' is in {u}, the input's unit is {unit}")
            return number, u
        if is_number(x):  # "1e2": YAML reads an exponent without a point as text
            return float(x), unit or ""
    raise _fail(path, where, f"expected a number or '<number> <unit>', got {x!r}")


def _same_unit(pairs: list[tuple[float, str]], path: Path, where: str) -> tuple[list[float], str]:
    """The values in one unit, the first one given (``[0.1 m/s, 0.4 kn]``: m/s); units that do not
    convert (or a bare number beside a quantity) are one line."""
    from seafmu.units import UnitError, convert

    units = list(dict.fromkeys(u for _, u in pairs if u))
    if units and any(not u for _, u in pairs):  # a bare number is SI in a scenario, here it would not be
        raise _fail(path, where, f"mixes bare numbers with units ({', '.join(units)}); give every value "
                    "its unit, or the input a unit:")
    if len(units) <= 1:
        return [x for x, _ in pairs], (units[0] if units else "")
    try:
        return [convert(x, u, units[0]) for x, u in pairs], units[0]
    except UnitError as exc:
        raise _fail(path, where, f"mixes units {', '.join(sorted(units))} ({exc})") from None


def _text(x: Scalar, unit: str) -> str:
    """A value as the ``--set`` text: floats by repr (exact round trip), with the unit if any."""
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, float):
        x = float(x)
        s = repr(x)
        return f"{s} {unit}" if unit else s
    if isinstance(x, int):
        return f"{x} {unit}" if unit else str(x)
    return str(x)


def _axis(name: str, inp: Input, path: Path) -> tuple[list[Scalar], str]:
    """A list or grid input's values (numbers in its unit, or any scalars) and that unit."""
    where = f"vary.{name}"
    if inp.values is not None:
        vals: list[Scalar] = list(inp.values)
        numeric = [(isinstance(v, int | float) and not isinstance(v, bool))
                   or (isinstance(v, str) and (is_number(v) or split_quantity(v) is not None)) for v in vals]
        unit = inp.unit or ""
        if all(numeric) and any(isinstance(v, str) for v in vals):
            nums, unit = _same_unit([_quantity(v, inp.unit, path, f"{where}.values") for v in vals],
                                    path, f"{where}.values")
            vals = list(nums)
        if len({(type(v) is bool, v) for v in vals}) < len(vals):  # the same case twice, counted twice
            raise _fail(path, f"{where}.values", "values repeat")
        return vals, unit
    g = inp.grid
    assert g is not None
    (a, ua), (b, ub) = (_quantity(g.start, inp.unit, path, f"{where}.grid.start"),
                        _quantity(g.stop, inp.unit, path, f"{where}.grid.stop"))
    (a, b), unit = _same_unit([(a, ua), (b, ub)], path, f"{where}.grid")
    if not (math.isfinite(a) and math.isfinite(b)):
        raise _fail(path, f"{where}.grid", f"start and stop must be finite (got {a:g}, {b:g})")
    pts = [float(v) for v in np.linspace(a, b, g.num)]
    if len(set(pts)) < len(pts):
        raise _fail(path, f"{where}.grid", f"{g.num} points from {a:g} to {b:g} repeat values")
    return pts, unit


def _ppf(name: str, inp: Input, u: np.ndarray, path: Path) -> tuple[list[Scalar], str]:
    """Unit-cube coordinates -> the input's values (inverse CDF), and their unit."""
    from scipy import stats

    where = f"vary.{name}"
    if inp.uniform is not None:
        (lo, hi), unit = _same_unit([_quantity(v, inp.unit, path, f"{where}.uniform") for v in inp.uniform],
                                    path, f"{where}.uniform")
        if not hi > lo:
            raise _fail(path, f"{where}.uniform", f"the upper bound {hi:g} must be above the lower {lo:g}")
        return [float(x) for x in lo + u * (hi - lo)], unit
    if inp.normal is not None:
        n = inp.normal
        pairs = [_quantity(n.mean, inp.unit, path, f"{where}.normal.mean"),
                 _quantity(n.std, inp.unit, path, f"{where}.normal.std")]
        for b in (n.min, n.max):
            if b is not None:
                pairs.append(_quantity(b, inp.unit, path, f"{where}.normal"))
        nums, unit = _same_unit(pairs, path, f"{where}.normal")
        mean, std = nums[0], nums[1]
        if not std > 0:
            raise _fail(path, f"{where}.normal.std", "must be > 0")
        lo = (_quantity(n.min, unit, path, where)[0] - mean) / std if n.min is not None else -np.inf
        hi = (_quantity(n.max, unit, path, where)[0] - mean) / std if n.max is not None else np.inf
        if not hi > lo:
            raise _fail(path, f"{where}.normal", "max must be above min")
        uu = np.clip(u, 1e-12, 1 - 1e-12)
        return [float(x) for x in stats.truncnorm.ppf(uu, lo, hi, loc=mean, scale=std)], unit
    if inp.lognormal is not None:
        med, unit = _quantity(inp.lognormal.median, inp.unit, path, f"{where}.lognormal.median")
        if not med > 0:
            raise _fail(path, f"{where}.lognormal.median", "must be > 0")
        uu = np.clip(u, 1e-12, 1 - 1e-12)
        return [float(x) for x in stats.lognorm.ppf(uu, inp.lognormal.sigma, scale=med)], unit
    options = inp.choice or []
    idx = np.minimum((u * len(options)).astype(int), len(options) - 1)
    return [options[i] for i in idx], inp.unit or ""


def _design(method: str, d: int, n: int, seed: int) -> np.ndarray:
    """n points in [0, 1)^d: Latin hypercube or scrambled Sobol (scipy.stats.qmc), Saltelli (SALib)."""
    from scipy.stats import qmc

    if method == "lhs":
        return qmc.LatinHypercube(d=d, rng=np.random.default_rng(seed)).random(n)
    if method == "sobol":
        return qmc.Sobol(d=d, scramble=True, rng=np.random.default_rng(seed)).random(n)
    if method == "saltelli":
        from SALib.sample import sobol as salib_sobol

        problem = {"num_vars": d, "names": [f"x{i}" for i in range(d)], "bounds": [[0.0, 1.0]] * d}
        return np.asarray(salib_sobol.sample(problem, n, calc_second_order=False, seed=seed))
    return np.random.default_rng(seed).random((n, d))


def _seed_list(model: StudyModel) -> list[int | None]:
    s = model.seeds
    if s is None:
        return [None]
    if isinstance(s, int):
        return list(range(1, s + 1))
    if isinstance(s, list):
        return list(s)
    return list(range(s.start, s.start + s.count))


def _fixed_overrides(model: StudyModel) -> list[str]:
    if isinstance(model.set, list):
        return list(model.set)
    return [f"{k}={_text(v, '')}" for k, v in model.set.items()]


def case_key(scenario_text: bytes, overrides: list[str], seed: int | None, extra: Any) -> str:
    """What makes a finished case the same case on a rerun: the base scenario's bytes, the
    overrides, the seed, and what the worker computes (metrics, kept signals)."""
    h = hashlib.sha256(scenario_text)
    h.update(json.dumps([overrides, seed, extra], sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


def load_study(path: str | Path, validate: bool = True) -> Study:
    """Read a study file, make its cases and (``validate``) check each one as a scenario."""
    # Long because it is the study's checks in file order, each with its one-line error, then the
    # case design (grids crossed with samples crossed or paired with seeds) they lead to.
    path = Path(path)
    doc = read_mapping(path, "study", StudyError)
    try:
        model = StudyModel.model_validate(doc)
    except ValidationError as exc:
        raise StudyError(f"{path}: {validation_message(exc)}") from None

    base = Path(model.scenario)
    if base.suffix in (".yaml", ".yml") and not base.is_absolute():
        base = (path.parent / base).resolve()
    try:
        scenario_file = scenario_path(base if base.suffix else model.scenario)
    except ScenarioError as exc:
        raise _fail(path, "scenario", str(exc)) from None
    scenario_ref = str(base) if base.suffix else model.scenario

    for k, text in enumerate(_fixed_overrides(model)):
        try:
            parse_override(text)
        except ScenarioError as exc:
            raise _fail(path, f"set[{k}]", str(exc)) from None
    for name, inp in model.vary.items():
        if inp.set is None and not _TARGET.match(name):
            raise _fail(path, f"vary.{name}", "an input is 'instance.variable' (or "
                        "'instance.variable@TIME'), or a name with 'set:' templates")
        if name in ROW_COLUMNS or name.startswith(ROW_PREFIXES):
            raise _fail(path, f"vary.{name}", f"'{name}' names a column of every case's row; call the input "
                        "something else")
        if inp.set is not None:
            for tmpl in inp.set:
                if "{value}" not in tmpl and "{value}" not in str(inp.set[tmpl]):
                    raise _fail(path, f"vary.{name}.set", f"'{tmpl}' does not use {{value}}")

    grid_names = [n for n, i in model.vary.items() if not i.sampled]
    sampled_names = [n for n, i in model.vary.items() if i.sampled]
    axes: dict[str, list[Scalar]] = {}
    units: dict[str, str] = {}
    for n in grid_names:
        axes[n], units[n] = _axis(n, model.vary[n], path)
    seeds = _seed_list(model)
    n_samples = 1
    if sampled_names:
        n_pts = model.sampling.samples
        if model.sampling.method == "sobol" and n_pts & (n_pts - 1):
            raise _fail(path, "sampling.samples", f"Sobol sequences need a power of 2 (got {n_pts})")
        if model.sampling.method == "saltelli" and n_pts & (n_pts - 1):
            raise _fail(path, "sampling.samples", f"the Saltelli design needs a power of 2 (got {n_pts})")
        n_samples = n_pts * (len(sampled_names) + 2) if model.sampling.method == "saltelli" else n_pts
    if model.pair_seeds:
        if model.seeds is None:
            raise _fail(path, "pair_seeds", "needs seeds")
        if len(seeds) != n_samples:
            raise _fail(path, "pair_seeds", f"{len(seeds)} seeds for {n_samples} samples; pairing needs "
                        "as many of each")
    # counted before anything is made: 100000 samples crossed with 100000 seeds would fill the memory
    n_grid = math.prod(len(v) for v in axes.values()) if axes else 1
    total = n_grid * n_samples * (1 if model.pair_seeds else len(seeds))
    if total > MAX_CASES:
        raise _fail(path, "vary", f"{total} cases; a study is limited to {MAX_CASES}")
    design = None
    samples: list[dict[str, Scalar]] = [{}]
    if sampled_names:
        design = _design(model.sampling.method, len(sampled_names), model.sampling.samples,
                         model.sampling.seed)
        cols = {}
        for j, n in enumerate(sampled_names):
            cols[n], units[n] = _ppf(n, model.vary[n], design[:, j], path)
        samples = [{n: cols[n][i] for n in sampled_names} for i in range(len(design))]
    if model.pair_seeds:
        combos = [(i, s, seeds[i]) for i, s in enumerate(samples)]
    else:
        combos = [(i, s, seed) for i, s in enumerate(samples) for seed in seeds]

    fixed = _fixed_overrides(model)
    scenario_text = scenario_file.read_bytes()
    extra = [m.model_dump() for m in model.metrics] + [model.keep]
    cases: list[Case] = []
    for point in itertools.product(*axes.values()) if axes else [()]:
        grid_values = dict(zip(axes, point, strict=True))
        for sample_i, sample, seed in combos:
            values = {**grid_values, **sample}
            values = {n: values[n] for n in model.vary}  # study order
            overrides = list(fixed)
            for n, v in values.items():
                inp = model.vary[n]
                vt = _text(v, units[n])
                if inp.set is None:
                    overrides.append(f"{n}={vt}")
                else:
                    for tmpl, tv in inp.set.items():
                        target = tmpl.replace("{value}", str(v))
                        tv_text = str(tv).replace("{value}", vt) if isinstance(tv, str) else _text(tv, "")
                        overrides.append(f"{target}={tv_text}")
            targets = [o.partition("=")[0].strip() for o in overrides]
            if len(set(targets)) < len(targets):  # the last would win, and the row show the other value
                dup = next(t for t in targets if targets.count(t) > 1)
                raise _fail(path, "vary", f"case {len(cases)}: {dup} is set more than once (by two inputs, "
                            "or by 'set:' and an input); each variable may be set by one only")
            c = Case(len(cases), overrides, seed, values, sample_i if sampled_names else None)
            c.key = case_key(scenario_text, overrides, seed, extra)
            cases.append(c)
    study = Study(model.name, model.description, path, scenario_ref, scenario_file, model, cases,
                  dict(model.vary), units, design, sampled_names)
    if validate:
        validate_cases(study)
    return study


def case_overrides(case: Case) -> list[Override]:
    return [parse_override(o) for o in case.overrides]


def validate_cases(study: Study, cases: list[Case] | None = None) -> None:
    """Every case (or ``cases``) as a scenario (``load_scenario``, the ``seafmu run`` path), the kept
    signals and metric signals among its recorded outputs; the first problem is one line naming the
    case. The resolved scenarios are kept for the workers when the study is small enough."""
    path = study.source
    keep = len(study.cases) <= KEEP_SCENARIOS
    for c in study.cases if cases is None else cases:
        try:
            sc = load_scenario(study.scenario_file, case_overrides(c), c.seed)
        except ScenarioError as exc:
            raise StudyError(f"{path}: case {c.index} ({', '.join(c.overrides) or 'base'}"
                             f"{'' if c.seed is None else f', seed {c.seed}'}): {exc}") from None
        if keep:
            study.scenarios[c.index] = sc
        if study.base is None:
            study.base = sc
            recorded = {f"{i}.{v}" for i, v in sc.outputs}
            for k, sig in enumerate(study.model.keep):
                if sig not in recorded:
                    raise _fail(path, f"keep[{k}]", f"'{sig}' is not a recorded signal of {sc.name}")
            for k, m in enumerate(study.model.metrics):
                for attr in ("signal", "minus"):
                    sig = getattr(m, attr)
                    if sig is not None and sig not in recorded:
                        raise _fail(path, f"metrics[{k}].{attr}",
                                    f"'{sig}' is not a recorded signal of {sc.name}")
                if m.after >= sc.duration:
                    raise _fail(path, f"metrics[{k}].after",
                                f"{m.after:g} s is not before the end of the run")
