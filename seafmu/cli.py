"""The ``seafmu`` command: build, check, run, sweep and export scenarios.

Exit codes: 0 the run ended and its checks pass; 1 a check fails; 2 bad input or a failure (bad
scenario, FMU error, missing file, output folder in use by another run), one line on stderr;
128 + the signal number when SIGINT, SIGTERM or SIGHUP stopped ``seafmu run`` (130, 143, 129):
the run stops between two master steps, writes its results up to there and reports
"interrupted at t = ... s" on one line.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from seafmu.outdir import nonempty_path, os_error_text

if TYPE_CHECKING:
    from seafmu.master import RunResult, StopRequest
    from seafmu.plots import Plotter
    from seafmu.scenario import Scenario

# The errors that end a command with one line (exit 2): (module, class). Looked up among the
# modules this command imported (_user_errors), so naming them costs no import.
USER_ERRORS = (
    ("seafmu.scenario", "ScenarioError"),
    ("seafmu.master", "SimulationError"),
    ("seafmu.components.vessel_spec", "VesselFileError"),
    ("seafmu.identification.trial", "TrialError"),
    ("seafmu.outdir", "OutputFolderError"),
    ("seafmu.export", "ExportError"),
    ("seafmu.sweep.study", "StudyError"),
    ("seafmu.hardware.profile", "ProfileError"),
    ("seafmu.hardware.link", "HardwareError"),
)


def one_line(text: str) -> str:
    """A message as one printable line: line breaks, control characters (a scenario's own text may
    hold any) shown escaped, so neither the line count nor the terminal changes."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


class Parser(argparse.ArgumentParser):
    """argparse with seafmu's one-line errors: ``seafmu: error: run --seed: invalid int value: 'abc'``
    and exit 2, not a usage dump. The subcommands' parsers are made by ``add_parser`` of the main
    one, so they are of this class too (sweep, identify, emulate included)."""

    command: str | None = None  # the main parser's own errors (unrecognised arguments) name it

    def error(self, message: str) -> NoReturn:
        where = " ".join(self.prog.split()[1:]) or self.command or ""
        named = re.fullmatch(r"argument (\S+): (.*)", message, re.DOTALL)
        if named:  # 'run --seed: ...': the subcommand and its flag, as the user typed them
            where, message = f"{where} {named[1]}".strip(), named[2]
        elif not where and message == "the following arguments are required: command":
            message = f"no command given; one of {', '.join(all_commands())}"
        self.exit(2, f"seafmu: error: {one_line(f'{where}: {message}' if where else message)}\n")


def _cmd_build(args: argparse.Namespace) -> int:
    from seafmu.build import VESSELS, build_all

    vessels = tuple(args.vessel) if args.vessel else VESSELS
    unknown = [v for v in vessels if v not in VESSELS]  # a name, never a path: it names the build files
    if unknown:
        from seafmu.components.names import did_you_mean

        print(f"seafmu: error: --vessel {one_line(unknown[0])}: not a vessel with FMUs"
              f"{did_you_mean(unknown[0], VESSELS)} (vessels: {', '.join(VESSELS)})", file=sys.stderr)
        return 2
    if args.link:
        from seafmu.hardware.profile import load_profile

        for profile in args.link:  # a profile that does not load stops the build before it starts
            load_profile(profile)
    for r in build_all(vessels, force=args.force):
        print(f"{'built  ' if r.rebuilt else 'current'} {r.path}")
    for profile in args.link or []:
        from seafmu.build import build_dir
        from seafmu.hardware.link_fmu import build_link_fmu
        from seafmu.unitdefs import base_unit

        print(f"built   {build_link_fmu(profile, build_dir(), base_unit=base_unit)}")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from seafmu.scenario import load_scenario

    sc = load_scenario(args.scenario)
    print(f"{sc.source}: OK — vessel {sc.vessel}, {len(sc.instances)} FMUs, "
          f"{len(sc.connections)} connections, {len(sc.events)} events, {len(sc.checks)} checks, "
          f"{sc.n_steps} steps, {sc.n_samples} samples x {len(sc.outputs)} signals "
          f"({sc.result_bytes / 1e6:.3g} MB of results in memory)")
    return 0


