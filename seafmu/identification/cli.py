"""The `seafmu identify` and `seafmu diagnose` subcommands (registered by seafmu.cli).

Each prints a short readable summary (or, with --json, only the JSON document on stdout) and
writes the figures and a Markdown report into the output folder. A bad trial ends with one line
on stderr and exit code 2, like every other seafmu command.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from seafmu.identification.trial import (
    BASELINES,
    Trial,
    TrialError,
    check_vessel,
    csv_trial,
    load_trial,
)
from seafmu.outdir import OutputFolderError, claim_output_folder, nonempty_path

if TYPE_CHECKING:  # the fitting stack (scipy) loads only when a command runs
    from seafmu.identification.fitting import FitResult


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `identify` and `diagnose` to the seafmu command line."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("trial", help="trial YAML (see docs/identification.md), or a maneuver CSV such as "
                                      "a `seafmu run` results.csv")
    common.add_argument("-o", "--output", type=nonempty_path,
                        help="output folder (default: results/<trial name>)")
    common.add_argument("--vessel", type=_nonempty,
                        help="vessel name or file (maneuver CSV, write-back); overrides the trial")
    common.add_argument("--baseline", type=_nonempty,
                        help="override the trial's baseline model (e.g. linear_quadratic)")
    common.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    common.add_argument("--write-vessel", metavar="OUT_YAML", type=nonempty_path,
                        help="write the identified parameters into a copy of the vessel file")
    i = subparsers.add_parser("identify", parents=[common],
                              help="fit a measured trial's baseline model (parameters, CIs, NRMSE, AIC)")
    i.set_defaults(fn=cmd_identify)
    d = subparsers.add_parser("diagnose", parents=[common],
                              help="find what the baseline model gets wrong, name the effect, "
                                   "measure the gain")
    d.add_argument("--effects", type=_effects,
                   help="comma-separated subset of the effect catalogue (default: all)")
    d.set_defaults(fn=cmd_diagnose)


def _nonempty(text: str) -> str:
    """An argparse type: an empty --vessel or --baseline would silently mean 'not given'."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty; give a name or leave the flag out")
    return text


def _effects(text: str) -> str:
    """An argparse type: an empty --effects list would silently mean every effect."""
    if not any(e.strip() for e in text.split(",")):
        raise argparse.ArgumentTypeError("empty list; name at least one effect or leave the flag out")
    return text


def load(args: argparse.Namespace) -> Trial:
    """The trial named on the command line, with the --vessel and --baseline overrides applied.

    Checked before any fit: the --write-vessel folder exists (it is never created), and a vessel
    named for a 1-2 DOF trial has the trial's DOF and a plausible mass (a maneuver log is checked
    against its vessel column by column when it is read).
    """
    path = Path(args.trial)
    if args.write_vessel:
        out = Path(args.write_vessel)
        if out.parent.exists() and not out.parent.is_dir():
            raise TrialError(f"--write-vessel {out}: {out.parent} is a file, not a folder")
        if not out.parent.is_dir():
            raise TrialError(f"--write-vessel {out}: the folder {out.parent} does not exist "
                             "(it is not created)")
        if out.is_dir():
            raise TrialError(f"--write-vessel {out}: is a folder; give the vessel file to write")
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
    if args.write_vessel:
        out = Path(args.write_vessel).resolve()
        inputs = {p.resolve() for p in [path, *([trial.source] if trial.source else []), *trial.files]}
        if out in inputs:  # the measured data would be replaced by a vessel file, nothing left to refit
            raise TrialError(f"--write-vessel {args.write_vessel}: is one of the trial's own files; give "
                             "another file to write")
        if not trial.vessel:
            raise TrialError(f"--write-vessel {args.write_vessel}: the trial names no vessel to start the "
                             "file from; give --vessel")
    if args.baseline:
        key = (trial.kind, trial.table if trial.kind == "static" else None)
        allowed = BASELINES[key][1]
        if args.baseline not in allowed:
            raise TrialError(f"--baseline {args.baseline}: not one of {', '.join(allowed)} "
                             f"for a {trial.kind} trial")
        trial.baseline = args.baseline
    if trial.kind != "maneuver" and trial.vessel and (args.vessel or args.write_vessel):
        from seafmu.components.vessel_spec import load_vessel

        check_vessel(trial, load_vessel(trial.vessel))
    return trial


