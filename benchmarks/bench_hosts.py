"""Benchmark: the same scenario and the same four FMUs under seafmu's master, libcosim and ecos.

Each engine runs in its own fresh process (same start-up for all: imports, FMU loading); the
engines take turns, --repeat rounds, best of each. ``wall`` covers everything from the child's
start (imports, loading, initialisation, stepping; seafmu's master also records its usual outputs,
the other engines record nothing, so the comparison favours them); ``cpu`` is the child's CPU time
(all threads), a steadier figure on a loaded machine; ``stepping`` the stepping alone
(initialisation included for libcosim and ecos, ~10 ms). seafmu-jacobi is seafmu's master with
``coupling: jacobi``, the scheme libcosim and ecos use (equal results to 1e-9).
Goals (issue 9): seafmu's master >= 1.5x faster than libcosim and not slower than ecos (wall).

    python benchmarks/bench_hosts.py [--scenario minerva2_dp] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

from seafmu.export import export_osp, export_ssp
from seafmu.scenario import load_scenario

_CHILD = r"""
import json, os, sys, time
t0 = time.perf_counter()
engine, scenario, path, step, duration = sys.argv[1:6]
step, duration = float(step), float(duration)
n = round(duration / step)
if engine in ("seafmu", "seafmu-jacobi"):
    import dataclasses
    from seafmu.master import run
    from seafmu.scenario import load_scenario
    sc = load_scenario(scenario)
    if engine == "seafmu-jacobi":
        sc = dataclasses.replace(sc, coupling="jacobi")
    stepping = run(sc, mode="fmu", progress=False).wall_time
elif engine == "libcosim":
    from libcosimpy import CosimLogging
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    CosimLogging.log_output_level(CosimLogging.CosimLogLevel.WARNING)
    ex = CosimExecution.from_osp_config_file(path + "/OspSystemStructure.xml")
    mgr = CosimManipulator.create_scenario_manager()
    ex.add_manipulator(mgr)
    ex.load_scenario(mgr, path + "/scenario.json")
    t1 = time.perf_counter()
    assert ex.step(n)
    stepping = time.perf_counter() - t1
else:
    from pathlib import Path
    from seafmu import hosts
    from seafmu.export import load_events
    ecospy = hosts._load_ecos()
    sim = ecospy.EcosSimulation(ssp_path=path, step_size=step)
    events = Path(path[:-4] + ".events.json")
    if events.is_file():
        hosts._ecos_events(ecospy, sim, load_events(events), step)
    t1 = time.perf_counter()
    sim.init(parameter_set="initialValues")
    sim.step(n)
    stepping = time.perf_counter() - t1
    sim.terminate()
    sim.free()
cpu = sum(os.times()[:2])
print(json.dumps({"wall": time.perf_counter() - t0, "cpu": cpu, "stepping": stepping}))
"""


def _time(engine: str, scenario: str, path: str, step: float, duration: float) -> dict[str, float]:
    proc = subprocess.run([sys.executable, "-c", _CHILD, engine, scenario, path, repr(step), repr(duration)],
                          capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"{engine} failed: {proc.stderr.strip().splitlines()[-1:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="minerva2_dp")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="seafmu_bench_hosts_") as tmp:
        ssp, osp = Path(tmp) / f"{sc.name}.ssp", Path(tmp) / "osp"
        export_ssp(sc, ssp)
        export_osp(sc, osp)
        engines = {"seafmu": "", "seafmu-jacobi": "", "libcosim": str(osp), "ecos": str(ssp)}
        runs: dict[str, list[dict[str, float]]] = {e: [] for e in engines}
        for _ in range(args.repeat):  # the engines take turns: a load change hits them alike
            for e, p in engines.items():
                runs[e].append(_time(e, args.scenario, p, sc.step, sc.duration))
    best = {e: {k: min(r[k] for r in rs) for k in rs[0]} for e, rs in runs.items()}
    steps = round(sc.duration / sc.step)
    print(f"scenario {sc.name}: {len(sc.instances)} FMUs, {steps} steps of {sc.step:g} s; "
          f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; best of "
          f"{args.repeat}, each in a fresh process (imports and FMU loading included); load average "
          f"{load0:.1f} before, {os.getloadavg()[0]:.1f} after")
    print(f"{'engine':<16}{'wall [s]':>10}{'cpu [s]':>9}{'stepping':>10}{'RTF':>6}{'wall vs seafmu':>16}")
    for e, b in best.items():
        print(f"{e:<16}{b['wall']:>10.2f}{b['cpu']:>9.2f}{b['stepping']:>10.2f}"
              f"{sc.duration / b['wall']:>6.0f}{b['wall'] / best['seafmu']['wall']:>16.2f}")
    lc, ec = best["libcosim"]["wall"] / best["seafmu"]["wall"], best["ecos"]["wall"] / best["seafmu"]["wall"]
    print(f"goal seafmu >= 1.5x faster than libcosim: {'met' if lc >= 1.5 else 'NOT met'} ({lc:.2f}x); "
          f"goal not slower than ecos: {'met' if ec >= 1.0 else 'NOT met'} ({ec:.2f}x)")


if __name__ == "__main__":
    main()
