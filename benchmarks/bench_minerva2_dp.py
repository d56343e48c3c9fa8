"""Benchmark: minerva2_dp through four FMUs (fmpy) against the same components in-process.

Prints wall time, real-time factor, microseconds per step for each FMU, and the ratio
FMU-orchestrated / in-process, both measured in this run (best of --repeat runs each).
Goals (issue 2): ratio <= 1.3 and real-time factor >= 100 on a 2-core machine.

    python benchmarks/bench_minerva2_dp.py [--repeat 3] [--scenario minerva2_dp]
"""

from __future__ import annotations

import argparse
import platform

from seafmu.build import build_fmu
from seafmu.master import RunResult, run
from seafmu.scenario import load_scenario


def best(scenario: str, mode: str, repeat: int) -> RunResult:
    sc = load_scenario(scenario)
    runs = [run(sc, mode=mode, progress=False) for _ in range(repeat)]  # type: ignore[arg-type]
    return min(runs, key=lambda r: r.wall_time)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="minerva2_dp")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    for inst in sc.instances:
        if inst.kind:
            build_fmu(sc.vessel, inst.kind)
    fmu = best(args.scenario, "fmu", args.repeat)
    inproc = best(args.scenario, "inprocess", args.repeat)
    steps = round(sc.duration / sc.step)
    print(f"scenario {sc.name}: {sc.duration:g} s simulated, {steps} master steps of {sc.step:g} s; "
          f"{platform.processor() or platform.machine()}, Python {platform.python_version()}; "
          f"best of {args.repeat}")
    print(f"{'':<22}{'FMUs (fmpy)':>14}{'in-process':>14}{'ratio':>8}")
    print(f"{'wall time [s]':<22}{fmu.wall_time:>14.3f}{inproc.wall_time:>14.3f}"
          f"{fmu.wall_time / inproc.wall_time:>8.2f}")
    print(f"{'real-time factor':<22}{fmu.realtime_factor:>14.1f}{inproc.realtime_factor:>14.1f}")
    a, b = fmu.us_per_step(), inproc.us_per_step()
    for name in a:
        print(f"{name + ' [us/step]':<22}{a[name]:>14.1f}{b[name]:>14.1f}{a[name] / b[name]:>8.2f}")
    ratio = fmu.wall_time / inproc.wall_time
    print(f"goal ratio <= 1.3: {'met' if ratio <= 1.3 else 'NOT met'} ({ratio:.2f}); "
          f"goal real-time factor >= 100: {'met' if fmu.realtime_factor >= 100 else 'NOT met'} "
          f"({fmu.realtime_factor:.0f})")


if __name__ == "__main__":
    main()
