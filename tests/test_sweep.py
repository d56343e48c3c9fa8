"""`seafmu sweep`: a small study on a local Dask cluster (2 workers), a failing case recorded without
stopping the study, resume after an interrupted run without redoing finished cases, bad study files
as one-line errors, and a worst case reproduced exactly by its printed command."""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_run_robustness import _default_signals

from seafmu.cli import main
from seafmu.sweep.study import StudyError, load_study

SCENARIO = """name: sweep_dp
vessel: minerva2
duration: {duration}
step: 0.05
record_interval: 0.1
fmus:
  plant:
    kind: plant
    parameters: {{seed: 1, current_speed: 0.1 m/s, current_direction: 45 deg, down_0: 5 m, substep: 0.05 s,
                 wave_hs: 0.3 m, wave_tp: 5 s, wave_components: 10}}
  observer: {{kind: observer}}
  controller:
    kind: controller
    parameters: {{down_ref: 5 m}}
  allocator: {{kind: allocator}}
checks:
  - {{name: north error, signal: plant.north, minus: controller.north_ref, metric: max_abs, after: 2,
     max: 0.06}}
  - {{name: EKF north rms, signal: observer.north_hat, minus: plant.north, metric: rms, after: 2, max: 0.1}}
"""

Done = subprocess.CompletedProcess[str]

STUDY = """name: small
scenario: base.yaml
vary:
  plant.current_speed: {uniform: [0.0 m/s, 0.3 m/s]}
  controller.ref_omega: {values: [0.0, 0.1]}     # 0 passes validation (min 0), fails in the FMU
sampling: {method: lhs, samples: 2, seed: 3}
seeds: 2
keep: [plant.north]
worst: 8
metrics:
  - {name: north rms, signal: plant.north, minus: controller.north_ref, metric: rms, after: 2}
"""


def _write(folder: Path, duration: float, study: str = STUDY) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.yaml").write_text(SCENARIO.format(duration=duration))
    p = folder / "study.yaml"
    p.write_text(study)
    return p


def _sweep(args: list[str], cwd: Path, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "seafmu.cli", "sweep", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=240, **kw)


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory, built_fmus: object) -> tuple[Path, Done]:
    folder = tmp_path_factory.mktemp("sweep")
    _write(folder, 8)
    return folder, _sweep(["study.yaml", "--workers", "2", "--out", "out", "-q"], folder)


def test_small_study_on_local_cluster(small: tuple[Path, Done]) -> None:
    folder, proc = small
    assert proc.returncode == 1, proc.stderr  # some cases fail: not every case passes
    frame = pd.read_parquet(folder / "out" / "cases.parquet")
    assert len(frame) == 8 and sorted(frame["case"]) == list(range(8))
    assert {"plant.current_speed", "controller.ref_omega", "seed", "status", "error", "wall_time_s",
            "check: north error", "pass: north error", "metric: north rms", "command"} <= set(frame.columns)
    assert len(set(frame["worker"])) == 2  # two worker processes shared the cases
    ok = frame[frame["controller.ref_omega"] == 0.1]
    assert set(ok["status"]) <= {"pass", "fail"} and np.all(np.isfinite(ok["check: north error"]))
    assert (ok["pass: north error"] == (ok["check: north error"] <= 0.06)).all()
    # the sampled speeds span the interval, each with both seeds
    assert ok.groupby("plant.current_speed")["seed"].apply(sorted).tolist() == [[1, 2], [1, 2]]
    series = pd.read_parquet(folder / "out" / ok["timeseries"].iloc[0])
    assert list(series.columns) == ["time", "plant.north"] and len(series) == 81
    report = (folder / "out" / "report.md").read_text()
    for part in ("## Pass rate", "Wilson interval", "distributions.png", "inputs_vs_checks.png", "Spearman",
                 "## Worst cases", "seafmu run base.yaml --set"):
        assert part in report, part
    for png in ("pass_rates.png", "distributions.png", "inputs_vs_checks.png"):
        assert (folder / "out" / png).stat().st_size > 1000


