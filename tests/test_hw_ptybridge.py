"""The null-modem's fixed pty paths (``pty:PATH``): one owner at a time, stale ones taken over.

The reported case: a second emulator given the same path replaced the first one's symlink without
a word, so a link opening the path talked to whichever emulator came last (a HIL recording that
mixed two vessels: a thruster's efficiency diagnosed at 0.53 where the emulator ran 0.6)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from seafmu.hardware.ptybridge import NullModem, PortInUse
from seafmu.scenario import REPO


def test_a_held_path_is_refused_and_left_to_its_owner(tmp_path: Path) -> None:
    link = tmp_path / "nmea"
    with NullModem(link_b=link) as first:
        with pytest.raises(PortInUse, match=f"{link}: in use by another process \\(pid {os.getpid()}"):
            NullModem(link_b=link)
        assert os.readlink(link) == first.b  # still the first one's
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # its link and lock removed at close


def test_a_second_emulator_on_the_same_ports_exits_with_one_line(tmp_path: Path) -> None:
    serial, slcan = tmp_path / "nmea", tmp_path / "slcan"
    argv = [sys.executable, "-m", "seafmu.emulate", "minerva2", "--serial", f"pty:{serial}",
            "--can", f"slcan:pty:{slcan}", "--duration", "30"]
    first = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert first.stdout is not None and first.stdout.readline().startswith("READY")
        held = os.readlink(serial)
        second = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
        assert second.returncode == 2 and second.stdout == "", second
        assert second.stderr.strip() == (
            f"seafmu emulate: error: {serial}: in use by another process (pid {first.pid}, e.g. another "
            "`seafmu emulate`): stop it, or give another pty:PATH")
        assert os.readlink(serial) == held and first.poll() is None  # the first one untouched
    finally:
        first.terminate()
        first.wait(timeout=10)
    assert not serial.exists() and not slcan.exists()


def test_a_path_left_by_a_killed_process_is_taken_over(tmp_path: Path) -> None:
    link = tmp_path / "nmea"
    code = (f"from seafmu.hardware.ptybridge import NullModem; import time; NullModem(link_b={str(link)!r}); "
            "print('up', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "up"
    proc.kill()  # no close: its symlink and lock file stay behind
    proc.wait(timeout=10)
    assert link.is_symlink() and (tmp_path / "nmea.lock").exists()
    with NullModem(link_b=link) as nm:
        assert os.readlink(link) == nm.b
    assert not link.is_symlink() and not (tmp_path / "nmea.lock").exists()


def test_a_file_at_the_path_is_refused_and_kept(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("mine")
    with pytest.raises(PortInUse, match="exists and is not a pty link"):
        NullModem(link_b=path)
    assert path.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
