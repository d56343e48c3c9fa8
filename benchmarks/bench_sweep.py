"""Sweep throughput: the same 40-case study on a local Dask cluster with 1 and 2 workers, and as 40
sequential ``seafmu run`` processes.

Prints the speed-up of 2 workers over 1 (goal >= 1.8x on a 2-core machine), the per-case overhead
of the sweep over a bare run (goal <= 10 %; a bare run = the master loop of the same case,
``loop_time_s``, measured in the same worker at the same time as the case's ``wall_time_s``, so
other load on the host cancels out), the fixed cost of a sweep, and cases per hour per core, to
size a cluster. Each sweep is timed end to end (``seafmu sweep`` in a fresh process: validation,
cluster start, cases, cases.parquet, report).

    python benchmarks/bench_sweep.py [--cases 40] [--scenario minerva2_dp] [--duration 300]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

from seafmu.scenario import scenario_path


def _timed(argv: list[str], cwd: Path) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        sys.exit(f"{shlex.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--scenario", default="minerva2_dp")
    ap.add_argument("--duration", type=float, default=None, help="shorten the scenario (s)")
    args = ap.parse_args()
    seafmu = [sys.executable, "-m", "seafmu.cli"]
    subprocess.run([*seafmu, "build"], check=True, capture_output=True)
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        work = Path(tmp)
        doc = yaml.safe_load(scenario_path(args.scenario).read_text())
        if args.duration:
            doc["duration"] = args.duration
            doc["events"] = [e for e in doc.get("events", []) if e["time"] < args.duration]
            doc["checks"] = [c for c in doc.get("checks", []) if c.get("after", 0) < args.duration
                             and c.get("before", 0) <= args.duration]
        (work / "base.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        (work / "study.yaml").write_text(
            f"name: bench\nscenario: base.yaml\nseeds: {args.cases}\n")

        results = {}
        for n in (1, 2):
            wall = _timed([*seafmu, "sweep", "study.yaml", "--workers", str(n), "--out", f"w{n}", "-q"], work)
            frame = pd.read_parquet(work / f"w{n}" / "cases.parquet")
            assert len(frame) == args.cases and (frame["status"] != "error").all()
            results[n] = (wall, frame)
            print(f"sweep, {n} worker{'s' if n > 1 else ''}: {wall:7.1f} s for {args.cases} cases "
                  f"({wall / args.cases:.2f} s per case end to end; median case in its worker "
                  f"{frame['wall_time_s'].median():.2f} s, CPU {frame['cpu_time_s'].median():.2f} s)",
                  flush=True)

        seq_wall, bare = 0.0, []
        for seed in range(1, args.cases + 1):
            seq_wall += _timed([*seafmu, "run", "base.yaml", "--seed", str(seed), "-q", "-o", "run"], work)
            bare.append(json.loads((work / "run" / "summary.json").read_text())["wall_time_s"])
        bare_s = float(pd.Series(bare).median())
        per_run = seq_wall / args.cases
        print(f"{args.cases} sequential seafmu run processes: {seq_wall:7.1f} s ({per_run:.2f} s per run;"
              f" its simulation loop, the bare run, median {bare_s:.2f} s)")

        (w1, f1), (w2, _) = results[1], results[2]
        cores = min(2, len(os.sched_getaffinity(0)))
        speedup = w1 / w2
        overhead_e2e = (w1 / args.cases) / bare_s - 1
        both = pd.concat([f1, results[2][1]])
        overhead_case = float(((both["wall_time_s"] - both["loop_time_s"]) / both["loop_time_s"]).median())
        fixed = w1 - float(f1["wall_time_s"].sum())
        print()
        print(f"speed-up, 2 workers over 1:            {speedup:5.2f}x  (goal >= 1.8x)")
        print(f"overhead per case in its worker over the bare run of the same case (scenario load and "
              f"validation, FMU instances, checks; measured together, so load cancels): "
              f"{100 * overhead_case:+5.1f} % (goal <= 10 %)")
        print(f"fixed cost of a sweep (start-up, validation of every case, cluster, cases.parquet, report): "
              f"{fixed:.1f} s; 1-worker sweep end to end per case over the sequential runs' bare loop: "
              f"{100 * overhead_e2e:+5.1f} %")
        print(f"sweep vs sequential seafmu run processes: {seq_wall / w1:5.2f}x faster on 1 worker, "
              f"{seq_wall / w2:5.2f}x on 2")
        print(f"cases per hour per core ({args.scenario}, {doc['duration']:g} s simulated): "
              f"{3600 * args.cases / (w2 * cores):.0f} (2 workers), {3600 * args.cases / w1:.0f} (1 worker)")
        cpu = pd.concat([f1["cpu_time_s"], results[2][1]["cpu_time_s"]]).median()
        print(f"cases per hour per core from the CPU time a case takes in its worker ({cpu:.2f} s, "
              f"independent of other load on the host): {3600 / cpu:.0f}")
        print(f"load average at the end: {os.getloadavg()[0]:.1f} (a shared machine lowers every figure)")


if __name__ == "__main__":
    main()
