"""Bad command-line arguments (fault-injection review): each is one line ``seafmu: error: ...`` and
exit 2, found before a port is opened, READY printed or a file written; a folder of the user's own
files is never written into, while an earlier seafmu output folder is reused."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import seafmu.hardware.emulator as emulator
from seafmu.cli import main
from seafmu.outdir import LOCK_FILE, MARKER, OutputFolderError, check_output_folder

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "scenarios" / "data"
TOW = str(DATA / "amv_osf_tow_resistance.yaml")  # a static trial: identified in about a second
ROV = str(DATA / "rov_cfd_force_speed.yaml")


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``seafmu ARGV`` in this process; argparse ends by SystemExit."""
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = int(exc.code or 0)
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line(rc: int, err: str, start: str) -> None:
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, (rc, err)
    assert err.startswith(start), err


def _short_scenario(folder: Path) -> Path:
    doc = {"name": "short", "vessel": "minerva2", "duration": 0.5, "step": 0.05,
           "fmus": {k: {"kind": k} for k in ("plant", "observer", "controller", "allocator")}}
    path = folder / "short.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _user_folder(path: Path) -> dict[str, str]:
    """A folder of the user's own results, never a seafmu output folder."""
    path.mkdir()
    files = {"results.csv": "time,mine\n0,1\n", "report.md": "# my notes\n"}
    for name, text in files.items():
        (path / name).write_text(text)
    return files


# -- seafmu emulate (findings 1-4) ------------------------------------------------------------------

@pytest.fixture
def no_ports(monkeypatch: pytest.MonkeyPatch) -> None:
    """An argument that escapes the checks fails the test at once instead of opening the ports and
    waiting for a thruster command forever."""
    def opened(spec: str, bridges: list) -> tuple[str, str]:
        raise AssertionError(f"a port was opened ({spec}) for arguments that should be refused")

    monkeypatch.setattr(emulator, "_port", opened)


def _emulate(tmp_path: Path, *extra: str) -> list[str]:
    return ["emulate", "minerva2", "--serial", f"pty:{tmp_path / 'nmea'}", "--can",
            f"slcan:pty:{tmp_path / 'slcan'}", "--duration", "0.5", *extra]


@pytest.mark.parametrize(("flag", "value", "allowed"), [
    ("--step", "0", "from 0.0001 to 1 s"),
    ("--step", "1e-9", "from 0.0001 to 1 s"),
    ("--step", "100", "from 0.0001 to 1 s"),
    ("--step", "nan", "from 0.0001 to 1 s"),
    ("--step", "-0.01", "from 0.0001 to 1 s"),
    ("--status-rate", "0", "from 0.1 to 1000 per s"),
    ("--status-rate", "-5", "from 0.1 to 1000 per s"),
    ("--duration", "-1", "finite number of seconds > 0"),
    ("--duration", "nan", "finite number of seconds > 0"),
    ("--duration", "inf", "finite number of seconds > 0"),
    ("--command-timeout", "0", "finite number of seconds > 0"),
    ("--bitrate", "abc", "from 10000 to 1000000"),
    ("--bitrate", "0", "from 10000 to 1000000"),
])
def test_emulate_numbers_out_of_range_name_the_flag_and_its_range(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], no_ports: None, flag: str, value: str,
        allowed: str) -> None:
    rc, out, err = _cli(_emulate(tmp_path, flag, value), capsys)
    _one_line(rc, err, f"seafmu: error: emulate {flag}: must be ")
    assert allowed in err and err.rstrip().endswith(f"got {value}") and out == ""


@pytest.mark.parametrize(("extra", "expected"), [
    (["--status-rate", "500"], "--status-rate 500: at most one status frame per step"),
    (["--bitrate", "83000"], "--bitrate 83000: an slcan adapter takes one of"),
    (["--record", "{tmp}/nofolder/true.csv"], "nofolder does not exist"),
    (["--thruster-efficiency", "3=2"], "'thruster_efficiency_3' must be within [0, 1.5]"),
    (["--profile", "emulator_pty", "--set", "seed=-1"], "seed"),
    (["--thruster-efficiency", "9=0.5"], "'9=0.5': expected THRUSTER=FRACTION with THRUSTER a thruster "
     "number from 1 to 7"),
    (["--scenario", "amv_osf_autopilot"], "--scenario amv_osf_autopilot: a scenario of vessel 'amv_osf', not "
     "'minerva2'"),
    (["--fault", "drive-frozen:3@0.1-0.3", "--fault", "drive-silent:3@0.2"],
     "--fault drive-silent:3@0.2: overlaps"),
    (["--fault", "drive-frozen:3@1"], "--fault drive-frozen:3@1: starts at 1 s, not before --duration 0.5 s"),
])
def test_emulate_arguments_together_are_checked_before_any_port(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], no_ports: None, extra: list[str],
        expected: str) -> None:
    rc, out, err = _cli(_emulate(tmp_path, *(e.format(tmp=tmp_path) for e in extra)), capsys)
    _one_line(rc, err, "seafmu emulate: error: ")
    assert expected in err and out == ""


