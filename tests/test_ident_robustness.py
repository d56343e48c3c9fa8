"""Issue 8, identification: bad inputs end in one line naming the input (exit 2, no traceback),
data files stay inside the trial's folder and are never quoted unless they are data tables,
write-back never creates folders, a log is not fitted with another vessel's file, and the
maneuver output-error fit is linear in the log length with MINPACK's results.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from seafmu.components.vessel_spec import VesselFileError, load_vessel
from seafmu.identification import arrowlm
from seafmu.identification.cli import main, one_line
from seafmu.identification.diagnosis import identify
from seafmu.identification.maneuver import (
    identify_maneuver,
    load_maneuver_csv,
    simulate_maneuver,
    write_maneuver_csv,
)
from seafmu.identification.trial import TrialError, load_trial
from seafmu.identification.writeback import write_back

ROOT = Path(__file__).resolve().parents[1]
SECRET = "root:x:0:0:secret-token-1234:/root:/bin/bash"

DECAY_YAML = """name: coast
kind: decay
dof: surge
files: [{file}]
columns:
  time: {{column: t, unit: s}}
  output: {{column: u, unit: m/s}}
constants: {{mass: 50 kg}}
baseline: linear_quadratic
"""


def _decay_csv(n: int = 60, dt: float = 0.1, y: list[str] | None = None, t: list[str] | None = None) -> str:
    t = t if t is not None else [f"{dt * i:.6g}" for i in range(n)]
    y = y if y is not None else [f"{math.exp(-0.2 * dt * i):.6f}" for i in range(n)]
    return "# coast-down\nt,u\n" + "".join(f"{a},{b}\n" for a, b in zip(t, y, strict=True))


def _trial(folder: Path, csv: str | bytes, file: str = "run.csv", yaml_text: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / file
    if isinstance(csv, bytes):
        target.write_bytes(csv)
    else:
        target.write_text(csv)
    path = folder / "trial.yaml"
    path.write_text(yaml_text if yaml_text is not None else DECAY_YAML.format(file=file))
    return path


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    rc = main(argv)
    return rc, capsys.readouterr().err.strip()


def _assert_one_line(rc: int, err: str, *fragments: str) -> None:
    assert rc == 2, err
    assert err.startswith("seafmu: error: ") and "\n" not in err and "Traceback" not in err, err
    for frag in fragments:
        assert frag in err, (frag, err)


# -- 1-2 DOF trials: each bad input is one line naming the file and what is wrong ------------------

def _gap(n: int = 60) -> list[str]:
    return [f"{0.1 * i + (40.0 if i >= 30 else 0.0):.6g}" for i in range(n)]


CASES = {
    "non_utf8": (b"# k\xf6rning\nt,u\n0,1\n0.1,0.9\n", "not UTF-8 text (byte 0xf6 on line 1)"),
    "nul_bytes": (b"t,u\n0,1\x00\n", "not a text file (NUL byte on line 2)"),
    "overflow": (_decay_csv(y=["1e308"] + ["0.5"] * 59), "line 3: column 'u' is 1e+308: out of range"),
    "inf": (_decay_csv(y=["0.5"] * 10 + ["inf"] + ["0.4"] * 49), "line 13: column 'u' is inf (NaN/inf"),
    "backwards": (_decay_csv(t=[f"{0.1 * i:.6g}" for i in range(30)] + ["1.0"]
                             + [f"{0.1 * i:.6g}" for i in range(31, 60)]), "goes backwards to 1 s"),
    "gap": (_decay_csv(t=_gap()), "line 33: time column 't' jumps from 2.9 s to 43 s"),
    "too_few": (_decay_csv(n=7), "7 samples; a decay trial needs at least 20"),
    "all_zero": (_decay_csv(y=["0"] * 60), "column 'u' (output) is constant (0 throughout): nothing decays"),
    "constant": (_decay_csv(y=["1.5"] * 60), "is constant (1.5 throughout)"),
    "not_a_table": (SECRET + "\n" + SECRET + "\n", "not a CSV data table"),
    "text_table": ("user,password\nbob,hunter2\n", "not a CSV data table"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_data_file_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             case: str) -> None:
    csv, expected = CASES[case]
    trial = _trial(tmp_path / case, csv)
    rc, err = _run(["identify", str(trial), "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, str(tmp_path / case / "run.csv"), expected)
    assert "secret" not in err and "hunter2" not in err


def test_all_zero_decay_is_an_error_not_a_zero_fit(tmp_path: Path) -> None:
    """The reported case: d_L = 0 [0, 0] from a record in which nothing moves."""
    with pytest.raises(TrialError, match="no decay to fit"):
        load_trial(_trial(tmp_path, _decay_csv(y=["0"] * 60)))


def test_step_trial_without_a_command_is_refused(tmp_path: Path) -> None:
    rows = "".join(f"{0.1 * i:.3g},{math.exp(-0.02 * i):.6f},0\n" for i in range(60))
    yaml_text = DECAY_YAML.format(file="run.csv").replace("kind: decay", "kind: step").replace(
        "  output:", "  input: {column: n, unit: rev/s}\n  output:")
    with pytest.raises(TrialError, match="'n' \\(input\\) is zero throughout"):
        load_trial(_trial(tmp_path, "t,u,n\n" + rows, yaml_text=yaml_text))


def test_time_gap_threshold_is_five_sample_intervals(tmp_path: Path) -> None:
    """Jitter and a couple of dropped samples are fine; more than 5 intervals is a gap."""
    t = [0.1 * i for i in range(60)]
    t[30:] = [x + 0.35 for x in t[30:]]  # 4.5 intervals: accepted
    load_trial(_trial(tmp_path / "ok", _decay_csv(t=[f"{x:.6g}" for x in t])))
    t[30:] = [x + 0.2 for x in t[30:]]  # 6.5 intervals: a gap
    with pytest.raises(TrialError, match=r"jumps from 2\.9 s to 3\.55 s, 6\.5 sample intervals"):
        load_trial(_trial(tmp_path / "gap", _decay_csv(t=[f"{x:.6g}" for x in t])))


# -- paths: a trial names files in its folder only, and nothing of a non-data file is quoted --------

@pytest.mark.parametrize(("entry", "expected"), [
    ("/etc/passwd", "files[0]: '/etc/passwd' is an absolute path"),
    ("../outside/run.csv", "files[0]: '../outside/run.csv' lies outside the trial's folder"),
    ("sub/../../outside/run.csv", "lies outside the trial's folder"),
    ("link.csv", "files[0]: 'link.csv' lies outside the trial's folder"),
])
def test_trial_files_stay_in_the_trial_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str], entry: str,
                                              expected: str) -> None:
    (tmp_path / "outside").mkdir()
    secret = tmp_path / "outside" / "run.csv"
    secret.write_text(SECRET + "\n")
    folder = tmp_path / "trial"
    folder.mkdir()
    (folder / "sub").mkdir()
    (folder / "link.csv").symlink_to(secret)
    trial = folder / "trial.yaml"
    trial.write_text(DECAY_YAML.format(file=entry))
    rc, err = _run(["identify", str(trial), "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, str(trial), expected)
    assert "secret" not in err and "root:x" not in err


def test_files_in_subfolders_and_the_vessel_file_beside_the_trial_are_fine(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "r1.csv").write_text(_decay_csv())
    (tmp_path / "amv_copy.yaml").write_text((ROOT / "components" / "vessels" / "amv_osf.yaml").read_text())
    (tmp_path / "trial.yaml").write_text(DECAY_YAML.format(file="runs/r1.csv") + "vessel: amv_copy.yaml\n")
    trial = load_trial(tmp_path / "trial.yaml")
    assert trial.runs[0].n == 60 and trial.vessel == str(tmp_path / "amv_copy.yaml")
    (tmp_path / "trial.yaml").write_text(DECAY_YAML.format(file="runs/r1.csv") + "vessel: ../x/v.yaml\n")
    with pytest.raises(TrialError, match=r"vessel: '\.\./x/v\.yaml' lies outside the trial's folder"):
        load_trial(tmp_path / "trial.yaml")


@pytest.mark.parametrize(("text", "expected"), [
    ("name: x\nkind: decay\n  files: [a.csv\n" + SECRET + "\n", "not valid YAML (line 3, column"),
    ("name: ../../escape\nkind: decay\ndof: surge\nfiles: [run.csv]\n",
     "name: '../../escape' is not a plain"),
])
def test_trial_yaml_errors_quote_nothing_of_the_file(tmp_path: Path, text: str, expected: str) -> None:
    (tmp_path / "run.csv").write_text(_decay_csv())
    (tmp_path / "t.yaml").write_text(text)
    with pytest.raises(TrialError) as err:
        load_trial(tmp_path / "t.yaml")
    msg = str(err.value)
    assert expected in msg and "\n" not in msg and "secret" not in msg and "files: [" not in msg, msg


def test_non_utf8_trial_yaml(tmp_path: Path) -> None:
    (tmp_path / "t.yaml").write_bytes(b"name: k\xf6rning\n")
    with pytest.raises(TrialError, match=r"t\.yaml: not UTF-8 text \(byte 0xf6 on line 1\)"):
        load_trial(tmp_path / "t.yaml")


@pytest.mark.parametrize("scale", [1e6, 1e12])
def test_rescaled_data_gives_a_report_and_standard_json(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        scale: float) -> None:
    """The shipped pendulum decay with every column times 1e6 or 1e12 (units gone wrong): every fit
    may diverge, and still diagnose writes its report (its ranking plot had nothing finite to scale
    to) and --json prints JSON that other readers take (no Infinity or NaN: null)."""
    import csv
    import json

    src = Path(__file__).resolve().parents[1] / "scenarios" / "data"
    rows = []
    for r in csv.reader((src / "pendulum_free_decay.csv").read_text().splitlines()):
        try:
            rows.append([repr(float(x) * scale) for x in r])
        except ValueError:
            rows.append(r)
    with open(tmp_path / "pendulum_free_decay.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    (tmp_path / "pendulum_free_decay.yaml").write_text((src / "pendulum_free_decay.yaml").read_text())
    trial = tmp_path / "pendulum_free_decay.yaml"
    for cmd in ("identify", "diagnose"):
        rc = main([cmd, str(trial), "--json", "-o", str(tmp_path / cmd)])
        out = capsys.readouterr().out
        assert rc == 0, cmd
        strict = {"parse_constant": lambda c, cmd=cmd: pytest.fail(f"{cmd} --json wrote {c}")}
        json.loads(out, **strict)
        name = "diagnosis" if cmd == "diagnose" else "identification"
        json.loads((tmp_path / cmd / f"{name}.json").read_text(), **strict)
        assert (tmp_path / cmd / f"{name}.md").is_file()


# -- write-back never creates folders ------------------------------------------------------------

def test_write_vessel_into_a_missing_folder_is_refused_before_fitting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trial = _trial(tmp_path / "t", _decay_csv())
    target = tmp_path / "nonexistent" / "dir" / "x.yaml"
    t0 = time.perf_counter()
    rc, err = _run(["identify", str(trial), "--vessel", "amv_osf", "--write-vessel", str(target),
                    "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, f"--write-vessel {target}: the folder {target.parent} does not exist")
    assert not (tmp_path / "nonexistent").exists() and time.perf_counter() - t0 < 5.0
    with pytest.raises(VesselFileError, match="does not exist \\(it is not created\\)"):
        write_back("amv_osf", {"D_Q[0,0]": 40.0}, target, {"trial": "t"})
    assert not (tmp_path / "nonexistent").exists()


def test_write_vessel_onto_the_trials_own_files_or_without_a_vessel_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The measured data (or the trial file) is never replaced by a vessel file; a trial that names
    no vessel has nothing to start the file from: one line each, before any fit, nothing written."""
    trial = _trial(tmp_path / "t", _decay_csv())
    files = sorted(p for p in trial.parent.iterdir() if p.is_file())
    before = {p: p.read_bytes() for p in files}
    for target in files:
        rc, err = _run(["identify", str(trial), "--vessel", "amv_osf", "--write-vessel", str(target),
                        "-o", str(tmp_path / "out")], capsys)
        _assert_one_line(rc, err, f"--write-vessel {target}: is one of the trial's own files")
    assert {p: p.read_bytes() for p in files} == before and len(files) >= 2
    rc, err = _run(["identify", str(trial), "--write-vessel", str(tmp_path / "v.yaml"),
                    "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, "the trial names no vessel to start the file from; give --vessel")
    assert not (tmp_path / "v.yaml").exists()


# -- vessel / log mismatch ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Short plant-made maneuver logs of both vessels (SI columns: time, eta, nu, tau_*)."""
    folder = tmp_path_factory.mktemp("logs")
    out = {}
    for name, duration in (("amv_osf", 30.0), ("minerva2", 20.0)):
        data, _ = simulate_maneuver(load_vessel(name), duration=duration, dt=0.1, seed=0)
        out[name] = write_maneuver_csv(data, folder / f"{name}.csv")
    return out


def _edit_log(src: Path, dst: Path, fn) -> Path:  # type: ignore[no-untyped-def]
    lines = src.read_text().splitlines()
    header = lines[1].split(",")
    rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[2:]])
    header, rows = fn(header, rows)
    dst.write_text(lines[0] + "\n" + ",".join(header) + "\n"
                   + "\n".join(",".join(f"{v:.10g}" for v in r) for r in rows) + "\n")
    return dst


