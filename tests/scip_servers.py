"""A tiny scripted SCIP peer for client tests: TCP (loopback) or a pseudo-terminal.

Each request line (CommandFramer) is passed to ``respond(line) -> bytes``; the bytes
are sent back as they are, so tests can answer with real captured replies, garbage or
truncated messages. ``on_connect`` bytes are sent as soon as a client attaches.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import tty
from collections.abc import Callable

from drivers.hokuyo.codec import CommandFramer


class ScriptedScipServer:
    """Serve one client at a time with a reply function; ``url`` after ``start()``."""

    def __init__(self, respond: Callable[[bytes], bytes], *, pty: bool = False,
                 on_connect: bytes = b"") -> None:
        self.respond = respond
        self.use_pty = pty
        self.on_connect = on_connect
        self.requests: list[bytes] = []
        self.url = ""
        self._stop_r, self._stop_w = os.pipe()
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self.connections = 0
        self._stopped = False
        self._writer: threading.Thread | None = None

    def start(self) -> str:
        if self.use_pty:
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)
            self.url = f"scip+serial://{os.ttyname(self._slave)}"
        else:
            self._listener = socket.create_server(("127.0.0.1", 0))
            self.url = f"scip+tcp://127.0.0.1:{self._listener.getsockname()[1]}"
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        if self.use_pty and self.on_connect:  # a pty buffers a few kB only: write as it is read
            self._writer = threading.Thread(target=self._send, args=(self.on_connect,), daemon=True)
            self._writer.start()
        return self.url

    def _send(self, data: bytes) -> None:
        if not data:
            return
        with contextlib.suppress(OSError):
            if self._conn is not None:
                self._conn.sendall(data)
            elif self._master is not None:
                os.write(self._master, data)

    def _serve(self) -> None:
        framer = CommandFramer()
        while True:
            readers = [self._stop_r]
            if self._listener is not None:
                readers.append(self._listener)
            if self._conn is not None:
                readers.append(self._conn)
            if self._master is not None:
                readers.append(self._master)
            readable, _, _ = select.select(readers, [], [])
            if self._stop_r in readable:
                return
            if self._listener is not None and self._listener in readable:
                conn, _ = self._listener.accept()
                if self._conn is not None:
                    self._conn.close()
                self._conn, framer = conn, CommandFramer()
                self.connections += 1
                self._send(self.on_connect)
                continue
            try:
                if self._conn is not None and self._conn in readable:
                    data = self._conn.recv(65536)
                    if not data:
                        self._conn.close()
                        self._conn = None
                        continue
                elif self._master is not None and self._master in readable:
                    data = os.read(self._master, 65536)
                else:
                    continue
            except OSError:
                continue
            for line in framer.feed(data):
                self.requests.append(line)
                self._send(self.respond(line))

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        os.write(self._stop_w, b"x")
        if self._thread is not None:
            self._thread.join(5)
        for sock in (self._conn, self._listener):
            if sock is not None:
                sock.close()
        for fd in (self._master, self._slave, self._stop_r, self._stop_w):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        if self._writer is not None:
            self._writer.join(5)

    def __enter__(self) -> ScriptedScipServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
