"""``seafmu sweep STUDY.yaml``: validate every case, run them on Dask, write cases.parquet and the report.

Exit codes as ``seafmu run``: 0 every case ran and passed its checks, 1 every case ran and some
failed a check or could not run (each recorded with its one-line error), 2 bad input (the study
file, a case that does not validate, a scheduler that cannot be reached), 128 + the signal number
when SIGINT, SIGTERM or SIGHUP stopped the study (finished cases kept; a rerun continues).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import os
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from seafmu.sweep import forkserver

if TYPE_CHECKING:
    from seafmu.sweep.study import Study

# What validates the study (numpy, pydantic, seafmu.scenario: ~0.15 s) is imported in the functions
# that use it, so the fork server can start before it (``_early_server``).


def register(sub: Any) -> None:
    s = sub.add_parser("sweep", help="run a study (grid, Monte Carlo) over a scenario on Dask")
    s.add_argument("study", help="study file (studies/<name>/study.yaml, or a path)")
    s.add_argument("--dry-run", action="store_true",
                   help="validate every case and print the case table; run nothing")
    s.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the local cluster (default: the cores available)")
    s.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler (tcp://HOST:8786); default DASK_SCHEDULER_ADDRESS, "
                   "else a local cluster")
    s.add_argument("--out", metavar="DIR", help="study folder (default: results/sweeps/<study name>)")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.set_defaults(fn=cmd_sweep)


def study_path(arg: str) -> Path:
    """A path, or the name of a shipped study (studies/<name>/study.yaml)."""
    p = Path(arg)
    if p.is_file():
        return p
    from seafmu.components.names import did_you_mean
    from seafmu.scenario import REPO
    from seafmu.sweep.study import StudyError

    shipped = REPO / "studies" / arg / "study.yaml"
    if not p.suffix and shipped.is_file():
        return shipped
    names = sorted(q.parent.name for q in (REPO / "studies").glob("*/study.yaml"))
    raise StudyError(f"study '{arg}': no such file or shipped study{did_you_mean(arg, names)} "
                     f"(shipped: {', '.join(names)})")


def _case_table(study: Study, done: dict[int, dict[str, Any]]) -> list[str]:
    names = list(study.inputs)
    head = ["case", "seed", *names, "status"]
    rows = []
    for c in study.cases:
        vals = [f"{c.inputs[n]:.6g}" if isinstance(c.inputs[n], float) else str(c.inputs[n]) for n in names]
        rows.append([str(c.index), "" if c.seed is None else str(c.seed), *vals,
                     done[c.index]["status"] if c.index in done else "to run"])
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return [fmt.format(*head), *(fmt.format(*r) for r in rows)]


def _early_server(args: argparse.Namespace) -> None:
    """Start the local cluster's fork server (``seafmu.sweep.forkserver``) first thing, warming up on
    the base scenario as the study file names it (its YAML read, not validated): its warm-up is the
    critical path of the first case, and the ~0.15 s of imports that validate the study then run
    beside it. Only where the study file names a scenario file (a path, relative to the study's
    folder) and a local cluster will run it; otherwise (a shipped scenario's name, a file that does
    not read, --dry-run, --scheduler or DASK_SCHEDULER_ADDRESS, as ``execute.scheduler_address``,
    not imported yet) the server starts with the cluster, after the study is read. A file this reads
    wrongly costs time, never correctness: the server warmed up on another scenario, and a worker
    then loads the study's FMUs itself."""
    if args.dry_run or args.scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS"):
        return
    from seafmu.yamlfile import read_mapping

    try:
        study = study_path(args.study)
        base = Path(read_mapping(study, "study", ValueError)["scenario"])
    except Exception:  # the study's validation reports whatever is wrong, in one line
        return
    base = base if base.is_absolute() else study.parent / base
    if base.suffix in (".yaml", ".yml") and base.is_file():
        forkserver.start(base.resolve())


def _build(study: Study) -> bool:
    """Build the base scenario's FMUs if their sources changed (the workers only read them); True if
    any was rebuilt."""
    from seafmu.build import build_fmu

    sc = study.base_scenario()
    rebuilt = False
    for inst in sc.instances:
        if inst.kind is not None and build_fmu(sc.vessel, inst.kind).rebuilt:
            print(f"built {sc.vessel} {inst.kind}")
            rebuilt = True
    return rebuilt


def _prepare(study: Study, out: Path, workers: int | None, scheduler: str | None) -> Any:
    """Validate every case, with the local cluster (returned; None if there is nothing to run or the
    study runs on an existing scheduler) started first, so that its fork server imports and warms
    up (~0.8 s of CPU, the start's critical path) while the cases are validated (it may be running
    already: ``_early_server``). A case that does not validate closes it; an FMU rebuilt meanwhile
    restarts it and its server (they loaded the old one)."""
    from seafmu.cores import core_count
    from seafmu.sweep.execute import StudyFolder, scheduler_address, start_local_cluster
    from seafmu.sweep.study import validate_cases

    done = StudyFolder(out).finished(study) if out.is_dir() else {}
    n = min(workers or core_count(), len(study.cases) - len(done))
    local = n > 0 and scheduler_address(scheduler) is None
    cluster = start_local_cluster(n, study.scenario_file) if local else None
    try:
        validate_cases(study, study.cases[:1])
        if _build(study) and cluster is not None:  # the server and its forks loaded the old FMUs
            cluster.close(timeout=10)
            cluster = None
            forkserver.stop()
            cluster = start_local_cluster(n, study.scenario_file)
        validate_cases(study, study.cases[1:])
    except BaseException:
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        raise
    return cluster


