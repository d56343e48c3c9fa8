"""Benchmark: the same scenario and the same four FMUs under seafmu's master, libcosim and ecos.

Each engine runs in its own fresh process (same start-up for all: imports, FMU loading), best of
--repeat; the wall time covers loading, initialisation and stepping, with no recording in the
other engines (seafmu's master records its usual outputs, so the comparison favours the others).
Goals (issue 9): seafmu's master >= 1.5x faster than libcosim and not slower than ecos.

    python benchmarks/bench_hosts.py [--scenario minerva2_dp] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

from seafmu.export import export_osp, export_ssp
from seafmu.scenario import load_scenario

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
engine, scenario, path, step, duration = sys.argv[1:6]
step, duration = float(step), float(duration)
n = round(duration / step)
if engine == "seafmu":
    from seafmu.master import run
    from seafmu.scenario import load_scenario
    run(load_scenario(scenario), mode="fmu", progress=False)
elif engine == "seafmu-jacobi":
    import dataclasses
    from seafmu.master import run
    from seafmu.scenario import load_scenario
    run(dataclasses.replace(load_scenario(scenario), coupling="jacobi"), mode="fmu", progress=False)
elif engine == "libcosim":
    from libcosimpy import CosimLogging
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    CosimLogging.log_output_level(CosimLogging.CosimLogLevel.WARNING)
    ex = CosimExecution.from_osp_config_file(path + "/OspSystemStructure.xml")
    mgr = CosimManipulator.create_scenario_manager()
    ex.add_manipulator(mgr)
    ex.load_scenario(mgr, path + "/scenario.json")
    assert ex.step(n)
else:
    from pathlib import Path
    from seafmu import hosts
    from seafmu.export import load_events
    ecospy = hosts._load_ecos()
    sim = ecospy.EcosSimulation(ssp_path=path, step_size=step)
    events = Path(path[:-4] + ".events.json")
    if events.is_file():
        hosts._ecos_events(ecospy, sim, load_events(events), step)
    sim.init(parameter_set="initialValues")
    sim.step(n)
    sim.terminate()
    sim.free()
print(json.dumps({"wall": time.perf_counter() - t0}))
"""


def _time(engine: str, scenario: str, path: str, step: float, duration: float) -> float:
    proc = subprocess.run([sys.executable, "-c", _CHILD, engine, scenario, path, repr(step), repr(duration)],
                          capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"{engine} failed: {proc.stderr.strip().splitlines()[-1:]}")
    return float(json.loads(proc.stdout.strip().splitlines()[-1])["wall"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="minerva2_dp")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    with tempfile.TemporaryDirectory(prefix="seafmu_bench_hosts_") as tmp:
        ssp, osp = Path(tmp) / f"{sc.name}.ssp", Path(tmp) / "osp"
        export_ssp(sc, ssp)
        export_osp(sc, osp)
        engines = {"seafmu": "", "seafmu-jacobi": "", "libcosim": str(osp), "ecos": str(ssp)}
        best = {e: min(_time(e, args.scenario, p, sc.step, sc.duration) for _ in range(args.repeat))
                for e, p in engines.items()}
    steps = round(sc.duration / sc.step)
    print(f"scenario {sc.name}: {len(sc.instances)} FMUs, {steps} steps of {sc.step:g} s; "
          f"{platform.machine()}, Python {platform.python_version()}; best of {args.repeat}, "
          "each in a fresh process (imports and FMU loading included)")
    print(f"{'engine':<16}{'wall [s]':>10}{'RTF':>8}{'vs seafmu':>11}")
    for e, w in best.items():
        print(f"{e:<16}{w:>10.2f}{sc.duration / w:>8.0f}{w / best['seafmu']:>11.2f}")
    lc, ec = best["libcosim"] / best["seafmu"], best["ecos"] / best["seafmu"]
    print(f"goal seafmu >= 1.5x faster than libcosim: {'met' if lc >= 1.5 else 'NOT met'} ({lc:.2f}x); "
          f"goal not slower than ecos: {'met' if ec >= 1.0 else 'NOT met'} ({ec:.2f}x)")


if __name__ == "__main__":
    main()
