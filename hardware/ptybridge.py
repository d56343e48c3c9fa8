"""A virtual null-modem cable: two pseudo-terminals whose bytes are copied across by a thread.

Each end is an ordinary tty device (``/dev/pts/N``) that pyserial and python-can's slcan open like
a USB adapter, so both the vessel emulator and seafmu's link run their real serial code, in
different processes. (It is what ``socat pty,raw,echo=0 pty,raw,echo=0`` does; socat is not a
Python dependency, and a pty's own master side has no device path a port could open.)

Like a real line with nobody listening, bytes for an end that is not being read are dropped once
the kernel buffer is full, never blocking the other end.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import threading
import tty
from pathlib import Path


class PortInUse(OSError):
    """A pty path another live process holds."""


def _lock_path(link: Path) -> Path:
    return link.with_name(link.name + ".lock")


def _claim(link: Path) -> int:
    """Hold ``LINK.lock`` (an flock, which the kernel releases when this process ends, however it
    ends) while ``link`` is this bridge's. Why: a second emulator given the same path replaced the
    first one's symlink without a word, and a link opening the path then talked to whichever
    emulator came last (a HIL recording mixed two vessels). A lock left by a process that has
    ended is free and taken over. Returns the lock's fd; raises ``PortInUse`` naming the holder."""
    path = _lock_path(link)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise PortInUse(f"{link}: in use by another process (pid {holder}, e.g. another "
                            "`seafmu emulate`): stop it, or give another pty:PATH") from None
        # the holder before us may have removed the file between our open and our lock (it does so
        # at close, still holding it): a lock on a removed file guards nothing, so take the new one
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)


class NullModem:
    """Two linked ptys: ``a`` and ``b`` are device paths; optional symlinks give them fixed names."""

    def __init__(self, link_a: str | Path | None = None, link_b: str | Path | None = None) -> None:
        self._fds: list[int] = []
        ma, sa = os.openpty()
        mb, sb = os.openpty()
        # The slave fds stay open here: a pty whose slave is closed reports EIO on the master and
        # loses its settings; raw mode so neither end echoes or translates CR/LF.
        for fd in (sa, sb):
            tty.setraw(fd)
        for fd in (ma, mb):
            os.set_blocking(fd, False)
        self._fds = [ma, mb, sa, sb]
        self.a, self.b = os.ttyname(sa), os.ttyname(sb)
        self.dropped = 0
        self._links: list[tuple[Path, str, int]] = []  # (symlink, its target, its lock's fd)
        try:
            for link, target in ((link_a, self.a), (link_b, self.b)):
                if link is not None:
                    p = Path(link)
                    p.parent.mkdir(parents=True, exist_ok=True)
                    self._links.append((p, target, _claim(p)))
                    if p.is_symlink():
                        p.unlink()  # left by a process that ended without closing
                    elif p.exists():
                        raise PortInUse(f"{p}: exists and is not a pty link: give another pty:PATH")
                    p.symlink_to(target)
        except BaseException:
            self._release_links()
            for fd in self._fds:
                os.close(fd)
            raise
        self._wake_r, self._wake_w = os.pipe()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="null-modem", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        ma, mb = self._fds[0], self._fds[1]
        other = {ma: mb, mb: ma}
        while not self._stop:
            ready, _, _ = select.select([ma, mb, self._wake_r], [], [], 1.0)
            for fd in ready:
                if fd == self._wake_r:
                    return
                try:
                    data = os.read(fd, 65536)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    return
                try:
                    self.dropped += len(data) - os.write(other[fd], data)
                except BlockingIOError:
                    self.dropped += len(data)
                except OSError:
                    return

    def close(self) -> None:
        self._stop = True
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=2.0)
        for fd in [*self._fds, self._wake_r, self._wake_w]:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._fds = []
        self._release_links()

    def _release_links(self) -> None:
        """Remove this bridge's symlinks (only while they still point at its ptys) and their locks."""
        for p, target, lock in self._links:
            with contextlib.suppress(OSError):
                if os.readlink(p) == target:
                    p.unlink()
            with contextlib.suppress(OSError):
                _lock_path(p).unlink()  # still holding the lock: see _claim
            os.close(lock)
        self._links = []

    def __enter__(self) -> NullModem:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