def _check_folder_study(out: Path, study: Study) -> None:
    """A study folder holds one study (changed or not: a rerun redoes only the cases that changed);
    another study's name there would have its cases.parquet and report replaced by this one's."""
    from seafmu.sweep.study import StudyError
    from seafmu.yamlfile import read_mapping

    try:
        held = read_mapping(out / "study.yaml", "study", ValueError).get("name")
    except (OSError, ValueError):  # none there, or not ours to judge: the folder is used as it is
        return
    if isinstance(held, str) and held != study.name:
        raise StudyError(f"{out}: holds the results of study '{held}', not '{study.name}'; give another "
                         "--out (or remove that folder)")


def cmd_sweep(args: argparse.Namespace) -> int:
    if args.workers is not None and args.workers < 1:
        from seafmu.sweep.study import StudyError

        raise StudyError(f"--workers {args.workers}: must be at least 1")
    # The server is stopped with the cluster (``_sweep``); after a bad study it ends by itself once
    # its warm-up is over and it finds this process gone.
    _early_server(args)
    return _sweep(args)


def _sweep(args: argparse.Namespace) -> int:
    from seafmu.master import StopRequest, stop_on_signals
    from seafmu.outdir import check_output_folder
    from seafmu.sweep.execute import StudyFolder, run_study, write_cases
    from seafmu.sweep.report import write_study_report
    from seafmu.sweep.study import load_study, validate_cases
    from seafmu.sweep.warm import collector_paused

    study = load_study(study_path(args.study), validate=False)
    out = Path(args.out) if args.out else Path("results") / "sweeps" / study.name
    if not args.dry_run and out.resolve() != study.source.resolve().parent:
        # not a folder of the user's own files (its report.md would be replaced); the study's own
        # folder is meant for its results (a study file and its scenario beside them)
        check_output_folder(out)
    _check_folder_study(out, study)
    if args.dry_run:
        validate_cases(study)
        done = StudyFolder(out).finished(study) if out.is_dir() else {}
        for line in _case_table(study, done):
            print(line)
        print(f"{study.name}: {len(study.cases)} cases, all valid; {len(study.cases) - len(done)} to run"
              f"{f' ({len(done)} finished in {out})' if done else ''}")
        return 0
    stop = StopRequest()
    with stop_on_signals(stop), contextlib.ExitStack() as stack:
        with collector_paused():  # every case valid before anything runs
            cluster = _prepare(study, out, args.workers, args.scheduler)
        try:
            folder = stack.enter_context(StudyFolder(out))
            if study.source.resolve() != (out / "study.yaml").resolve():  # what was run, beside its results
                shutil.copyfile(study.source, out / "study.yaml")
        except BaseException:
            if cluster is not None:
                cluster.close(timeout=10)
            raise
        outcome = run_study(study, folder, workers=args.workers, scheduler=args.scheduler,
                            progress=not args.quiet, stop=stop, cluster=cluster)  # closes the cluster
        stack.callback(forkserver.stop)  # after the cluster is closed (callbacks run last first)
        stack.callback(outcome.close)
        with collector_paused():  # the figures' many short-lived objects; a full collection here cost 0.1 s
            cases = write_cases(study, folder, outcome.rows)
            report, worst = write_study_report(study, outcome, out)
    statuses = [r["status"] for r in outcome.rows.values()]
    n = len(statuses)
    print(f"{study.name}: {n} of {outcome.total} cases finished ({outcome.skipped} before, {outcome.ran} now"
          f"{f' on {outcome.workers} workers in {outcome.wall_time:.1f} s' if outcome.ran else ''}): "
          f"{statuses.count('pass')} pass, {statuses.count('fail')} fail a check, "
          f"{statuses.count('error')} could not run")
    for line in worst:
        print(f"  worst: {line}")
    print(f"cases: {cases}")
    print(f"report: {report}")
    # Everything is written and the cluster closed: the interpreter's final garbage collection over
    # every object of pandas, pyarrow, matplotlib, scipy and Dask would add ~0.6 s to the command for
    # nothing (the process exits); objects frozen now are left to the exit.
    gc.freeze()
    if outcome.interrupted:
        print(f"seafmu: sweep interrupted ({outcome.interrupted}); {n} of {outcome.total} cases kept in "
              f"{out}; run the same command again to finish", file=sys.stderr)
        return stop.exit_code
    return 0 if statuses.count("pass") == outcome.total else 1
