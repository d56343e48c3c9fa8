"""Benchmark: where a cached ``seafmu run SCENARIO`` spends its time, this checkout against a base commit.

Issue 13: a cached ``seafmu run minerva2_dp`` end to end (imports, FMU load, 300 s simulated,
results, plots, report) under 3 s. Both checkouts are measured in this run, interleaved, best of
--repeat (the machine is a shared 2-core one): the base commit is checked out into a temporary git
worktree (removed at the end) and run with the ``seafmu`` package names mapped to its folders.

Printed for each: the end-to-end wall time of ``python -m seafmu.cli run SCENARIO -q`` (FMUs built
and kernels cached by a first, unmeasured run); the same run in phases (imports of the CLI and
the run's modules, scenario + FMU load + simulation, the simulation alone, checks and summary,
report with its figures); and, from ``python -X importtime``, the import time of the run's
process by package (the figures' worker process imports matplotlib in parallel, not counted).
Ratios are this checkout / base.

    python benchmarks/bench_startup.py [--base HEAD] [--repeat 5] [--scenario minerva2_dp]
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Runs `python -m MODULE ARGS` (or -c CODE) with seafmu's package names mapped to a checkout's
# folders, as the editable install maps them to this one.
LAUNCH = """
import importlib.abc, importlib.machinery, importlib.util, runpy, sys
root = sys.argv.pop(1)
folders = {"seafmu": "seafmu", "seafmu.components": "components", "seafmu.fmus": "fmus",
           "seafmu.hardware": "hardware"}
class Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name in folders:
            d = root + "/" + folders[name]
            return importlib.util.spec_from_file_location(name, d + "/__init__.py",
                                                          submodule_search_locations=[d])
        if name.startswith("seafmu."):  # only in this checkout, never the installed one
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            if spec is None:
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return spec
        return None
sys.meta_path.insert(0, Finder())
what = sys.argv.pop(1)
if what == "-c":
    code = sys.argv.pop(1)
    exec(compile(code, "<phases>", "exec"), {"__name__": "__main__"})
else:
    sys.argv[0] = what
    runpy.run_module(what, run_name="__main__", alter_sys=True)
"""

# The run of `seafmu run SCENARIO -q -o OUT` in phases (seafmu/cli.py's _run, timed).
PHASES = """
import json, sys, time
from pathlib import Path
clock = time.process_time if sys.argv[3] == "cpu" else time.perf_counter
t0 = clock()
import seafmu.cli
from seafmu.master import run
from seafmu.outdir import RunFolder
from seafmu.report import write_placeholder_report, write_report
from seafmu.results import CsvStream, evaluate_checks, summary, write_summary
from seafmu.scenario import load_scenario
t1 = clock()
try:
    from seafmu.plots import Plotter
    plotter = Plotter()
    plotter.start()
except ImportError:
    plotter = None
scenario, out = sys.argv[1], Path(sys.argv[2])
sc = load_scenario(scenario)
with RunFolder(out):
    write_placeholder_report(sc.name, out)
    seafmu.cli._build_kinds(sc)
    csv = CsvStream(out / "results.csv")
    result = run(sc, mode="fmu", progress=False, sink=csv)
    csv.close()
    t2 = clock()
    checks = evaluate_checks(result)
    data = summary(result, checks)
    write_summary(data, out / "summary.json")
    t3 = clock()
    if plotter is not None:
        write_report(result, checks, data, out, plotter)
    else:
        write_report(result, checks, data, out)
    t4 = clock()
sim = {"sim alone": result.wall_time} if clock is time.perf_counter else {}
print(json.dumps({"imports": t1 - t0, "load + sim": t2 - t1, **sim,
                  "checks + summary": t3 - t2, "report + figures": t4 - t3, "total": t4 - t0}))
