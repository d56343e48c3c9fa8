"""Property tests (hypothesis) over scenario numbers and fields: whatever a scenario file holds,
validation gives a scenario within every bound or one line ``seafmu: error: <file>: <field>: ...``
— never a traceback, never a run that cannot be allocated. In-process validation only (fast)."""

from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from seafmu.cli import main
from seafmu.master import RunResult
from seafmu.results import evaluate_checks
from seafmu.scenario import (
    MAX_DURATION,
    MAX_RESULT_BYTES,
    MAX_STEPS,
    MIN_STEP,
    Scenario,
    ScenarioError,
    load_scenario,
)
from seafmu.units import UnitError, to_si
from seafmu.yamlfile import read_mapping

# modest by default (the suite stays fast); SEAFMU_HYPOTHESIS_EXAMPLES=2000 for a deeper search
EXAMPLES = int(os.environ.get("SEAFMU_HYPOTHESIS_EXAMPLES", "60"))
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])

BASE: dict[str, Any] = {
    "name": "t",
    "vessel": "minerva2",
    "duration": 10.0,
    "step": 0.05,
    "record_interval": 0.1,
    "fmus": {
        "plant": {"kind": "plant", "parameters": {"current_speed": "0.1 m/s", "seed": 1}},
        "observer": {"kind": "observer", "step_multiple": 1},
        "controller": {"kind": "controller"},
        "allocator": {"kind": "allocator"},
    },
    "events": [{"time": 5, "set": "controller.north_ref", "value": "2 m"}],
    "checks": [{"signal": "plant.north", "metric": "max_abs", "after": 2, "before": 8, "max": 10}],
}

SPECIAL = [0, -0.0, 1, -1, 5e-324, 1e-300, 1e-12, 1e-7, 1e-6, 0.05, 0.1, 0.3, 9.99, 10, 10.0000001, 1e7,
           1e7 + 1, 2**31, 2**63, 1e308, 10**400, math.inf, -math.inf, math.nan]
numbers = st.one_of(
    st.sampled_from(SPECIAL),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=1e-8, max_value=1e8),
    st.integers(min_value=-(10**20), max_value=10**20),
)
UNITS = ["m", "s", "ms", "h", "deg", "m/s", "kn", "N", "rpm", "furlong", ""]
quantities = st.builds(lambda x, u: f"{x} {u}".strip(), numbers, st.sampled_from(UNITS))
values = st.one_of(
    numbers, quantities, st.booleans(), st.none(), st.text(max_size=12),
    st.lists(numbers, max_size=3), st.dictionaries(st.text(max_size=4), numbers, max_size=2),
)
PATHS = [
    "duration", "step", "record_interval", "realtime", "name", "vessel",
    "fmus/observer/step_multiple", "fmus/plant/step_multiple", "fmus/plant/parameters/current_speed",
    "fmus/plant/parameters/seed", "fmus/plant/parameters/noise_scale",
    "events/0/time", "events/0/value", "events/0/set",
    "checks/0/after", "checks/0/before", "checks/0/max", "checks/0/min", "checks/0/metric",
    "outputs", "connections", "events", "checks", "fmus",
]
mutations = st.lists(st.tuples(st.sampled_from(PATHS), values), min_size=1, max_size=4)


def _apply(doc: dict, path: str, value: Any) -> None:
    keys = path.split("/")
    node: Any = doc
    for k in keys[:-1]:  # an earlier mutation may have replaced a parent: then nothing to mutate
        if isinstance(node, list) and k.isdigit() and int(k) < len(node):
            node = node[int(k)]
        elif isinstance(node, dict) and isinstance(node.get(k), dict | list):
            node = node[k]
        else:
            return
    last = keys[-1]
    if isinstance(node, list) and last.isdigit() and int(last) < len(node):
        node[int(last)] = value
    elif isinstance(node, dict):
        node[last] = value


def _validate(doc: Any) -> tuple[Scenario | None, str]:
    """``seafmu check`` in process: (the scenario or None, the one stderr line or "")."""
    with tempfile.TemporaryDirectory(prefix="seafmu_prop_") as folder:
        path = Path(folder) / "s.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
        err, out = io.StringIO(), io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(["check", str(path)])
        lines = err.getvalue().strip().splitlines()
        if code == 0:
            assert not lines and out.getvalue().startswith(f"{path}: OK"), (out.getvalue(), err.getvalue())
            event("valid")
            return load_scenario(path), ""
    assert code == 2, (code, err.getvalue())
    assert len(lines) == 1, err.getvalue()
    event(f"error: {lines[0].split(': ', 3)[-1].split(':')[0][:40]}")
    assert lines[0].startswith(f"seafmu: error: {path}: "), lines[0]
    assert "Traceback" not in lines[0]
    return None, lines[0]