def _build_kinds(sc: Scenario) -> None:
    """Build the scenario's seafmu FMUs whose sources changed (as ``run`` does), saying which."""
    from seafmu.build import build_fmu

    for inst in sc.instances:
        if inst.kind is not None:
            r = build_fmu(sc.vessel, inst.kind)
            if r.rebuilt:
                print(f"built {r.path}")


def _cmd_export(args: argparse.Namespace) -> int:
    from seafmu.export import (
        Export,
        ExportError,
        check_exportable,
        check_osp_target,
        check_ssp_target,
        export_osp,
        export_ssp,
    )
    from seafmu.scenario import load_scenario

    if not args.ssp and not args.osp:
        raise ExportError("nothing to write: give --ssp FILE.ssp and/or --osp DIR")
    sc = load_scenario(args.scenario)
    check_exportable(sc)  # every input checked before anything is built or written
    if args.ssp:
        check_ssp_target(Path(args.ssp))
    if args.osp:
        check_osp_target(Path(args.osp))
    _build_kinds(sc)
    done = []
    if args.ssp:
        done.append(export_ssp(sc, Path(args.ssp)))
    if args.osp:
        done.append(export_osp(sc, Path(args.osp)))
    result = Export.merged(done)
    for f in result.files:
        print(f"wrote {f}")
    print(one_line(result.summary()))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from seafmu.master import StopRequest, stop_on_signals
    from seafmu.plots import Plotter

    stop = StopRequest()
    # The figures' worker starts first: it imports matplotlib while the scenario loads and runs.
    with Plotter() as plotter, stop_on_signals(stop):  # from here on, SIGINT/SIGTERM/SIGHUP only
        return _run(args, stop, plotter)                # ask the run to stop


def _run(args: argparse.Namespace, stop: StopRequest, plotter: Plotter | None = None) -> int:
    from seafmu.master import SimulationError, run
    from seafmu.outdir import RunFolder
    from seafmu.report import write_failure_report, write_placeholder_report, write_report
    from seafmu.results import CsvStream, evaluate_checks, summary, write_summary
    from seafmu.scenario import load_scenario, parse_override

    overrides = [parse_override(s) for s in args.set or []]
    sc = load_scenario(args.scenario, overrides, args.seed)
    if args.coupling:
        sc = dataclasses.replace(sc, coupling=args.coupling)
    if stop.requested:
        print(f"seafmu: interrupted ({stop.name}) before the run started; nothing written", file=sys.stderr)
        return stop.exit_code
    out = Path(args.output) if args.output else Path("results") / sc.name
    mode = "inprocess" if args.inprocess else "fmu"
    error = ""
    result: RunResult | None = None
    with RunFolder(out):  # locked for this run, the previous run's outputs removed
        write_placeholder_report(sc.name, out)
        try:
            if mode == "fmu":
                _build_kinds(sc)
            record = out / "recording" if any(i.hardware for i in sc.instances) else None
            csv = CsvStream(out / "results.csv")
            try:
                result = run(sc, mode=mode, progress=not args.quiet and not sc.realtime, record_dir=record,
                             stop=stop, sink=csv)
            except SimulationError as exc:  # failed mid-run: the results up to there are reported
                if exc.partial is None:
                    raise
                result, error = exc.partial, str(exc)
            finally:
                try:
                    csv.close()
                except OSError as exc:  # its last flush names no file
                    exc.filename = exc.filename or str(csv.path)
                    raise
        except Exception as exc:
            if result is None:  # nothing recorded: the report says why, then the usual one line
                write_failure_report(sc.name, out, " ".join(_describe(exc).split()))
                raise
            # steps ran, but results.csv could not be completed (a full disk): the results in
            # memory still make the summary and the report, which say so
            error = error or " ".join(_describe(exc).split())
            result.error = result.error or error
        checks = evaluate_checks(result)
        data = summary(result, checks)
        write_summary(data, out / "summary.json")
        if args.format == "parquet":
            from seafmu.results import write_parquet

            write_parquet(result, out / "results.parquet")
        # last: a report means every file (figures included) is complete
        report = write_report(result, checks, data, out, plotter)
    print(f"{sc.name}: {result.t_end:g} s simulated in {result.wall_time:.2f} s "
          f"(real-time factor {result.realtime_factor:.0f}, mode {mode}, {sc.coupling} coupling)")
    for name, us in data["us_per_step"].items():
        print(f"  {name:<12} {us:8.1f} µs/step")
    if result.pacing_summary:
        print(f"  pacing: {result.pacing_summary}")
    for c in checks:
        shown = f"{c.note}" if c.note else f"{c.value:.4g}"
        print(f"  [{'PASS' if c.passed else 'FAIL'}] {c.name}: {shown} ({c.bound})")
    print(f"report: {report}")
    if error:
        print(f"seafmu: error: {one_line(error)} (results up to t = {result.t_end:g} s in {out})",
              file=sys.stderr)
        return 2
    if stop.requested:
        where = (f"interrupted at t = {result.t_end:g} s of {sc.duration:g} s" if result.interrupted
                 else f"interrupted at t = {result.t_end:g} s, the end of the run")
        print(f"seafmu: {where} ({stop.name}); results up to there in {out}", file=sys.stderr)
        return stop.exit_code
    return 0 if data["checks_passed"] else 1


