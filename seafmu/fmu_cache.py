"""Unpacked FMUs kept between runs, one folder per FMU file content, in the user's cache folder.

Why: an FMU runs from its unpacked folder (fmpy loads its binary from a file, pythonfmu imports its
Python from ``resources/``), and unpacking a seafmu vessel's four FMUs makes ~470 files. On the
project's 2-core test machine (ext4, online discard) that took 0.05 s on a quiet disk and 0.3-0.6 s
right after other runs had removed theirs: on the critical path of every ``seafmu run`` and of a
sweep's first case (its fork server unpacks them). A folder made once per FMU version and reused by
every later process costs a hash of the file (~1 ms). OSP's libcosim keeps its unpacked FMUs the
same way (its persistent file cache).

Where: ``$SEAFMU_FMU_CACHE`` if set, else ``$XDG_CACHE_HOME/seafmu/fmus`` (default
``~/.cache/seafmu/fmus``); if that cannot be written, ``<temp folder>/seafmu-fmus-<uid>``, used only
when this user owns it and nobody else may write it (anyone who could plant files in it could run
code in every later run). Each FMU version is ``<file stem>-<SHA-256 of the file, 20 hex digits>/``:
unpacked into a private folder beside it and renamed into place, so a folder under its final name
is complete; two processes unpacking the same FMU at once both succeed, one copy is dropped.

In use: a process holds a shared ``flock`` on the version's ``.lock`` until it ends (a forked child,
such as a sweep's worker, shares it). When a new version of an FMU is unpacked (the FMU was
rebuilt), versions of the same FMU beyond the ``KEEP`` most recently used are removed, except those
a living process holds; so are the half-unpacked folders of a killed process.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

ENV = "SEAFMU_FMU_CACHE"
KEEP = 3  # versions of one FMU kept: a few checkouts or branches built in turn do not unpack again
LOCK = ".lock"
_UNPACKING = ".unpacking-"  # a version being unpacked, renamed to its final name when complete
_REMOVING = ".removing-"  # a version being removed
_VERSION = re.compile(r"(?P<stem>.+)-(?P<digest>[0-9a-f]{20})")
_held: dict[Path, int] = {}  # versions this process uses: the descriptor holding the shared lock
_roots: dict[tuple[str | None, str | None, str], Path] = {}  # root() by the variables that choose it


class CacheError(OSError):
    """The cache folder cannot be used; the message is one line naming it and the fix."""


# The same folder rule and write test as the kernels' numba cache (``components/kernels/_jit.py``),
# not imported from there: that module imports numba (~0.1 s), which a run that only unpacks does not need.
def _default_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "seafmu" / "fmus"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def _private_temp_root() -> Path:
    path = Path(tempfile.gettempdir()) / f"seafmu-fmus-{os.getuid()}"
    with contextlib.suppress(FileExistsError):
        path.mkdir(mode=0o700)
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise CacheError(f"{path}: not a folder of this user's that only it can write; set {ENV} to "
                         "a folder of yours to keep unpacked FMUs in")
    return path


def root() -> Path:
    """The folder holding the unpacked FMUs (made if needed)."""
    explicit = os.environ.get(ENV)
    key = (explicit, os.environ.get("XDG_CACHE_HOME"), os.path.expanduser("~"))
    if key not in _roots:
        if explicit:
            if not _writable(Path(explicit)):
                raise CacheError(f"{ENV}={explicit}: cannot create or write that folder")
            _roots[key] = Path(explicit)
        else:
            default = _default_root()
            _roots[key] = default if _writable(default) else _private_temp_root()
    return _roots[key]


def digest(fmu: Path) -> str:
    with open(fmu, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()[:20]


def unpacked(fmu: Path) -> Path:
    """The folder ``fmu`` is unpacked in, held by this process until it ends."""
    version = root() / f"{Path(fmu).stem}-{digest(fmu)}"
    if version in _held:
        return version
    try:
        for _ in range(3):  # a version removed between finding and holding it is unpacked again
            fd = _hold(version)
            if fd is not None:
                _held[version] = fd
                return version
            _unpack(Path(fmu), version)
    except CacheError:
        raise
    except OSError as exc:  # a full disk, or a file system without locks (some network mounts)
        raise CacheError(f"{version}: cannot unpack or lock the FMU there ({exc.strerror or exc}); "
                         f"set {ENV} to a folder on a local disk") from None
    raise CacheError(f"{version}: removed by another process each time it was unpacked")


def _hold(version: Path) -> int | None:
    """A descriptor holding a shared lock on ``version``, or None if it is not there (any more)."""
    try:
        fd = os.open(version / LOCK, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH)  # waits only while a pruning process removes this very version
    except OSError:
        os.close(fd)
        raise
    # Removal happens under the exclusive lock, so once this one is shared the lock file is either
    # still where it was opened (the version is in place) or gone with its folder.
    try:
        held = os.fstat(fd)
        in_place = held.st_nlink > 0 and os.stat(version / LOCK).st_ino == held.st_ino
    except FileNotFoundError:
        in_place = False
    if not in_place:
        os.close(fd)
        return None
    with contextlib.suppress(OSError):
        os.utime(version / LOCK)  # last use, for pruning
    return fd


def _unpack(fmu: Path, version: Path) -> None:
    from fmpy import extract

    tmp = Path(tempfile.mkdtemp(prefix=f"{_UNPACKING}{version.name}-", dir=version.parent))
    fd = None
    try:
        try:
            fd = os.open(tmp / LOCK, os.O_RDWR | os.O_CREAT, 0o600)
            fcntl.flock(fd, fcntl.LOCK_EX)  # an unpacking in progress is not taken for a killed one's
            extract(str(fmu), unzipdir=str(tmp))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        try:
            os.rename(tmp, version)  # atomic: complete under its final name, or not there
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not version.is_dir():  # not another process's copy taking the name first
                raise
            return
    finally:
        if fd is not None:
            os.close(fd)
    _prune(version)


def _remove_unused(folder: Path) -> None:
    """Remove ``folder`` unless a living process holds its lock. A folder being removed whose lock
    file is gone (its remover was killed midway) goes too; one being unpacked without a lock file
    yet (its unpacker just made it) stays."""
    try:
        fd: int | None = os.open(folder / LOCK, os.O_RDONLY)
    except FileNotFoundError:
        if not folder.name.startswith(_REMOVING):
            return
        fd = None
    except OSError:
        return
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # held: in use, or being unpacked or removed
                return
        gone = folder
        if not folder.name.startswith(_REMOVING):
            gone = folder.parent / f"{_REMOVING}{folder.name}-{os.getpid()}"
            try:
                os.rename(folder, gone)  # its name is free at once
            except OSError:  # renamed or removed meanwhile by another process
                return
        shutil.rmtree(gone, ignore_errors=True)
    finally:
        if fd is not None:
            os.close(fd)  # a process waiting to hold this version now finds its lock file unlinked


def _prune(made: Path, keep: int = KEEP) -> None:
    """After ``made`` was unpacked: remove the versions of the same FMU beyond the ``keep`` most
    recently used and not in use, and what killed processes left."""
    stem = made.name.rsplit("-", 1)[0]  # ``made`` is named ``<stem>-<digest>`` by ``unpacked``
    versions = []
    for d in made.parent.iterdir():
        if d.name.startswith((_UNPACKING, _REMOVING)):
            _remove_unused(d)
            continue
        m = _VERSION.fullmatch(d.name)
        if m and m["stem"] == stem and d != made:
            try:
                versions.append((os.stat(d / LOCK).st_mtime, d))
            except OSError:
                continue
    versions.sort(reverse=True)
    for _, d in versions[max(0, keep - 1):]:
        _remove_unused(d)
