"""Runs that lose nothing (issue 8): stop signals, streaming results, the output-folder lock, stale
files, unpacked FMUs, and every run-sizing number bounded before anything is allocated.

The signal tests start a real ``seafmu run`` of a long scenario through the FMUs, wait until it has
streamed rows to results.csv (it is stepping), send the signal, and check what it left behind.
"""

from __future__ import annotations

import copy
import dataclasses
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import Ports

from seafmu import fmu_cache
from seafmu.cli import main
from seafmu.master import SimulationError, StopRequest, run
from seafmu.outdir import LOCK_FILE
from seafmu.report import PLACEHOLDER_MARK
from seafmu.results import CsvStream, evaluate_checks, write_csv
from seafmu.scenario import MAX_STEPS, SCENARIO_DIR, ScenarioError, load_scenario

REPO = Path(__file__).resolve().parents[1]
LONG = 3000.0  # s: about 20 s of wall time through the FMUs; the tests stop it after 2-3 s


def _long_scenario(tmp_path: Path) -> Path:
    doc = yaml.safe_load((SCENARIO_DIR / "minerva2_dp.yaml").read_text())
    doc["duration"] = LONG
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _data_rows(csv: Path) -> int:
    try:
        return max(0, len(csv.read_bytes().splitlines()) - 1)
    except FileNotFoundError:
        return 0


def _default_signals() -> None:
    """In the child: the stop signals as from a terminal. Run from a shell's background job (or
    under nohup) pytest inherits SIGINT (SIGHUP) ignored, and seafmu keeps an ignored signal ignored."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def _start(scenario: Path, out: Path, tmpdir: Path) -> subprocess.Popen[str]:
    """``seafmu run`` in a child with its own temp dir and its own cache of unpacked FMUs
    (``_fmu_cache``)."""
    tmpdir.mkdir(exist_ok=True)
    env = {**os.environ, "TMPDIR": str(tmpdir), fmu_cache.ENV: str(_fmu_cache(tmpdir))}
    return subprocess.Popen([sys.executable, "-m", "seafmu.cli", "run", str(scenario), "-q", "-o", str(out)],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_signals)


def _fmu_cache(tmpdir: Path) -> Path:
    return tmpdir.parent / "fmu_cache"


def _unheld_versions(cache: Path) -> list[Path]:
    """The unpacked FMU versions in ``cache`` that no process holds (an exclusive lock can be taken)."""
    free = []
    for version in cache.iterdir():
        fd = os.open(version / fmu_cache.LOCK, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            free.append(version)
        except OSError:
            pass
        finally:
            os.close(fd)
    return free


def _wait_stepping(proc: subprocess.Popen[str], csv: Path, rows: int = 1500, timeout: float = 60.0) -> int:
    """Wait until the run has streamed ``rows`` samples (> 1 chunk): it is stepping."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        n = _data_rows(csv)
        if n >= rows:
            return n
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("the run did not start stepping")