def test_failing_case_recorded_without_stopping(small: tuple[Path, Done]) -> None:
    folder, _ = small
    frame = pd.read_parquet(folder / "out" / "cases.parquet")
    bad = frame[frame["controller.ref_omega"] == 0.0]
    assert len(bad) == 4 and set(bad["status"]) == {"error"}
    for e in bad["error"]:
        assert "ref_omega" in e and "\n" not in e
    assert (frame["status"] != "error").sum() == 4  # the others all ran
    report = (folder / "out" / "report.md").read_text()
    assert "## Cases that could not run" in report
    # a check is evaluated by the 4 cases that ran, not by those that could not, even where their
    # rows carry a check value NaN that failed (a run stopped early: the simulation diverged)
    from seafmu.sweep.execute import Outcome, StudyFolder
    from seafmu.sweep.report import write_study_report

    study = load_study(folder / "study.yaml")
    rows = StudyFolder(folder / "out").finished(study)
    for r in rows.values():
        if r["status"] == "error":
            r.update({"check: north error": float("nan"), "pass: north error": False})
    out = folder / "report_stopped_runs"
    out.mkdir()
    write_study_report(study, Outcome(8, 0, 8, "", rows, 1.0, 2), out)
    table = [ln for ln in (out / "report.md").read_text().splitlines()
             if ln.startswith(("| north error | <=", "| EKF north rms | <="))]
    assert len(table) == 2 and all(ln.split("|")[3].strip() == "4" for ln in table), table
    assert all(ln.split("|")[2].strip().endswith(" m") for ln in table), table  # the bound with its unit


def test_worst_case_reproduces_exactly(small: tuple[Path, Done]) -> None:
    """The command printed for the worst case that ran gives bit-identical check values."""
    folder, proc = small
    frame = pd.read_parquet(folder / "out" / "cases.parquet")
    printed = [line.split("): ", 1)[1] for line in proc.stdout.splitlines()
               if line.startswith("  worst: case")]
    ran = frame[frame["status"] != "error"]
    worst = ran.loc[(ran["check: north error"] - 0.06).idxmax()]
    assert worst["command"] in printed
    argv = shlex.split(worst["command"])
    assert argv[:2] == ["seafmu", "run"] and "--seed" in argv
    cwd = Path.cwd()
    try:
        os.chdir(folder)
        rc = main([*argv[1:], "-o", "repro", "-q"])
    finally:
        os.chdir(cwd)
    assert rc == (0 if worst["status"] == "pass" else 1)
    checks = json.loads((folder / "repro" / "summary.json").read_text())["checks"]
    for c in checks:
        assert c["value"] == worst[f"check: {c['name']}"], c["name"]  # exact, not approximate


