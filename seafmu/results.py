"""Results of a run: the CSV of recorded signals, the acceptance checks, and the JSON summary.

``CsvStream`` writes results.csv while the run goes (header first, then chunks of rows, each
flushed); ``write_csv`` writes the same format at once. The summary is written atomically.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from seafmu.master import RunResult
from seafmu.outdir import atomic_write_text
from seafmu.scenario import Check, time_slack

CSV_FORMAT = "%.10g"


@dataclass
class CheckResult:
    name: str
    metric: str
    value: float
    bound: str
    passed: bool
    note: str = ""  # why a check could not be evaluated (no samples, run stopped early, not finite)


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


def check_name(c: Check) -> str:
    """A check's name: its own, else what it measures and where."""
    label = c.signal if c.minus is None else f"{c.signal} - {c.minus}"
    window = f"t >= {c.after:g} s" + (f", t <= {c.before:g} s" if c.before is not None else "")
    return c.name or f"{c.metric}({label}) over {window}"


def evaluate_checks(result: RunResult) -> list[CheckResult]:
    """Each check over its window; one that cannot be evaluated FAILs with a note saying why."""
    out = []
    t = result.time
    t_end = result.scenario.duration if result.t_end is None else result.t_end
    for c in result.scenario.checks:
        y = np.array(result.signals[c.signal], dtype=float)
        if c.minus is not None:
            y = y - result.signals[c.minus]
        if c.angle:
            y = _wrap(y)
        mask = t >= c.after - time_slack(c.after)
        if c.before is not None:
            mask &= t <= c.before + time_slack(c.before)
        w = y[mask]
        window_end = result.scenario.duration if c.before is None else min(c.before, result.scenario.duration)
        note = ""
        if not result.complete and window_end > t_end + time_slack(t_end):
            note = (f"not evaluated: the run stopped at t = {t_end:g} s, before the end of this window "
                    f"({window_end:g} s)")
        elif w.size == 0:
            note = "not evaluated: no samples in the window"
        elif not np.all(np.isfinite(w)):
            note = f"not evaluated: the signal is not finite at t = {t[mask][~np.isfinite(w)][0]:g} s"
        value = math.nan if note else _METRICS[c.metric](w)
        ok = math.isfinite(value)
        bounds = []
        if c.max is not None:
            ok = ok and value <= c.max
            bounds.append(f"<= {c.max:g}")
        if c.min is not None:
            ok = ok and value >= c.min
            bounds.append(f">= {c.min:g}")
        name = check_name(c)
        out.append(CheckResult(name, c.metric, value, " and ".join(bounds), ok, note))
    return out


def write_csv(result: RunResult, path: Path) -> None:
    names = list(result.signals)
    data = np.column_stack([result.time, *[result.signals[n] for n in names]])
    np.savetxt(path, data, delimiter=",", header=",".join(["time", *names]), comments="", fmt=CSV_FORMAT)


def format_rows(rows: np.ndarray) -> str:
    """Rows as ``np.savetxt(..., delimiter=",", fmt=CSV_FORMAT)`` writes them, character for
    character (the same ``%`` formatting of each float), in 60 % of its time: savetxt formats a
    tuple of NumPy scalars per row, this maps the format over Python floats."""
    x = np.asarray(rows, dtype=float)
    x = x.reshape(-1, 1) if x.ndim == 1 else x  # one value per line, as savetxt
    fmt = CSV_FORMAT.__mod__
    text = "\n".join([",".join(map(fmt, row)) for row in x.tolist()])
    return text + "\n" if text else ""


class CsvStream:
    """results.csv written while the run goes: the master's ``sink``. Each chunk is flushed to the
    OS at once, so whatever ends the process keeps every row written before; ``close`` also
    syncs the file to disk. Same format as ``write_csv``."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._fh: IO[str] | None = None
        self.rows = 0

    def begin(self, columns: list[str]) -> None:
        self._fh = open(self.path, "w", encoding="utf-8", newline="")
        self._fh.write(",".join(columns) + "\n")
        self._fh.flush()

    def write(self, rows: np.ndarray) -> None:
        if self._fh is None:
            raise RuntimeError("CsvStream.write before begin")
        # one write per chunk: a killed writer leaves whole chunks, not half rows
        self._fh.write(format_rows(rows))
        self._fh.flush()
        self.rows += len(rows)

    def close(self) -> None:
        if self._fh is not None:
            try:
                self._fh.flush()
                os.fsync(self._fh.fileno())
            finally:
                self._fh.close()
                self._fh = None


def write_parquet(result: RunResult, path: Path) -> None:
    """The recorded signals as Parquet (pandas + pyarrow; time first, one column per signal),
    written atomically: what a script or a study opens without parsing text."""
    import pandas as pd

    from seafmu.outdir import atomic_path

    frame = pd.DataFrame({"time": result.time, **result.signals})
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, engine="pyarrow", index=False)


def summary(result: RunResult, checks: list[CheckResult]) -> dict[str, Any]:
    sc = result.scenario
    given = {"overrides": list(sc.overrides)} if sc.overrides else {}
    if sc.seed is not None:
        given["seed"] = sc.seed
    return {
        **given,
        "scenario": sc.name,
        "source": str(sc.source),
        "vessel": sc.vessel,
        "mode": result.mode,
        "duration_s": sc.duration,
        "step_s": sc.step,
        "simulated_s": result.t_end,
        "samples": len(result.time),
        "complete": result.complete,
        "interrupted": result.interrupted or None,
        "error": result.error or None,
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
    atomic_write_text(path, json.dumps(_json_safe(data), indent=2, allow_nan=False) + "\n")