def _add_build(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("build", help="build the FMUs (only those whose sources changed)")
    b.add_argument("--vessel", action="append", help="only this vessel (repeatable)")
    b.add_argument("--force", action="store_true", help="rebuild even if up to date")
    b.add_argument("--link", action="append", metavar="PROFILE",
                   help="also build the hardware link of this profile as an FMU (for other FMI tools)")
    b.set_defaults(fn=_cmd_build)


def _add_check(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("check", help="validate a scenario without running it")
    c.add_argument("scenario")
    c.set_defaults(fn=_cmd_check)


def _add_run(sub: argparse._SubParsersAction) -> None:
    from seafmu.scenario import COUPLINGS, DEFAULT_SCENARIO

    r = sub.add_parser("run", help=f"run a scenario (default: {DEFAULT_SCENARIO})")
    r.add_argument("scenario", nargs="?", default=None)
    r.add_argument("-o", "--output", type=nonempty_path, help="output folder (default: results/<scenario>)")
    r.add_argument("--inprocess", action="store_true", help="run the components without FMI (comparison)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--coupling", choices=COUPLINGS,
                   help="override the scenario's coupling: gauss-seidel (each FMU reads the newest "
                   "outputs) or jacobi (every FMU steps with the outputs of the previous step, as libcosim "
                   "and ecos do)")
    r.add_argument("--set", action="append", metavar="INST.VAR=VALUE",
                   help="override a parameter as the scenario file would set it (units, ranges checked), "
                   "e.g. plant.current_speed=0.2m/s; INST.VAR@TIME=VALUE adds an event; repeatable")
    r.add_argument("--seed", type=int, help="seed of every random source of the scenario (sensor noise, "
                   "waves, current): every parameter named seed")
    r.add_argument("--format", choices=("csv", "parquet"), default="csv",
                   help="parquet: also write results.parquet beside results.csv")
    r.set_defaults(fn=_cmd_run)


def _add_export(sub: argparse._SubParsersAction) -> None:
    x = sub.add_parser("export", help="write a scenario for other engines: SSP 1.0 file and/or OSP folder")
    x.add_argument("scenario")
    x.add_argument("--ssp", metavar="FILE.ssp", type=nonempty_path,
                   help="write an SSP 1.0 archive (FMUs, connections, parameters)")
    x.add_argument("--osp", metavar="DIR", type=nonempty_path,
                   help="write OspSystemStructure.xml and the FMUs into DIR")
    x.set_defaults(fn=_cmd_export)


def _add_sweep(sub: argparse._SubParsersAction) -> None:
    from seafmu.sweep.forkserver import single_threaded_blas

    single_threaded_blas()  # before seafmu.sweep.cli imports numpy
    from seafmu.sweep.cli import register

    register(sub)


def _add_identification(sub: argparse._SubParsersAction) -> None:
    from seafmu.identification.cli import register

    register(sub)


def _add_emulate(sub: argparse._SubParsersAction) -> None:
    from seafmu.emulate import plant_set_values, scenario_plant_parameters
    from seafmu.hardware.cli import register
    from seafmu.hardware.emulator import ScenarioReader

    register(sub, reader=ScenarioReader(scenario_plant_parameters, plant_set_values))


def _add_testplan(sub: argparse._SubParsersAction) -> None:
    from seafmu.testplan.cli import add_parser, run

    add_parser(sub).set_defaults(fn=run)


# Every subcommand, in the order --help lists them: (the names one function adds, the function).
# A command line naming one registers that one only, so `seafmu run` imports no emulator, sweep
# or identification code (up to a second of imports; tests/test_startup.py).
COMMANDS: tuple[tuple[tuple[str, ...], Callable[[argparse._SubParsersAction], None]], ...] = (
    (("build",), _add_build),
    (("check",), _add_check),
    (("run",), _add_run),
    (("sweep",), _add_sweep),
    (("export",), _add_export),
    (("identify", "diagnose"), _add_identification),
    (("emulate",), _add_emulate),
    (("testplan",), _add_testplan),
)


def all_commands() -> tuple[str, ...]:
    return tuple(name for names, _ in COMMANDS for name in names)


def build_parser(command: str | None = None) -> Parser:
    """The parser of ``seafmu``: given the subcommand a command line names, with that subcommand
    only; ``None`` (help, an unknown or missing command), with every one, so --help and the
    invalid-choice message list them all. Either way the output for the same command line is the
    same."""
    known = command in all_commands()
    parser = Parser(prog="seafmu", description="Marine GNC co-simulation with FMI 2.0 FMUs")
    parser.command = command if known else None
    # Given one command, the usage line (of an unrecognised-argument error) still lists them all.
    every = "{" + ",".join(all_commands()) + "}" if known else None
    sub = parser.add_subparsers(dest="command", required=True, metavar=every)
    for names, add in COMMANDS:
        if not known or command in names:
            add(sub)
    return parser


def _user_errors() -> tuple[type[BaseException], ...]:
    """The one-line errors (USER_ERRORS) whose modules are loaded: an error class of a module
    this command never imported cannot have been raised."""
    found: list[type[BaseException]] = [OSError]
    for module, name in USER_ERRORS:
        cls = getattr(sys.modules.get(module), name, None)
        if cls is not None:
            found.append(cls)
    return tuple(found)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = argv[0] if argv and not argv[0].startswith("-") else None
    try:
        args = build_parser(command).parse_args(argv)  # inside: a Ctrl-C while it imports is one line too
        return args.fn(args)
    except KeyboardInterrupt:
        print("seafmu: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if not isinstance(exc, _user_errors()):
            raise
        print(f"seafmu: error: {one_line(_describe(exc))}", file=sys.stderr)
        return 2


def _describe(exc: BaseException) -> str:
    """An OSError as '<file>: <what is wrong>' (its str is '[Errno 17] File exists: '<file>''),
    the format of every other error."""
    return os_error_text(exc) if isinstance(exc, OSError) else str(exc)


if __name__ == "__main__":
    sys.exit(main())