def test_resume_after_interrupt(tmp_path: Path, built_fmus: object) -> None:
    """SIGINT stops the study cleanly (exit 130, rows kept, cluster closed); the rerun — of the
    study with a value added in front, which renumbers every case — runs only the cases that had
    not finished and leaves the finished rows untouched; a third run has nothing left to do."""
    study = """name: resume
scenario: base.yaml
vary:
  plant.current_speed: {values: [0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.18, 0.2, 0.22],
                       unit: m/s}
seeds: [4]
"""
    _write(tmp_path, 150, study)  # 12 cases of ~0.2 s: the interrupt lands while some are left
    rows = tmp_path / "out" / "cases"
    proc = subprocess.Popen([sys.executable, "-m", "seafmu.cli", "sweep", "study.yaml", "--workers", "2",
                             "--out", "out", "-q"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_signals)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and len(list(rows.glob("*.json")) if rows.is_dir() else []) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "sweep interrupted (SIGINT)" in err
    first = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in rows.glob("*.json")}
    k = len(first)
    assert 2 <= k < 12, "the interrupt came too late to test a resume"
    assert len(pd.read_parquet(tmp_path / "out" / "cases.parquet")) == k
    (tmp_path / "study.yaml").write_text(study.replace("[0.0, 0.02", "[0.3, 0.0, 0.02"))
    again = _sweep(["study.yaml", "--workers", "2", "--out", "out", "-q"], tmp_path)
    assert again.returncode in (0, 1), again.stderr
    assert f"13 of 13 cases finished ({k} before, {13 - k} now" in again.stdout, again.stdout
    for p in rows.glob("*.json"):
        if p.name in first:
            assert (p.stat().st_mtime_ns, p.read_bytes()) == first[p.name], f"{p.name} was redone"
    frame = pd.read_parquet(tmp_path / "out" / "cases.parquet")
    assert frame["case"].tolist() == list(range(13))
    assert frame["plant.current_speed"].tolist() == pytest.approx([0.3, *(0.02 * i for i in range(12))])
    third = _sweep(["study.yaml", "--out", "out", "-q"], tmp_path)  # nothing left: no cluster, nothing run
    assert "(13 before, 0 now)" in third.stdout