def test_emulate_accepts_the_bounds_it_names(tmp_path: Path) -> None:
    """The checks refuse only what they say: the ends of each range pass them."""
    parser = emulator.build_parser()
    for extra in (["--step", "1e-4", "--status-rate", "1000"], ["--step", "1", "--status-rate", "0.1"],
                  ["--bitrate", "1000000", "--duration", "1e-3"]):
        args = parser.parse_args(_emulate(tmp_path, *extra)[1:])
        profile, _, faults = emulator._checked(args, "slcan", f"pty:{tmp_path / 'slcan'}", None)
        assert faults == []
        assert profile.can.bitrate == args.bitrate
    assert not (tmp_path / "nmea").exists()


def test_emulate_entry_point_refuses_before_ready(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "seafmu.emulate", *_emulate(tmp_path, "--step", "0")[1:]],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc
    assert proc.stderr == "seafmu: error: emulate --step: must be a number from 0.0001 to 1 s, got 0\n"
    assert not list(tmp_path.iterdir())  # no pseudo-terminal link made


# -- argparse errors of every subcommand (finding 4) ------------------------------------------------

@pytest.mark.parametrize(("argv", "expected"), [
    (["run", "base.yaml", "--seed", "abc"], "run --seed: invalid int value: 'abc'"),
    (["run", "--coupling", "parallel"], "run --coupling: invalid choice: 'parallel'"),
    (["run", "--frob"], "run: unrecognized arguments: --frob"),
    (["check"], "check: the following arguments are required: scenario"),
    (["testplan", "supply", "--scale", "x"], "testplan --scale: invalid float value: 'x'"),
    (["identify", TOW, "--json", "--frob"], "identify: unrecognized arguments: --frob"),
    (["emulate", "minerva2", "--serial", "pty"], "emulate: the following arguments are required: --can"),
    ([], "no command given; one of build, check, run, sweep, export, identify, diagnose, emulate, testplan"),
])
def test_argument_errors_are_one_line(argv: list[str], expected: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = _cli(argv, capsys)
    _one_line(rc, err, f"seafmu: error: {expected}")
    assert out == "" and "usage:" not in err


# -- empty lists and paths (finding 5) --------------------------------------------------------------

@pytest.mark.parametrize(("argv", "expected"), [
    (["diagnose", ROV, "--effects", ""],
     "diagnose --effects: empty list; name at least one effect or leave the flag out"),
    (["diagnose", ROV, "--effects", " , "], "diagnose --effects: empty list"),
    (["run", "{tmp}/short.yaml", "--inprocess", "-o", ""], "run -o/--output: empty path"),
    (["identify", TOW, "-o", ""], "identify -o/--output: empty path"),
    (["identify", TOW, "--write-vessel", ""], "identify --write-vessel: empty path"),
    (["identify", TOW, "--vessel", ""], "identify --vessel: empty"),
    (["testplan", "supply", "-o", ""], "testplan -o/--output: empty path"),
    (["export", "minerva2_dp", "--osp", ""], "export --osp: empty path"),
    (["export", "minerva2_dp", "--ssp", ""], "export --ssp: empty path"),
    (["check", ""], "scenario '': empty name"),
])
def test_empty_lists_and_paths_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           monkeypatch: pytest.MonkeyPatch, argv: list[str],
                                           expected: str) -> None:
    work = tmp_path / "cwd"  # where the default output folders would go
    work.mkdir()
    monkeypatch.chdir(work)
    _short_scenario(tmp_path)
    rc, _, err = _cli([a.format(tmp=tmp_path) for a in argv], capsys)
    _one_line(rc, err, f"seafmu: error: {expected}")
    assert not list(work.iterdir())  # no default folder used instead


# -- testplan arguments before anything is written (finding 6) --------------------------------------

@pytest.mark.parametrize("seed", ["-1", "2147483648", "x"])
def test_testplan_seed_is_refused_before_anything_is_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], seed: str) -> None:
    rc, _, err = _cli(["testplan", "supply", "--seed", seed, "-o", str(tmp_path / "tp6")], capsys)
    _one_line(rc, err, "seafmu: error: testplan --seed: must be a whole number from 0 to 2147483647")
    assert not (tmp_path / "tp6").exists()


