"""HokuyoScanner against scripted peers that answer with real captured bytes, garbage,
truncated or refused replies (TCP and pseudo-terminal)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from drivers.hokuyo.client import HokuyoScanner
from drivers.hokuyo.codec import Response, ResponseFramer, format_response
from lasercal_hw.errors import DeviceTimeoutError, ProtocolError, ScannerStatusError, TransportError
from tests.scip_captures import capture
from tests.scip_servers import ScriptedScipServer

pytestmark = pytest.mark.timeout(30)

UTM = ResponseFramer().feed(capture("utm30lx_read"))
UXM = ResponseFramer().feed(capture("uxm30lxe_read"))
UTM_SCAN: Response = UTM[-1]


def utm_replay(scans_per_stream: int = 3) -> Callable[[bytes], bytes]:
    """Answer like the captured UTM-30LX; ME streams send the captured scan N times."""
    captured = {b"VV": UTM[0].to_bytes(), b"PP": UTM[2].to_bytes(), b"II": UTM[3].to_bytes(),
                b"BM": UTM[4].to_bytes(), b"QT": b"QT\n00P\n\n"}
    tm1 = iter([r.to_bytes() for r in UXM if r.echo == b"TM1"] * 10)

    def respond(line: bytes) -> bytes:
        if line in captured:
            return captured[line]
        if line.startswith(b"ME00001080010"):
            scan = format_response(line, b"99", UTM_SCAN.data_lines)
            return format_response(line, b"00") + scan * scans_per_stream
        if line.startswith(b"GE0000108001"):
            return format_response(line, b"00", UTM_SCAN.data_lines)
        if line in (b"TM0", b"TM2"):
            return format_response(line, b"00")
        if line == b"TM1":
            return next(tm1)
        return format_response(line, b"0E")

    return respond


@pytest.fixture(params=["tcp", "pty"])
def link(request: pytest.FixtureRequest) -> str:
    return request.param


def serve(respond: Callable[[bytes], bytes], link: str, on_connect: bytes = b"") -> ScriptedScipServer:
    return ScriptedScipServer(respond, pty=link == "pty", on_connect=on_connect)


@pytest.fixture
def utm_server(link: str) -> Iterator[ScriptedScipServer]:
    with serve(utm_replay(), link) as server:
        yield server


def test_open_reads_identity_parameters_and_status_from_captured_replies(utm_server) -> None:
    with HokuyoScanner.open(utm_server.url, sync_clock=False) as scanner:
        identity = scanner.identity()
        assert identity.firmware == "P.1.05(17/Apr./2009)"
        assert identity.serial == "00903971"
        assert identity.model == "UTM-30LX(Hokuyo Automatic Co.,Ltd.)"
        parameters = scanner.parameters()
        assert (parameters.min_range_mm, parameters.max_range_mm) == (23, 60000)
        assert parameters.scan_period_s == pytest.approx(0.025)
        geometry = scanner.geometry()
        assert geometry.beam_count == 1081
        assert geometry.angles_rad()[0] == pytest.approx(np.deg2rad(-135))
        status = scanner.status()
        assert status.time_ms == 0x4991D0 and status.laser_on and status.healthy
    assert utm_server.requests[:4] == [b"QT", b"VV", b"PP", b"II"]


def test_clock_sync_uses_tm0_tm1_tm2(utm_server) -> None:
    with HokuyoScanner.open(utm_server.url) as scanner:
        estimate = scanner.clock()
    assert estimate.source == "tm"
    assert utm_server.requests[3:] == [b"TM0", *[b"TM1"] * 10, b"TM2"]
    # the captured TM1 values are 3 292 603 .. 3 292 611 ms; the anchor maps them to now
    assert abs(3_292_603 / 1000 + estimate.offset_s - time.time()) < 5


def test_stream_decodes_captured_scans_to_the_oracle(utm_server) -> None:
    with HokuyoScanner.open(utm_server.url, sync_clock=False) as scanner:
        scanner.start_streaming(intensities=True)
        scans = [scanner.next_scan(2.0) for _ in range(3)]
        with pytest.raises(DeviceTimeoutError):
            scanner.next_scan(0.2)
        scanner.stop_streaming()
        assert scanner.dropped_scans() == 0
    for scan in scans:
        assert scan.raw_ranges_mm.sum() == 1_287_760
        assert scan.intensities is not None and scan.intensities.sum() == 2_602_800
        np.testing.assert_allclose(scan.ranges_m, scan.raw_ranges_mm / 1000.0)
    stream_request = next(r for r in utm_server.requests if r.startswith(b"ME"))
    assert stream_request == b"ME0000108001000;LC1"
    assert utm_server.requests[-1] == b"QT"


def test_single_scan_with_intensities(utm_server) -> None:
    with HokuyoScanner.open(utm_server.url, sync_clock=False) as scanner:
        scan = scanner.single_scan(intensities=True)
    assert scan.raw_ranges_mm[:5].tolist() == [45, 48, 49, 50, 49]
    assert b"BM" in utm_server.requests  # laser on first; "02 already on" is accepted


def test_stale_stream_on_the_line_is_drained(link: str) -> None:
    stale = UTM_SCAN.to_bytes()
    stale = stale[len(stale) // 2 :] + stale * 3
    with serve(utm_replay(), link, on_connect=stale) as server, HokuyoScanner.open(
        server.url, sync_clock=False
    ) as scanner:
        assert scanner.identity().serial == "00903971"


def test_garbage_replies_raise_protocol_error_within_the_timeout(link: str) -> None:
    def respond(line: bytes) -> bytes:
        return b"QT\n00P\n\n" if line == b"QT" else b"\x00\xfe#garbage\x7f\n\n"

    with serve(respond, link) as server:
        started = time.monotonic()
        with pytest.raises(ProtocolError, match=r"no valid reply to VV within 0\.5 s"):
            HokuyoScanner.open(server.url, timeout_s=0.5)
        assert time.monotonic() - started < 0.5 + 0.2 + 0.5  # timeout + quiet drain + slack


def test_truncated_reply_raises_protocol_error(link: str) -> None:
    def respond(line: bytes) -> bytes:
        return b"QT\n00P\n\n" if line == b"QT" else UTM[0].to_bytes()[:40]

    with serve(respond, link) as server, pytest.raises(ProtocolError, match="not a complete SCIP message"):
        HokuyoScanner.open(server.url, timeout_s=0.5)


def test_silence_raises_device_timeout(link: str) -> None:
    with serve(lambda line: b"", link) as server, pytest.raises(DeviceTimeoutError, match="no reply to VV"):
        HokuyoScanner.open(server.url, timeout_s=0.3)


def test_status_error_carries_code_and_command_specific_meaning(link: str) -> None:
    base = utm_replay()

    def respond(line: bytes) -> bytes:
        return b"BM\n01Q\n\n" if line == b"BM" else base(line)

    with (
        serve(respond, link) as server,
        HokuyoScanner.open(server.url, sync_clock=False) as scanner,
        pytest.raises(ScannerStatusError) as info,
    ):
        scanner.single_scan()
    assert info.value.status == "01"
    assert info.value.meaning == "unable to control due to laser malfunction"


def test_device_left_in_time_adjust_mode_is_recovered(link: str) -> None:
    base = utm_replay()
    state = {"tm": True}

    def respond(line: bytes) -> bytes:
        if line == b"TM2":
            state["tm"] = False
        if state["tm"]:
            return format_response(line, b"0E")
        return base(line)

    with serve(respond, link) as server, HokuyoScanner.open(server.url, sync_clock=False) as scanner:
        assert scanner.identity().protocol == "SCIP 2.0"


def test_tagged_stream_refused_is_retried_untagged(link: str) -> None:
    base = utm_replay(scans_per_stream=2)

    def respond(line: bytes) -> bytes:
        return format_response(line, b"0H") if b";" in line else base(line)

    with serve(respond, link) as server, HokuyoScanner.open(server.url, sync_clock=False) as scanner:
        scanner.start_streaming(intensities=True)
        assert scanner.next_scan(2.0).raw_ranges_mm.max() == 5856
        scanner.stop_streaming()


def test_stream_lost_without_reconnect_reports_transport_error() -> None:
    with ScriptedScipServer(utm_replay(scans_per_stream=1)) as server:
        scanner = HokuyoScanner.open(server.url, sync_clock=False, reconnect=False)
        try:
            scanner.start_streaming(intensities=True)
            scanner.next_scan(2.0)
            server.stop()
            with pytest.raises(TransportError, match="stream lost"):
                scanner.next_scan(3.0)
        finally:
            scanner.close()


def test_watchdog_reconnects_a_silent_stream_and_reports_the_gap(link: str) -> None:
    with serve(utm_replay(scans_per_stream=2), link) as server, HokuyoScanner.open(
        server.url, sync_clock=False
    ) as scanner:
        scanner.start_streaming(intensities=True)
        scans = [scanner.next_scan(5.0) for _ in range(4)]
        stats = scanner.stream_stats()
        scanner.stop_streaming()
    assert [s.raw_ranges_mm.sum() for s in scans] == [1_287_760] * 4
    assert stats.reconnects == 1
    (gap,) = stats.gaps
    assert "no data for 1 s" in gap.reason
    assert 1.0 <= gap.duration_s < 3.0
    assert sum(r.startswith(b"ME") for r in server.requests) == 2