def _descends_from(pid: int, ancestor: int) -> bool:
    """Whether process ``pid`` is ``ancestor`` or one of its descendants (Linux /proc)."""
    while pid > 1:
        if pid == ancestor:
            return True
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            return False
        pid = int(stat.rsplit(")", 1)[1].split()[1])  # the field after the state: the parent's pid
    return False


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """Stop a process started in its own session, and its children (the worker under a nanny)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    with contextlib.suppress(ProcessLookupError):  # a child left behind by the leader
        os.killpg(proc.pid, signal.SIGKILL)


def test_study_on_an_existing_scheduler(tmp_path: Path, built_fmus: object) -> None:
    """A plain `dask scheduler` / `dask worker` pair on 127.0.0.1 (a free port chosen by the scheduler,
    no dashboard) runs a 3-case study given by --scheduler, and again by DASK_SCHEDULER_ADDRESS:
    every case on that one worker process, none on a local cluster; both torn down after."""
    _write(tmp_path, 6, "name: remote\nscenario: base.yaml\nseeds: [2]\n"
           "vary:\n  plant.current_speed: {values: [0.05, 0.1, 0.15], unit: m/s}\n")
    dask_cli = Path(sys.executable).with_name("dask")
    sched_file = tmp_path / "scheduler.json"
    scheduler = subprocess.Popen([str(dask_cli), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--no-dashboard", "--scheduler-file", str(sched_file)], cwd=tmp_path,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    worker = None
    try:
        deadline = time.monotonic() + 60
        address = ""
        while not address and time.monotonic() < deadline and scheduler.poll() is None:
            try:  # the scheduler writes the file after creating it: it may be there but empty
                address = json.loads(sched_file.read_text())["address"]
            except (FileNotFoundError, json.JSONDecodeError):
                time.sleep(0.05)
        assert address.startswith("tcp://127.0.0.1:"), address
        worker = subprocess.Popen([str(dask_cli), "worker", address, "--nworkers", "1", "--nthreads", "1",
                                   "--no-dashboard", "--host", "127.0.0.1",
                                   "--local-directory", str(tmp_path / "dask-worker")],
                                  cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  start_new_session=True)
        env = {k: v for k, v in os.environ.items() if k != "DASK_SCHEDULER_ADDRESS"}
        runs = [(["--scheduler", address, "--out", "out"], env),
                (["--out", "out_env"], {**env, "DASK_SCHEDULER_ADDRESS": address})]
        for args, run_env in runs:
            proc = _sweep(["study.yaml", "--workers", "4", "-q", *args], tmp_path, env=run_env)
            assert proc.returncode in (0, 1), proc.stderr
            assert "3 of 3 cases finished (0 before, 3 now on 1 workers" in proc.stdout, proc.stdout
            frame = pd.read_parquet(tmp_path / args[-1] / "cases.parquet")
            assert frame["case"].tolist() == [0, 1, 2]
            assert frame["plant.current_speed"].tolist() == [0.05, 0.1, 0.15]
            assert frame["seed"].tolist() == [2, 2, 2]
            assert set(frame["status"]) <= {"pass", "fail"}, frame["error"].tolist()
            assert np.all(np.isfinite(frame["check: north error"]))
            (where,) = set(frame["worker"])  # one worker process ran every case: the dask worker's
            assert _descends_from(int(where.rsplit(":", 1)[1]), worker.pid), where
    finally:
        if worker is not None:
            _stop(worker)
        _stop(scheduler)
    assert worker.returncode is not None and scheduler.returncode is not None


@pytest.mark.parametrize("study, expected", [
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0, 1]}}\nbogus: 1\n",
     "bogus: unknown field"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0, 1], values: [1]}}\n",
     "give exactly one of values, grid, uniform"),
    ("name: x\nscenario: nowhere\n", "scenario: scenario 'nowhere': no such file or shipped scenario"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [-1 m/s, 0.2 m/s]}}\n"
     "sampling: {samples: 4}\n", "m/s is below the minimum 0"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0 m/s, 2 deg]}}\n",
     "mixes units deg, m/s"),
    ("name: x\nscenario: base.yaml\nvary: {plant.nothing: {values: [1, 2]}}\n",
     "--set plant.nothing=1: no such variable in FMU 'plant'"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0, 1]}}\n"
     "sampling: {method: sobol, samples: 6}\n", "Sobol sequences need a power of 2"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0, 1]}}\nsampling: {samples: 3}\n"
     "seeds: 4\npair_seeds: true\n", "4 seeds for 3 samples"),
    ("name: x\nscenario: base.yaml\nkeep: [plant.nothing]\n", "keep[0]: 'plant.nothing' is not a recorded"),
    ("name: x\nscenario: base.yaml\nvary: {thruster: {values: [1, 2]}}\n", "vary.thruster: an input is"),
    ("- just a list\n", "expected a mapping of study fields"),
    # counted before the cases are made (this cross product would fill the memory)
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {uniform: [0, 1]}}\n"
     "sampling: {samples: 100000}\nseeds: 100000\n", "10000000000 cases; a study is limited to 100000"),
    ("name: x\nscenario: base.yaml\nvary: {plant.seed: {values: [1, 2]}}\nseeds: [9]\n",
     "--seed: 9 and --set plant.seed=1 both set plant.seed"),
    ("name: x\nscenario: base.yaml\nvary:\n  plant.current_speed: {values: [0.1, 0.2]}\n"
     "  x: {values: [0.3], set: {plant.current_speed: '{value}'}}\n",
     "case 0: plant.current_speed is set more than once"),
    ("name: x\nscenario: base.yaml\nset: {plant.current_speed: 0.1}\n"
     "vary: {plant.current_speed: {values: [0.2]}}\n", "plant.current_speed is set more than once"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {values: [0.1, 0.1, 0.2]}}\n",
     "vary.plant.current_speed.values: values repeat"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {grid: {start: 0.1, stop: 0.1, num: 3}}}\n",
     "3 points from 0.1 to 0.1 repeat values"),
    ("name: x\nscenario: base.yaml\nvary: {plant.current_speed: {grid: {start: 0, stop: '1e400', num: 3}}}\n",
     "start and stop must be finite"),
    ("name: x\nscenario: base.yaml\nvary: {key: {values: [1, 2], set: {'plant.fail_mode_{value}': 1}}}\n",
     "'key' names a column of every case's row"),
    ("name: x\nscenario: base.yaml\nmetrics: [{name: a, signal: plant.north},\n"
     "  {name: a, signal: plant.east}]\n",
     "metric names repeat (a)"),
    ("name: x\nscenario: base.yaml\nmetrics: [{name: a, signal: plant.north, after: 4, before: 2}]\n",
     "the window ends (before: 2) before it starts (after: 4)"),
])
def test_bad_study_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], study: str,
                               expected: str) -> None:
    path = _write(tmp_path, 8, study)
    assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("seafmu: error: "), err
    assert expected in err
    assert not (tmp_path / "out").exists()  # nothing ran, nothing written


def test_a_folder_of_another_study_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path, 8, "name: second\nscenario: base.yaml\nseeds: 2\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "study.yaml").write_text("name: first\nscenario: base.yaml\n")
    assert main(["sweep", str(path), "--out", str(out), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds the results of study 'first', not 'second'" in err, err
    (out / "study.yaml").write_text("name: second\nscenario: base.yaml\nseeds: 3\n")  # the same, changed
    assert main(["sweep", str(path), "--out", str(out), "--dry-run"]) == 0


def test_a_folder_of_the_user_s_own_files_is_refused(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """As run -o: a folder that holds files but no sweep's (its report.md would be replaced)."""
    path = _write(tmp_path, 8, "name: mine\nscenario: base.yaml\nseeds: 2\n")
    out = tmp_path / "userdir"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "not empty and not a seafmu output folder (it holds notes.txt)" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]  # nothing written


