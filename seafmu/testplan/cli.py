"""``seafmu testplan VESSEL [--hardware PROFILE]``: the argparse definition and the command."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from seafmu.outdir import OutputFolderError, check_output_folder, nonempty_path

# --seed goes to the plant's seed parameter: an FMI Integer (32 bits) with minimum 0. Checked by the
# parser: the plant refused it only after the first trial's scenario was written.
SEED_RANGE = (0, 2**31 - 1)


def _seed(text: str) -> int:
    """An argparse type: a seed in SEED_RANGE."""
    low, high = SEED_RANGE
    try:
        seed = int(text)
    except ValueError:
        seed = low - 1
    if not low <= seed <= high:
        raise argparse.ArgumentTypeError(f"must be a whole number from {low} to {high} (the plant's "
                                         f"sensor-noise seed), got {text}")
    return seed


def _folder(text: str) -> Path:
    return Path(nonempty_path(text))  # Path("") would be the current folder


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``testplan`` sub-command."""
    p = subparsers.add_parser(
        "testplan",
        help="run the hydrodynamic test plan: trials, damping identification, vessel file, report",
        description="Surge, sway and yaw trials (accelerate, hold, release, step from rest) with the "
                    "axis_trial controller holding the other DOFs, roll/pitch release decays; identifies "
                    "the damping (diagonal and the coupled Y_r, N_v), writes the trials, a vessel file with "
                    "the identified damping and a report (docs/testplan.md).")
    p.add_argument("vessel", help="bundled vessel name (amv_osf, minerva2, minerva2_published_damping, "
                   "supply)")
    p.add_argument("--hardware", metavar="PROFILE", help="run against a vessel through this hardware link "
                   "profile (real time) instead of the plant")
    p.add_argument("-o", "--output", type=_folder, help="output folder (default results/testplan_<vessel>)")
    p.add_argument("--fmu", action="store_true", help="run the plant and GNC as FMUs (default: in-process)")
    p.add_argument("--seed", type=_seed, default=1, help="sensor-noise seed of the plant (default 1)")
    p.add_argument("--axes", metavar="AXIS[,AXIS]", help="run only these trials (surge, sway, yaw, roll, "
                   "pitch; default all the vessel has; with --hardware: surge, sway, yaw)")
    p.add_argument("--scale", type=float, default=1.0, help="multiply every phase duration by this "
                   "(0 < SCALE <= 10, default 1): a shorter plan for CI or a first look on hardware, "
                   "at the cost of accuracy (docs/testplan.md)")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the plan; 0 when done, 1 when no vessel file could be written (non-physical damping), 2 on
    bad input or a failed run (one line)."""
    # Imported here, not at the top: every `seafmu` command builds this parser, and the test plan's
    # identification stack (SciPy statistics) would add about 0.6 s to each of them.
    from seafmu.components.vessel_spec import VesselFileError, bundled_vessels
    from seafmu.hardware.profile import load_profile
    from seafmu.master import SimulationError
    from seafmu.scenario import ScenarioError
    from seafmu.testplan.runner import TestplanError, relative_error, run_testplan

    vessel = args.vessel
    if vessel not in bundled_vessels():
        from seafmu.components.names import did_you_mean

        known = bundled_vessels()
        print(f"seafmu: error: vessel '{vessel}': not a bundled vessel{did_you_mean(vessel, known)} "
              f"(bundled: {', '.join(known)})", file=sys.stderr)
        return 2
    if args.hardware is not None:
        try:
            prof = load_profile(args.hardware)
        except (ValueError, OSError) as exc:
            print(f"seafmu: error: --hardware {args.hardware}: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        if getattr(prof, "vessel", vessel) != vessel:
            print(f"seafmu: error: --hardware {args.hardware}: profile is for vessel '{prof.vessel}', not "
                  f"'{vessel}'", file=sys.stderr)
            return 2
    out = args.output or Path("results") / f"testplan_{vessel}"
    axes = [a.strip() for a in args.axes.split(",") if a.strip()] if args.axes is not None else None
    if axes is not None and not axes:
        print("seafmu: error: --axes: empty; give one or more of surge, sway, yaw, roll, pitch",
              file=sys.stderr)
        return 2
    try:
        check_output_folder(out)  # before the vessel is loaded or anything written
    except OutputFolderError as exc:
        print(f"seafmu: error: {exc}", file=sys.stderr)
        return 2
    try:
        res = run_testplan(vessel, out, hardware=args.hardware, mode="fmu" if args.fmu else "inprocess",
                           seed=args.seed, scale=args.scale, axes=axes)
    except (TestplanError, VesselFileError, SimulationError, ScenarioError, ValueError, OSError,
            OutputFolderError) as exc:
        print(f"seafmu: error: testplan {vessel}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(f"testplan {vessel}: {len(res.plans)} trials in {res.wall:.1f} s")
    for name, row in res.identified.items():
        err = relative_error(row)
        diff = f"{100 * err:.2f} %" if err != float("inf") else f"abs {row['value']:.3g}"
        print(f"  {name:<10} {row['value']:>14.6g}   file {row['file']:>14.6g}   ({diff})")
    print(f"report: {out / 'report.md'}; vessel file: {res.vessel_file or res.not_written}")
    return 0 if res.vessel_file else 1


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m seafmu.testplan.cli``) until ``seafmu testplan`` is wired."""
    from seafmu.cli import Parser  # seafmu's one-line argument errors

    parser = Parser(prog="seafmu")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    return run(parser.parse_args(["testplan", *(argv if argv is not None else sys.argv[1:])]))


if __name__ == "__main__":
    raise SystemExit(main())
