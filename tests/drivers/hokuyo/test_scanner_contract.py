"""Contract suite: HokuyoScanner against the fake UTM-30LX-EW, over TCP and over a
pseudo-terminal (the same tests for both links)."""

from __future__ import annotations

import itertools
import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
import serial

from drivers.hokuyo.client import HokuyoScanner
from drivers.hokuyo.codec import TIMESTAMP_MODULUS, ResponseFramer
from drivers.hokuyo.transport import parse_url
from fakes.scip_faults import ScipFaults
from fakes.scip_server import FakeScannerServer
from lasercal_hw.errors import ConfigError, ScannerStatusError, TransportError
from lasercal_hw.run.devices import Scanner

pytestmark = pytest.mark.timeout(60)

STEPS = np.arange(1081)


class KnownSource:
    """A ``RangeSource``: distances 1000 + step mm, except error code 1 on steps 0..9 and
    60001 (> DMAX) on step 10; intensity 2 * step."""

    def ranges_mm(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        ranges = 1000 + STEPS
        ranges[:10] = 1
        ranges[10] = 60001
        return ranges.astype(np.int64), (2 * STEPS).astype(np.int64)


EXPECTED_M = np.where((STEPS < 10) | (STEPS == 10), np.nan, (1000 + STEPS) / 1000.0)


@pytest.fixture(params=["tcp", "pty"])
def link(request: pytest.FixtureRequest) -> str:
    return request.param


def fake(link: str, **options) -> FakeScannerServer:
    options.setdefault("source", KnownSource())
    return FakeScannerServer(pty=link == "pty", **options)


@pytest.fixture
def server(link: str) -> Iterator[FakeScannerServer]:
    with fake(link) as running:
        yield running


@pytest.fixture
def scanner(server: FakeScannerServer) -> Iterator[HokuyoScanner]:
    with HokuyoScanner.open(server.url, timeout_s=1.0) as opened:
        yield opened


def take(scanner: HokuyoScanner, count: int, timeout_s: float = 2.0) -> list:
    return [scanner.next_scan(timeout_s) for _ in range(count)]


def test_info(scanner: HokuyoScanner) -> None:
    protocol_methods = [n for n in vars(Scanner) if not n.startswith("_")]
    assert len(protocol_methods) == 7
    assert all(callable(getattr(scanner, name)) for name in protocol_methods)
    identity = scanner.identity()
    assert identity.model == "UTM-30LX-EW"
    assert identity.vendor.startswith("Hokuyo")
    parameters = scanner.parameters()
    assert (parameters.min_range_mm, parameters.max_range_mm, parameters.steps_per_revolution) == (
        23, 60000, 1440)
    assert (parameters.first_step, parameters.last_step, parameters.front_step) == (0, 1080, 540)
    assert parameters.scan_period_s == pytest.approx(0.025)
    status = scanner.status()
    assert status.healthy and status.laser_on is False
    assert status.time_ms is not None
    assert scanner.clock().source == "tm"


@pytest.mark.parametrize("intensities", [False, True])
def test_single_scan(scanner: HokuyoScanner, intensities: bool) -> None:
    scan = scanner.single_scan(intensities=intensities)
    assert scan.geometry.beam_count == 1081
    np.testing.assert_array_equal(scan.ranges_m, EXPECTED_M)
    assert scan.raw_ranges_mm[:11].tolist() == [1] * 10 + [60001]
    if intensities:
        assert scan.intensities is not None
        np.testing.assert_array_equal(scan.intensities, 2 * STEPS)
    else:
        assert scan.intensities is None
    assert 0 < scan.host_time_s - scan.device_time_s < 0.2  # GD: latest complete scan


def test_stream_with_intensities(scanner: HokuyoScanner) -> None:
    scanner.start_streaming(intensities=True)
    scans = take(scanner, 40)
    status = scanner.status()  # II answered between two scan messages
    scans += take(scanner, 5)
    scanner.stop_streaming()
    assert status.laser_on
    assert [s.sequence for s in scans] == list(range(45))
    for scan in scans:
        np.testing.assert_array_equal(scan.ranges_m, EXPECTED_M)
        np.testing.assert_array_equal(scan.intensities, 2 * STEPS)
    periods = np.diff([s.device_time_s for s in scans])
    np.testing.assert_allclose(periods, 0.025, atol=0.0015)
    lags = np.array([s.host_time_s - s.device_time_s for s in scans])
    assert np.all(lags > 0) and np.all(lags < 0.25)
    assert scanner.dropped_scans() == 0
    assert scanner.stream_stats().received >= 45  # scans that came before the QT reply count too


def test_timestamps_unwrap_across_the_24_bit_wrap(link: str) -> None:
    with fake(link, start_time_ms=TIMESTAMP_MODULUS - 900) as server, HokuyoScanner.open(
        server.url
    ) as scanner:
        before = scanner.status().time_ms
        scanner.start_streaming()
        scans = take(scanner, 40)
        scanner.stop_streaming()
        after = scanner.status().time_ms
    assert before is not None and after is not None
    assert before > TIMESTAMP_MODULUS - 900 and after < 2000  # the device counter wrapped
    periods = np.diff([s.device_time_s for s in scans])
    np.testing.assert_allclose(periods, 0.025, atol=0.0015)
    lags = np.array([s.host_time_s - s.device_time_s for s in scans])
    assert np.all(np.abs(lags) < 0.25)


def test_corrupted_blocks_are_dropped_and_counted_while_the_stream_goes_on(link: str) -> None:
    with fake(link, faults=ScipFaults(corrupt_every_scans=5)) as server, HokuyoScanner.open(
        server.url
    ) as scanner:
        scanner.start_streaming(intensities=True)
        scans = take(scanner, 32)
        scanner.stop_streaming()
        stats = scanner.stream_stats()
    sequences = [s.sequence for s in scans]
    skipped = sum(b - a - 1 for a, b in itertools.pairwise(sequences))
    assert stats.corrupted >= 7
    assert scanner.dropped_scans() == stats.corrupted
    assert skipped in (stats.corrupted, stats.corrupted - 1)  # the last one may follow the last scan
    assert all(np.array_equal(s.intensities, 2 * STEPS) for s in scans)


def test_garbage_between_messages_is_skipped(link: str) -> None:
    with fake(link, faults=ScipFaults(garbage_every_messages=3)) as server, HokuyoScanner.open(
        server.url
    ) as scanner:
        assert scanner.identity().model == "UTM-30LX-EW"
        scanner.start_streaming()
        scans = take(scanner, 20)
        scanner.stop_streaming()
    assert [s.sequence for s in scans] == list(range(20))
    assert scanner.dropped_scans() == 0


def test_dropped_connection(link: str) -> None:
    """TCP: reconnect and resume within 2 s, gap reported. Pseudo-terminal: the fake hangs
    up for good (like an unplugged USB sensor), so the stream ends with TransportError."""
    with fake(link, faults=ScipFaults(drop_after_scans=20)) as server:
        scanner = HokuyoScanner.open(server.url, reconnect_timeout_s=1.0)
        try:
            scanner.start_streaming()
            if link == "pty":
                started = time.monotonic()
                with pytest.raises(TransportError, match="not re-established"):
                    take(scanner, 40)
                assert time.monotonic() - started < 1.0 + 3.0
                return
            scans = take(scanner, 30, timeout_s=3.0)
            stats = scanner.stream_stats()
        finally:
            scanner.close()
    assert stats.reconnects == 1 and len(stats.gaps) == 1
    gap = stats.gaps[0]
    assert 0 < gap.duration_s < 2.0
    resume = next(i for i in range(1, len(scans)) if scans[i].sequence - scans[i - 1].sequence > 1)
    assert resume == 20
    assert scans[resume].host_time_s - scans[resume - 1].host_time_s < 2.0
    assert scans[resume].sequence - scans[resume - 1].sequence == gap.missed_scans + 1
    assert gap.missed_scans == round(gap.duration_s / 0.025) - 1
    assert scanner.dropped_scans() == 0


def _leave_a_stream_running(url: str) -> None:
    """An earlier client starts MD, reads a little and goes away without QT."""
    address = parse_url(url)
    request = b"MD0000108000000\n"
    if address.kind == "tcp":
        with socket.create_connection((address.host, address.port), timeout=2) as sock:
            sock.sendall(request)
            sock.recv(100)
        return
    with serial.serial_for_url(address.device, timeout=2) as port:
        port.write(request)
        port.read(100)


def test_client_after_an_abandoned_stream_gets_clean_data(server: FakeScannerServer) -> None:
    _leave_a_stream_running(server.url)
    time.sleep(0.1)  # let the abandoned stream put scans on the line (pty keeps streaming)
    with HokuyoScanner.open(server.url) as scanner:
        assert scanner.identity().model == "UTM-30LX-EW"
        scanner.start_streaming(intensities=True)
        scans = take(scanner, 10)
        scanner.stop_streaming()
        assert scanner.dropped_scans() == 0
    assert [s.sequence for s in scans] == list(range(10))
    assert all(np.array_equal(s.intensities, 2 * STEPS) for s in scans)


def test_laser_sensitivity_reset_and_bit_rate_commands(scanner: HokuyoScanner, link: str) -> None:
    assert scanner.laser_on() is True
    assert scanner.laser_on() is False  # already on: status 02 is not an error
    assert scanner.status().laser_on
    scanner.laser_off()
    assert not scanner.status().laser_on
    scanner.set_high_sensitivity(True)
    scanner.set_high_sensitivity(True)  # already set: 02 is not an error
    scanner.laser_on()
    scanner.reset()
    status = scanner.status()
    assert not status.laser_on and status.time_ms is not None and status.time_ms < 1000  # timer reset
    if link == "tcp":
        with pytest.raises(ScannerStatusError) as info:
            scanner.set_bit_rate(115200)
        assert info.value.status == "0F"  # meaningless on Ethernet
    else:
        scanner.set_bit_rate(115200)  # already at that rate: 03 is not an error
        scanner.set_bit_rate(57600)
        assert scanner.status().model == "UTM-30LX-EW"  # still talking after the change
    with pytest.raises(ConfigError, match="bit rate 0"):
        scanner.set_bit_rate(0)


def test_refused_command_raises_status_error_with_meaning(scanner: HokuyoScanner) -> None:
    with pytest.raises(ScannerStatusError) as info:
        scanner.set_motor_speed(0)
    assert info.value.status == "04"
    assert info.value.meaning == "not compatible with this sensor model"


def test_framer_sees_the_exact_bytes_of_a_fake_scan(server: FakeScannerServer) -> None:
    """The fake's wire output parses with the codec's framer: ack then scans, nothing left over."""
    address = parse_url(server.url)
    data = b""
    if address.kind == "tcp":
        with socket.create_connection((address.host, address.port), timeout=2) as sock:
            sock.sendall(b"ME0000108001003\n")
            while data.count(b"\n\n") < 4:
                data += sock.recv(65536)
    else:
        with serial.serial_for_url(address.device, timeout=2) as port:
            port.write(b"ME0000108001003\n")
            while data.count(b"\n\n") < 4:
                data += port.read(max(port.in_waiting, 1))
    framer = ResponseFramer()
    responses = framer.feed(data)
    assert [(r.echo, r.status) for r in responses] == [
        (b"ME0000108001003", b"00"), (b"ME0000108001002", b"99"), (b"ME0000108001001", b"99"),
        (b"ME0000108001000", b"99")]
    assert framer.discarded_bytes == 0


def test_queue_overflow_drops_oldest_and_counts(server: FakeScannerServer) -> None:
    with HokuyoScanner.open(server.url, queue_size=4) as scanner:
        scanner.start_streaming()
        first = scanner.next_scan(2.0)
        time.sleep(0.5)  # ~20 scans arrive while nobody reads
        queued = [scanner.next_scan(2.0) for _ in range(4)]
        stats = scanner.stream_stats()
        scanner.stop_streaming()
    assert stats.queue_overflows >= 10 and stats.corrupted == 0
    assert scanner.dropped_scans() == stats.queue_overflows
    assert queued[0].sequence - first.sequence > 10  # the newest scans were kept
    assert [s.sequence for s in queued] == list(range(queued[0].sequence, queued[0].sequence + 4))