def _col(header: list[str], name: str) -> int:
    return header.index(name)


def _set(name: str, value: float, rows_from: int = 0):  # type: ignore[no-untyped-def]
    def fn(h: list[str], r: np.ndarray) -> tuple[list[str], np.ndarray]:
        r[rows_from:, _col(h, name)] = value
        return h, r
    return fn


def _gap_rows(h: list[str], r: np.ndarray) -> tuple[list[str], np.ndarray]:
    r[150:, 0] += 30.0
    return h, r


def _more_thrusters(h: list[str], r: np.ndarray) -> tuple[list[str], np.ndarray]:
    h = [*h, *(f"plant.thrust_{i}" for i in range(1, 5))]
    return h, np.hstack([r, np.ones((r.shape[0], 4))])


def _kilo(h: list[str], r: np.ndarray) -> tuple[list[str], np.ndarray]:
    r[:, _col(h, "tau_X")] *= 1000.0  # logged in N but the numbers are mN
    return h, r


MANEUVER_CASES = {
    "minerva_log_amv_vessel": ("minerva2", "amv_osf", None, "the log has 6-DOF columns (down, roll, pitch, "
                               "w, p, q), vessel 'amv_osf' has 3"),
    "amv_log_minerva_vessel": ("amv_osf", "minerva2", None, "the log has 3-DOF columns only"),
    "extra_thrusters": ("amv_osf", "amv_osf", _more_thrusters,
                        "columns for 4 thrusters (plant.thrust_1 ... plant.thrust_4), vessel 'amv_osf' "
                        "has 2"),
    "implausible_force": ("amv_osf", "amv_osf", _kilo, "column 'tau_X' reaches"),
    "zero_motion": ("amv_osf", "amv_osf", lambda h, r: (h, np.column_stack([r[:, 0], 0 * r[:, 1:]])),
                    "no motion: every velocity column (u, v, r) is constant"),
    "sway_never_moves": ("amv_osf", "amv_osf", _set("v", 0.0),
                         "column 'v' (v) is constant (0 throughout): sway is not excited"),
    "constant_forces": ("amv_osf", "amv_osf", lambda h, r: (h, np.where(
        np.isin(np.arange(r.shape[1]), [_col(h, c) for c in ("tau_X", "tau_Y", "tau_N")]), 2.0, r)),
        "the forces (tau_X, tau_Y, tau_N) are constant"),
    "overflow": ("amv_osf", "amv_osf", _set("u", 1e308, 100), "column 'u' is 1e+308 at data row 101"),
    "gap": ("amv_osf", "amv_osf", _gap_rows, "time jumps from 14.9 s to 45 s at data row 151"),
    "too_few": ("amv_osf", "amv_osf", lambda h, r: (h, r[:50]), "only 50 samples; a 3-DOF maneuver fit"),
    "time_backwards": ("amv_osf", "amv_osf", _set("time", 3.0, 100),
                       "not strictly increasing at data row 101 (t = 3 after 9.9)"),
}