def test_numbers_with_an_exponent_are_numbers(tmp_path: Path) -> None:
    """YAML reads ``1e2`` (no point) as text; it is still 100, never 1 in a unit 'e2'."""
    path = _write(tmp_path, 8, "name: e\nscenario: base.yaml\nvary:\n"
                  "  controller.kp_north: {values: [1e2, 50, '2.5e1']}\n"
                  "  plant.current_speed: {uniform: ['1e-2 m/s', '2E-1 m/s']}\nsampling: {samples: 2}\n")
    s = load_study(path)
    assert sorted({c.inputs["controller.kp_north"] for c in s.cases}) == [25.0, 50.0, 100.0]
    assert all(0.01 <= c.inputs["plant.current_speed"] <= 0.2 for c in s.cases)
    assert "controller.kp_north=100.0" in s.cases[0].overrides


def test_values_in_units_that_convert_are_taken_in_the_first_one_s(tmp_path: Path) -> None:
    """``[0.1 m/s, 0.4 kn]`` is two speeds, in m/s (the first unit given), as a scenario's
    quantities convert; a bare number beside a quantity (SI in a scenario, it would not be here), or
    units that do not convert, are one line."""
    path = _write(tmp_path, 8, "name: u\nscenario: base.yaml\nvary:\n"
                  "  plant.current_speed: {values: [0.1 m/s, 0.4 kn]}\n")
    s = load_study(path)
    assert [c.inputs["plant.current_speed"] for c in s.cases] == pytest.approx([0.1, 0.4 * 1852 / 3600])
    assert s.cases[1].overrides == [f"plant.current_speed={0.4 * 1852 / 3600!r} m/s"]
    grid = _write(tmp_path, 8, "name: u\nscenario: base.yaml\nvary:\n"
                  "  plant.current_speed: {grid: {start: 0.1 m/s, stop: 0.4 kn, num: 2}}\n")
    assert [c.inputs["plant.current_speed"] for c in load_study(grid).cases] == pytest.approx(
        [0.1, 0.4 * 1852 / 3600])  # a grid's stop in its own unit, not taken as m/s
    for values, why in (("[0.1, 0.4 kn]", "mixes bare numbers with units (kn)"),
                        ("[0.1 m/s, 2 deg]", "mixes units deg, m/s ('deg' does not convert to 'm/s')")):
        _write(tmp_path, 8, "name: u\nscenario: base.yaml\nvary:\n"
               f"  plant.current_speed: {{values: {values}}}\n")
        with pytest.raises(StudyError, match=re.escape(why)):
            load_study(path)


