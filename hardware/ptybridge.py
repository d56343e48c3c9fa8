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
import os
import select
import threading
import tty
from pathlib import Path


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
        self._links: list[Path] = []
        for link, target in ((link_a, self.a), (link_b, self.b)):
            if link is not None:
                p = Path(link)
                p.parent.mkdir(parents=True, exist_ok=True)
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
                p.symlink_to(target)
                self._links.append(p)
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
        for p in self._links:
            with contextlib.suppress(OSError):
                p.unlink()

    def __enter__(self) -> NullModem:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