def json_text(doc: Any) -> str:
    """Standard JSON: a value that is not finite (a diverged fit's interval) is null, as in a run's
    summary.json; Python's json would write Infinity and NaN, which other readers refuse."""
    def clean(x: Any) -> Any:
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, list):
            return [clean(v) for v in x]
        return x

    from seafmu.identification import report as rp

    plain = json.loads(json.dumps(doc, default=rp._jsonable))
    return json.dumps(clean(plain), indent=2, allow_nan=False)


def one_line(msg: str) -> str:
    """A multi-line error (one problem per line, each naming the file) as one line: the file
    named once, the problems joined by '; '."""
    lines = [ln.strip() for ln in msg.splitlines() if ln.strip()]
    if len(lines) <= 1:
        return lines[0] if lines else msg
    first = lines[0]
    head = first[: first.index(": ") + 2] if ": " in first else ""
    rest = [ln[len(head):] if head and ln.startswith(head) else ln for ln in lines[1:]]
    return "; ".join([first, *rest])


def _vessel_from_summary(csv_path: Path) -> str | None:
    """The vessel of the run that wrote the log, from the summary.json beside it; None when there is
    none. A summary.json that is there but unusable is an error naming it: passing over it would
    blame a missing file, or a later error would name no file at all."""
    from seafmu.components.names import did_you_mean
    from seafmu.components.vessel_spec import bundled_vessels, vessel_path
    from seafmu.identification.trial import echo_cell, read_text

    summary = csv_path.parent / "summary.json"
    if not summary.exists():
        return None
    try:
        doc = json.loads(read_text(summary, "summary"))
    except json.JSONDecodeError as exc:
        raise TrialError(f"{summary}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno}); "
                         "fix it or give --vessel") from None
    if not isinstance(doc, dict) or "vessel" not in doc:
        what = "has no 'vessel' field" if isinstance(doc, dict) else \
            f"expected a JSON object with a 'vessel' field, got a {type(doc).__name__}"
        raise TrialError(f"{summary}: {what}; give --vessel")
    vessel = doc["vessel"]
    if not isinstance(vessel, str) or not vessel.strip():
        shown = json.dumps(vessel)  # as written in the file: 3, "", null
        shown = shown if len(shown) <= 24 else shown[:21] + "..."
        raise TrialError(f"{summary}: vessel: expected a vessel name, got {shown}; give --vessel")
    if not vessel_path(vessel).is_file():
        bundled = bundled_vessels()
        raise TrialError(f"{summary}: vessel: no such vessel {echo_cell(vessel)}"
                         f"{did_you_mean(vessel, bundled)} (bundled: {', '.join(bundled)}); give --vessel")
    return vessel


def _out(args: argparse.Namespace, trial: Trial) -> Path:
    return Path(args.output) if args.output else Path("results") / trial.name


def cmd_identify(args: argparse.Namespace) -> int:
    """`seafmu identify`: the baseline fit (and, for maneuvers, the other method beside it)."""
    return _run(args, diagnose=False)


def cmd_diagnose(args: argparse.Namespace) -> int:
    """`seafmu diagnose`: baseline, every applicable catalogue effect, the acceptance rule."""
    return _run(args, diagnose=True)