"""


def _cmd(root: Path, *args: str) -> list[str]:
    return [sys.executable, "-c", LAUNCH, str(root), *args]


def _cpu_of_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def end_to_end(root: Path, scenario: str, out: Path) -> tuple[float, float]:
    """(wall, CPU of the run and the processes it started, figure workers included) in seconds."""
    c, t = _cpu_of_children(), time.perf_counter()
    p = subprocess.run(_cmd(root, "seafmu.cli", "run", scenario, "-q", "-o", str(out)), cwd=root,
                       capture_output=True, text=True)
    dt, dc = time.perf_counter() - t, _cpu_of_children() - c
    if p.returncode not in (0, 1):
        raise SystemExit(f"{root}: seafmu run failed ({p.returncode}): {p.stderr.strip()[-500:]}")
    return dt, dc


def phases(root: Path, scenario: str, out: Path, clock: str) -> dict[str, float]:
    """The run's phases in wall time or in this process's CPU time (``clock``: wall, cpu)."""
    p = subprocess.run(_cmd(root, "-c", PHASES, scenario, str(out), clock), cwd=root, capture_output=True,
                       text=True)
    if p.returncode != 0:
        raise SystemExit(f"{root}: phases failed: {p.stderr.strip()[-500:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def _group(module: str) -> str:
    """A module's package for the import table; an FMU's bundled copy is 'FMU bundles'."""
    top = module.split(".")[0]
    if top.startswith("seafmu_fmu_") or re.match(r".*_(plant|observer|controller|allocator)_fmu_", top):
        return "FMU bundles"
    if top == "seafmu" and "." in module:
        sub = module.split(".")[1]
        return f"seafmu.{sub}" if sub in ("components", "fmus", "hardware") else "seafmu (top)"
    return top


def import_times(root: Path, scenario: str, out: Path) -> dict[str, float]:
    """Seconds of import per package in the run's process (self times summed, -X importtime)."""
    p = subprocess.run([sys.executable, "-X", "importtime", *_cmd(root, "seafmu.cli", "run", scenario, "-q",
                                                                 "-o", str(out))[1:]],
                       cwd=root, capture_output=True, text=True)
    groups: dict[str, float] = defaultdict(float)
    for line in p.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+\d+ \|\s*(\S+)", line)
        if m:
            groups[_group(m[2])] += int(m[1]) / 1e6
    return dict(groups)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="HEAD", help="the commit to compare with (default HEAD)")
    ap.add_argument("--repeat", type=int, default=5, help="runs of each kind per checkout (best is kept)")
    ap.add_argument("--scenario", default="minerva2_dp")
    args = ap.parse_args()
    if args.repeat < 1:
        raise SystemExit("bench_startup: --repeat must be >= 1")
    with tempfile.TemporaryDirectory(prefix="seafmu_bench_startup_") as tmp:
        base = Path(tmp) / "base"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(base), args.base],
                       check=True)
        try:
            roots = {"this": REPO, "base": base}
            outs = {k: Path(tmp) / f"out_{k}" for k in roots}
            for k, root in roots.items():  # FMUs built, kernels compiled and cached: not measured
                end_to_end(root, args.scenario, outs[k])
            e2e: dict[str, list[tuple[float, float]]] = {k: [] for k in roots}
            ph: dict[str, list[dict[str, float]]] = {k: [] for k in roots}
            cpu: dict[str, list[dict[str, float]]] = {k: [] for k in roots}
            for _ in range(args.repeat):
                for k, root in roots.items():
                    e2e[k].append(end_to_end(root, args.scenario, outs[k]))
                    ph[k].append(phases(root, args.scenario, outs[k], "wall"))
                    cpu[k].append(phases(root, args.scenario, outs[k], "cpu"))
            imp = {k: import_times(root, args.scenario, outs[k]) for k, root in roots.items()}
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(base)], check=False)
    rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.base], capture_output=True,
                         text=True).stdout.strip()
    print(f"seafmu run {args.scenario} -q, cached; best of {args.repeat}; this checkout against base "
          f"{args.base} ({rev})")
    print(f"{'':28s} {'this [s]':>9s} {'base [s]':>9s} {'ratio':>7s}")
    best = {k: min(w for w, _ in v) for k, v in e2e.items()}
    print(f"{'end to end (seafmu run)':28s} {best['this']:9.3f} {best['base']:9.3f} "
          f"{best['this'] / best['base']:7.2f}   goal < 3 s: {'met' if best['this'] < 3 else 'not met'}")
    least = {k: min(c for _, c in v) for k, v in e2e.items()}
    print(f"{'  CPU, with its workers':28s} {least['this']:9.3f} {least['base']:9.3f} "
          f"{least['this'] / least['base']:7.2f}")
    for title, table in (("the run in phases, wall time:", ph),
                         ("the same, CPU time of the run's process:", cpu)):
        print(title)
        for key in table["this"][0]:
            a, b = (min(r[key] for r in table[k]) for k in ("this", "base"))
            print(f"  {key:26s} {a:9.3f} {b:9.3f} {a / b if b else float('nan'):7.2f}")
    print("imports in the run's process, by package (self times, -X importtime, one run each):")
    names = sorted(set(imp["this"]) | set(imp["base"]), key=lambda n: -max(imp["this"].get(n, 0),
                                                                          imp["base"].get(n, 0)))
    for n in names[:20]:
        a, b = imp["this"].get(n, 0.0), imp["base"].get(n, 0.0)
        print(f"  {n:26s} {a:9.3f} {b:9.3f} {a / b if b else float('nan'):7.2f}")
    a, b = sum(imp["this"].values()), sum(imp["base"].values())
    print(f"  {'all imports':26s} {a:9.3f} {b:9.3f} {a / b:7.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
