"""A recording that cannot be written (a full disk, a file-size limit) stops the recording, not the
run; an OSError that does end a run mid-way keeps the results up to there and names the file.

Writes that fail: a file-size limit (RLIMIT_FSIZE, in a child process: EFBIG, as `ulimit -f`) and
``/dev/full`` behind a recording file's name (ENOSPC, as a full disk)."""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import can
import numpy as np
import pytest
import yaml
from conftest import Ports

from seafmu.cli import main
from seafmu.hardware.recording import Recorder
from seafmu.report import PLACEHOLDER_MARK
from seafmu.scenario import SCENARIO_DIR

REPO = Path(__file__).resolve().parents[1]
FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not FULL.exists(), reason="no /dev/full here")


def _frames(n: int, t0: float = 1000.0) -> list[tuple[can.Message, bool, float]]:
    return [(can.Message(arbitration_id=0x100 + k % 4, data=bytes([k % 256] * 8)), bool(k % 2), t0 + 0.01 * k)
            for k in range(n)]


def _whole_lines(path: Path) -> list[str]:
    text = path.read_text()
    assert text.endswith("\n"), f"{path.name} ends in half a line: {text[-80:]!r}"
    return text.splitlines()


def _sizes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in sorted(folder.iterdir()) if p.is_file()}


CHILD = textwrap.dedent("""
    import json, resource, sys
    import can, numpy as np
    from seafmu.hardware.recording import Recorder

    folder, limit = sys.argv[1], int(sys.argv[2])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
    warned, sizes = [], None
    rec = Recorder(folder, warn=warned.append)
    rec.start_signals(["a", "b"], "test")
    for k in range(3000):
        rec.frame(can.Message(arbitration_id=0x100 + k % 4, data=bytes(8)), bool(k % 2), 1000.0 + 0.01 * k)
        rec.serial_bytes(b"$SDDPT,5.0,0.0*00\\r\\n")
        rec.row(0.01 * k, np.array([1.0, 2.5]))
        rec.line(f"line {k}")
        if k % 100 == 99:
            rec.flush()
        if rec.stopped and sizes is None:
            sizes = {p: __import__("os").path.getsize(f"{folder}/{p}") for p in ("can.asc", "signals.csv")}
    rec.write_trial({"name": "t"})
    rec.close()
    rec.close()
    print(json.dumps({"warned": warned, "stopped": rec.stopped, "sizes": sizes}))
""")


def test_a_file_size_limit_stops_the_recording_once_and_leaves_readable_files(tmp_path: Path) -> None:
    """`ulimit -f`: can.asc outgrows the limit first. Every call returns, one warning names the file
    and the reason, nothing is written after it, and every file reads as far as it goes."""
    folder = tmp_path / "rec"
    proc = subprocess.run([sys.executable, "-c", CHILD, str(folder), "20000"], cwd=REPO, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and not proc.stderr, proc.stderr
    got = json.loads(proc.stdout)
    expected = f"recording stopped: {folder / 'can.asc'}: File too large; the run goes on without it"
    assert got["warned"] == [expected] and got["stopped"] == expected
    sizes = _sizes(folder)
    assert {k: sizes[k] for k in got["sizes"]} == got["sizes"]  # nothing written after the stop
    assert sizes["can.asc"] <= 20000
    lines = _whole_lines(folder / "can.asc")
    assert lines[-1] == "End TriggerBlock"  # terminated in the room the cut half line left
    frames = list(can.LogReader(str(folder / "can.asc")))
    assert 100 < len(frames) < 3000 and all(len(m.data) == 8 for m in frames)
    rows = _whole_lines(folder / "signals.csv")[2:]
    assert 100 < len(rows) < 3000 and all(r.split(",")[1:] == ["1", "2.5"] for r in rows)
    assert _whole_lines(folder / "link.log")[-1] == expected


@needs_dev_full
def test_a_full_disk_under_one_file_stops_the_recording_mid_run(tmp_path: Path) -> None:
    """link.log on a full disk (ENOSPC at its first line): the CAN log and signals.csv written
    before are closed whole (can.asc terminated), later calls do nothing and warn no more."""
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "link.log").symlink_to(FULL)
    warned: list[str] = []
    rec = Recorder(folder, warn=warned.append)
    rec.start_signals(["a"], "test")
    for msg, rx, t in _frames(50):
        rec.frame(msg, rx, t)
        rec.row(t - 1000.0, np.array([t]))
    rec.line("plant: watchdog alarm")  # the first write that fails
    expected = (f"recording stopped: {folder / 'link.log'}: No space left on device; "
                "the run goes on without it")
    assert warned == [expected] and rec.stopped == expected
    before = _sizes(folder)
    for msg, rx, t in _frames(50, t0=2000.0):
        rec.frame(msg, rx, t)
        rec.row(t, np.array([t]))
        rec.serial_bytes(b"$SDDPT,5.0,0.0*00\r\n")
    rec.line("more")
    rec.flush()
    rec.write_trial({"name": "t"})
    rec.close()
    assert warned == [expected] and _sizes(folder) == before
    assert _whole_lines(folder / "can.asc")[-1] == "End TriggerBlock"
    assert [m.data for m in can.LogReader(str(folder / "can.asc"))] == [m.data for m, _, _ in _frames(50)]
    assert len(_whole_lines(folder / "signals.csv")) == 2 + 50


