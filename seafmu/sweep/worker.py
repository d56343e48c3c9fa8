"""One case of a study, in a worker process: the same scenario loading and master as ``seafmu run``.

A worker process looks its FMUs up once for all its cases (``seafmu.master``; unpacked once per FMU
version, ``seafmu.fmu_cache``); each case instantiates and frees its own FMU instances. A case comes
with its scenario resolved by the study's validation when the study is small
(``study.KEEP_SCENARIOS``), so it is not validated twice; otherwise it is loaded here exactly as
``seafmu run`` loads it. Whatever goes wrong in a case comes back as its row (status ``error`` and
the one-line reason), never as an exception that would reach the study: a failing case never stops
the others.
"""

from __future__ import annotations

import math
import os
import socket
import time
from typing import Any

import numpy as np

CHECK = "check: "  # column prefixes in cases.parquet
PASS = "pass: "
METRIC = "metric: "


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def metric_value(m: dict[str, Any], time_s: np.ndarray, signals: dict[str, np.ndarray]) -> float:
    """A study metric (a check's metric without a bound, or ``settling_time``: the time from the
    window's start (``after``) until the signal enters the tolerance band for good; NaN if it never
    does) over its window."""
    y = np.asarray(signals[m["signal"]], dtype=float)
    if m.get("minus"):
        y = y - signals[m["minus"]]
    if m.get("angle"):
        y = _wrap(y)
    mask = time_s >= m["after"] - 1e-9 * max(1.0, abs(m["after"]))
    if m.get("before") is not None:
        mask &= time_s <= m["before"] + 1e-9 * max(1.0, abs(m["before"]))
    w, t = y[mask], time_s[mask]
    if w.size == 0 or not np.all(np.isfinite(w)):
        return math.nan
    kind = m["metric"]
    if kind == "settling_time":
        outside = np.flatnonzero(np.abs(w) > m["tolerance"])
        if outside.size == 0:
            return 0.0
        last = outside[-1]
        return float(t[last + 1] - m["after"]) if last + 1 < t.size else math.nan  # never settled: NaN
    return float({"max_abs": lambda: np.max(np.abs(w)), "final_abs": lambda: abs(w[-1]),
                  "rms": lambda: np.sqrt(np.mean(w**2)), "max": lambda: np.max(w),
                  "min": lambda: np.min(w), "mean": lambda: np.mean(w)}[kind]())


def run_case(task: dict[str, Any]) -> dict[str, Any]:
    """Run one case; returns its row (inputs, seed, checks, metrics, wall time, status, error) and,
    under ``"_series"``, the kept signals (the caller writes them)."""
    from seafmu.components.vessel_spec import VesselFileError
    from seafmu.master import SimulationError, run
    from seafmu.results import evaluate_checks
    from seafmu.scenario import ScenarioError, load_scenario, parse_override

    started, t0, c0 = time.time(), time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"case": task["case"], "key": task["key"], "seed": task["seed"],
                           **task["inputs"], "status": "error", "error": "",
                           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    result = None
    try:
        sc = task.get("resolved")  # validated by the study already (a small study), else validated here
        if sc is None:
            sc = load_scenario(task["scenario"], [parse_override(o) for o in task["overrides"]], task["seed"])
        t_run = time.perf_counter()
        try:
            result = run(sc, mode="fmu", progress=False)
        except SimulationError as exc:
            result = exc.partial
            row["error"] = " ".join(str(exc).split())
        row["run_time_s"] = time.perf_counter() - t_run  # the run itself: FMUs instantiated, loop, freed
    except (ScenarioError, SimulationError, VesselFileError, OSError, ValueError) as exc:
        row["error"] = " ".join(str(exc).split())
    except Exception as exc:  # anything else is still this case's failure, not the study's
        row["error"] = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    checks_ok = False
    if result is not None:
        checks = evaluate_checks(result)
        for c in checks:
            row[CHECK + c.name] = c.value
            row[PASS + c.name] = bool(c.passed)
        checks_ok = all(c.passed for c in checks)
        for m in task["metrics"]:
            try:
                row[METRIC + m["name"]] = metric_value(m, result.time, result.signals)
            except (KeyError, ValueError) as exc:
                row[METRIC + m["name"]] = math.nan
                row["error"] = row["error"] or f"metric {m['name']}: {exc}"
        row["simulated_s"] = float(result.t_end or 0.0)
        row["loop_time_s"] = float(result.wall_time)  # the master loop alone
        row["realtime_factor"] = float(result.realtime_factor)
        if task["keep"]:
            row["_series"] = {"time": np.asarray(result.time),
                              **{k: np.asarray(result.signals[k]) for k in task["keep"]}}
    if not row["error"]:
        row["status"] = "pass" if checks_ok else "fail"
    row["wall_time_s"] = time.perf_counter() - t0
    row["started"], row["finished"] = started, started + row["wall_time_s"]  # Unix time: the study's timeline
    row["cpu_time_s"] = time.process_time() - c0  # this process's CPU: what the case costs on a shared host
    return row