def _within_bounds(sc: Scenario) -> None:
    assert MIN_STEP <= sc.step <= sc.duration <= MAX_DURATION
    assert 1 <= sc.n_steps <= MAX_STEPS and sc.result_bytes <= MAX_RESULT_BYTES
    assert all(1 <= i.step_multiple <= sc.n_steps and sc.n_steps % i.step_multiple == 0 for i in sc.instances)
    assert sc.n_steps % sc.record_every == 0
    for t, *_ in sc.events:
        assert 0 <= t < sc.duration
    # every check window holds a recorded sample, on the master's own time axis (k h per row)
    if sc.n_samples <= 200_000:
        t = np.arange(sc.n_samples) * sc.record_every * sc.step
        signals = {f"{i}.{v}": np.zeros(len(t)) for i, v in sc.outputs}
        r = RunResult(sc, t, signals, 1.0, {}, {}, "fmu")
        assert [c.note for c in evaluate_checks(r)] == [""] * len(sc.checks)


@SETTINGS
@given(mutations)
def test_mutated_scenarios_validate_or_fail_in_one_line(changes: list[tuple[str, Any]]) -> None:
    doc = copy.deepcopy(BASE)
    for path, value in changes:
        _apply(doc, path, value)
    sc, _ = _validate(doc)
    if sc is not None:
        _within_bounds(sc)


@st.composite
def grid(draw: st.DrawFn) -> dict[str, Any]:
    """Mostly consistent grids (duration = n steps, record interval and step multiple dividing n,
    windows on or between samples), each field replaced by a hostile number one time in six."""
    def hostile() -> bool:
        return draw(st.integers(0, 5)) == 0

    step = draw(st.one_of(st.sampled_from([1e-12, 1e-7, 1e-6, 0.01, 0.05, 0.1, 1.0, 10.0, 1e308]),
                          st.floats(1e-7, 100.0)))
    n = draw(st.sampled_from([MAX_STEPS, MAX_STEPS + 1, 10**12]) if hostile() else st.integers(1, 100_000))
    duration = draw(numbers) if hostile() else step * n
    every = draw(st.sampled_from([n + 1, 10**9])) if hostile() else draw(st.integers(1, 20))
    if n % every and not hostile():
        every = 1
    record = None if draw(st.booleans()) else (draw(numbers) if hostile() else step * every)
    if record is None:
        every = 1
    multiple = draw(st.sampled_from([n + 1, 10**9, 10**30])) if hostile() else draw(
        st.sampled_from([m for m in (1, 2, 3, 5, n) if n % m == 0]))
    dt = step * every
    if hostile():
        after: Any = draw(numbers)
    elif draw(st.booleans()):
        after = draw(st.integers(-2, n // every + 2)) * dt  # on a sample (or outside the run)
    else:
        after = (draw(st.integers(0, n // every)) + 0.5) * dt  # between two samples
    if hostile() or not isinstance(after, float):
        before = draw(numbers)
    else:
        span = draw(st.sampled_from([None, 0.1, 0.5, 1.0, 1.5, 3.0]))
        before = None if span is None else after + span * dt
    return {"duration": duration, "step": step, "record_interval": record, "multiple": multiple,
            "after": after, "before": before}


@SETTINGS
@given(grid())
def test_time_grids_are_bounded_and_every_check_window_has_samples(g: dict[str, Any]) -> None:
    """Duration, step, record interval, step multiple and a check window drawn together (the grid
    interactions: whole numbers of steps, windows between samples): valid ones respect every bound,
    and evaluating their checks on the master's time axis never meets an empty window."""
    doc = copy.deepcopy(BASE)
    doc.update(duration=g["duration"], step=g["step"])
    doc["events"] = []
    if g["record_interval"] is None:
        del doc["record_interval"]
    else:
        doc["record_interval"] = g["record_interval"]
    doc["fmus"]["observer"]["step_multiple"] = g["multiple"]
    doc["checks"][0].update(after=g["after"], before=g["before"])
    doc["outputs"] = ["plant.north"]
    sc, _ = _validate(doc)
    if sc is None:
        return
    _within_bounds(sc)


@SETTINGS
@given(st.one_of(numbers, quantities, st.text(max_size=30), st.booleans(), st.none()),
       st.sampled_from(["m", "rad", "m/s", "s", "1", ""]))
def test_to_si_returns_a_float_or_a_unit_error(value: Any, unit: str) -> None:
    try:
        x = to_si(value, unit)
    except UnitError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 400
    else:
        assert isinstance(x, float)


@settings(max_examples=EXAMPLES * 3, deadline=None)
@given(st.one_of(st.binary(max_size=300),
                 st.text(alphabet="ab:-[]{}&*!|>?,'\" \n\t#%@`0123456789.e", max_size=300).map(str.encode)))
def test_any_bytes_read_as_a_mapping_or_one_line(data: bytes) -> None:
    with tempfile.NamedTemporaryFile(suffix=".yaml", delete=False) as fh:
        fh.write(data)
    path = Path(fh.name)
    try:
        doc = read_mapping(path, "scenario", ScenarioError)
    except ScenarioError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(path))
    else:
        assert isinstance(doc, dict)
    finally:
        path.unlink()