# -- a folder of the user's own files (finding 7) ---------------------------------------------------

def test_output_folder_check_knows_seafmu_folders(tmp_path: Path) -> None:
    check_output_folder(tmp_path / "new")  # missing: created later by the command
    (tmp_path / "empty").mkdir()
    check_output_folder(tmp_path / "empty")
    for mark in (MARKER, LOCK_FILE, "summary.json", "identification.json", "diagnosis.md",
                 "OspSystemStructure.xml"):
        folder = tmp_path / f"seafmu_{mark.strip('.')}"
        folder.mkdir()
        (folder / mark).write_text("")
        (folder / "notes.txt").write_text("mine\n")
        check_output_folder(folder)
    _user_folder(tmp_path / "user")
    with pytest.raises(OutputFolderError, match="not empty and not a seafmu output folder"):
        check_output_folder(tmp_path / "user")


def test_run_refuses_a_users_folder_and_reuses_its_own(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    scenario = _short_scenario(tmp_path)
    user = tmp_path / "userdir"
    files = _user_folder(user)
    rc, out, err = _cli(["run", str(scenario), "--inprocess", "-q", "-o", str(user)], capsys)
    assert out == ""
    _one_line(rc, err, f"seafmu: error: {user}: not empty and not a seafmu output folder (it holds "
                       "report.md, results.csv)")
    assert {p.name: p.read_text() for p in user.iterdir()} == files  # nothing written, nothing replaced
    own = tmp_path / "own"  # an earlier run's folder (its lock file, its outputs) and a file of the user's
    own.mkdir()
    (own / LOCK_FILE).write_text("")
    (own / "results.csv").write_text("time\n0\n")
    (own / "notes.txt").write_text("mine\n")
    rc, _, err = _cli(["run", str(scenario), "--inprocess", "-q", "-o", str(own)], capsys)
    assert rc in (0, 1) and err == "", err  # a rerun into it stays allowed
    assert (own / "results.csv").read_text() != "time\n0\n" and (own / "notes.txt").read_text() == "mine\n"


@pytest.mark.parametrize("argv", [
    ["identify", TOW],
    ["diagnose", ROV],
    ["testplan", "supply"],
    ["export", "minerva2_dp", "--osp"],
])
def test_every_command_refuses_a_users_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              argv: list[str]) -> None:
    user = tmp_path / "userdir"
    files = _user_folder(user)
    rc, _, err = _cli([*argv, str(user)] if argv[-1] == "--osp" else [*argv, "-o", str(user)], capsys)
    _one_line(rc, err, "seafmu: error: ")
    assert f"{user}: not empty and not a seafmu output folder" in err
    assert {p.name: p.read_text() for p in user.iterdir()} == files


def test_identify_reuses_its_own_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "id"
    for _ in range(2):
        rc, _, err = _cli(["identify", TOW, "-o", str(out)], capsys)
        assert rc == 0 and err == "", err
    assert (out / MARKER).is_file() and (out / "identification.json").is_file()


# -- paths of the wrong kind (finding 8) ------------------------------------------------------------

@pytest.mark.parametrize(("argv", "expected"), [
    (["run", "{tmp}/folder"], "{tmp}/folder: is a folder, not a scenario file"),
    (["check", "/dev/null"], "/dev/null: is not a regular file"),
    (["export", "minerva2_dp", "--ssp", "{tmp}/afile/x.ssp"], "{tmp}/afile is a file, not a folder"),
    (["export", "minerva2_dp", "--osp", "{tmp}/afile/x"], "{tmp}/afile is a file, not a folder"),
    (["identify", TOW, "--write-vessel", "{tmp}/afile/x.yaml", "-o", "{tmp}/o"],
     "--write-vessel {tmp}/afile/x.yaml: {tmp}/afile is a file, not a folder"),
    (["run", "{tmp}/short.yaml", "--inprocess", "-o", "{tmp}/afile/out"],
     "{tmp}/afile is a file, not a folder"),
    (["testplan", "supply", "-o", "{tmp}/afile/out"], "{tmp}/afile is a file, not a folder"),
])
def test_paths_of_the_wrong_kind_say_so(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                                        expected: str) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "afile").write_text("a file\n")
    _short_scenario(tmp_path)
    before = sorted(tmp_path.iterdir())
    rc, _, err = _cli([a.format(tmp=tmp_path) for a in argv], capsys)
    _one_line(rc, err, "seafmu: error: ")
    assert expected.format(tmp=tmp_path) in err and "does not exist" not in err
    assert sorted(tmp_path.iterdir()) == before
