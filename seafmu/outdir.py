"""The output folder of ``seafmu run``: one run at a time, no stale files, files complete or absent.

- A run holds an exclusive ``fcntl.flock`` on ``<folder>/.seafmu-run.lock`` (its PID inside) for
  its whole life; a second run into the same folder fails at once with one line (exit 2). The
  kernel drops the lock when the process ends, however it ends, so a killed run never leaves the
  folder locked. The lock file itself stays (deleting it would let two runs lock two files).
- Under the lock, the previous run's outputs (``OUTPUTS``, ``OUTPUT_DIRS``) are removed before
  anything is written: old and new files are never mixed. Other files in the folder are left alone.
- Files written whole (summary, plots, report) are written to a temporary name in the same folder
  and renamed over the target (``os.replace``, atomic on POSIX): a reader sees the old or the new
  file, never half of one, whenever the writer is stopped.
- Every command that writes a folder (run, identify, diagnose, testplan, export --osp) first checks
  it (``check_output_folder``): a folder that holds files but none of ``SIGNATURES`` is the user's,
  not an earlier seafmu output, and is refused before anything is written (its results.csv or
  report.md would be replaced). The commands other than run mark their folder with ``MARKER``
  (run's mark is its lock file), so a rerun after a failure half-way is recognised too.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import os
import shutil
from collections.abc import Iterator
from itertools import islice
from pathlib import Path

LOCK_FILE = ".seafmu-run.lock"
SWEEP_LOCK_FILE = ".seafmu-sweep.lock"  # a study folder's (seafmu/sweep/execute.py)
OUTPUTS = ("results.csv", "results.parquet", "summary.json", "report.md", "trajectory.png", "states.png",
           "thrusters.png", "allocation.png")
OUTPUT_DIRS = ("recording",)
MARKER = ".seafmu-output"
# A folder holding one of these was written by seafmu: the marker, run's and sweep's lock files, and
# the files the commands wrote before the marker existed (run and testplan summary.json, identify and
# diagnose their reports, export --osp its system structure, sweep its cases).
SIGNATURES = (MARKER, LOCK_FILE, SWEEP_LOCK_FILE, "summary.json", "identification.json",
              "identification.md", "diagnosis.json", "diagnosis.md", "OspSystemStructure.xml",
              "cases.parquet")


class OutputFolderError(RuntimeError):
    """The output folder cannot be used (locked by another run, the user's own folder); one line."""


def nonempty_path(text: str) -> str:
    """An argparse type for a path option: an empty path would silently mean the current folder or
    the default (``Path("")`` is ``.``), so it is refused by name."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty path; give a path or leave the flag out")
    return text


def check_output_folder(path: Path) -> None:
    """Refuse, before anything is written, an output folder that exists, is not empty and holds none
    of ``SIGNATURES`` (the user's own files would be replaced), or whose path runs through a file.
    A new folder, an empty one and an earlier seafmu output folder are fine."""
    path = Path(path)
    for parent in path.parents:  # the nearest existing ancestor must be a folder to create one in
        if parent.exists():
            if not parent.is_dir():
                raise OutputFolderError(f"{path}: {parent} is a file, not a folder")
            break
    if path.exists() and not path.is_dir():
        raise OutputFolderError(f"{path}: file exists")  # the message of run's mkdir before this check
    if not path.is_dir() or any((path / name).exists() for name in SIGNATURES):
        return
    held = sorted(p.name for p in islice(path.iterdir(), 50))
    if held:
        shown = ", ".join(held[:3]) + (", ..." if len(held) > 3 else "")
        raise OutputFolderError(f"{path}: not empty and not a seafmu output folder (it holds {shown}); "
                                "seafmu would replace files there: give a new or empty folder")


def claim_output_folder(path: Path) -> None:
    """Check the folder (``check_output_folder``), create it and mark it as seafmu's (``MARKER``),
    for the commands that have no lock file."""
    check_output_folder(path)
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).touch()


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path``; renamed over it when the block ends without error."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def atomic_write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())


class RunFolder:
    """``with RunFolder(path):`` — the folder created, locked for this run, and cleared of old outputs."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._fd: int | None = None

    def __enter__(self) -> RunFolder:
        check_output_folder(self.path)  # the lock file marks the folder as a run's from here on
        self.path.mkdir(parents=True, exist_ok=True)
        lock = self.path / LOCK_FILE
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            os.close(fd)
            who = f" (pid {owner})" if owner.isdigit() else ""
            raise OutputFolderError(f"{self.path}: in use by another seafmu run{who}; wait for it to end "
                                    "or choose another folder with -o") from None
        except OSError:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        try:
            self.clear()
        except BaseException:
            self.release()
            raise
        return self

    def clear(self) -> None:
        """Remove the outputs a previous run left (and the temporary files of a killed one)."""
        for name in OUTPUTS:
            for p in (self.path / name, *self.path.glob(f".{name}.*.tmp")):
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
        for name in OUTPUT_DIRS:
            d = self.path / name
            if d.is_dir() and not d.is_symlink():
                shutil.rmtree(d)
            elif d.exists() or d.is_symlink():
                d.unlink()

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __exit__(self, *exc: object) -> None:
        self.release()


def os_error_text(exc: OSError) -> str:
    """'<file>: <what is wrong>', the command line's wording of an OSError (its str is '[Errno 17]
    File exists: '<file>''); its str where it names no file."""
    if exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror[:1].lower()}{exc.strerror[1:]}"
    return str(exc)
