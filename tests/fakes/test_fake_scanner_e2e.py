"""The real SCIP client (drivers.hokuyo.client) against the fake scanner, end to end."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.hokuyo.client import HokuyoScanner
from fakes.scan_scene import Cylinder, RoomScene
from fakes.scip_faults import ScipFaults
from fakes.scip_server import FakeScannerServer
from lasercal_hw.errors import TransportError

pytestmark = pytest.mark.timeout(60)
SCENE = RoomScene(cylinders=(Cylinder((1.5, 0.0), 0.020),))


@pytest.fixture(params=["tcp", "pty"])
def scanner(request: pytest.FixtureRequest) -> Iterator[HokuyoScanner]:
    with FakeScannerServer(pty=request.param == "pty", source=SCENE) as server:
        client = HokuyoScanner.open(server.url, timeout_s=2.0)
        try:
            yield client
        finally:
            client.close()


def test_client_reads_identity_and_a_single_scan(scanner: HokuyoScanner) -> None:
    identity = scanner.identity()
    assert identity.model == "UTM-30LX-EW" and identity.protocol == "SCIP 2.0"
    geometry = scanner.geometry()
    assert (geometry.first_step, geometry.last_step, geometry.front_step) == (0, 1080, 540)
    scan = scanner.single_scan(intensities=True)
    assert scan.ranges_m.size == 1081 and scan.intensities is not None
    assert scan.ranges_m[540] == pytest.approx(1.480, abs=0.001)  # rod surface straight ahead
    assert np.isfinite(scan.ranges_m).all()


def test_client_streams_consecutive_scans(scanner: HokuyoScanner) -> None:
    scanner.start_streaming()
    scans = [scanner.next_scan(timeout_s=2.0) for _ in range(5)]
    scanner.stop_streaming()
    assert [s.sequence for s in scans] == list(range(scans[0].sequence, scans[0].sequence + 5))
    assert np.diff([s.device_time_s for s in scans]) == pytest.approx(0.025, abs=1e-3)
    assert scanner.dropped_scans() == 0
    assert not scanner.status().laser_on


def test_stream_across_the_timer_wrap_stays_monotonic() -> None:
    start_ms = (1 << 24) - 1500  # the wrap comes 1.5 s after start: after open(), during the stream
    with (
        FakeScannerServer(source=SCENE, start_time_ms=start_ms) as server,
        HokuyoScanner.open(server.url, timeout_s=2.0) as client,
    ):
        before_ms = client.status().time_ms
        client.start_streaming()
        stamps = [client.next_scan(timeout_s=2.0).device_time_s for _ in range(80)]
        client.stop_streaming()
        after_ms = client.status().time_ms
    assert before_ms is not None and after_ms is not None
    assert before_ms > start_ms and after_ms < before_ms  # the 24-bit timer wrapped while streaming
    assert np.all(np.diff(stamps) == pytest.approx(0.025, abs=1e-3))


def test_client_counts_corrupted_scans_and_survives_garbage() -> None:
    faults = ScipFaults(corrupt_every_scans=3, garbage_every_messages=4)
    with (
        FakeScannerServer(source=SCENE, faults=faults, reply_timing="immediate") as server,
        HokuyoScanner.open(server.url, timeout_s=2.0) as client,
    ):
        client.start_streaming(intensities=True)
        scans = [client.next_scan(timeout_s=2.0) for _ in range(8)]
        client.stop_streaming()
        assert client.stream_stats().corrupted >= 3
    assert all(s.ranges_m[540] == pytest.approx(1.480, abs=0.001) for s in scans)


def test_client_reconnects_after_a_dropped_connection() -> None:
    faults = ScipFaults(drop_after_scans=5)
    with (
        FakeScannerServer(source=SCENE, faults=faults, reply_timing="immediate") as server,
        HokuyoScanner.open(server.url, timeout_s=2.0, reconnect_timeout_s=10.0) as client,
    ):
        client.start_streaming()
        scans = [client.next_scan(timeout_s=5.0) for _ in range(8)]
        stats = client.stream_stats()
        client.stop_streaming()
    assert stats.reconnects >= 1 and server.stats.connections >= 2
    assert len(scans) == 8 and scans[-1].sequence > scans[0].sequence


def _resources() -> tuple[int, int]:
    return len(os.listdir("/proc/self/fd")), threading.active_count()


@pytest.mark.parametrize("link", ["tcp", "pty"])
def test_every_descriptor_and_thread_is_released(link: str) -> None:
    """Normal use, a dropped link (TCP: reconnect; pty: hung up for good) and a refused
    connection leave no socket, pty, pipe or thread behind on either side."""
    before = _resources()
    with FakeScannerServer(pty=link == "pty", source=SCENE, faults=ScipFaults(drop_after_scans=3)) as server:
        with HokuyoScanner.open(server.url, timeout_s=2.0, reconnect_timeout_s=1.0) as client:
            client.start_streaming()
            with contextlib.suppress(TransportError):  # the pty ends the stream, TCP reconnects
                for _ in range(6):
                    client.next_scan(timeout_s=3.0)
        url = server.url
    if link == "tcp":
        with pytest.raises(TransportError, match="cannot connect"):
            HokuyoScanner.open(url, timeout_s=1.0)  # the server is gone: connection refused
    assert _resources() == before


def test_reconnect_warnings_name_the_scanner_once(caplog: pytest.LogCaptureFixture) -> None:
    with (
        FakeScannerServer(source=SCENE, faults=ScipFaults(drop_after_scans=3)) as server,
        HokuyoScanner.open(server.url, timeout_s=2.0) as client,
    ):
        client.start_streaming()
        for _ in range(6):
            client.next_scan(timeout_s=3.0)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert any("reconnecting" in message for message in warnings)
    assert all(message.count("scip+tcp://") == 1 for message in warnings), "\n".join(warnings)
