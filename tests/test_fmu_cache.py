"""Unpacked FMUs kept between runs (``seafmu.fmu_cache``): unpacked once per FMU version and reused,
safe when processes unpack at once, held while in use, pruned when an FMU is rebuilt, and a cache
folder that cannot be used is a one-line error.

Each process that uses the cache runs as a fresh interpreter: a process holds what it unpacked
until it ends, as the tests' own would.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from seafmu import fmu_cache

REPO = Path(__file__).resolve().parents[1]

UNPACK = """
import json, os, sys
from pathlib import Path
from seafmu import fmu_cache
folder = fmu_cache.unpacked(Path(sys.argv[1]))
st = os.stat(folder / "modelDescription.xml")
print(json.dumps({"folder": str(folder), "made": [st.st_ino, st.st_ctime_ns]}), flush=True)
if len(sys.argv) > 2:  # hold it until told to end
    sys.stdin.readline()
"""


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, fmu_cache.ENV: str(cache)}


def _unpack(fmu: Path, cache: Path) -> dict[str, object]:
    proc = subprocess.run([sys.executable, "-c", UNPACK, str(fmu)], cwd=REPO, env=_env(cache),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _holding(fmu: Path, cache: Path) -> tuple[subprocess.Popen[str], dict[str, object]]:
    """A process that unpacked ``fmu`` and holds it until its stdin closes."""
    proc = subprocess.Popen([sys.executable, "-c", UNPACK, str(fmu), "hold"], cwd=REPO, env=_env(cache),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    return proc, json.loads(proc.stdout.readline())


def _versions(cache: Path) -> list[str]:
    return sorted(p.name for p in cache.iterdir())


def _rebuilt(fmu: Path, folder: Path, n: int) -> Path:
    """Another version of ``fmu`` (a rebuild: same file name, other content)."""
    folder.mkdir(parents=True)
    copy = folder / fmu.name
    copy.write_bytes(fmu.read_bytes())
    with zipfile.ZipFile(copy, "a") as z:
        z.writestr("documentation/build.txt", f"build {n}\n")
    return copy


@pytest.fixture
def plant(built_fmus: dict) -> Path:
    return Path(built_fmus[("minerva2", "plant")])


def test_an_fmu_is_unpacked_once_and_reused_by_later_processes(plant: Path, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    first, second = _unpack(plant, cache), _unpack(plant, cache)
    assert first == second  # the same folder, the same files: not unpacked again
    folder = Path(str(first["folder"]))
    assert folder.parent == cache and folder.name == f"{plant.stem}-{fmu_cache.digest(plant)}"
    with zipfile.ZipFile(plant) as z:  # complete: every member of the FMU is there, byte for byte
        for info in z.infolist():
            if not info.is_dir():
                assert (folder / info.filename).read_bytes() == z.read(info), info.filename
    assert _versions(cache) == [folder.name]  # nothing else left: no half-unpacked folder


def test_processes_unpacking_the_same_fmu_at_once_share_one_copy(plant: Path, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    procs = [subprocess.Popen([sys.executable, "-c", UNPACK, str(plant)], cwd=REPO, env=_env(cache),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(6)]
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
        outs.append(json.loads(out))
    assert len({json.dumps(o, sort_keys=True) for o in outs}) == 1  # all on the very same files
    assert _versions(cache) == [Path(str(outs[0]["folder"])).name]


def test_a_rebuilt_fmu_prunes_old_versions_but_never_one_in_use(plant: Path, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    builds = [_rebuilt(plant, tmp_path / f"build{i}", i) for i in range(6)]
    holder, held = _holding(builds[0], cache)  # the oldest version, in use by a living process
    try:
        for b in builds[1:]:
            _unpack(b, cache)
            time.sleep(0.02)  # distinct last-use times
        names = _versions(cache)
        digests = [f"{plant.stem}-{fmu_cache.digest(b)}" for b in builds]
        # the held one, and the KEEP most recently used of the others; nothing half-done
        assert names == sorted([digests[0], *digests[-fmu_cache.KEEP:]])
        assert Path(str(held["folder"])).name == digests[0]
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=30)
    _unpack(_rebuilt(plant, tmp_path / "build6", 6), cache)  # released: now pruned like the others
    assert digests[0] not in _versions(cache) and len(_versions(cache)) == fmu_cache.KEEP


def test_what_a_killed_unpacking_left_is_removed_and_a_running_one_is_not(plant: Path,
                                                                          tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    killed = cache / f"{fmu_cache._UNPACKING}{plant.stem}-0123456789abcdef0123-x"
    (killed / "resources").mkdir(parents=True)
    (killed / fmu_cache.LOCK).touch()  # its lock was released when its process died
    running = cache / f"{fmu_cache._UNPACKING}{plant.stem}-0123456789abcdef0123-y"
    running.mkdir()
    fd = os.open(running / fmu_cache.LOCK, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as an unpacking process holds it
        _unpack(plant, cache)
        names = _versions(cache)
        assert killed.name not in names and running.name in names
    finally:
        os.close(fd)


def test_a_cache_folder_that_cannot_be_used_is_a_one_line_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a folder")
    bad = tmp_path / "file" / "cache"
    proc = subprocess.run([sys.executable, "-m", "seafmu.cli", "run", "minerva2_dp", "-q", "-o",
                           str(tmp_path / "out")], cwd=REPO, env=_env(bad), capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"seafmu: error: {fmu_cache.ENV}={bad}: cannot create or write that folder"]


def test_the_shared_temp_fallback_is_refused_when_others_may_write_it(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """With no usable cache folder in the home, the temp folder's ``seafmu-fmus-<uid>`` is used, but
    only if nobody else can write it: whoever could plant files there could run code in every run."""
    monkeypatch.delenv(fmu_cache.ENV, raising=False)
    (tmp_path / "home").write_text("not a folder")  # ~/.cache cannot be made
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home" / "cache"))
    monkeypatch.setattr(fmu_cache.tempfile, "gettempdir", lambda: str(tmp_path))
    fallback = tmp_path / f"seafmu-fmus-{os.getuid()}"
    assert fmu_cache.root() == fallback and (fallback.stat().st_mode & 0o777) == 0o700
    fmu_cache._roots.clear()
    fallback.chmod(0o777)
    with pytest.raises(fmu_cache.CacheError, match=f"{fallback}: not a folder of this user's"):
        fmu_cache.root()
    fmu_cache._roots.clear()


def test_a_version_removed_while_a_process_waits_to_hold_it_is_unpacked_again(plant: Path,
                                                                             tmp_path: Path) -> None:
    """A process that finds a version just as another removes it (pruning holds the exclusive lock)
    waits, sees the version gone, and unpacks it anew: it never runs from a half-removed folder."""
    cache = tmp_path / "cache"
    first = _unpack(plant, cache)
    version = Path(str(first["folder"]))
    fd = os.open(version / fmu_cache.LOCK, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as a pruning process does while it removes the version
        proc = subprocess.Popen([sys.executable, "-c", UNPACK, str(plant)], cwd=REPO, env=_env(cache),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(1.0)
        assert proc.poll() is None  # waiting for the lock
        gone = cache / f"{fmu_cache._REMOVING}{version.name}-test"
        version.rename(gone)
        shutil.rmtree(gone)
    finally:
        os.close(fd)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    again = json.loads(out)
    assert again["folder"] == str(version) and again["made"] != first["made"]  # unpacked anew, same place
    assert (version / "modelDescription.xml").is_file() and _versions(cache) == [version.name]


def test_a_file_system_without_locks_is_a_one_line_error_naming_the_fix(
        plant: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Some network mounts refuse ``flock`` (ENOLCK): the error names the folder and the variable
    that moves the cache to a local disk, instead of a bare errno."""
    import errno

    def no_locks(fd: int, op: int) -> None:
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setenv(fmu_cache.ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(fmu_cache.fcntl, "flock", no_locks)
    with pytest.raises(fmu_cache.CacheError) as info:
        fmu_cache.unpacked(plant)
    version = tmp_path / "cache" / f"{plant.stem}-{fmu_cache.digest(plant)}"
    assert str(info.value) == (f"{version}: cannot unpack or lock the FMU there (No locks available); "
                               f"set {fmu_cache.ENV} to a folder on a local disk")
    assert version not in fmu_cache._held and not list((tmp_path / "cache").iterdir())  # nothing half-made
