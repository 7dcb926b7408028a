"""TCP listener shared by the fake's three servers: loopback only, one thread per client."""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import socket
import threading
from collections.abc import Callable

from lasercal_hw.errors import ConfigError, TransportError

logger = logging.getLogger(__name__)

Handler = Callable[[socket.socket], None]


def require_loopback(address: str) -> str:
    """The address if it is an IPv4 loopback address (127.0.0.0/8); ConfigError otherwise."""
    try:
        parsed = ipaddress.ip_address(address)
    except ValueError as exc:
        raise ConfigError(f"fake robot address {address!r} is not an IP address; use 127.0.0.X") from exc
    if parsed.version != 4 or not parsed.is_loopback:
        raise ConfigError(f"fake robot address {address} is not a loopback address; "
                          "fakes bind only to 127.0.0.X")
    return address


class TcpListener:
    """Accepts clients on ``address:port`` and runs ``handler(sock)`` for each on its own
    thread. ``close_clients`` drops every connection (fault injection); ``close`` also
    stops listening."""

    def __init__(self, address: str, port: int, handler: Handler, name: str) -> None:
        self.address = require_loopback(address)
        self.port = port
        self.name = name
        self._handler = handler
        self._clients: set[socket.socket] = set()
        self._clients_lock = threading.Lock()
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._server.bind((address, port))
        except OSError as exc:
            self._server.close()
            raise TransportError(f"cannot listen on {address}:{port} ({name}): {exc.strerror}; "
                                 "is another fake running on this address?") from exc
        self._server.listen(8)
        self._thread = threading.Thread(target=self._accept_loop, name=f"fake-ur-{name}-accept", daemon=True)

    def start(self) -> None:
        """Start accepting."""
        self._thread.start()

    def _accept_loop(self) -> None:
        while True:
            try:
                client, _ = self._server.accept()
            except OSError:
                return  # listener closed
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._clients_lock:
                self._clients.add(client)
            threading.Thread(target=self._serve, args=(client,), name=f"fake-ur-{self.name}",
                             daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        try:
            self._handler(client)
        except OSError as exc:
            logger.debug("%s client ended: %s", self.name, exc)
        except Exception:
            logger.exception("%s client handler failed", self.name)
        finally:
            with self._clients_lock:
                self._clients.discard(client)
            client.close()

    def close_clients(self) -> None:
        """Shut down every client connection (their handlers then end)."""
        with self._clients_lock:
            clients = list(self._clients)
        for client in clients:
            with contextlib.suppress(OSError):
                client.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        """Stop listening and drop every client."""
        with contextlib.suppress(OSError):
            self._server.shutdown(socket.SHUT_RDWR)
        self._server.close()
        self.close_clients()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)


def read_lines(sock: socket.socket) -> Callable[[], str | None]:
    """A reader returning one line at a time (without CR/LF), None at EOF."""
    buffer = bytearray()

    def next_line() -> str | None:
        while b"\n" not in buffer:
            chunk = sock.recv(4096)
            if not chunk:
                return None
            buffer.extend(chunk)
        index = buffer.index(b"\n")
        line = bytes(buffer[:index])
        del buffer[:index + 1]
        return line.decode("utf-8", errors="replace").rstrip("\r")

    return next_line