def _run(args: argparse.Namespace, diagnose: bool) -> int:
    """Shared body of both commands: load, fit, report, optional write-back and replay, print."""
    from seafmu.components.vessel_spec import VesselFileError
    from seafmu.identification import diagnosis as dg
    from seafmu.identification import report as rp

    try:
        trial = load(args)
        if diagnose:
            effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
            result: dg.Identification | dg.Diagnosis = dg.diagnose(trial, effects)
        else:
            result = dg.identify(trial)
    except (TrialError, VesselFileError) as exc:
        print(f"seafmu: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # the data defeated the fit
        print(f"seafmu: error: {args.trial}: cannot be fitted ({type(exc).__name__}: "
              f"{one_line(str(exc))[:200]})", file=sys.stderr)
        return 2
    out = _out(args, trial)
    try:  # checked after the fit, whose errors name the data; created and marked before any write
        claim_output_folder(out)
    except OutputFolderError as exc:
        print(f"seafmu: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    if isinstance(result, dg.Diagnosis):
        report = rp.write_diagnosis_report(result, out)
        fit = result.extended
        method = f"{fit.method}, baseline {rp._baseline_name(trial, result.baseline)}" + (
            f" extended by {result.effect} (seafmu diagnose)" if result.cause
            else f" (seafmu diagnose: {result.effect})")
    else:
        report = rp.write_identify_report(result, out)
        fit = result.fit
        method = f"{fit.method}, baseline {trial.baseline} (seafmu identify)"
    doc = result.to_json()
    lines = rp.summary_lines(result)
    if args.write_vessel:
        closing = close_loop(trial, fit, Path(args.write_vessel), method, args.vessel)
        doc.update(closing["json"])
        lines += closing["lines"]
        with open(report, "a") as fh:
            fh.write("\n## Close the loop\n\n" + "".join(f"- {ln}\n" for ln in closing["lines"]))
    name = "diagnosis.json" if diagnose else "identification.json"
    text = json_text(doc)
    (out / name).write_text(text + "\n")
    if args.json:
        print(text)
        print(f"report: {report}", file=sys.stderr)
    else:
        print("\n".join(lines))
        print(f"report: {report}")
    return 0


def close_loop(trial: Trial, fit: FitResult, out_path: Path, method: str,
               vessel: str | None) -> dict[str, Any]:
    """Write the vessel file, then replay the trial through the plant with the old and the new file.

    Returns {"json": keys for the JSON document, "lines": lines for the summary and the report}.
    """
    from seafmu.identification.replay import Replay, replay
    from seafmu.identification.writeback import write_vessel_file

    msg, path = write_vessel_file(trial, fit, out_path, method, vessel)
    doc: dict[str, Any] = {"write_back": msg}
    lines = [msg]
    old = vessel or trial.vessel
    if path is None or old is None:
        return {"json": doc, "lines": lines}
    try:
        rep = replay(trial, fit, old, path)
    except (TrialError, ValueError, np.linalg.LinAlgError) as exc:
        rep = f"replay failed: {exc}"
    if isinstance(rep, Replay):
        doc["replay"] = rep.to_json()
        lines.append(rep.line(f"'{old}'", str(path)))
        if rep.ratio < 1.0:
            lines.append(_worse_note(fit, rep))
    else:
        doc["replay"] = {"skipped": rep}
        lines.append(rep if rep.startswith("replay failed") else f"replay skipped: {rep}")
    return {"json": doc, "lines": lines}


def _worse_note(fit: FitResult, rep: Any) -> str:
    """Why a written file can replay worse: what the fit holds that a scenario sets, not a vessel file
    (a lost thruster's efficiency, a current, a steady force), is not in it, and the damping fitted
    beside it does not stand alone."""
    # a lost thruster's efficiency, a current, a steady force: what a scenario sets, no vessel file
    other = [f"{k} = {v:.4g}" for k, v in fit.params.items() if re.match(r"^(eta_T\[|v_c_|F_0\[)", k)]
    why = (f"; the fit's {', '.join(other[:4])}{', ...' if len(other) > 4 else ''} are no vessel-file "
           "properties and are not in it, and the damping fitted beside them does not stand alone (a "
           "scenario sets them: e.g. plant.thruster_efficiency_i, plant.current_speed)" if other else "")
    return (f"warning: the written file replays this trial worse than the one it started from (gain "
            f"{rep.ratio:.3g}x){why}")


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (python -m seafmu.identification.cli ...) until seafmu.cli registers us."""
    from seafmu.cli import Parser  # seafmu's one-line argument errors

    parser = Parser(prog="seafmu", description="identification and diagnosis")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    from seafmu.components.vessel_spec import VesselFileError

    try:
        return int(args.fn(args))
    except (VesselFileError, OSError, TrialError) as exc:
        print(f"seafmu: error: {one_line(str(exc))}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
