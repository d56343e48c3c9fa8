"""Plots (PNG) and the Markdown report of a run: trajectory, states vs references, thruster use.

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

import matplotlib

matplotlib.use("Agg")  # files only: runs on machines with no display
import matplotlib.pyplot as plt
import numpy as np

from seafmu.master import RunResult
from seafmu.outdir import atomic_path, atomic_write_text
from seafmu.results import CheckResult

ANGLES = {"roll", "pitch", "yaw"}
PLACEHOLDER_MARK = "<!-- seafmu: run in progress -->"


def _save(fig: Any, path: Path) -> None:
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)


def _find(result: RunResult, var: str) -> str | None:
    """The first recorded 'instance.var' with this variable name."""
    return next((k for k in result.signals if k.split(".", 1)[1] == var), None)


def plot_trajectory(result: RunResult, path: Path) -> bool:
    n, e = _find(result, "north"), _find(result, "east")
    if n is None or e is None:
        return False
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(result.signals[e], result.signals[n], label="true", lw=1.5)
    nh, eh = _find(result, "north_hat"), _find(result, "east_hat")
    if nh and eh:
        ax.plot(result.signals[eh], result.signals[nh], "--", label="estimated", lw=1)
    nr, er = _find(result, "north_ref"), _find(result, "east_ref")
    if nr and er:
        ax.plot(result.signals[er], result.signals[nr], "k+", ms=10, label="setpoints")
    ax.plot(result.signals[e][0], result.signals[n][0], "go", label="start")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(f"{result.scenario.name}: trajectory (NED)")
    fig.tight_layout()
    _save(fig, path)
    return True


def plot_states(result: RunResult, path: Path) -> bool:
    from seafmu.components.vessel_spec import ETA_NAMES, NU_NAMES

    names = [n for n in ETA_NAMES[6] + NU_NAMES[6] if _find(result, n)]
    eta = [n for n in names if n in ETA_NAMES[6]]
    if not eta:
        return False
    fig, axes = plt.subplots(len(eta), 1, figsize=(9, 1.9 * len(eta) + 0.6), sharex=True, squeeze=False)
    t = result.time
    for ax, n in zip(axes[:, 0], eta, strict=True):
        scale, unit = (180 / np.pi, "deg") if n in ANGLES else (1.0, "m")
        for suffix, style, label in (("", "-", "true"), ("_hat", "--", "estimate"), ("_d", ":", "desired"),
                                     ("_ref", "-", "reference")):
            key = _find(result, n + suffix)
            if key is None:
                continue
            y = result.signals[key] * scale
            kw: dict[str, Any] = {"lw": 0.8} if suffix == "_ref" else {"lw": 1.2}
            if suffix == "_ref":
                kw["color"] = "k"
                kw["alpha"] = 0.5
            ax.plot(t, y, style, label=label, **kw)
        ax.set_ylabel(f"{n} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize=8, ncol=4)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"{result.scenario.name}: states vs references")
    fig.tight_layout()
    _save(fig, path)
    return True


def plot_thrusters(result: RunResult, path: Path) -> bool:
    speeds = sorted((k for k in result.signals if k.split(".", 1)[1].startswith("n_")
                     and k.split(".", 1)[1][2:].isdigit()), key=lambda k: int(k.rsplit("_", 1)[1]))
    thrusts = sorted((k for k in result.signals if k.split(".", 1)[1].startswith("thrust_")
                      and k.split(".", 1)[1][7:].isdigit()), key=lambda k: int(k.rsplit("_", 1)[1]))
    if not speeds and not thrusts:
        return False
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for k in speeds:
        axes[0].plot(result.time, result.signals[k], lw=1, label=k.split(".", 1)[1])
    for k in thrusts:
        axes[1].plot(result.time, result.signals[k], lw=1, label=k.split(".", 1)[1])
    axes[0].set_ylabel("shaft speed [rev/s]")
    axes[1].set_ylabel("thrust [N]")
    axes[1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # a hardware link reports no thrust: no empty legend
            ax.legend(fontsize=7, ncol=4, loc="best")
    fig.suptitle(f"{result.scenario.name}: thruster use")
    fig.tight_layout()
    _save(fig, path)
    return True


def allocation_table(result: RunResult) -> list[str]:
    """Per allocator: saturation onset, worst error, the thesis's indicator and energy."""
    insts = sorted({k.split(".", 1)[0] for k in result.signals if k.endswith(".alloc_error")})
    if not insts:
        return []
    rows = ["| allocator | first time with error > 1e-6 [s] | max ‖Bu − τ‖ | "
            "Σ negative front thrust (indicator) | mean Σu² |", "|---|---|---|---|---|"]
    t = result.time
    for i in insts:
        err = result.signals[f"{i}.alloc_error"]
        over = np.flatnonzero(err > 1e-6)
        onset = f"{t[over[0]]:g}" if over.size else "never"
        ind = result.signals.get(f"{i}.front_negative_thrust")
        en = result.signals.get(f"{i}.thrust_energy")
        rows.append(f"| {i} | {onset} | {np.nanmax(err):.4g} | "
                    f"{'' if ind is None else f'{np.nansum(ind):.4g}'} | "
                    f"{'' if en is None else f'{np.nanmean(en):.4g}'} |")
    return rows


def plot_allocation(result: RunResult, path: Path) -> bool:
    keys = sorted(k for k in result.signals if k.endswith(".alloc_error"))
    if not keys:
        return False
    fig, ax = plt.subplots(figsize=(9, 4))
    for k in keys:
        ax.plot(result.time, result.signals[k], lw=1.2, label=k.split(".", 1)[0])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("allocation error ‖Bu − τ‖")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{result.scenario.name}: allocation error")
    fig.tight_layout()
    _save(fig, path)
    return True


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


def write_report(result: RunResult, checks: list[CheckResult], summary: dict[str, Any], out: Path) -> Path:
    sc = result.scenario
    figures: list[tuple[str, str]] = []
    failed: list[str] = []
    for fn, name, title in ((plot_trajectory, "trajectory.png", "Trajectory"),
                            (plot_states, "states.png", "States vs references"),
                            (plot_thrusters, "thrusters.png", "Thruster use"),
                            (plot_allocation, "allocation.png", "Allocation error")):
        try:
            if fn(result, out / name):
                figures.append((title, name))
        except Exception as exc:  # a figure that cannot be drawn must not cost the report
            plt.close("all")
            failed.append(f"{name}: {type(exc).__name__}: {' '.join(str(exc).split())[:200]}")
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