@pytest.mark.parametrize("case", sorted(MANEUVER_CASES))
def test_bad_maneuver_log_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                      logs: dict[str, Path], case: str) -> None:
    log_of, vessel, edit, expected = MANEUVER_CASES[case]
    path = logs[log_of] if edit is None else _edit_log(logs[log_of], tmp_path / "log.csv", edit)
    rc, err = _run(["identify", str(path), "--vessel", vessel, "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, str(path), expected)


def test_non_utf8_and_non_table_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "a.csv").write_bytes(b"time,u\n0,\xff\n")
    rc, err = _run(["identify", str(tmp_path / "a.csv"), "--vessel", "amv_osf", "-o", str(tmp_path)], capsys)
    _assert_one_line(rc, err, "a.csv: not UTF-8 text (byte 0xff on line 2)")
    (tmp_path / "b.csv").write_text(SECRET + "\n" * 3)
    rc, err = _run(["identify", str(tmp_path / "b.csv"), "--vessel", "amv_osf", "-o", str(tmp_path)], capsys)
    _assert_one_line(rc, err, "b.csv: not a CSV data table")
    assert "secret" not in err


def test_trial_of_another_vessel_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trial = _trial(tmp_path / "t", _decay_csv())  # mass 50 kg: the AMV, not Minerva 2
    rc, err = _run(["identify", str(trial), "--vessel", "minerva2", "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, "constants.mass = 50 kg, but vessel 'minerva2' has 2800 kg rigid-body")
    heave = _trial(tmp_path / "h", _decay_csv(), yaml_text=DECAY_YAML.format(file="run.csv").replace(
        "dof: surge", "dof: heave"))
    rc, err = _run(["identify", str(heave), "--vessel", "amv_osf", "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, "vessel 'amv_osf' has no heave DOF")


def test_multi_line_problems_become_one_line() -> None:
    msg = "/a/b.csv: missing column for 'yaw'\n/a/b.csv: only 40 samples\n/a/b.csv: time is not increasing"
    assert one_line(msg) == "/a/b.csv: missing column for 'yaw'; only 40 samples; time is not increasing"


def test_seafmu_command_gives_one_line_and_exit_2(tmp_path: Path) -> None:
    """Through the installed entry point: no traceback on stderr."""
    trial = _trial(tmp_path / "t", b"t,u\n0,\xe9\n")
    proc = subprocess.run([sys.executable, "-m", "seafmu.cli", "identify", str(trial), "-o",
                           str(tmp_path / "o")], capture_output=True, text=True, cwd=ROOT, timeout=120,
                          check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("seafmu: error: ")
    assert "not UTF-8 text" in proc.stderr and "Traceback" not in proc.stderr


# -- random inputs: an error line or a fit, never anything else ------------------------------------

_FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@_FAST
@given(raw=st.binary(max_size=400))
def test_random_bytes_as_a_trial_csv(tmp_path: Path, raw: bytes) -> None:
    trial = _trial(tmp_path, b"t,u\n" + raw)
    try:
        load_trial(trial)
    except TrialError as exc:
        assert "\n" not in str(exc) and str(tmp_path) in str(exc)


_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(min_value=-3.0, max_value=3.0),
    st.sampled_from([0.0, 1e308, -1e308, 1e-308, 1e15, 1e16, 5e-324]),
)


@st.composite
def _decay_records(draw: st.DrawFn) -> str:
    """A coast-down record, mostly plausible (any scale, noise, sampling), sometimes corrupted by an
    arbitrary float, a repeated or jumping time, or a cell of text."""
    n = draw(st.integers(20, 60))
    dt = draw(st.sampled_from([1e-3, 0.05, 0.1, 1.0, 30.0]))
    amp = draw(st.sampled_from([0.0, 1e-300, 1e-6, 1.0, -2.0, 1e6, 1e14, 1e300]))
    rate = draw(st.floats(0.0, 5.0))
    noise = draw(st.sampled_from([0.0, 1e-3, 0.1, 3.0]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    t = np.arange(n) * dt
    y = amp * np.exp(-rate * t / max(t[-1], 1e-12)) + noise * abs(amp) * rng.normal(size=n)
    cells_t, cells_y = [repr(float(x)) for x in t], [repr(float(x)) for x in y]
    for _ in range(draw(st.integers(0, 2))):
        i = draw(st.integers(0, n - 1))
        kind = draw(st.sampled_from(["value", "time", "text"]))
        if kind == "value":
            cells_y[i] = repr(draw(_VALUES))
        elif kind == "time":
            cells_t[i] = repr(float(t[i] + draw(st.sampled_from([-2 * dt, -dt, 10 * dt, 0.4 * dt]))))
        else:
            cells_y[i] = draw(st.sampled_from(["", "abc", "1,5", "0x10", "1e999"]))
    return "t,u\n" + "".join(f"{a},{b}\n" for a, b in zip(cells_t, cells_y, strict=True))


@pytest.mark.filterwarnings("error::RuntimeWarning")
@_FAST
@given(csv=_decay_records())
def test_random_values_in_a_decay_trial_give_an_error_or_a_fit(tmp_path: Path, csv: str) -> None:
    try:
        fit = identify(load_trial(_trial(tmp_path, csv))).fit
    except TrialError as exc:
        assert "\n" not in str(exc)
    else:
        assert set(fit.params) == {"d_L", "d_Q"}


@pytest.mark.filterwarnings("error::RuntimeWarning")
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([0.0, 1e-300, 1e-60, 1e-3, 1.0, 30.0, 1e300]),
       tau_scale=st.sampled_from([0.0, 1.0, 20.0, 1e3]), n=st.integers(125, 200),
       constant_cols=st.lists(st.integers(1, 9), max_size=3), smooth=st.booleans(),
       method=st.sampled_from(["ls", "output_error"]))
@example(seed=511, scale=1e-3, tau_scale=1.0, n=183, constant_cols=[], smooth=False,
         method="output_error")  # surge quadratic damping fitted negative, held at 0 (found by CI)
def test_random_maneuver_tables_give_an_error_or_a_fit(tmp_path: Path, seed: int, scale: float,
                                                       tau_scale: float, n: int, constant_cols: list[int],
                                                       smooth: bool, method: str) -> None:
    rng = np.random.default_rng(seed)
    table = rng.normal(size=(n, 10))
    if smooth:
        table = np.cumsum(table, axis=0) / math.sqrt(n)
    table[:, 1:7] *= scale
    table[:, 7:] *= tau_scale
    table[:, 0] = np.arange(n) * 0.1
    for c in constant_cols:
        table[:, c] = 1.0
    path = tmp_path / "log.csv"
    np.savetxt(path, table, delimiter=",", header="time,north,east,yaw,u,v,r,tau_X,tau_Y,tau_N", comments="")
    vessel = load_vessel("amv_osf")
    try:
        fit = identify_maneuver(load_maneuver_csv(path, vessel), vessel, method=method, max_nfev=10)
    except TrialError as exc:
        assert all(ln.startswith(str(path)) for ln in str(exc).splitlines())
    else:  # a full fit: every surge term fitted, or held (at 0: fitted negative; at the vessel file:
        # the log cannot tell it, or barely moves surge) and said
        at_file = any(re.match(r"damping of (\w, )*u\b.* held at (the vessel file|the start)", w)
                      for w in fit.warnings)
        for key in ("D_L", "D_Q"):
            at_0 = any(f"{key}[0,0]" in w and "held at 0" in w for w in fit.warnings)
            assert (f"{key}[0,0]" in fit.params) != (at_0 or at_file)
            if at_0:
                assert fit.extras["matrices"][key][0][0] == 0.0
            elif at_file:
                assert fit.extras["matrices"][key][0][0] == getattr(vessel, f"{key}")[0, 0]


# -- the output-error fit: MINPACK's iteration on the block structure, linear in the log length ------

def _arrow_problem(S: int = 6, L: int = 40) -> tuple:
    """Segments sharing two parameters, each with its own 2-state start: an arrow Jacobian."""
    rng = np.random.default_rng(0)
    t = np.linspace(0, 4, L)
    truth = rng.normal(size=(S, 2))
    y = (truth[:, :1] * np.exp(-0.7 * t) + truth[:, 1:] * np.sin(0.9 * t) + 0.03 * t**2
         + 0.01 * rng.normal(size=(S, L)))

    def fun(z: np.ndarray) -> np.ndarray:
        X = z[2:].reshape(S, 2)
        return X[:, :1] * np.exp(-z[0] * t) + X[:, 1:] * np.sin(3 * z[1] * t) + 0.1 * z[1] * t**2 - y

    def jac(z: np.ndarray) -> arrowlm.ArrowJacobian:
        h, f0 = 1e-7, fun(z)
        Jp, Jx = np.empty((S, L, 2)), np.empty((S, L, 2))
        for k in range(2):
            zz = z.copy()
            zz[k] += h
            Jp[:, :, k] = (fun(zz) - f0) / h
            zz = z.copy()
            zz[2 + k :: 2] += h
            Jx[:, :, k] = (fun(zz) - f0) / h
        return arrowlm.ArrowJacobian(Jp, Jx)

    def dense(z: np.ndarray) -> np.ndarray:
        J = jac(z)
        D = np.zeros((S * L, 2 + 2 * S))
        D[:, :2] = J.Jp.reshape(S * L, 2)
        for s in range(S):
            D[s * L : (s + 1) * L, 2 + 2 * s : 4 + 2 * s] = J.Jx[s]
        return D

    z0 = np.concatenate([[0.4, 0.45], (truth + 0.5 * rng.normal(size=(S, 2))).ravel()])
    return fun, jac, dense, z0


@pytest.mark.parametrize("max_nfev", [3, 6, 40])
def test_arrow_levenberg_marquardt_follows_minpack(max_nfev: int) -> None:
    fun, jac, dense, z0 = _arrow_problem()
    ref = least_squares(lambda z: fun(z).ravel(), z0, jac=dense, method="lm", x_scale=1.0, max_nfev=max_nfev)
    got = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=max_nfev)
    assert got.nfev == ref.nfev and got.message == ref.message and got.success == ref.success
    assert np.max(np.abs(got.x - ref.x)) < 1e-8 and got.cost == pytest.approx(ref.cost, rel=1e-8)
    # the parameter block of (J^T J)^-1 equals the dense pseudo-inverse's
    D = dense(got.x)
    A = D.T @ D
    cs = np.sqrt(np.diag(A))
    full = np.linalg.pinv(A / np.outer(cs, cs), hermitian=True) / np.outer(cs, cs)
    np.testing.assert_allclose(got.jac.normal().inverse_pp(), full[:2, :2], rtol=1e-8)


def test_arrow_levenberg_marquardt_with_a_bound_never_reached_is_unchanged() -> None:
    fun, jac, _, z0 = _arrow_problem()
    free = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=40)
    bounded = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=40, lower=np.array([-5.0, -5.0]))
    assert min(free.x[:2]) > -5.0
    assert np.array_equal(bounded.x, free.x) and bounded.nfev == free.nfev and bounded.status == free.status


@pytest.mark.parametrize("lower", [[1.0, -np.inf], [-np.inf, 0.4], [1.0, 0.4]])
def test_arrow_levenberg_marquardt_keeps_lower_bounds(lower: list[float]) -> None:
    """A bound the free minimum lies beyond: the fit ends on it, at the minimum within the bounds
    (scipy's bounded trust-region fit of the same problem), and no iterate leaves the bounds."""
    fun, jac, dense, z0 = _arrow_problem()
    free = arrowlm.levenberg_marquardt(fun, jac, z0, max_nfev=200)
    lo = np.array(lower)
    assert np.any(free.x[:2] < lo)  # the bound is active
    seen: list[np.ndarray] = []

    def watched(z: np.ndarray) -> np.ndarray:
        seen.append(z[:2].copy())
        return fun(z)

    got = arrowlm.levenberg_marquardt(watched, jac, z0, max_nfev=200, lower=lo)
    assert all(np.all(z >= lo) for z in seen)
    ref = least_squares(lambda z: fun(z).ravel(), np.maximum(z0, np.r_[lo, np.full(z0.size - 2, -np.inf)]),
                        jac=dense, bounds=(np.r_[lo, np.full(z0.size - 2, -np.inf)], np.inf), method="trf",
                        x_scale=1.0, ftol=1e-12, xtol=1e-12, gtol=1e-12)
    assert got.success and got.cost == pytest.approx(ref.cost, rel=1e-6)
    active = free.x[:2] < lo
    assert np.all(got.x[:2][active] == lo[active])  # on the bound exactly
    np.testing.assert_allclose(got.x, ref.x, atol=1e-4)


def _timed_fit(data, vessel) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Seconds (best of three) and tracemalloc peak MB of an output-error fit."""
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        identify_maneuver(data, vessel, method="output_error", segment=5.0, max_nfev=8)
        times.append(time.perf_counter() - t0)
    tracemalloc.start()
    identify_maneuver(data, vessel, method="output_error", segment=5.0, max_nfev=8)
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return min(times), peak


def test_output_error_scales_linearly_with_the_log_length() -> None:
    """2 000 vs 8 000 rows with 5 s segments (112 segments at 8 000 rows): the dense Jacobian had
    one column per segment and state, so memory grew as rows^2 and MINPACK's QR as rows^3.
    Asserted on memory only (tracemalloc: deterministic): exponent below 1.3; the dense version
    measured 1.9, this one 0.97. Time is a benchmark's job (benchmarks/bench_maneuver_scaling.py
    prints it), not a test's: on a shared machine a timing ratio is noise."""
    vessel = load_vessel("amv_osf")
    data, _ = simulate_maneuver(vessel, duration=799.9, dt=0.1, seed=3)
    small = data.select(slice(0, 2000))
    t_small, m_small = _timed_fit(small, vessel)
    t_big, m_big = _timed_fit(data, vessel)
    ratio = data.n / small.n
    mem_exp = math.log(m_big / m_small) / math.log(ratio)
    assert mem_exp < 1.3, (m_small, m_big, mem_exp, t_small, t_big)


def test_a_decay_jumping_from_zero_to_1e14_is_one_line_error_not_a_crash(tmp_path: Path) -> None:
    """Found by the random decay records: the Jacobian overflowed inside the optimiser."""
    csv = "t,u\n0.0,0.0\n" + "".join(f"{0.001 * i!r},1e14\n" for i in range(1, 20))
    with pytest.raises(TrialError, match="overflowed") as exc:
        identify(load_trial(_trial(tmp_path, csv)))
    assert "\n" not in str(exc.value)


# -- maneuver logs: every row as wide as the header, no '_' in numbers, no doubled column names ----

def _edit_row(src: Path, dst: Path, row: int, fn) -> Path:  # type: ignore[no-untyped-def]
    """The log with data row ``row`` (1-based; the file has one '#' line and the header first)
    replaced by ``fn(cells)``."""
    lines = src.read_text().splitlines()
    cells = lines[row + 1].split(",")
    lines[row + 1] = ",".join(fn(cells))
    dst.write_text("\n".join(lines) + "\n")
    return dst


def _comma(cells: list[str]) -> list[str]:  # u = 0.1234 written 0,1234
    assert "." in cells[4]
    return [*cells[:4], *cells[4].split(".", 1), *cells[5:]]


def _doubled(name: str, src: Path, dst: Path) -> Path:
    """The log with one more column named ``name``: twice the u column (a plausible other log)."""
    lines = src.read_text().splitlines()
    out = [lines[0], lines[1] + f",{name}"]
    out += [ln + f",{2 * float(ln.split(',')[4])!r}" for ln in lines[2:]]
    dst.write_text("\n".join(out) + "\n")
    return dst


ROW_CASES = {
    "decimal_comma": (_comma, "data row 20 has 11 fields, the header has 10"),
    "extra_field": (lambda c: [*c, "999"], "data row 20 has 11 fields, the header has 10"),
    "short_row": (lambda c: c[:-1], "data row 20 has 9 fields, the header has 10"),
    "underscore": (lambda c: [*c[:4], "0_5", *c[5:]], "data row 20, column 'u': not a number ('0_5')"),
    "underscore_exp": (lambda c: [*c[:4], "3_3e-1", *c[5:]],
                       "data row 20, column 'u': not a number ('3_3e-1')"),
}


@pytest.mark.parametrize("case", sorted(ROW_CASES))
def test_a_maneuver_row_that_does_not_fit_the_header_is_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: dict[str, Path], case: str) -> None:
    assert load_maneuver_csv(logs["amv_osf"], load_vessel("amv_osf")).n == 301  # the log as written loads
    fn, expected = ROW_CASES[case]
    path = _edit_row(logs["amv_osf"], tmp_path / "log.csv", 20, fn)
    rc, err = _run(["identify", str(path), "--vessel", "amv_osf", "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, f"{path}: {expected}")


def test_underscores_are_refused_by_the_compiled_reader_too(tmp_path: Path, logs: dict[str, Path],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """numpy's loadtxt refuses '0_5' today; one that parsed cells with Python's float() (as older
    numpy did) would take it as 5. With such a reader in place the log is still refused."""
    def python_float_reader(lines: list[str], **_: object) -> np.ndarray:
        return np.array([[float(c) for c in ln.split(",")] for ln in lines], ndmin=2)

    monkeypatch.setattr(np, "loadtxt", python_float_reader)
    vessel = load_vessel("amv_osf")
    assert load_maneuver_csv(logs["amv_osf"], vessel).n == 301  # the stand-in reads a plain log
    path = _edit_row(logs["amv_osf"], tmp_path / "log.csv", 7, lambda c: [*c[:5], "0_5", *c[6:]])
    with pytest.raises(TrialError, match=r"log\.csv: data row 7, column 'v': not a number \('0_5'\)"):
        load_maneuver_csv(path, vessel)


def test_a_maneuver_column_named_twice_is_refused_when_it_is_read(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], logs: dict[str, Path]) -> None:
    path = _doubled("u", logs["amv_osf"], tmp_path / "log.csv")
    rc, err = _run(["identify", str(path), "--vessel", "amv_osf", "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, f"{path}: column 'u' appears twice in the header")
    unused = _doubled("note", logs["amv_osf"], tmp_path / "unused.csv")
    unused = _doubled("note", unused, tmp_path / "unused2.csv")
    assert load_maneuver_csv(unused, load_vessel("amv_osf")).n == 301  # a column nobody reads


SUMMARY_CASES = {
    "not_json": ("{not json", "not valid JSON (Expecting property name enclosed in double quotes at line 1, "
                              "column 2)"),
    "a_list": ("[1,2,3]", "expected a JSON object with a 'vessel' field, got a list"),
    "no_vessel": ('{"scenario": "x"}', "has no 'vessel' field; give --vessel"),
    "not_a_name": ('{"vessel": 3}', "vessel: expected a vessel name, got 3"),
    "unknown": ('{"vessel": "titanic"}', "vessel: no such vessel 'titanic' (bundled: amv_osf, "),
    "typo": ('{"vessel": "amv_os"}', "vessel: no such vessel 'amv_os'; did you mean 'amv_osf'?"),
}


@pytest.mark.parametrize("case", sorted(SUMMARY_CASES))
def test_a_corrupt_summary_json_beside_a_log_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      logs: dict[str, Path], case: str) -> None:
    """It was passed over ('needs --vessel (or a summary.json next to it...)' although one was
    there), or its vessel failed later in an error naming no file."""
    text, expected = SUMMARY_CASES[case]
    log = tmp_path / "results.csv"
    log.write_text(logs["amv_osf"].read_text())
    (tmp_path / "summary.json").write_text(text)
    rc, err = _run(["identify", str(log), "-o", str(tmp_path / "out")], capsys)
    _assert_one_line(rc, err, f"{tmp_path / 'summary.json'}: {expected}")
