"""The `seafmu identify` and `seafmu diagnose` subcommands (registered by seafmu.cli).

Each prints a short readable summary (or, with --json, only the JSON document on stdout) and
writes the figures and a Markdown report into the output folder. A bad trial ends with one line
on stderr and exit code 2, like every other seafmu command.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from seafmu.identification.trial import BASELINES, Trial, TrialError, csv_trial, load_trial


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `identify` and `diagnose` to the seafmu command line."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("trial", help="trial YAML (see docs/identification.md), or a maneuver CSV such as "
                                      "a `seafmu run` results.csv")
    common.add_argument("-o", "--output", help="output folder (default: results/<trial name>)")
    common.add_argument("--vessel",
                        help="vessel name or file (maneuver CSV, write-back); overrides the trial")
    common.add_argument("--baseline", help="override the trial's baseline model (e.g. linear_quadratic)")
    common.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    common.add_argument("--write-vessel", metavar="OUT_YAML",
                        help="write the identified parameters into a copy of the vessel file")
    i = subparsers.add_parser("identify", parents=[common],
                              help="fit a measured trial's baseline model (parameters, CIs, NRMSE, AIC)")
    i.set_defaults(fn=cmd_identify)
    d = subparsers.add_parser("diagnose", parents=[common],
                              help="find what the baseline model gets wrong, name the effect, "
                                   "measure the gain")
    d.add_argument("--effects", help="comma-separated subset of the effect catalogue (default: all)")
    d.set_defaults(fn=cmd_diagnose)


def load(args: argparse.Namespace) -> Trial:
    """The trial named on the command line, with the --vessel and --baseline overrides applied."""
    path = Path(args.trial)
    if path.suffix.lower() == ".csv":
        vessel = args.vessel or _vessel_from_summary(path)
        if not vessel:
            raise TrialError(f"{path}: a bare CSV is read as a maneuver log and needs --vessel "
                             f"(or a summary.json next to it, as `seafmu run` writes)")
        trial = csv_trial(path, vessel)
    else:
        trial = load_trial(path)
    if args.vessel:
        trial.vessel = args.vessel
    if args.baseline:
        key = (trial.kind, trial.table if trial.kind == "static" else None)
        allowed = BASELINES[key][1]
        if args.baseline not in allowed:
            raise TrialError(f"--baseline {args.baseline}: not one of {', '.join(allowed)} "
                             f"for a {trial.kind} trial")
        trial.baseline = args.baseline
    return trial


def _vessel_from_summary(csv_path: Path) -> str | None:
    summary = csv_path.parent / "summary.json"
    try:
        return str(json.loads(summary.read_text())["vessel"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _out(args: argparse.Namespace, trial: Trial) -> Path:
    return Path(args.output) if args.output else Path("results") / trial.name


def cmd_identify(args: argparse.Namespace) -> int:
    from seafmu.identification.diagnosis import identify, write_vessel
    from seafmu.identification.report import _jsonable, summary_lines, write_identify_report

    try:
        trial = load(args)
        ident = identify(trial)
    except TrialError as exc:
        print(f"seafmu: error: {exc}", file=sys.stderr)
        return 2
    out = _out(args, trial)
    report = write_identify_report(ident, out)
    doc = ident.to_json()
    (out / "identification.json").write_text(json.dumps(doc, indent=2, default=_jsonable) + "\n")
    msg = None
    if args.write_vessel:
        method = f"{ident.fit.method}, baseline {trial.baseline} (seafmu identify)"
        msg = write_vessel(trial, ident.fit, Path(args.write_vessel), method, args.vessel)
    if args.json:
        if msg:
            doc["write_back"] = msg
        print(json.dumps(doc, indent=2, default=_jsonable))
        print(f"report: {report}", file=sys.stderr)
    else:
        print("\n".join(summary_lines(ident)))
        if msg:
            print(msg)
        print(f"report: {report}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from seafmu.identification.diagnosis import diagnose, write_vessel
    from seafmu.identification.report import _jsonable, summary_lines, write_diagnosis_report

    try:
        trial = load(args)
        effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
        diag = diagnose(trial, effects)
    except TrialError as exc:
        print(f"seafmu: error: {exc}", file=sys.stderr)
        return 2
    out = _out(args, trial)
    report = write_diagnosis_report(diag, out)
    doc = diag.to_json()
    (out / "diagnosis.json").write_text(json.dumps(doc, indent=2, default=_jsonable) + "\n")
    msg = None
    if args.write_vessel:
        method = f"{diag.extended.method}, baseline {trial.baseline}" + (
            f" extended by {diag.effect} (seafmu diagnose)" if diag.cause
            else " (seafmu diagnose: no effect found)")
        msg = write_vessel(trial, diag.extended, Path(args.write_vessel), method, args.vessel)
    if args.json:
        if msg:
            doc["write_back"] = msg
        print(json.dumps(doc, indent=2, default=_jsonable))
        print(f"report: {report}", file=sys.stderr)
    else:
        print("\n".join(summary_lines(diag)))
        if msg:
            print(msg)
        print(f"report: {report}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (python -m seafmu.identification.cli ...) until seafmu.cli registers us."""
    parser = argparse.ArgumentParser(prog="seafmu", description="identification and diagnosis")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    from components.vessel_spec import VesselFileError

    try:
        return int(args.fn(args))
    except (VesselFileError, OSError) as exc:
        print(f"seafmu: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