def test_dry_run_and_case_design(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    study = """name: design
scenario: base.yaml
vary:
  plant.current_speed: {uniform: [0.0 m/s, 0.2 m/s]}
  plant.current_direction: {normal: {mean: 45 deg, std: 10 deg, min: 30 deg, max: 60 deg}}
  plant.wave_hs: {lognormal: {median: 0.3 m, sigma: 0.2}}
  allocator.method: {choice: [0, 1]}
  failed: {values: [1, 3], set: {"plant.fail_mode_{value}@4": 1, "allocator.enable_{value}@4": 0}}
sampling: {method: sobol, samples: 8, seed: 1}
seeds: {start: 10, count: 8}
pair_seeds: true
"""
    path = _write(tmp_path, 8, study)
    s = load_study(path)
    assert len(s.cases) == 16
    speeds = sorted({c.inputs["plant.current_speed"] for c in s.cases})
    assert len(speeds) == 8 and 0 <= speeds[0] and speeds[-1] <= 0.2
    # scrambled Sobol: one point in each eighth of the interval
    assert sorted(int(v / 0.025) for v in speeds) == list(range(8))
    assert all(30 <= c.inputs["plant.current_direction"] <= 60 for c in s.cases)
    assert {c.inputs["allocator.method"] for c in s.cases} == {0, 1}
    assert sorted({c.seed for c in s.cases}) == list(range(10, 18))
    c3 = next(c for c in s.cases if c.inputs["failed"] == 3)
    assert "plant.fail_mode_3@4=1" in c3.overrides and "allocator.enable_3@4=0" in c3.overrides
    assert len({c.key for c in s.cases}) == 16
    assert main(["sweep", str(path), "--dry-run", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "design: 16 cases, all valid; 16 to run" in out and out.count("to run") == 17
    assert not (tmp_path / "out").exists()


def test_settling_time_metric() -> None:
    from seafmu.sweep.worker import metric_value

    t = np.round(np.arange(0, 10.01, 0.1), 10)
    y = np.where(t < 1, 1.0, np.exp(-(t - 1)))  # a step at t = 1 s decaying: |y| <= 0.05 from t = 1 + 3.0
    m = {"signal": "y", "minus": None, "angle": False, "after": 1.0, "before": None,
         "metric": "settling_time", "tolerance": 0.05}
    assert metric_value(m, t, {"y": y}) == pytest.approx(3.0)
    assert np.isnan(metric_value({**m, "tolerance": 1e-6}, t, {"y": y}))  # never settles within the run
    assert metric_value({**m, "metric": "max", "after": 2.0}, t, {"y": y}) == pytest.approx(np.exp(-1))


def test_wilson_interval() -> None:
    from seafmu.sweep.report import wilson

    lo, hi = wilson(0, 10)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(0.2775, abs=1e-4)  # 1.96^2/(10+1.96^2)
    lo, hi = wilson(50, 100)
    assert lo == pytest.approx(0.4038, abs=1e-4) and hi == pytest.approx(0.5962, abs=1e-4)


@pytest.mark.parametrize("k,n,conf", [(0, 1, 0.95), (0, 40, 0.95), (37, 40, 0.95), (40, 40, 0.9),
                                      (13, 29, 0.99), (1, 3, 0.5)])
def test_wilson_interval_equals_scipy(k: int, n: int, conf: float) -> None:
    """The closed form (written out to keep scipy.stats out of the sweep) is scipy's Wilson interval."""
    from scipy.stats import binomtest

    from seafmu.sweep.report import wilson

    ci = binomtest(k, n).proportion_ci(confidence_level=conf, method="wilson")
    assert wilson(k, n, conf) == pytest.approx((ci.low, ci.high), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_spearman_equals_scipy(seed: int) -> None:
    """Rho and its p-value as scipy.stats.spearmanr, with ties (rounded values) and without."""
    from scipy.stats import spearmanr

    from seafmu.sweep.report import spearman

    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 60))
    x = rng.normal(size=n)
    y = 0.4 * x + rng.normal(size=n)
    if seed % 2:
        x, y = np.round(x), np.round(y, 1)
    res = spearmanr(x, y)
    rho, p = spearman(x, y)
    assert rho == pytest.approx(res.statistic, abs=1e-12)
    assert p == pytest.approx(res.pvalue, rel=1e-9, abs=1e-15)


def test_sobol_indices_from_a_saltelli_design(tmp_path: Path) -> None:
    """A value that depends on one input only: that input's first-order and total indices near 1,
    the other's near 0 (SALib on the study's own Saltelli design)."""
    from seafmu.sweep.report import sobol_table

    study = """name: s
scenario: base.yaml
vary:
  plant.current_speed: {uniform: [0.0 m/s, 0.2 m/s]}
  plant.current_direction: {uniform: [0 deg, 90 deg]}
sampling: {method: saltelli, samples: 256, seed: 1}
"""
    s = load_study(_write(tmp_path, 8, study), validate=False)
    assert len(s.cases) == 256 * (2 + 2)
    speed = np.array([c.inputs["plant.current_speed"] for c in s.cases])
    frame = pd.DataFrame({"sample": [c.sample for c in s.cases], "check: drift": 3 * speed**2})
    (row,) = sobol_table(s, frame, ["check: drift"])
    s_speed, s_dir = ([float(x) for x in cell.split(" / ")] for cell in row[1:])
    assert s_speed[0] > 0.9 and s_speed[1] > 0.9
    assert abs(s_dir[0]) < 0.05 and abs(s_dir[1]) < 0.05


def test_case_with_its_validated_scenario_runs_as_one_loaded_in_the_worker(tmp_path: Path,
                                                                            built_fmus: object) -> None:
    """A small study hands each case the scenario its validation resolved; a large one (above
    KEEP_SCENARIOS) lets the worker load it. Both give the same row, bit for bit."""
    from seafmu.sweep.execute import _task
    from seafmu.sweep.study import KEEP_SCENARIOS
    from seafmu.sweep.worker import run_case

    s = load_study(_write(tmp_path, 6, "name: r\nscenario: base.yaml\nseeds: [3]\n"
                          "vary:\n  plant.current_speed: {values: [0.12], unit: m/s}\n"))
    (case,) = s.cases
    assert s.scenarios[0].seed == 3 and len(s.cases) <= KEEP_SCENARIOS
    given = _task(s, case)
    loaded = {**given, "resolved": None}
    rows = [run_case(t) for t in (given, loaded)]
    assert rows[0]["status"] in ("pass", "fail")
    skip = {"wall_time_s", "cpu_time_s", "loop_time_s", "run_time_s", "realtime_factor", "started",
            "finished"}
    assert {k: v for k, v in rows[0].items() if k not in skip} == {k: v for k, v in rows[1].items()
                                                                   if k not in skip}
    assert any(k.startswith("check: ") for k in rows[0])


def test_case_failing_validation_after_the_cluster_started(tmp_path: Path, built_fmus: object) -> None:
    """The first case validates, so the local cluster starts while the others are validated; the
    second does not: one line naming it, exit 2, the cluster closed, nothing written."""
    study = ("name: late\nscenario: base.yaml\n"
             "vary:\n  plant.current_speed: {values: [0.1, 0.2, -1.0], unit: m/s}\n")
    _write(tmp_path, 6, study)
    t0 = time.monotonic()
    proc = _sweep(["study.yaml", "--workers", "2", "--out", "out"], tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("seafmu: error: "), proc.stderr
    assert "case 2 (plant.current_speed=-1.0 m/s)" in proc.stderr and "below the minimum 0" in proc.stderr
    assert not (tmp_path / "out").exists()
    assert time.monotonic() - t0 < 120  # the workers did not keep the command alive