def _stale_outputs(out: Path) -> None:
    """An older run's files in the folder, and a file of the user's."""
    (out / "recording").mkdir(parents=True)
    (out / "recording" / "can.asc").write_text("old recording\n")
    (out / "summary.json").write_text('{"stale": true}\n')
    (out / "allocation.png").write_bytes(b"old")
    (out / ".report.md.99999.tmp").write_text("half a report of a killed run")
    (out / "notes.txt").write_text("mine\n")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_a_stop_signal_stops_cleanly_and_keeps_everything(built_fmus: dict, tmp_path: Path,
                                                          sig: signal.Signals,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    scenario, out, tmpdir = _long_scenario(tmp_path), tmp_path / "out", tmp_path / "tmp"
    _stale_outputs(out)
    proc = _start(scenario, out, tmpdir)
    try:
        seen = _wait_stepping(proc, out / "results.csv")
        # the folder is locked while the run goes: a second run into it is refused, in one line
        assert main(["run", str(scenario), "-q", "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "in use by another seafmu run (pid " in err[0], err
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + sig, (proc.returncode, stderr)
    assert "Traceback" not in stderr and "failed in" not in stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("seafmu: interrupted at t = "), stderr
    t_int = float(lines[0].split("t = ")[1].split(" s")[0])
    assert f"({sig.name})" in lines[0] and 0 < t_int < LONG

    # results.csv: every row up to the interrupt, contiguous, none lost
    data = np.loadtxt(out / "results.csv", delimiter=",", skiprows=1)
    assert len(data) >= seen
    t = data[:, 0]
    assert t[0] == 0.0 and t[-1] == pytest.approx(t_int, abs=1e-9)
    assert np.all(np.diff(t)[:-1] == pytest.approx(0.1, abs=1e-9)) and 0 < np.diff(t)[-1] <= 0.1 + 1e-9
    # the report, complete, and the summary say where it stopped
    report = (out / "report.md").read_text()
    assert PLACEHOLDER_MARK not in report
    assert f"interrupted at t = {t_int:g} s" in report and report.rstrip().endswith("for scripts")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["interrupted"] == sig.name
    assert summary["simulated_s"] == pytest.approx(t_int) and summary["samples"] == len(data)
    for png in ("trajectory.png", "states.png", "thrusters.png", "allocation.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png
    # no stale file of the older run, the user's file untouched
    assert not (out / "recording").exists() and not list(out.glob(".*.tmp"))
    assert (out / "notes.txt").read_text() == "mine\n"
    # nothing left in the temp folder; the four FMUs stay unpacked for the next run, held by no process
    assert not list(tmpdir.iterdir())
    assert len(_unheld_versions(_fmu_cache(tmpdir))) == 4


def test_sigkill_keeps_the_streamed_rows_and_frees_the_fmus(built_fmus: dict, tmp_path: Path) -> None:
    """SIGKILL cannot be handled: what was streamed stays, the report says the run was killed, and
    the unpacked FMUs it held are free for the next run (the locks went with the process)."""
    scenario, out, tmpdir = _long_scenario(tmp_path), tmp_path / "out", tmp_path / "tmp"
    proc = _start(scenario, out, tmpdir)
    try:
        seen = _wait_stepping(proc, out / "results.csv")
    finally:
        proc.kill()
        proc.communicate()
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) - 1 >= seen and all(len(r.split(",")) == len(rows[0].split(",")) for r in rows)
    report = (out / "report.md").read_text()
    assert PLACEHOLDER_MARK in report and "killed" in report
    assert not list(tmpdir.iterdir())
    assert len(_unheld_versions(_fmu_cache(tmpdir))) == 4


def test_a_locked_output_folder_is_refused_untouched(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.csv").write_text("time\n0\n")
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(fd, b"4242\n")
        assert main(["run", "-q", "-o", str(out), "--inprocess"]) == 2
    finally:
        os.close(fd)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"seafmu: error: {out}: in use by another seafmu run (pid 4242); wait for it to end or "
                   "choose another folder with -o"]
    assert (out / "results.csv").read_text() == "time\n0\n"  # nothing of the other run touched


def test_stop_request_ends_the_loop_between_steps_and_stops_every_unit(
        built_fmus: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """In process: the flag set mid-run (as the signal handler does) ends the loop before the next
    step; every unit gets its clean stop; the sink got every row."""
    import seafmu.master as master

    sc = load_scenario("minerva2_dp")
    stop = StopRequest()
    real_step = master.BlockUnit.do_step

    def step(self: master.BlockUnit, t: float, h: float) -> None:
        real_step(self, t, h)
        if t >= 12.0 and self.name == "observer":
            stop.request(signal.SIGTERM)  # mid-step, after the plant and the observer stepped

    stopped: list[str] = []
    monkeypatch.setattr(master.BlockUnit, "do_step", step)
    monkeypatch.setattr(master, "_stop_unit", lambda u: stopped.append(u.name))
    rows: list[np.ndarray] = []

    class Sink:
        def begin(self, columns: list[str]) -> None:
            self.columns = columns

        def write(self, block: np.ndarray) -> None:
            rows.append(block)

    r = run(sc, mode="inprocess", progress=False, stop=stop, sink=Sink())
    assert r.interrupted == "SIGTERM" and not r.complete
    assert r.t_end == pytest.approx(12.05) and r.time[-1] == pytest.approx(12.05)  # the step completed
    assert r.steps == {"plant": 241, "observer": 241, "controller": 241, "allocator": 241}
    assert stopped == ["plant", "observer", "controller", "allocator"]
    np.testing.assert_array_equal(np.vstack(rows)[:, 0], r.time)
    # checks whose window the run did not reach FAIL, saying so; others are evaluated
    checks = {c.name: c for c in evaluate_checks(r)}
    assert checks["roll stays small, rad"].note.startswith("not evaluated: the run stopped at t = 12.05 s")
    assert not checks["roll stays small, rad"].passed


def test_stop_signals_only_set_the_flag_and_an_ignored_one_stays_ignored() -> None:
    from seafmu.master import stop_on_signals

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    previous_hup = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as under nohup
    try:
        stop = StopRequest()
        with stop_on_signals(stop):
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.01)
            assert not stop.requested  # nohup's choice is kept
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.01)  # the handler runs between bytecodes: no exception, only the flag
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)
        assert stop.signum == signal.SIGTERM and stop.name == "SIGTERM" and stop.exit_code == 143
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous_hup)
    assert {s: signal.getsignal(s) for s in before} == before  # the old handlers are back


def test_stop_unit_prefers_a_clean_close() -> None:
    from seafmu.master import _stop_unit

    calls = []

    class Link:
        def close(self) -> None:
            calls.append("close")

        def terminate(self) -> None:
            calls.append("terminate")

    class Fmu:
        def terminate(self) -> None:
            calls.append("fmu terminate")

    _stop_unit(Link())  # type: ignore[arg-type]
    _stop_unit(Fmu())  # type: ignore[arg-type]
    assert calls == ["close", "fmu terminate"]


def test_a_failing_fmu_keeps_the_results_up_to_the_failure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    import seafmu.master as master

    real_step = master.BlockUnit.do_step

    def step(self: master.BlockUnit, t: float, h: float) -> None:
        if t >= 7.0 and self.name == "controller":
            raise SimulationError("controller at t = 7.000 s: singular matrix")
        real_step(self, t, h)

    monkeypatch.setattr(master.BlockUnit, "do_step", step)
    out = tmp_path / "out"
    assert main(["run", "-q", "--inprocess", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("seafmu: error: controller at t = 7.000 s: singular matrix")
    data = np.loadtxt(out / "results.csv", delimiter=",", skiprows=1)
    assert data[-1, 0] == pytest.approx(7.0)
    report = (out / "report.md").read_text()
    assert "failed at t = 7 s of 300 s" in report and PLACEHOLDER_MARK not in report
    assert json.loads((out / "summary.json").read_text())["error"].startswith("controller at t = 7.000 s")


def test_streamed_csv_equals_the_one_written_at_once(tmp_path: Path) -> None:
    sc = load_scenario("amv_osf_autopilot")
    sc = dataclasses.replace(sc, duration=30.0, events=[e for e in sc.events if e[0] < 30.0], checks=[])
    sink = CsvStream(tmp_path / "streamed.csv")
    try:
        r = run(sc, mode="inprocess", progress=False, sink=sink)
    finally:
        sink.close()
    write_csv(r, tmp_path / "whole.csv")
    assert (tmp_path / "streamed.csv").read_text() == (tmp_path / "whole.csv").read_text()


def test_a_check_window_without_samples_fails_saying_so(tmp_path: Path) -> None:
    sc = load_scenario("amv_osf_autopilot")
    c = sc.checks[0]
    # bypassing validation (which refuses it): a window between two samples
    empty = c.model_copy(update={"after": 10.01, "before": 10.02, "name": "empty"})
    sc = dataclasses.replace(sc, duration=20.0, events=[e for e in sc.events if e[0] < 20.0], checks=[empty])
    [res] = evaluate_checks(run(sc, mode="inprocess", progress=False))
    assert not res.passed and res.note == "not evaluated: no samples in the window"


# -- run-sizing numbers: one line, exit 2, before anything is allocated -----------------------------

_BASE = {
    "name": "t", "vessel": "minerva2", "duration": 10, "step": 0.05,
    "fmus": {"plant": {"kind": "plant", "parameters": {"seed": 1}}, "observer": {"kind": "observer"},
             "controller": {"kind": "controller", "parameters": {"down_ref": "5 m"}},
             "allocator": {"kind": "allocator"}},
    "events": [{"time": 2, "set": "controller.north_ref", "value": "1 m"}],
}
# the reported repro files (../shared/repro/scenario_*.yaml), as they were
REPROS = {
    "step_huge": ({"step": 1.0e308}, "step: 1e+308 s is longer than the duration 10 s"),
    "step_tiny": ({"step": 1.0e-12}, "step: 1e-12 s is below the smallest step, 1e-06 s"),
    "duration_huge": ({"duration": 1.0e308}, "duration: 1e+308 s is above the limit of 1e+07 s"),
}


def _repro(tmp_path: Path, change: dict) -> Path:
    doc = copy.deepcopy(_BASE)
    doc.update(change)
    path = tmp_path / "repro.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize("name", list(REPROS))
def test_repro_scenarios_fail_check_and_run_in_one_line(tmp_path: Path, name: str) -> None:
    change, expected = REPROS[name]
    path = _repro(tmp_path, change)
    for args in (["check", str(path)], ["run", str(path), "-o", str(tmp_path / "o")]):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "seafmu.cli", *args], cwd=REPO, capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 2, (args, proc.stdout, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"seafmu: error: {path}: {expected}"), proc.stderr
        assert time.perf_counter() - t0 < 30
    assert not (tmp_path / "o").exists()  # refused before the output folder was touched


def test_a_big_yaml_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / "big.yaml"
    with open(path, "w") as fh:  # 50 MB: took 148 s and 4 GB before its error
        fh.write("name: t\nevents:\n")
        line = "  - {time: 1, set: controller.north_ref, value: 1 m}\n"
        fh.write(line * (50_000_000 // len(line)))
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError, match=r"big\.yaml: file is 50 MB; scenario files are limited to 1 MB"):
        load_scenario(path)
    assert time.perf_counter() - t0 < 0.5


@pytest.mark.parametrize(("text", "expected"), [
    ("name: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested more than 64 levels deep"),
    ("name: " + "[" * 70 + "]" * 70 + "\n", "nested more than 64 levels deep (line 1)"),
    ("".join("  " * i + f"k{i}:\n" for i in range(80)) + "  " * 80 + "x: 1\n",
     "nested more than 64 levels deep (line 65)"),
    ("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n" for p, c in zip("abcdefg", "bcdefgh", strict=True)),
     "expands to more than 1,000,000 values"),
    ("a: &a [1, *a]\n", "refers to its own enclosing node"),
    ("duration: " + "9" * 5000 + "\n", "Exceeds the limit (4300 digits)"),
], ids=["deep", "deep-70", "deep-block", "alias-bomb", "recursive-alias", "huge-int"])
def test_hostile_yaml_gives_one_line(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert expected in str(err.value) and "\n" not in str(err.value)
    assert time.perf_counter() - t0 < 1.0


def test_check_prints_the_size_of_the_run(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "minerva2_dp"]) == 0
    out = capsys.readouterr().out
    assert "6000 steps, 3001 samples x 133 signals (3.22 MB of results in memory)" in out, out


def test_the_master_refuses_an_oversized_scenario_made_in_code() -> None:
    sc = dataclasses.replace(load_scenario("minerva2_dp"), step=1e-9)
    with pytest.raises(SimulationError, match=f"above the limits \\({MAX_STEPS} steps"):
        run(sc, mode="inprocess", progress=False)


def test_sigterm_of_a_hardware_run_stops_the_thrusters_and_finishes_the_recording(
        built_fmus: dict, tmp_path: Path, own_ports: Ports) -> None:
    """The reported HIL case: SIGTERM left no trial.yaml, an unterminated can.asc and no results.csv.
    Against the emulator on this test's own pseudo-terminals (not the shared /tmp/seafmu-emulator)."""
    doc = yaml.safe_load((REPO / "scenarios" / "hil" / "minerva2_dp_emulator.yaml").read_text())
    doc["fmus"]["plant"] = {"hardware": str(own_ports.profile)}
    (tmp_path / "hil.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    emulator = subprocess.Popen(
        [sys.executable, "-m", "seafmu.emulate", "minerva2", "--serial", f"pty:{own_ports.serial}",
         "--can", f"slcan:pty:{own_ports.slcan}", "--scenario", "minerva2_dp", "--duration", "60"],
        cwd=REPO, stdout=subprocess.PIPE, text=True)
    out = tmp_path / "out"
    proc = None
    try:
        assert emulator.stdout is not None and emulator.stdout.readline().startswith("READY")
        proc = _start(tmp_path / "hil.yaml", out, tmp_path / "tmp")
        _wait_stepping(proc, out / "results.csv", rows=25)  # 2.5 s of the vessel in real time
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=30)
    finally:
        for p in (proc, emulator):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(timeout=10)
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr and "Warning" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("seafmu: interrupted at t = "), stderr
    rec = out / "recording"
    assert (rec / "trial.yaml").is_file()
    assert (rec / "can.asc").read_text().rstrip().endswith("End TriggerBlock")  # the log was closed
    assert len((rec / "signals.csv").read_text().splitlines()) > 20
    assert "interrupted at t = " in (out / "report.md").read_text()
    assert not list((tmp_path / "tmp").iterdir())


def test_an_fmu_file_that_unpacks_too_big_is_refused_before_it_is_unpacked(
        built_fmus: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import seafmu.scenario as scenario

    fmu = built_fmus[("minerva2", "observer")]
    path = tmp_path / "s.yaml"
    path.write_text(f"name: t\nvessel: minerva2\nduration: 1\nstep: 0.05\n"
                    f"fmus: {{observer: {{fmu: {fmu}}}}}\n")
    load_scenario(path)  # within the limit
    monkeypatch.setattr(scenario, "MAX_FMU_UNPACKED_BYTES", 100_000)
    expected = r"fmus\.observer\.fmu: not a readable FMU \(unpacks to [0-9.]+ [kM]B; the limit is 100 kB\)"
    with pytest.raises(ScenarioError, match=expected):
        load_scenario(path)


def test_ctrl_c_while_the_command_line_is_built_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A Ctrl-C in the first tenth of a second lands while the parser imports its commands: the
    same one line and exit 130 as later, not Python's traceback."""
    import seafmu.cli as cli

    def interrupted(command: str | None) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["run", "minerva2_dp"]) == 130
    assert capsys.readouterr().err == "seafmu: interrupted\n"
