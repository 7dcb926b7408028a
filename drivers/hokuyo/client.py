"""Hokuyo SCIP 2.0 scanner client (UTM-30LX-EW and relatives) over TCP or serial.

``HokuyoScanner.open(url)`` connects, resynchronises (QT, then drain until silence, so a
stream left running by an earlier client does not confuse it), reads VV/PP/II and
synchronises the clock with TM. Single scans use BM + GD/GE; streams use MD/ME with a
reader thread, a bounded queue and automatic reconnection. Implements
``lasercal_hw.run.devices.Scanner``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from types import TracebackType

import numpy as np

from drivers.hokuyo.codec import (
    DecodedScan,
    Response,
    ResponseFramer,
    ScanRequest,
    decode_scan_lines,
    decode_timestamp_line,
    parse_parameter_lines,
    status_meaning,
)
from drivers.hokuyo.info import (
    ScannerParameters,
    ScannerStatus,
    StreamGap,
    StreamStats,
    parse_identity,
    parse_parameters,
    parse_status,
)
from drivers.hokuyo.stamps import ClockEstimate, ClockSample, DeviceClock, TimestampUnwrapper
from drivers.hokuyo.transport import SerialTransport, Transport, open_transport
from lasercal_hw.errors import (
    ChecksumError,
    ConfigError,
    DeviceError,
    DeviceTimeoutError,
    ProtocolError,
    ScannerStatusError,
    TransportError,
)
from lasercal_hw.models import LaserScan, ScanGeometry, ScannerIdentity

logger = logging.getLogger(__name__)

QUIET_S = 0.2
"""Silence that ends the drain after the initial QT (scip2.md P-1)."""
MAX_DRAIN_S = 2.0
READER_POLL_S = 0.1
PARAMETER_TRIES = 3
"""Times a VV/PP/II query is sent before a bad line checksum is an error."""
TAG_SAFE_STATUSES = ("0C", "0D", "0G", "0H")
"""Statuses a device may give a tagged request it cannot parse; the client retries untagged."""


def _echo_matches(received: bytes, expected: bytes) -> bool:
    """Exact echo, or one with a stale partial line glued in front (a message cut short)."""
    return received.endswith(expected)


class HokuyoScanner:
    """A SCIP 2.0 laser scanner. Use ``HokuyoScanner.open(url)``; close it when done."""

    def __init__(
        self,
        url: str,
        transport: Transport,
        *,
        timeout_s: float = 1.0,
        connect_timeout_s: float = 3.0,
        queue_size: int = 256,
        reconnect: bool = True,
        reconnect_timeout_s: float = 30.0,
    ) -> None:
        self.url = url
        self.timeout_s = timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.reconnect = reconnect
        self.reconnect_timeout_s = reconnect_timeout_s
        self._transport: Transport | None = transport
        self._framer = ResponseFramer()
        self._pending: deque[Response] = deque()
        self._io_lock = threading.Lock()
        self._command_lock = threading.Lock()
        self._replies: queue.Queue[Response] = queue.Queue()
        self._scans: queue.Queue[LaserScan | DeviceError] = queue.Queue(maxsize=max(queue_size, 1))
        self._reader: threading.Thread | None = None
        self._stop_reader = threading.Event()
        self._unwrapper = TimestampUnwrapper()
        self._clock = DeviceClock()
        self._identity: ScannerIdentity | None = None
        self._parameters: ScannerParameters | None = None
        self._geometry: ScanGeometry | None = None
        self._stream: ScanRequest | None = None
        self._stream_geometry: ScanGeometry | None = None
        self._session = 0
        self._reset_stream_counters()

    # ------------------------------------------------------------------ opening

    @classmethod
    def open(
        cls,
        url: str,
        *,
        timeout_s: float = 1.0,
        connect_timeout_s: float = 3.0,
        sync_clock: bool = True,
        queue_size: int = 256,
        reconnect: bool = True,
        reconnect_timeout_s: float = 30.0,
        first_step: int | None = None,
        last_step: int | None = None,
        cluster: int = 1,
        transport: Transport | None = None,
        quiet_s: float = QUIET_S,
    ) -> HokuyoScanner:
        """Connect to ``url`` (``scip+tcp://...`` or ``scip+serial://...``) and read its info.

        ``timeout_s`` bounds every command reply; ``first_step``/``last_step``/``cluster``
        choose the scan layout (default: all measurable steps). ``transport`` replaces the
        connection opened from ``url`` (an in-memory peer for fuzzing); ``quiet_s`` is the
        silence that ends the initial drain."""
        scanner = cls(
            url,
            transport if transport is not None else open_transport(url, connect_timeout_s),
            timeout_s=timeout_s,
            connect_timeout_s=connect_timeout_s,
            queue_size=queue_size,
            reconnect=reconnect,
            reconnect_timeout_s=reconnect_timeout_s,
        )
        try:
            scanner._first_drain(quiet_s)
            scanner.refresh_info()
            scanner._geometry = scanner.parameters().geometry(first_step, last_step, cluster)
            if sync_clock:
                try:
                    scanner.synchronise_clock()
                except ScannerStatusError as exc:
                    logger.warning("%s: clock sync refused (%s); using stream stamps only", url, exc)
        except BaseException:
            scanner.close()
            raise
        return scanner

    def __enter__(self) -> HokuyoScanner:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ low-level I/O

    def _current_transport(self) -> Transport:
        transport = self._transport
        if transport is None:
            raise TransportError(f"{self.url}: connection is closed")
        return transport

    def _write(self, data: bytes) -> None:
        with self._io_lock:
            transport = self._current_transport()
        transport.write(data)

    def _resynchronise(self, *, quiet_s: float = QUIET_S, max_drain_s: float = MAX_DRAIN_S) -> None:
        """Send QT and drop everything until ``quiet_s`` of silence (P-1)."""
        transport = self._current_transport()
        transport.write(b"QT\n")
        start = last_data = time.monotonic()
        sent_extra_qt = False
        drained = 0
        while True:
            now = time.monotonic()
            if now - last_data >= quiet_s:
                break
            if now - start >= max_drain_s:
                if sent_extra_qt:
                    logger.warning(
                        "%s: scanner still sending after %.1f s of QT; going on", self.url, now - start
                    )
                    break
                transport.write(b"QT\n")
                sent_extra_qt, start = True, now
            try:
                data = transport.read_some(min(quiet_s - (now - last_data), max_drain_s))
            except DeviceTimeoutError:
                continue
            drained += len(data)
            last_data = time.monotonic()
            for response in self._framer.feed(data):
                if response.echo == b"QT" and response.status_text == "0E":
                    logger.info("%s: scanner was in time-adjust mode; sending TM2", self.url)
                    transport.write(b"TM2\nQT\n")
        if drained:
            logger.debug("%s: drained %d bytes after QT", self.url, drained)
        self._framer.reset()
        self._pending.clear()

    def _first_drain(self, quiet_s: float) -> None:
        """The drain right after connecting. A TCP scanner that drops the connection here,
        before answering anything, is serving another client: a UTM-30LX-EW serves one TCP
        client at a time (the fake closes a second connection at once, docs/scip-fake.md)."""
        try:
            self._resynchronise(quiet_s=quiet_s)
        except DeviceTimeoutError:
            raise
        except TransportError as exc:
            if not self.url.startswith("scip+tcp:"):
                raise
            raise TransportError(
                f"{self.url}: the scanner closed the connection before answering "
                f"({self._without_url(exc)}); it is most likely busy with another client, as a "
                "UTM-30LX-EW serves one TCP client at a time: stop the other client (another "
                "lasercal command, a daemon job using this scanner, a ROS driver) and try again"
            ) from exc

    def _in_reader_mode(self) -> bool:
        reader = self._reader
        return reader is not None and reader.is_alive() and threading.current_thread() is not reader

    def _no_reply(self, echo: bytes, timeout_s: float, noise_bytes: int, others: list[bytes]) -> DeviceError:
        command = echo.decode("ascii", errors="replace")
        if noise_bytes or others:
            detail = f"{noise_bytes} bytes that are not a complete SCIP message" if noise_bytes else ""
            if others:
                shown = ", ".join(sorted({o.decode("ascii", "replace") for o in others}))[:80]
                detail += (" and " if detail else "") + f"replies to other commands ({shown})"
            return ProtocolError(
                f"{self.url}: no valid reply to {command} within {timeout_s:g} s; got {detail}"
            )
        return DeviceTimeoutError(f"{self.url}: no reply to {command} within {timeout_s:g} s")

    def _await_direct(self, echo: bytes, timeout_s: float) -> Response:
        deadline = time.monotonic() + timeout_s
        discarded_before = self._framer.discarded_bytes
        others: list[bytes] = []
        transport = self._current_transport()
        while True:
            while self._pending:
                response = self._pending.popleft()
                if _echo_matches(response.echo, echo):
                    return response
                logger.debug("%s: ignoring reply %r while waiting for %r", self.url, response.echo, echo)
                others.append(response.echo[:20])
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                noise = self._framer.discarded_bytes - discarded_before + self._framer.pending_bytes
                raise self._no_reply(echo, timeout_s, noise, others)
            try:
                data = transport.read_some(remaining)
            except DeviceTimeoutError:
                continue
            self._pending.extend(self._framer.feed(data))

    def _await_from_reader(self, echo: bytes, timeout_s: float) -> Response:
        deadline = time.monotonic() + timeout_s
        others: list[bytes] = []
        while True:
            remaining = deadline - time.monotonic()
            try:
                response = self._replies.get(timeout=max(remaining, 0.0))
            except queue.Empty:
                raise self._no_reply(echo, timeout_s, 0, others) from None
            if _echo_matches(response.echo, echo):
                return response
            others.append(response.echo[:20])

    def _transact(self, line: bytes, timeout_s: float | None = None) -> Response:
        """Send one request line and return the reply whose echo matches it."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        if threading.current_thread() is self._reader:  # reconnecting: the reader owns the link
            self._write(line + b"\n")
            return self._await_direct(line, timeout)
        if self._in_reader_mode():
            with self._command_lock:
                self._write(line + b"\n")
                return self._await_from_reader(line, timeout)
        with self._command_lock:
            self._write(line + b"\n")
            return self._await_direct(line, timeout)

    def _command(
        self, line: bytes, ok: tuple[str, ...] = ("00",), timeout_s: float | None = None
    ) -> Response:
        """``_transact`` plus status check: other statuses raise ``ScannerStatusError``."""
        response = self._transact(line, timeout_s)
        status = response.status_text
        if status not in ok:
            command = line.decode("ascii", errors="replace")
            raise ScannerStatusError(command, status, status_meaning(command, status))
        return response

    # ------------------------------------------------------------------ information

    def _read_fields(self, command: bytes) -> dict[str, str]:
        """The checked ``KEY:VALUE`` lines of a VV/PP/II reply. A reply with a bad line
        checksum is asked for again (a link can drop or flip a byte) up to
        ``PARAMETER_TRIES`` times in all; then ``ChecksumError`` names the line."""
        name = command.decode("ascii")
        attempt = 1
        while True:
            try:
                return parse_parameter_lines(self._command(command).data_lines, name)
            except ChecksumError as exc:
                if attempt >= PARAMETER_TRIES:
                    raise ChecksumError(
                        f"{self.url}: {exc}, {attempt} times in a row; the link corrupts data or the "
                        "scanner is faulty: check the cable (and the bit rate on a serial link)"
                    ) from exc
                logger.info("%s: %s; asking again", self.url, exc)
                attempt += 1

    def refresh_info(self) -> None:
        """Read VV and PP again (identity and parameters)."""
        version = self._read_fields(b"VV")
        self._parameters = parse_parameters(self._read_fields(b"PP"))
        self._identity = parse_identity(version, self._parameters.model)

    def identity(self) -> ScannerIdentity:
        """Vendor, product, firmware, protocol, serial (VV) and model (PP MODL)."""
        if self._identity is None:
            self.refresh_info()
        assert self._identity is not None
        return self._identity

    def parameters(self) -> ScannerParameters:
        """The PP parameters (range limits, steps, motor speed)."""
        if self._parameters is None:
            self.refresh_info()
        assert self._parameters is not None
        return self._parameters

    def status(self) -> ScannerStatus:
        """A fresh II status (laser, mode, link, sensor time, diagnostic)."""
        return parse_status(self._read_fields(b"II"))

    def geometry(self) -> ScanGeometry:
        """Beam layout of the scans this client requests."""
        if self._geometry is None:
            self._geometry = self.parameters().geometry()
        return self._geometry

    # ------------------------------------------------------------------ simple commands

    def laser_on(self) -> bool:
        """BM; True when it switched the laser on, False when it was already on."""
        return self._command(b"BM", ok=("00", "02")).status_text == "00"

    def laser_off(self) -> None:
        """QT: laser off, any stream stops."""
        self._command(b"QT")

    def reset(self) -> None:
        """RS: laser off, defaults restored, sensor timer reset to 0."""
        self._command(b"RS")
        self._unwrapper.reset()
        self._clock.reset()

    def set_bit_rate(self, baud: int) -> None:
        """SS: change the serial bit rate (and follow it on a serial transport)."""
        if not 0 < baud <= 999999:
            raise ConfigError(f"bit rate {baud} must be 1..999999")
        self._command(f"SS{baud:06d}".encode(), ok=("00", "03"))
        transport = self._current_transport()
        if isinstance(transport, SerialTransport):
            transport.set_baud(baud)

    def set_motor_speed(self, level: int) -> None:
        """CR: 0 default, 1..10 speed levels, 99 initial speed (UTM-30LX answers 04)."""
        if not (0 <= level <= 10 or level == 99):
            raise ConfigError(f"motor speed level {level} must be 0..10 or 99")
        self._command(f"CR{level:02d}".encode(), ok=("00", "03"))

    def set_high_sensitivity(self, enabled: bool) -> None:
        """HS: 1 high sensitivity, 0 normal."""
        self._command(b"HS1" if enabled else b"HS0", ok=("00", "02"))

    def synchronise_clock(self, samples: int = 10) -> ClockEstimate:
        """TM0, ``samples`` x TM1 (round trip measured), TM2; anchors the clock offset."""
        if self._in_reader_mode():
            raise DeviceError("cannot synchronise the clock while streaming; stop the stream first")
        self._command(b"TM0", ok=("00", "02"))
        collected: list[ClockSample] = []
        try:
            for _ in range(max(samples, 1)):
                sent = time.time()
                response = self._command(b"TM1")
                received = time.time()
                if not response.data_lines:
                    raise ProtocolError(f"{self.url}: TM1 reply carries no time")
                raw = decode_timestamp_line(response.data_lines[0])
                collected.append(ClockSample(sent, received, self._unwrapper.unwrap(raw)))
        finally:
            self._command(b"TM2", ok=("00", "03"))
        return self._clock.synchronise(collected)

    def clock(self) -> ClockEstimate:
        """The current device-to-host clock model."""
        return self._clock.estimate()

    # ------------------------------------------------------------------ scans

    def _make_scan(
        self, decoded: DecodedScan, geometry: ScanGeometry, host_time_s: float, sequence: int, device_ms: int
    ) -> LaserScan:
        raw = decoded.distances_mm
        params = self.parameters()
        valid = (raw >= params.min_range_mm) & (raw <= params.max_range_mm)
        return LaserScan(
            sequence=sequence,
            geometry=geometry,
            ranges_m=np.where(valid, raw / 1000.0, np.nan),
            raw_ranges_mm=raw,
            intensities=decoded.intensities,
            device_time_s=self._clock.to_host_s(device_ms),
            host_time_s=host_time_s,
        )

    def single_scan(self, *, intensities: bool = False, timeout_s: float | None = None) -> LaserScan:
        """BM, then GD (or GE with intensities): the latest complete scan."""
        if self._reader is not None:
            raise DeviceError("a stream is running; use next_scan() or stop_streaming() first")
        geometry = self.geometry()
        self.laser_on()
        request = ScanRequest(
            "GE" if intensities else "GD", geometry.first_step, geometry.last_step, geometry.cluster
        )
        response = self._command(request.line(), timeout_s=timeout_s)
        host_time = time.time()
        decoded = decode_scan_lines(response.data_lines, request)
        device_ms = self._unwrapper.unwrap(decoded.timestamp_ms)
        return self._make_scan(decoded, geometry, host_time, 0, device_ms)

    def _reset_stream_counters(self) -> None:
        self._received = 0
        self._overflows = 0
        self._corrupted = 0
        self._reconnects = 0
        self._gaps: list[StreamGap] = []
        self._sequence = -1
        self._last_device_ms: int | None = None
        self._last_host_s = 0.0
        self._gap_pending: str | None = None
        """Reason of a reconnect whose gap is measured at the next scan."""

    def _start_on_device(self, request: ScanRequest) -> ScanRequest:
        """Send MD/ME and wait for its acknowledgement; retry untagged if the tag is refused."""
        response = self._transact(request.line())
        if response.status_text in TAG_SAFE_STATUSES and request.tag is not None:
            logger.info(
                "%s: scanner refused the request tag (%s); retrying without", self.url, response.status_text
            )
            request = ScanRequest(
                request.command,
                request.first_step,
                request.last_step,
                request.cluster,
                request.interval,
                request.count,
                None,
            )
            response = self._transact(request.line())
        if response.status_text != "00":
            command = request.line().decode()
            raise ScannerStatusError(
                command, response.status_text, status_meaning(command, response.status_text)
            )
        return request

    def start_streaming(self, *, intensities: bool = False, interval: int = 0) -> None:
        """Start MD (or ME with intensities) on all scans (``interval`` skipped between two)."""
        if self._reader is not None:
            raise DeviceError("a stream is already running; stop_streaming() first")
        if not 0 <= interval <= 9:
            raise ConfigError(f"scan interval {interval} must be 0..9")
        geometry = self.geometry()
        self._session += 1
        request = ScanRequest(
            "ME" if intensities else "MD",
            geometry.first_step,
            geometry.last_step,
            geometry.cluster,
            interval,
            0,
            f"LC{self._session}",
        )
        self._reset_stream_counters()
        while not self._scans.empty():
            self._scans.get_nowait()
        params = self.parameters()
        self._clock.stream_delay_s = (
            params.scan_period_s * (geometry.last_step + 1) / params.steps_per_revolution
        )
        self._stream = self._start_on_device(request)
        self._stream_geometry = geometry
        self._stop_reader.clear()
        self._reader = threading.Thread(target=self._reader_main, name=f"scip-reader {self.url}", daemon=True)
        self._reader.start()

    def next_scan(self, timeout_s: float) -> LaserScan:
        """The next streamed scan; ``DeviceTimeoutError`` when none arrives in ``timeout_s``."""
        if self._reader is None and self._scans.empty():
            raise DeviceError("not streaming; call start_streaming() first")
        try:
            item = self._scans.get(timeout=max(timeout_s, 0.0))
        except queue.Empty:
            raise DeviceTimeoutError(
                f"{self.url}: no scan within {timeout_s:g} s; check the connection (the log says "
                "whether it was lost) or allow a longer timeout"
            ) from None
        if isinstance(item, DeviceError):
            raise item
        return item

    def dropped_scans(self) -> int:
        """Scans lost so far in this stream: queue overflows plus corrupted blocks."""
        return self._overflows + self._corrupted

    def stream_stats(self) -> StreamStats:
        """Counters of the current (or last) stream, including reconnect gaps."""
        gaps = tuple(self._gaps)
        return StreamStats(
            received=self._received,
            queue_overflows=self._overflows,
            corrupted=self._corrupted,
            reconnects=self._reconnects,
            missed_in_gaps=sum(g.missed_scans for g in gaps),
            gaps=gaps,
        )

    def stop_streaming(self) -> None:
        """QT, then stop the reader; scans already queued stay readable."""
        reader = self._reader
        if reader is None:
            return
        try:
            if reader.is_alive():
                self._command(b"QT")
        except DeviceError as exc:
            logger.warning("%s: QT while stopping the stream failed: %s", self.url, self._without_url(exc))
        finally:
            self._stop_reader.set()
            reader.join(timeout=5.0)
            if self._corrupted > 1:
                logger.warning(
                    "%s: %d corrupted scans dropped in this stream of %d received",
                    self.url, self._corrupted, self._received + self._corrupted,
                )
            self._reader = None
            self._stream = None
            while not self._replies.empty():
                self._replies.get_nowait()

    def close(self) -> None:
        """Stop any stream and close the connection; safe to call twice."""
        try:
            self.stop_streaming()
        finally:
            with self._io_lock:
                transport, self._transport = self._transport, None
            if transport is not None:
                transport.close()

    # ------------------------------------------------------------------ reader thread

    def _without_url(self, exc: Exception) -> str:
        """The message of ``exc`` without the leading ``URL: `` (for logs that name the URL)."""
        message = str(exc)
        transport = self._transport
        for url in (self.url, transport.url if transport is not None else self.url):
            message = message.removeprefix(f"{url}: ")
        return message

    def _reader_main(self) -> None:
        last_data = time.monotonic()
        watchdog_s = max(1.0, 20 * self.parameters().scan_period_s)
        while not self._stop_reader.is_set():
            while self._pending:  # scans that arrived together with a (re)start acknowledgement
                self._dispatch(self._pending.popleft(), time.time())
            try:
                data = self._current_transport().read_some(READER_POLL_S)
            except DeviceTimeoutError:
                if time.monotonic() - last_data > watchdog_s:
                    self._recover(f"no data for {watchdog_s:g} s")
                    last_data = time.monotonic()
                continue
            except TransportError as exc:
                if self._stop_reader.is_set():
                    break
                self._recover(self._without_url(exc))
                last_data = time.monotonic()
                continue
            last_data = time.monotonic()
            host_time = time.time()
            discarded_before = self._framer.discarded_chunks
            responses = self._framer.feed(data)
            self._corrupted += self._framer.discarded_chunks - discarded_before
            for response in responses:
                self._dispatch(response, host_time)

    def _is_stream_echo(self, echo: bytes, request: ScanRequest) -> bool:
        prefix = request.prefix()
        start = echo.rfind(prefix)
        if start < 0:
            return False
        body, _, tag = echo[start:].partition(b";")
        if len(body) != len(prefix) + 2 or not body[-2:].isdigit():
            return False
        return not tag or request.tag is None or tag.decode("ascii", "replace") == request.tag

    def _dispatch(self, response: Response, host_time: float) -> None:
        request = self._stream
        if request is None or not self._is_stream_echo(response.echo, request):
            self._replies.put(response)
            return
        status = response.status_text
        if status == "99":
            self._accept_scan(response, request, host_time)
        elif status == "00":
            logger.debug("%s: stream acknowledgement %r", self.url, response.echo)
        elif status == "0M":
            self._drop_corrupted("scanner unstable (0M)")
        else:
            command = response.echo.decode("ascii", "replace")
            error = ScannerStatusError(command, status, status_meaning(command, status))
            logger.error("%s: %s", self.url, error)
            self._enqueue(error)

    def _accept_scan(self, response: Response, request: ScanRequest, host_time: float) -> None:
        try:
            decoded = decode_scan_lines(response.data_lines, request)
        except ProtocolError as exc:
            self._drop_corrupted(str(exc))
            return
        device_ms = self._unwrapper.unwrap(decoded.timestamp_ms)
        self._clock.observe(device_ms, host_time)
        period_ms = 1000.0 * self.parameters().scan_period_s * ((request.interval or 0) + 1)
        missed = 0
        if self._last_device_ms is not None:
            elapsed_ms = device_ms - self._last_device_ms
            if elapsed_ms > 0:
                missed = max(round(elapsed_ms / period_ms) - 1, 0)
            if self._gap_pending is not None:
                reason = self._gap_pending
                duration_s = elapsed_ms / 1000.0 if elapsed_ms > 0 else host_time - self._last_host_s
                gap = StreamGap(missed, duration_s, reason)
                self._gaps.append(gap)
                logger.warning(
                    "%s: stream resumed after %.3f s, %d scans missed (%s)",
                    self.url,
                    duration_s,
                    missed,
                    reason,
                )
        self._gap_pending = None
        self._last_device_ms = device_ms
        self._last_host_s = host_time
        self._sequence += 1 + missed
        self._received += 1
        geometry = self._stream_geometry or self.geometry()
        self._enqueue(self._make_scan(decoded, geometry, host_time, self._sequence, device_ms))

    def _drop_corrupted(self, reason: str) -> None:
        """Count a dropped scan; only the first of a stream is a warning (the rest are
        summarised when the stream stops, instead of one line each)."""
        self._corrupted += 1
        if self._corrupted == 1:
            logger.warning("%s: corrupted scan dropped (%s); further ones are counted", self.url, reason)
        else:
            logger.debug("%s: corrupted scan dropped (%s)", self.url, reason)

    def _enqueue(self, item: LaserScan | DeviceError) -> None:
        try:
            self._scans.put_nowait(item)
        except queue.Full:
            try:
                self._scans.get_nowait()
                self._overflows += 1
            except queue.Empty:
                pass
            self._scans.put_nowait(item)

    def _recover(self, reason: str) -> None:
        """Reconnect with backoff and restart the stream; a final failure ends the stream."""
        request = self._stream
        if not self.reconnect or request is None:
            self._enqueue(TransportError(f"{self.url}: stream lost ({reason})"))
            self._stop_reader.set()
            return
        logger.warning("%s: %s; reconnecting", self.url, reason)
        with self._io_lock:
            old, self._transport = self._transport, None
        if old is not None:
            old.close()
        deadline = time.monotonic() + self.reconnect_timeout_s
        delay_s = 0.05
        reported = False
        while not self._stop_reader.is_set():
            try:
                transport = open_transport(self.url, min(self.connect_timeout_s, self.reconnect_timeout_s))
                with self._io_lock:
                    self._transport = transport
                self._framer.reset()
                self._pending.clear()
                self._resynchronise(quiet_s=0.1, max_drain_s=1.0)
                self._stream = self._start_on_device(request)
                self._reconnects += 1
                self._gap_pending = reason
                return
            except (TransportError, ProtocolError, ScannerStatusError) as exc:
                with self._io_lock:
                    failed, self._transport = self._transport, None
                if failed is not None:
                    failed.close()
                if time.monotonic() + delay_s > deadline:
                    self._enqueue(
                        TransportError(
                            f"{self.url}: connection lost ({reason}) and not re-established within "
                            f"{self.reconnect_timeout_s:g} s: {exc}"
                        )
                    )
                    self._stop_reader.set()
                    return
                if not reported and isinstance(exc.__cause__, ConnectionRefusedError):
                    # Nothing listens where the scanner was: it restarted or is gone. Say so
                    # now (the consumer decides), and keep trying until the deadline.
                    reported = True
                    self._enqueue(TransportError(
                        f"{self.url}: connection lost ({reason}) and refused on reconnect: the scanner "
                        f"restarted or is gone; still retrying for {self.reconnect_timeout_s:g} s"
                    ))
                logger.info("%s: reconnect failed (%s); retrying in %.2f s", self.url, exc, delay_s)
                self._stop_reader.wait(delay_s)
                delay_s = min(2 * delay_s, 1.0)
