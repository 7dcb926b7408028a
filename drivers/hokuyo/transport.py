"""Byte transports to a SCIP scanner: TCP (Ethernet units) and serial (USB/RS-232, ptys).

Selected by URL (``open_transport``):

* ``scip+tcp://HOST[:PORT]`` (port 10940 by default)
* ``scip+serial:///dev/ttyACM0[?baud=115200]`` (any device pyserial's
  ``serial_for_url`` opens, so pseudo-terminals work too)

Reads return whatever bytes arrived (at least one); message framing is the codec's
job. A read that gets nothing within its timeout raises ``DeviceTimeoutError``; a
closed or failed connection raises ``TransportError``.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import time
from dataclasses import dataclass
from typing import Protocol
from urllib.parse import parse_qs, urlsplit

import serial

from drivers.loopback import check_host
from lasercal_hw.errors import ConfigError, DeviceTimeoutError, TransportError

logger = logging.getLogger(__name__)

DEFAULT_TCP_PORT = 10940
DEFAULT_BAUD = 115200
READ_CHUNK_BYTES = 65536
ACCEPTED_FORMS = "scip+tcp://HOST[:PORT] (default port 10940) or scip+serial:///dev/ttyACM0[?baud=115200]"


class Transport(Protocol):
    """A bidirectional byte stream to one scanner."""

    url: str

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        ...

    def read_some(self, timeout_s: float) -> bytes:
        """At least one received byte; ``DeviceTimeoutError`` when none came in ``timeout_s``."""
        ...

    def close(self) -> None:
        """Close the connection; safe to call twice."""
        ...


@dataclass(frozen=True)
class TransportUrl:
    """A parsed scanner URL."""

    kind: str  # "tcp" or "serial"
    host: str = ""
    port: int = DEFAULT_TCP_PORT
    device: str = ""
    baud: int = DEFAULT_BAUD

    def __str__(self) -> str:
        if self.kind == "tcp":
            host = f"[{self.host}]" if ":" in self.host else self.host
            return f"scip+tcp://{host}:{self.port}"
        return f"scip+serial://{self.device}?baud={self.baud}"


def parse_url(url: str) -> TransportUrl:
    """Parse a scanner URL; ``ConfigError`` naming the accepted forms when it is not one."""
    try:
        parts = urlsplit(url.strip())
        if parts.scheme == "scip+tcp":
            if not parts.hostname or parts.path not in ("", "/") or parts.query:
                raise ValueError("needs a host and nothing after it")
            port = DEFAULT_TCP_PORT if parts.port is None else parts.port
            if port == 0:
                raise ValueError("port 0 is no port a scanner listens on; leave it out for 10940")
            return TransportUrl("tcp", host=parts.hostname, port=port)
        if parts.scheme == "scip+serial":
            if parts.netloc or not parts.path:
                raise ValueError("needs a device path such as /dev/ttyACM0")
            query = parse_qs(parts.query, strict_parsing=bool(parts.query))
            unknown = set(query) - {"baud"}
            if unknown:
                raise ValueError(f"unknown option(s) {', '.join(sorted(unknown))}")
            baud = int(query.get("baud", [str(DEFAULT_BAUD)])[-1])
            if baud <= 0:
                raise ValueError("baud must be positive")
            return TransportUrl("serial", device=parts.path, baud=baud)
    except ValueError as exc:
        raise ConfigError(f"bad scanner URL {url!r} ({exc}); use {ACCEPTED_FORMS}") from exc
    raise ConfigError(f"bad scanner URL {url!r}; use {ACCEPTED_FORMS}")


class TcpTransport:
    """SCIP over TCP (sensor is the server), with ``TCP_NODELAY``."""

    def __init__(self, address: TransportUrl, connect_timeout_s: float) -> None:
        self.url = str(address)
        check_host(str(address.host), "the scanner")
        try:
            self._sock: socket.socket | None = socket.create_connection(
                (address.host, address.port), timeout=connect_timeout_s
            )
        except TimeoutError as exc:
            raise DeviceTimeoutError(
                f"cannot connect to {self.url}: no answer within {connect_timeout_s:g} s; "
                "is the scanner powered and reachable?"
            ) from exc
        except OSError as exc:
            reason = exc.strerror or str(exc)
            raise TransportError(
                f"cannot connect to {self.url}: {reason}; is the scanner powered and reachable?"
            ) from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _socket(self) -> socket.socket:
        if self._sock is None:
            raise TransportError(f"connection to {self.url} is closed")
        return self._sock

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        sock = self._socket()
        try:
            sock.settimeout(5.0)
            sock.sendall(data)
        except TimeoutError as exc:
            raise DeviceTimeoutError(f"{self.url}: scanner does not accept data") from exc
        except OSError as exc:
            raise TransportError(f"{self.url}: write failed: {exc}") from exc

    def read_some(self, timeout_s: float) -> bytes:
        """At least one byte; ``DeviceTimeoutError`` after ``timeout_s`` without data."""
        sock = self._socket()
        try:
            sock.settimeout(max(timeout_s, 1e-4))
            data = sock.recv(READ_CHUNK_BYTES)
        except TimeoutError as exc:
            raise DeviceTimeoutError(f"{self.url}: no data within {timeout_s:g} s") from exc
        except OSError as exc:
            raise TransportError(f"{self.url}: connection failed: {exc}") from exc
        if not data:
            raise TransportError(f"{self.url}: connection closed by the scanner")
        return data

    def close(self) -> None:
        """Close the socket; safe to call twice."""
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.shutdown(socket.SHUT_RDWR)
            self._sock.close()
            self._sock = None


class SerialTransport:
    """SCIP over a serial device (USB CDC-ACM, RS-232 or a pseudo-terminal)."""

    def __init__(self, address: TransportUrl) -> None:
        self.url = str(address)
        try:
            self._port: serial.SerialBase | None = serial.serial_for_url(
                address.device, baudrate=address.baud, timeout=0.1, write_timeout=5.0
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(
                f"cannot open {self.url}: {exc}; is the scanner plugged in and the device readable?"
            ) from exc

    def _serial(self) -> serial.SerialBase:
        if self._port is None:
            raise TransportError(f"connection to {self.url} is closed")
        return self._port

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        port = self._serial()
        try:
            port.write(data)
            port.flush()
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeoutError(f"{self.url}: scanner does not accept data") from exc
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"{self.url}: write failed: {exc}") from exc

    def read_some(self, timeout_s: float) -> bytes:
        """At least one byte; ``DeviceTimeoutError`` after ``timeout_s`` without data."""
        port = self._serial()
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                waiting = port.in_waiting
                if waiting:
                    return port.read(min(waiting, READ_CHUNK_BYTES))
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceTimeoutError(f"{self.url}: no data within {timeout_s:g} s")
                port.timeout = min(remaining, 0.5)
                first = port.read(1)
                if first:
                    return first + port.read(min(port.in_waiting, READ_CHUNK_BYTES))
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"{self.url}: device failed or was closed: {exc}") from exc

    def set_baud(self, baud: int) -> None:
        """Follow a bit-rate change the scanner accepted (SS)."""
        try:
            self._serial().baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(f"{self.url}: cannot switch to {baud} bit/s: {exc}") from exc

    def close(self) -> None:
        """Close the port; safe to call twice."""
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                logger.debug("error while closing %s", self.url, exc_info=True)
            self._port = None


def open_transport(url: str, connect_timeout_s: float = 3.0) -> Transport:
    """Open the transport a scanner URL names (see the module docstring)."""
    address = parse_url(url)
    if address.kind == "tcp":
        return TcpTransport(address, connect_timeout_s)
    return SerialTransport(address)
