"""A fake Hokuyo UTM-30LX-EW serving SCIP 2.0 over TCP or a pseudo-terminal.

``FakeScannerServer`` runs one thread with a ``select`` loop: it reads request lines
(``CommandFramer``), answers them through ``ScipDevice`` and sends one scan message
per revolution while streaming. Revolutions follow absolute deadlines
(``origin + k * 25 ms``), so the scan rhythm never drifts. Every message is queued
whole, so a reply is never interleaved inside a scan message.

TCP: one client at a time; a second connection while one is open is accepted and
closed at once (refused). When the client disconnects the stream stops and the laser
goes off (urg_sim behaviour). Pseudo-terminal: the fake holds the slave side open in
raw mode, keeps streaming whether or not anyone reads (like a USB sensor) and never
sees a "disconnect". Only loopback addresses can be served.

Reply timing (``reply_timing``): ``"cycle"`` (default) answers commands at the next
revolution boundary like a real unit (scip2.md 6), except TM1/TM2 in time-adjust mode
which are answered at once; ``"immediate"`` answers on arrival.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import ipaddress
import logging
import os
import select
import socket
import struct
import termios
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass
from types import TracebackType

from drivers.hokuyo.codec import CommandFramer
from fakes.scan_scene import RangeSource, RoomScene
from fakes.scip_device import SCAN_PERIOD_S, ScipDevice
from fakes.scip_faults import FaultInjector, ScipFaults
from fakes.scip_identity import UTM_30LX_EW, LinkKind, ScipIdentity, SensorState
from lasercal_hw.errors import ConfigError, TransportError

logger = logging.getLogger(__name__)

DEFAULT_PORT = 10940
"""The UTM-30LX-EW's TCP port."""
OUTPUT_LIMIT_BYTES = 1 << 16
"""Unsent bytes kept per link (about ten ME scans, like a tty buffer); newer messages are dropped
beyond it (a sensor does not wait for a host that does not read)."""
MAX_CATCH_UP_SCANS = 40
"""Revolutions (1 s) the fake sends late after its own thread was starved of CPU, as a
real sensor's scans arrive late, not never, when the host is slow; only a longer stall
skips them. (With 4, a loaded CI machine made gaps a real sensor never has: a
fault-free dry run printed "stream had a gap (5 scans missed)" and repeated a waypoint.)"""
_DROP_FLUSH_TIMEOUT_S = 1.0
_READ_BYTES = 65536
REPLY_TIMINGS = ("cycle", "immediate")


def loopback_host(address: str) -> str:
    """Return ``address`` as a numeric loopback address or raise ``ConfigError``."""
    host = "127.0.0.1" if address == "localhost" else address
    try:
        parsed = ipaddress.ip_address(host)
    except ValueError:
        parsed = None
    if parsed is None or not parsed.is_loopback:
        raise ConfigError(
            f"refusing to serve the fake scanner on {address!r}: only loopback addresses "
            "(127.0.0.0/8, ::1, localhost) are allowed; use e.g. 127.0.0.1"
        )
    return str(parsed)


@dataclass
class ServerStats:
    """Counters for tests and logs."""

    connections: int = 0
    refused_connections: int = 0
    scans_sent: int = 0
    replies_sent: int = 0
    dropped_messages: int = 0
    skipped_revolutions: int = 0


