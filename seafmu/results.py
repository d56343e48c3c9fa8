"""Results of a run: the CSV of recorded signals, the acceptance checks, and the JSON summary."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.master import RunResult


@dataclass
class CheckResult:
    name: str
    metric: str
    value: float
    bound: str
    passed: bool


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


_METRICS = {
    "max_abs": lambda w: float(np.max(np.abs(w))),
    "final_abs": lambda w: float(abs(w[-1])),
    "rms": lambda w: float(np.sqrt(np.mean(w**2))),
    "max": lambda w: float(np.max(w)),
    "min": lambda w: float(np.min(w)),
    "mean": lambda w: float(np.mean(w)),
}


def evaluate_checks(result: RunResult) -> list[CheckResult]:
    out = []
    t = result.time
    for c in result.scenario.checks:
        y = np.array(result.signals[c.signal], dtype=float)
        label = c.signal
        if c.minus is not None:
            y = y - result.signals[c.minus]
            label = f"{c.signal} - {c.minus}"
        if c.angle:
            y = _wrap(y)
        mask = t >= c.after - 1e-9
        if c.before is not None:
            mask &= t <= c.before + 1e-9
        w = y[mask]
        if w.size == 0 or not np.all(np.isfinite(w)):
            value = math.nan
        else:
            value = _METRICS[c.metric](w)
        ok = math.isfinite(value)
        bounds = []
        if c.max is not None:
            ok = ok and value <= c.max
            bounds.append(f"<= {c.max:g}")
        if c.min is not None:
            ok = ok and value >= c.min
            bounds.append(f">= {c.min:g}")
        window = f"t >= {c.after:g} s" + (f", t <= {c.before:g} s" if c.before is not None else "")
        name = c.name or f"{c.metric}({label}) over {window}"
        out.append(CheckResult(name, c.metric, value, " and ".join(bounds), ok))
    return out


def write_csv(result: RunResult, path: Path) -> None:
    names = list(result.signals)
    data = np.column_stack([result.time, *[result.signals[n] for n in names]])
    np.savetxt(path, data, delimiter=",", header=",".join(["time", *names]), comments="", fmt="%.10g")


def summary(result: RunResult, checks: list[CheckResult]) -> dict[str, Any]:
    sc = result.scenario
    return {
        "scenario": sc.name,
        "source": str(sc.source),
        "vessel": sc.vessel,
        "mode": result.mode,
        "duration_s": sc.duration,
        "step_s": sc.step,
        "wall_time_s": round(result.wall_time, 4),
        "realtime_factor": round(result.realtime_factor, 1),
        "us_per_step": {k: round(v, 1) for k, v in result.us_per_step().items()},
        "steps": result.steps,
        "checks": [asdict(c) for c in checks],
        "checks_passed": all(c.passed for c in checks),
        "fmu_messages": result.log,
        "pacing": result.pacing,
    }


def _json_safe(x: Any) -> Any:
    """JSON has no NaN: a check on missing data is written as null, not as invalid JSON."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    return x


def write_summary(data: dict[str, Any], path: Path) -> None:
    path.write_text(json.dumps(_json_safe(data), indent=2, allow_nan=False) + "\n")
