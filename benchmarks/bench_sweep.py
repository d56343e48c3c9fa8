"""Sweep throughput: the same 40-case study on a local Dask cluster with 1 and 2 workers, and as 40
sequential ``seafmu run`` processes.

The study: the first 40 cases of the shipped DP Monte Carlo study (``minerva2_dp_monte_carlo``:
Minerva 2 holding station for 300 s in waves and current, Latin hypercube over current speed,
direction and wave height, paired with seeds; ``--study NAME`` names another shipped study), or
with ``--scenario NAME`` 40 seeds over a scenario (``minerva2_dp``: calm water, no waves, the
lightest case: 0.5 s against the Monte Carlo's 0.8 s, so the fixed cost weighs more). The base
scenario is copied beside the study (``--duration`` shortens it); the sequential runs are each
case's own ``seafmu run ... --set ... --seed`` line from cases.parquet.

The speed-up of 2 workers over 1 (goal >= 1.8x on a 2-core machine) is the ratio of the wall times
of the whole ``seafmu sweep`` command (a fresh process: start-up, validation of every case, cluster,
cases, cases.parquet, report, cluster closed), the same study file and the same 40 cases for both,
each into a fresh folder. Each sweep's time is split into its cases (from the first case's start
to the last case's end, from the rows' timestamps) and the fixed cost around them; the speed-up over
the cases alone is printed beside the end-to-end one, and the case length from which the end-to-end
speed-up reaches 1.8x with the fixed cost measured (the fixed cost does not shrink with 2 workers:
one warmed-up worker start before the first case, the report after the last). The per-case
overhead of the sweep over a bare run (goal <= 10 %): a bare run = the master loop of the same case
(``loop_time_s``), measured in the same worker at the same time as the case's ``wall_time_s``, so
other load on the host cancels out. Cases per hour per core are printed to size a cluster.

Before timing, one ``seafmu run`` of the base scenario warms the FMU build, the compiled kernels'
cache, Python's bytecode cache and the file cache, so neither worker count pays for them (a user's
machine keeps them; ``PYTHONDONTWRITEBYTECODE``, set on some build hosts, is cleared for the
commands timed); ``--repeat N`` alternates the order of the 1- and 2-worker sweeps N times and
reports the median of each, the best of each, and the median of the ratios of the back-to-back
pairs (sweep k with 1 worker and sweep k with 2, run one right after the other: the host's speed,
which drifts by 10-20 % over minutes on a shared machine, cancels within a pair but not between the
medians of sweeps minutes apart).

    python benchmarks/bench_sweep.py [--cases 40] [--study minerva2_dp_monte_carlo | --scenario NAME]
                                     [--duration S] [--repeat 3] [--no-sequential]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

from seafmu.scenario import REPO, scenario_path
from seafmu.sweep.study import load_study


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # see the docstring


def _timed(argv: list[str], cwd: Path) -> tuple[float, float, str]:
    """(wall time, CPU time of the command and every process it waited for, e.g. its workers, stdout)."""
    c0, t0 = _cpu_children(), time.perf_counter()
    proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, env=ENV)
    dt, cpu = time.perf_counter() - t0, _cpu_children() - c0
    if proc.returncode not in (0, 1):
        sys.exit(f"{shlex.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return dt, cpu, proc.stdout


Sweep = tuple[float, float, pd.DataFrame, float]


def _sweep(seafmu: list[str], work: Path, n: int, k: int, cases: int) -> Sweep:
    """(end-to-end wall time, the cases' span, the rows, CPU time of every process) of one sweep with
    n workers into a fresh folder."""
    out = f"w{n}_{k}"
    argv = [*seafmu, "sweep", "study.yaml", "--workers", str(n), "--out", out, "-q"]
    wall, cpu, stdout = _timed(argv, work)
    if any(line.startswith("built ") for line in stdout.splitlines()):
        print("  (the FMUs were rebuilt by this sweep: the sources changed meanwhile; its time includes the "
              "build and the kernels' compilation)")
    frame = pd.read_parquet(work / out / "cases.parquet")
    assert len(frame) == cases and (frame["status"] != "error").all(), frame["error"].tolist()
    assert frame["worker"].nunique() == n, frame["worker"].unique()
    span = float(frame["finished"].max() - frame["started"].min())
    return wall, span, frame, cpu


def _study(args: argparse.Namespace, work: Path) -> tuple[str, dict]:
    """Write ``work/base.yaml`` (the base scenario, shortened to ``--duration``) and ``work/study.yaml``
    (the shipped study's first ``--cases`` cases, or ``--cases`` seeds over ``--scenario``); returns
    (what is run, the base scenario)."""
    if args.scenario:
        study: dict = {"name": "bench", "seeds": args.cases}
        base, what = scenario_path(args.scenario), f"{args.scenario}, {args.cases} seeds"
    else:
        src = REPO / "studies" / args.study / "study.yaml"
        if not src.is_file():
            sys.exit(f"--study {args.study}: no such shipped study (studies/<name>/study.yaml)")
        study = yaml.safe_load(src.read_text())
        ref = Path(study["scenario"])
        base = (src.parent / ref) if ref.suffix else scenario_path(study["scenario"])
        if "sampling" in study:
            study["sampling"]["samples"] = args.cases
        if isinstance(study.get("seeds"), int):
            study["seeds"] = args.cases
        what = f"study {args.study}, its first {args.cases} cases"
    doc = yaml.safe_load(base.read_text())
    if args.duration:
        doc["duration"] = args.duration
        doc["events"] = [e for e in doc.get("events", []) if e["time"] < args.duration]
        doc["checks"] = [c for c in doc.get("checks", []) if c.get("after", 0) < args.duration
                         and c.get("before", 0) <= args.duration]
    (work / "base.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    study["scenario"] = "base.yaml"
    (work / "study.yaml").write_text(yaml.safe_dump(study, sort_keys=False))
    n = len(load_study(work / "study.yaml", validate=False).cases)
    if n != args.cases:
        sys.exit(f"{what}: makes {n} cases, not --cases {args.cases} (a grid study has its own count)")
    return what, doc


def main() -> None:
    # Long because it is the benchmark's procedure and its report, read top to bottom.
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=40)
    what = ap.add_mutually_exclusive_group()
    what.add_argument("--study", default="minerva2_dp_monte_carlo",
                      help="a shipped study, its first --cases cases (default: minerva2_dp_monte_carlo)")
    what.add_argument("--scenario", help="instead: --cases seeds over this scenario (e.g. minerva2_dp)")
    ap.add_argument("--duration", type=float, default=None, help="shorten the scenario (s)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="1- and 2-worker sweeps, alternated, this many times")
    ap.add_argument("--no-sequential", action="store_true", help="skip the sequential seafmu run processes")
    args = ap.parse_args()
    seafmu = [sys.executable, "-m", "seafmu.cli"]
    subprocess.run([*seafmu, "build"], check=True, capture_output=True)
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        work = Path(tmp)
        what, doc = _study(args, work)
        print(f"{what} ({doc['duration']:g} s simulated each)", flush=True)
        _timed([*seafmu, "run", "base.yaml", "-q", "-o", "warmup"], work)  # caches warm for both counts

        runs: dict[int, list[Sweep]] = {1: [], 2: []}
        for k in range(args.repeat):
            for n in ((1, 2) if k % 2 == 0 else (2, 1)):
                wall, span, frame, cpu_all = _sweep(seafmu, work, n, k, args.cases)
                runs[n].append((wall, span, frame, cpu_all))
                print(f"sweep, {n} worker{'s' if n > 1 else ''}: {wall:6.1f} s end to end = cases "
                      f"{span:5.1f} s (first start to last end) + fixed {wall - span:4.1f} s; median case in "
                      f"its worker {frame['wall_time_s'].median():.2f} s, "
                      f"CPU {frame['cpu_time_s'].median():.2f} s; CPU of all its processes {cpu_all:.1f} s",
                      flush=True)

        def med(n: int, i: int) -> float:
            return statistics.median(r[i] for r in runs[n])

        w1, w2, s1, s2 = med(1, 0), med(2, 0), med(1, 1), med(2, 1)
        b1, b2 = min(r[0] for r in runs[1]), min(r[0] for r in runs[2])
        frames = [r[2] for n in (1, 2) for r in runs[n]]
        both = pd.concat(frames)

        seq_wall, bare_s = None, None
        if not args.no_sequential:
            seq_wall, bare = 0.0, []
            for command in runs[1][0][2].sort_values("case")["command"]:  # each case's own reproducing line
                argv = [*seafmu, *shlex.split(command)[1:], "-q", "-o", "run"]
                seq_wall += _timed(argv, work)[0]
                bare.append(json.loads((work / "run" / "summary.json").read_text())["wall_time_s"])
            bare_s = float(pd.Series(bare).median())
            print(f"{args.cases} sequential seafmu run processes: {seq_wall:7.1f} s "
                  f"({seq_wall / args.cases:.2f} s per run; its simulation loop, the bare run, median "
                  f"{bare_s:.2f} s)")

        cores = min(2, len(os.sched_getaffinity(0)))
        overhead_run = float(((both["wall_time_s"] - both["run_time_s"]) / both["run_time_s"]).median())
        overhead_loop = float(((both["wall_time_s"] - both["loop_time_s"]) / both["loop_time_s"]).median())
        rep = f" (median of {args.repeat})" if args.repeat > 1 else ""
        print()
        print(f"speed-up, 2 workers over 1, whole seafmu sweep command{rep}: {w1 / w2:5.2f}x  (goal >= 1.8x; "
              f"{w1:.1f} s / {w2:.1f} s)")
        if args.repeat > 1:
            print(f"  best of {args.repeat} each (least disturbed by other load): {b1 / b2:5.2f}x "
                  f"({b1:.1f} s / {b2:.1f} s)")
            pairs = [runs[1][k][0] / runs[2][k][0] for k in range(args.repeat)]
            print(f"  per back-to-back pair (the host's speed drifts by 10-20 % over minutes; a pair shares "
                  f"it): median {statistics.median(pairs):5.2f}x ({', '.join(f'{r:.2f}' for r in pairs)})")
        print(f"  breakdown: cases {s1:.1f} s on 1 worker, {s2:.1f} s on 2 (speed-up over the cases alone "
              f"{s1 / s2:.2f}x); fixed cost (start-up, validation, cluster, cases.parquet, report, close) "
              f"{w1 - s1:.1f} s on 1 worker, {w2 - s2:.1f} s on 2")
        if s1 / s2 > 1.8:  # (F1 + N c) / (F2 + N c / r) = 1.8, solved for the case length c
            c18 = (1.8 * (w2 - s2) - (w1 - s1)) / (1 - 1.8 / (s1 / s2)) / args.cases
            print(f"  with these fixed costs and {args.cases} cases, 2 workers reach 1.8x end to end for "
                  f"cases of {max(c18, 0):.2f} s and longer (these: {s1 / args.cases:.2f} s on 1 worker)")
        print(f"overhead per case in its worker over the bare run of the same case (master.run: FMUs "
              f"instantiated, loop, freed; the sweep adds checks, metrics, the row; measured together, so "
              f"load cancels): {100 * overhead_run:+5.1f} % (goal <= 10 %)")
        print(f"  over the master loop alone (also counting the FMUs' instantiation, which every run pays): "
              f"{100 * overhead_loop:+5.1f} %")
        if seq_wall is not None and bare_s is not None:
            print(f"1-worker sweep end to end per case over the sequential runs' bare loop: "
                  f"{100 * ((w1 / args.cases) / bare_s - 1):+5.1f} %")
            print(f"sweep vs sequential seafmu run processes: {seq_wall / w1:5.2f}x faster on 1 worker, "
                  f"{seq_wall / w2:5.2f}x on 2")
        print(f"cases per hour per core ({what}, {doc['duration']:g} s simulated): "
              f"{3600 * args.cases / (w2 * cores):.0f} (2 workers), {3600 * args.cases / w1:.0f} (1 worker)")
        cpu = both["cpu_time_s"].median()
        print(f"cases per hour per core from the CPU time a case takes in its worker ({cpu:.2f} s, "
              f"independent of other load on the host): {3600 / cpu:.0f}")
        print(f"load average at the end: {os.getloadavg()[0]:.1f} (a shared machine lowers every figure)")


if __name__ == "__main__":
    main()