@needs_dev_full
@pytest.mark.parametrize("when", ["flush", "close"])
def test_a_buffered_file_that_cannot_be_flushed_stops_the_recording(tmp_path: Path, when: str) -> None:
    """nmea.raw is buffered: its bytes fail when flushed (every second) or closed (the link's
    close), which warns once and never raises; the CAN log is terminated all the same."""
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "nmea.raw").symlink_to(FULL)
    warned: list[str] = []
    rec = Recorder(folder, warn=warned.append)
    for msg, rx, t in _frames(10):
        rec.frame(msg, rx, t)
        rec.serial_bytes(b"$SDDPT,5.0,0.0*00\r\n")
    assert not warned
    if when == "flush":
        rec.flush()
    rec.close()
    outcome = "the run goes on without it" if when == "flush" else "when it was closed"
    assert warned == [f"recording stopped: {folder / 'nmea.raw'}: No space left on device; {outcome}"]
    assert _whole_lines(folder / "can.asc")[-1] == "End TriggerBlock"
    assert len(list(can.LogReader(str(folder / "can.asc")))) == 10


def _short_scenario(tmp_path: Path, duration: float) -> Path:
    doc = yaml.safe_load((SCENARIO_DIR / "minerva2_dp.yaml").read_text())
    doc["duration"] = duration
    doc["events"] = [e for e in doc.get("events", []) if e["time"] < duration]
    doc.pop("checks", None)
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_results_csv_failing_mid_run_keeps_the_results_and_names_the_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """An OSError out of the master mid-run (the results.csv stream on a full disk): one line naming
    results.csv, the report says when the run failed (never 'before its first step'), summary.json
    is written from the results in memory."""
    from seafmu import results

    real_write = results.CsvStream.write
    chunks = []

    def write(self: results.CsvStream, rows: np.ndarray) -> None:
        chunks.append(len(rows))
        if len(chunks) > 1:  # the chunk a 1000-row stream writes second: the file is full
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
        real_write(self, rows)

    monkeypatch.setattr(results.CsvStream, "write", write)
    out = tmp_path / "out"
    assert main(["run", str(_short_scenario(tmp_path, 300.0)), "-q", "--inprocess", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"seafmu: error: {out / 'results.csv'}: file too large"), err
    report = (out / "report.md").read_text()
    assert "before its first step" not in report and PLACEHOLDER_MARK not in report
    assert "failed at t = " in report and "results.csv: file too large" in report
    data = json.loads((out / "summary.json").read_text())
    assert data["error"].startswith(f"{out / 'results.csv'}: file too large") and not data["complete"]
    assert 0 < data["simulated_s"] < 300 and data["samples"] >= chunks[0]


def test_results_csv_that_cannot_be_closed_is_reported_with_the_results(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The last flush of results.csv fails after every step ran: not 'failed before its first step'
    (the old report); the summary and the report are written and name the file."""
    from seafmu import results

    def close(self: results.CsvStream) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(results.CsvStream, "close", close)
    out = tmp_path / "out"
    assert main(["run", str(_short_scenario(tmp_path, 5.0)), "-q", "--inprocess", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"seafmu: error: {out / 'results.csv'}: no space left on device (results up to t = 5 s "
                   f"in {out})"]
    report = (out / "report.md").read_text()
    assert "before its first step" not in report and "results.csv: no space left on device" in report
    assert json.loads((out / "summary.json").read_text())["simulated_s"] == 5.0


def _file_size_limit(limit: int) -> None:
    """In the run's child: the stop signals as from a terminal, and `ulimit -f` in bytes."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))


def test_a_hardware_run_whose_recording_outgrows_the_file_size_limit_runs_to_its_end(
        own_ports: Ports, tmp_path: Path) -> None:
    """The reported HIL case (`ulimit -f 60`): can.asc hit the limit, the run ended with exit 2 and
    '[Errno 27] File too large' naming no file, report.md said 'failed before its first step' and
    there was no summary.json. Against the emulator on this test's own pseudo-terminals."""
    ports = own_ports
    doc = yaml.safe_load((REPO / "scenarios" / "hil" / "minerva2_dp_emulator.yaml").read_text())
    doc["fmus"]["plant"] = {"hardware": str(ports.profile)}
    doc["duration"], doc["record_interval"] = 6, 0.5  # results.csv ~15 kB, can.asc ~13 kB/s
    doc.pop("events"), doc.pop("checks")
    scenario = tmp_path / "hil.yaml"
    scenario.write_text(yaml.safe_dump(doc, sort_keys=False))
    emulator = subprocess.Popen(
        [sys.executable, "-m", "seafmu.emulate", "minerva2", "--serial", f"pty:{ports.serial}",
         "--can", f"slcan:pty:{ports.slcan}", "--scenario", "minerva2_dp", "--duration", "60"],
        cwd=REPO, stdout=subprocess.PIPE, text=True)
    out = tmp_path / "out"
    try:
        assert emulator.stdout is not None and emulator.stdout.readline().startswith("READY")
        proc = subprocess.run([sys.executable, "-m", "seafmu.cli", "run", str(scenario), "-q", "--inprocess",
                               "-o", str(out)], cwd=REPO, capture_output=True, text=True, timeout=60,
                              preexec_fn=lambda: _file_size_limit(40_000))
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)
    assert proc.returncode in (0, 1), proc.stderr
    assert "Traceback" not in proc.stderr and "Errno" not in proc.stderr, proc.stderr
    can_log = out / "recording" / "can.asc"
    stopped = f"plant: recording stopped: {can_log}: File too large; the run goes on without it"
    assert [ln for ln in proc.stderr.splitlines() if "recording" in ln] == [stopped], proc.stderr
    assert np.loadtxt(out / "results.csv", delimiter=",", skiprows=1)[-1, 0] == pytest.approx(6.0)
    data = json.loads((out / "summary.json").read_text())
    assert data["complete"] and stopped in data["fmu_messages"]
    assert f"- {stopped}" in (out / "report.md").read_text()
    assert len(list(can.LogReader(str(can_log)))) > 100 and can_log.read_text().endswith("\n")