class FakeScannerServer:
    """A SCIP 2.0 fake scanner on ``address:port`` (TCP) or a pseudo-terminal.

    Use ``start()`` (returns once listening) and ``stop()``, or ``with``. ``url`` is
    ``scip+tcp://127.0.0.1:PORT`` or ``scip+serial:///dev/pts/N``.
    """

    def __init__(
        self,
        address: str = "127.0.0.1",
        port: int = 0,
        *,
        pty: bool = False,
        source: RangeSource | None = None,
        faults: ScipFaults | None = None,
        identity: ScipIdentity = UTM_30LX_EW,
        start_time_ms: int = 0,
        reply_timing: str = "cycle",
        scan_period_s: float = SCAN_PERIOD_S,
    ) -> None:
        if reply_timing not in REPLY_TIMINGS:
            raise ConfigError(f"reply_timing must be one of {REPLY_TIMINGS}, not {reply_timing!r}")
        if not 0 <= port <= 65535:
            raise ConfigError(f"port {port} is not in 0..65535")
        self.address = loopback_host(address)
        self.port = port
        self.use_pty = pty
        self.source: RangeSource = source if source is not None else RoomScene()
        self.faults = faults if faults is not None else ScipFaults()
        self.identity = identity
        self.start_time_ms = start_time_ms
        self.reply_timing = reply_timing
        self.scan_period_s = scan_period_s
        self.stats = ServerStats()
        self.device: ScipDevice | None = None
        self._url: str | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._drop_requested = threading.Event()
        self._finished = threading.Event()
        self._failure: BaseException | None = None
        self._wake_r, self._wake_w = -1, -1
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._framer = CommandFramer()
        self._pending: deque[tuple[bytes, float]] = deque()
        self._out = bytearray()
        self._injector = FaultInjector(self.faults)

    # ----------------------------------------------------------------- public API

    @property
    def url(self) -> str:
        """Where a client connects (valid after ``start()``)."""
        if self._url is None:
            raise TransportError("the fake scanner is not started; call start() first")
        return self._url

    @property
    def running(self) -> bool:
        """True while the serving thread runs."""
        return self._thread is not None and not self._finished.is_set()

    @property
    def failure(self) -> BaseException | None:
        """The exception that ended the serving thread, if any."""
        return self._failure

    def start(self) -> str:
        """Open the endpoint, start serving and return the URL (already listening)."""
        if self._thread is not None:
            raise TransportError("the fake scanner is already started")
        link = LinkKind.SERIAL if self.use_pty else LinkKind.ETHERNET
        self.device = ScipDevice(
            self.source,
            identity=self.identity,
            link=link,
            start_time_ms=self.start_time_ms,
            origin_s=time.monotonic(),
            scan_period_s=self.scan_period_s,
        )
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        try:
            self._url = self._open_pty() if self.use_pty else self._open_listener()
        except BaseException:
            self._close_all()
            raise
        self._thread = threading.Thread(target=self._serve, name="fake-scip-server", daemon=True)
        self._thread.start()
        logger.info("fake scanner serving on %s", self._url)
        return self._url

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop serving and close every descriptor; safe to call twice."""
        self._stopping.set()
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise TransportError(f"fake scanner thread did not stop within {timeout_s} s")
        self._close_all()

    def drop_connection(self) -> None:
        """Drop the client's link at the next scan boundary, as a cable pulled out would
        (thread-safe; the fake cell's scene fault ``scanner_drop_at_waypoint``)."""
        self._drop_requested.set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until the serving thread ends by itself (or ``stop()``); True if it did."""
        return self._finished.wait(timeout_s)

    def __enter__(self) -> FakeScannerServer:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # ----------------------------------------------------------------- endpoints

    def _open_listener(self) -> str:
        family = socket.AF_INET6 if ":" in self.address else socket.AF_INET
        listener = socket.socket(family, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((self.address, self.port))
        except OSError as exc:
            listener.close()
            raise ConfigError(
                f"cannot listen on {self.address}:{self.port}: {exc.strerror}; choose another port "
                "(0 picks a free one)"
            ) from exc
        listener.listen(4)
        listener.setblocking(False)
        self._listener = listener
        port = listener.getsockname()[1]
        host = f"[{self.address}]" if family == socket.AF_INET6 else self.address
        return f"scip+tcp://{host}:{port}"

    def _open_pty(self) -> str:
        master_fd, slave_fd = os.openpty()
        self._master_fd, self._slave_fd = master_fd, slave_fd
        tty.setraw(slave_fd)
        os.set_blocking(master_fd, False)
        return f"scip+serial://{os.ttyname(slave_fd)}"

    def _close_all(self) -> None:
        self._close_conn()
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        self._close_pty()
        for name in ("_wake_r", "_wake_w"):
            fd = getattr(self, name)
            if fd >= 0:
                os.close(fd)
                setattr(self, name, -1)

    def _close_conn(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def _close_pty(self) -> None:
        for name in ("_master_fd", "_slave_fd"):
            fd = getattr(self, name)
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
                setattr(self, name, None)

    # ----------------------------------------------------------------- serving loop

    def _serve(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # the thread must never die silently
            logger.exception("fake scanner stopped on an error")
            self._failure = exc
        finally:
            self._finished.set()

    def _link_fd(self) -> int | None:
        if self._conn is not None:
            return self._conn.fileno()
        return self._master_fd

    def _loop(self) -> None:
        device = self.device
        assert device is not None
        revolution = 1
        while not self._stopping.is_set():
            if self._listener is None and self._master_fd is None:
                return  # the pseudo-terminal was hung up by a fault: nothing left to serve
            next_boundary_s = device.scan_start_s(revolution)
            deadline_s = min(next_boundary_s, self._next_reply_due_s())
            readers = [self._wake_r]
            if self._listener is not None:
                readers.append(self._listener.fileno())
            link_fd = self._link_fd()
            if link_fd is not None:
                readers.append(link_fd)
            writers = [link_fd] if (link_fd is not None and self._out) else []
            timeout_s = max(0.0, deadline_s - time.monotonic())
            readable, writable, _ = select.select(readers, writers, [], timeout_s)
            if self._wake_r in readable:
                return
            if link_fd is not None and link_fd in readable:
                self._read_link()
            if self._listener is not None and self._listener.fileno() in readable:
                self._accept()
            now_s = time.monotonic()
            if now_s >= next_boundary_s:
                behind = int((now_s - next_boundary_s) // self.scan_period_s)
                if behind > MAX_CATCH_UP_SCANS:
                    self.stats.skipped_revolutions += behind
                    logger.warning("fake scanner stalled; skipping %d revolutions", behind)
                    revolution += behind
                while device.scan_start_s(revolution) <= now_s:
                    self._revolution_complete(device, revolution)
                    revolution += 1
            self._answer_due(device, time.monotonic(), boundary_s=None)
            if self._drop_requested.is_set():
                self._drop_requested.clear()
                if self._link_fd() is not None:
                    self._drop_link("drop requested")
            if writable or self._out:
                self._flush()

    def _next_reply_due_s(self) -> float:
        """When the head of the request queue must be answered outside a boundary."""
        if not self._pending or not self._answers_at_once(self._pending[0][0]):
            return float("inf")
        return self._pending[0][1] + self.faults.reply_delay_s

    def _answers_at_once(self, line: bytes) -> bool:
        """Immediate timing, or TM1/TM2 in time-adjust mode (answered within ~1 ms)."""
        device = self.device
        return self.reply_timing == "immediate" or (
            device is not None and device.state is SensorState.TIME_ADJUST and line[:3] in (b"TM1", b"TM2")
        )

    def _revolution_complete(self, device: ScipDevice, revolution: int) -> None:
        boundary_s = device.scan_start_s(revolution)
        if self._link_fd() is not None:
            message = device.complete_scan(device.scan_start_s(revolution - 1))
            if message is not None:
                self._emit(message, is_scan=True)
                self.stats.scans_sent += 1
                if self._injector.should_drop:
                    self._drop_link(f"fault injection: drop after {self.faults.drop_after_scans} scans")
                    return
        self._answer_due(device, boundary_s, boundary_s=boundary_s)

    def _answer_due(self, device: ScipDevice, now_s: float, *, boundary_s: float | None) -> None:
        """Answer queued requests whose time has come, in order."""
        while self._pending and self._link_fd() is not None:
            line, arrival_s = self._pending[0]
            ready_s = arrival_s + self.faults.reply_delay_s
            if ready_s > now_s:
                return
            if boundary_s is None and not self._answers_at_once(line):
                return
            self._pending.popleft()
            reply = device.handle(line, now_s)
            self._emit(reply.data, is_scan=False)
            self.stats.replies_sent += 1
            if reply.hang_up:
                self._drop_link("reboot (RB)")
                return

    def _emit(self, message: bytes, *, is_scan: bool) -> None:
        data = self._injector.outgoing(message, is_scan=is_scan)
        if len(self._out) + len(data) > OUTPUT_LIMIT_BYTES:
            self.stats.dropped_messages += 1
            logger.debug("output buffer full: dropping a %d-byte message", len(data))
            return
        self._out += data

    def _flush(self) -> None:
        while self._out:
            try:
                if self._conn is not None:
                    sent = self._conn.send(self._out)
                elif self._master_fd is not None:
                    sent = os.write(self._master_fd, self._out)
                else:
                    self._out.clear()
                    return
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if self._conn is not None:
                    logger.info("client connection lost while sending: %s", exc)
                    self._lose_client()
                    return
                if exc.errno == errno.EIO:  # pty with no reader attached yet
                    return
                raise
            del self._out[:sent]

    def _read_link(self) -> None:
        try:
            if self._conn is not None:
                data = self._conn.recv(_READ_BYTES)
            else:
                assert self._master_fd is not None
                data = os.read(self._master_fd, _READ_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            if self._conn is None and exc.errno == errno.EIO:
                return
            logger.info("client connection lost: %s", exc)
            self._lose_client()
            return
        if not data:
            if self._conn is not None:
                logger.info("client disconnected")
                self._lose_client()
            return
        arrival_s = time.monotonic()
        for line in self._framer.feed(data):
            self._pending.append((line, arrival_s))

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            conn, peer = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        if self._conn is not None:
            self.stats.refused_connections += 1
            logger.info("refusing a second client %s: one client at a time", peer)
            conn.close()
            return
        try:
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:  # the client went away between connect and accept
            logger.info("client %s gone before it was served: %s", peer, exc)
            conn.close()
            return
        self._conn = conn
        self.stats.connections += 1
        self._reset_link_state()
        logger.info("client connected from %s", peer)

    def _reset_link_state(self) -> None:
        self._framer = CommandFramer()
        self._pending.clear()
        self._out.clear()
        self._injector = FaultInjector(self.faults)

    def _lose_client(self) -> None:
        self._close_conn()
        self._reset_link_state()
        if self.device is not None:
            self.device.disconnect()

    def _drop_link(self, reason: str) -> None:
        """Send what is queued (best effort), then close the TCP connection or hang up
        the pseudo-terminal."""
        logger.info("dropping the link: %s", reason)
        deadline_s = time.monotonic() + _DROP_FLUSH_TIMEOUT_S
        fd = self._link_fd()
        while self._out and fd is not None and time.monotonic() < deadline_s:
            select.select([], [fd], [], max(0.0, deadline_s - time.monotonic()))
            self._flush()
            fd = self._link_fd()
        if self._conn is not None:
            self._lose_client()
            return
        idle_checks = 0
        while self._slave_fd is not None and time.monotonic() < deadline_s and idle_checks < 3:
            # Let the reader take what was sent: a hang-up discards unread input. The
            # kernel moves written bytes to the slave asynchronously, so wait for the
            # queue to read empty several times in a row.
            idle_checks = 0 if _unread_bytes(self._slave_fd) else idle_checks + 1
            time.sleep(0.005)
        self._close_pty()
        self._out.clear()


def _unread_bytes(tty_fd: int) -> int:
    """Bytes waiting to be read on a terminal."""
    return struct.unpack("i", fcntl.ioctl(tty_fd, termios.FIONREAD, b"\0\0\0\0"))[0]
