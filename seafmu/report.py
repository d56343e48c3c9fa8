"""The Markdown report of a run and its figures (PNG, drawn by ``seafmu.plots``): trajectory,
states vs references, thruster use, allocation error.

Every file is written atomically (a temporary name, then ``os.replace``), the report last: a
report.md that is not the placeholder means every file it names is complete. The placeholder,
written when the run starts, says the run is going — and, if it is still there after the process
ended, that the run was killed before it could write its report.
"""

from __future__ import annotations

import datetime
import os
from pathlib import Path
from typing import Any

import numpy as np

from seafmu import plots
from seafmu.master import RunResult
from seafmu.outdir import atomic_write_text
from seafmu.results import CheckResult

PLACEHOLDER_MARK = "<!-- seafmu: run in progress -->"


def series(result: RunResult) -> plots.Series:
    """What the figures read of a run."""
    return plots.Series(result.scenario.name, result.time, result.signals)


# The figures one by one (seafmu.plots draws them; matplotlib is imported when one is drawn).
def plot_trajectory(result: RunResult, path: Path) -> bool:
    return plots.trajectory(series(result), path)


def plot_states(result: RunResult, path: Path) -> bool:
    return plots.states(series(result), path)


def plot_thrusters(result: RunResult, path: Path) -> bool:
    return plots.thrusters(series(result), path)


def plot_allocation(result: RunResult, path: Path) -> bool:
    return plots.allocation(series(result), path)


def allocation_table(result: RunResult) -> list[str]:
    """Per allocator: saturation onset, worst error, the thesis's indicator and energy."""
    insts = sorted({k.split(".", 1)[0] for k in result.signals if k.endswith(".alloc_error")})
    if not insts:
        return []
    rows = [f"| allocator | first time with error > {plots.EXACT:g} [s] | max ‖Bu − τ‖ | "
            "Σ negative front thrust (indicator) | mean Σu² |", "|---|---|---|---|---|"]
    t = result.time
    for i in insts:
        err = result.signals[f"{i}.alloc_error"]
        over = np.flatnonzero(err > plots.EXACT)
        onset = f"{t[over[0]]:g}" if over.size else "never"
        ind = result.signals.get(f"{i}.front_negative_thrust")
        en = result.signals.get(f"{i}.thrust_energy")
        rows.append(f"| {i} | {onset} | {np.nanmax(err):.4g} | "
                    f"{'' if ind is None else f'{np.nansum(ind):.4g}'} | "
                    f"{'' if en is None else f'{np.nanmean(en):.4g}'} |")
    return rows


def write_placeholder_report(name: str, out: Path) -> Path:
    """report.md while the run goes; replaced by the real report at the end, whatever ends it short
    of SIGKILL, a power loss or a crash of the interpreter — which this text then explains."""
    now = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    text = "\n".join([
        PLACEHOLDER_MARK, f"# {name}: run in progress", "",
        f"Started {now} by process {os.getpid()}. This file is replaced by the report when the run ends, "
        "also when it is interrupted (SIGINT, SIGTERM, SIGHUP) or fails.", "",
        "If you read this after that process ended, it was killed (SIGKILL, power loss, a crash) before it "
        "could write its report: `results.csv` holds the samples up to its last flush (at most about "
        "1 s or 1000 rows before the end).", ""])
    path = out / "report.md"
    atomic_write_text(path, text)
    return path


def write_failure_report(name: str, out: Path, error: str) -> Path:
    """report.md of a run that failed before its first step (nothing recorded)."""
    path = out / "report.md"
    atomic_write_text(path, f"# {name}\n\nThe run failed before its first step: {error}\n")
    return path


def _stop_line(result: RunResult) -> str:
    sc = result.scenario
    if result.interrupted:
        return f"interrupted at t = {result.t_end:g} s of {sc.duration:g} s ({result.interrupted})"
    if result.error:
        return f"failed at t = {result.t_end:g} s of {sc.duration:g} s: {result.error}"
    return ""


def write_report(result: RunResult, checks: list[CheckResult], summary: dict[str, Any], out: Path,
                 plotter: plots.Plotter | None = None) -> Path:
    """The figures (by ``plotter``'s worker, started when the run started, else here), then
    report.md naming them: written last, when every figure is complete."""
    sc = result.scenario
    data = series(result)
    figures, failed = plotter.draw(data, out) if plotter is not None else plots.draw_all(data, out)
    stopped = _stop_line(result)
    lines = [
        f"# {sc.name}",
        "",
        *([f"**Run {stopped}.** The results, checks and figures cover t = 0 … {result.t_end:g} s.", ""]
          if stopped else []),
        sc.description.strip(),
        "",
        "## Run",
        "",
        "| item | value |",
        "|---|---|",
        f"| vessel | {sc.vessel} |",
        f"| scenario file | `{sc.source}` |",
        *([f"| overrides | {', '.join(f'`--set {o}`' for o in sc.overrides)} |"] if sc.overrides else []),
        *([f"| seed (every random source) | {sc.seed} |"] if sc.seed is not None else []),
        f"| mode | {result.mode} |",
        f"| simulated time | {result.t_end:g} s of {sc.duration:g} s, step {sc.step:g} s"
        f"{' (stopped early)' if stopped else ''} |",
        f"| wall time | {result.wall_time:.3f} s |",
        f"| real-time factor | {result.realtime_factor:.1f} |",
    ]
    for k, v in summary["us_per_step"].items():
        lines.append(f"| {k} | {v:.1f} µs per step ({result.steps[k]} steps) |")
    if result.pacing_summary:
        lines.append(f"| real-time pacing | {result.pacing_summary} |")
    lines += ["", "## Checks", ""]
    if checks:
        lines += ["| check | value | bound | result |", "|---|---|---|---|"]
        for c in checks:
            verdict = "PASS" if c.passed else "FAIL" + (f" ({c.note})" if c.note else "")
            value = "—" if c.note else f"{c.value:.4g}"
            lines.append(f"| {c.name} | {value} | {c.bound} | {verdict} |")
    else:
        lines.append("No checks in this scenario.")
    table = allocation_table(result)
    if table:
        lines += ["", "## Allocation", "", *table]
    if result.log:
        lines += ["", "## FMU messages", ""] + [f"- {m}" for m in result.log]
    lines += ["", "## Figures", ""]
    for title, name in figures:
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    if failed:
        lines += ["Figures that could not be drawn:", "", *[f"- {f}" for f in failed], ""]
    lines += ["## Files", "", "- `results.csv`: every recorded signal, one column per `instance.variable`",
              *(["- `results.parquet`: the same signals as Parquet (pandas, pyarrow)"]
                if (out / "results.parquet").is_file() else []),
              "- `summary.json`: timing, checks and messages, for scripts", ""]
    path = out / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path
