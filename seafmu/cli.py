"""The ``seafmu`` command: build, check and run scenarios.

Every expected failure (bad scenario, FMU error, missing file) ends with one line on stderr and
exit code 2; a run whose acceptance checks fail exits with 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from seafmu.scenario import DEFAULT_SCENARIO


def _cmd_build(args: argparse.Namespace) -> int:
    from seafmu.build import VESSELS, build_all

    vessels = tuple(args.vessel) if args.vessel else VESSELS
    for r in build_all(vessels, force=args.force):
        print(f"{'built  ' if r.rebuilt else 'current'} {r.path}")
    for profile in args.link or []:
        from hardware.link_fmu import build_link_fmu
        from seafmu.build import build_dir

        print(f"built   {build_link_fmu(profile, build_dir())}")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from seafmu.scenario import load_scenario

    sc = load_scenario(args.scenario)
    print(f"{sc.source}: OK — vessel {sc.vessel}, {len(sc.instances)} FMUs, "
          f"{len(sc.connections)} connections, {len(sc.events)} events, {len(sc.checks)} checks, "
          f"{round(sc.duration / sc.step)} steps")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from seafmu.master import run
    from seafmu.report import write_report
    from seafmu.results import evaluate_checks, summary, write_csv, write_summary
    from seafmu.scenario import load_scenario

    sc = load_scenario(args.scenario)
    out = Path(args.output) if args.output else Path("results") / sc.name
    out.mkdir(parents=True, exist_ok=True)
    mode = "inprocess" if args.inprocess else "fmu"
    if mode == "fmu":
        from seafmu.build import build_fmu

        for inst in sc.instances:
            if inst.kind is not None:
                r = build_fmu(sc.vessel, inst.kind)
                if r.rebuilt:
                    print(f"built {r.path}")
    record = out / "recording" if any(i.hardware for i in sc.instances) else None
    result = run(sc, mode=mode, progress=not args.quiet and not sc.realtime, record_dir=record)
    checks = evaluate_checks(result)
    data = summary(result, checks)
    write_csv(result, out / "results.csv")
    write_summary(data, out / "summary.json")
    report = write_report(result, checks, data, out)
    print(f"{sc.name}: {sc.duration:g} s simulated in {result.wall_time:.2f} s "
          f"(real-time factor {result.realtime_factor:.0f}, mode {mode})")
    for name, us in data["us_per_step"].items():
        print(f"  {name:<12} {us:8.1f} µs/step")
    if result.pacing_summary:
        print(f"  pacing: {result.pacing_summary}")
    for c in checks:
        print(f"  [{'PASS' if c.passed else 'FAIL'}] {c.name}: {c.value:.4g} ({c.bound})")
    print(f"report: {report}")
    return 0 if data["checks_passed"] else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="seafmu", description="Marine GNC co-simulation with FMI 2.0 FMUs")
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="build the FMUs (only those whose sources changed)")
    b.add_argument("--vessel", action="append", help="only this vessel (repeatable)")
    b.add_argument("--force", action="store_true", help="rebuild even if up to date")
    b.add_argument("--link", action="append", metavar="PROFILE",
                   help="also build the hardware link of this profile as an FMU (for other FMI tools)")
    b.set_defaults(fn=_cmd_build)
    c = sub.add_parser("check", help="validate a scenario without running it")
    c.add_argument("scenario")
    c.set_defaults(fn=_cmd_check)
    r = sub.add_parser("run", help=f"run a scenario (default: {DEFAULT_SCENARIO})")
    r.add_argument("scenario", nargs="?", default=None)
    r.add_argument("-o", "--output", help="output folder (default: results/<scenario>)")
    r.add_argument("--inprocess", action="store_true", help="run the components without FMI (comparison)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(fn=_cmd_run)
    from hardware.cli import register as register_hardware
    from seafmu.identification.cli import register as register_identification

    register_identification(sub)
    register_hardware(sub)
    args = parser.parse_args(argv)
    from components.vessel_spec import VesselFileError
    from seafmu.identification.trial import TrialError
    from seafmu.master import SimulationError
    from seafmu.scenario import ScenarioError

    try:
        return args.fn(args)
    except (ScenarioError, SimulationError, VesselFileError, TrialError, OSError) as exc:
        print(f"seafmu: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seafmu: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
