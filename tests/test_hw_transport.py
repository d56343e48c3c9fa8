"""Serial transport over pyserial's socket:// URL: a networked NMEA multiplexer (loopback only)."""

from __future__ import annotations

import socket
import threading
import time
from collections import Counter

from seafmu.hardware.transport import SerialLines


def test_socket_url_delivers_every_line_each_poll() -> None:
    """40 lines sent in bursts must all arrive, several per poll (pyserial's socket handler reports
    at most one waiting byte; reading that little starved the loop)."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    lines = [f"$GPHDT,{i:.1f},T*00".encode() for i in range(40)]

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            time.sleep(0.2)  # pyserial flushes the input when it opens: send after that
            for k in range(0, 40, 4):
                conn.sendall(b"\r\n".join(lines[k : k + 4]) + b"\r\n")
                time.sleep(0.02)
            conn.settimeout(5.0)
            conn.recv(1)  # hold the line until the client hangs up

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    port_lines = SerialLines(f"socket://127.0.0.1:{port}", 115200, {}, 1.0, Counter())
    got: list[bytes] = []
    polls = 0
    deadline = time.monotonic() + 3.0
    while len(got) < 40 and time.monotonic() < deadline:
        got += port_lines.read_lines()
        polls += 1
        time.sleep(0.05)  # a 20 Hz loop
    port_lines.close()
    server.close()
    assert got == lines
    assert polls < 15  # all within a few polls of the bursts, not one byte per poll
