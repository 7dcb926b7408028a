"""The fake scanner on the wire: TCP with raw sockets, the pseudo-terminal with pyserial,
fault injection as a client sees it."""

from __future__ import annotations

import contextlib
import itertools
import socket
import time
from collections.abc import Iterator

import pytest
import serial

from drivers.hokuyo import codec
from fakes.scip_faults import DEFAULT_GARBAGE, ScipFaults, corrupt_first_data_line
from fakes.scip_identity import SensorState
from fakes.scip_server import FakeScannerServer, loopback_host
from lasercal_hw.errors import ConfigError

pytestmark = pytest.mark.timeout(30)
READ_TIMEOUT_S = 5.0


def tcp_address(url: str) -> tuple[str, int]:
    host, port = url.removeprefix("scip+tcp://").rsplit(":", 1)
    return host, int(port)


def connect(server: FakeScannerServer) -> socket.socket:
    sock = socket.create_connection(tcp_address(server.url), timeout=READ_TIMEOUT_S)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


class Reader:
    """Reads from a socket or serial port until enough whole messages arrived."""

    def __init__(self, link: socket.socket | serial.Serial) -> None:
        self.link = link
        self.framer = codec.ResponseFramer()
        self.raw = bytearray()

    def _read(self) -> bytes:
        if isinstance(self.link, socket.socket):
            return self.link.recv(65536)
        return self.link.read(max(1, self.link.in_waiting))

    def messages(self, count: int) -> list[codec.Response]:
        got: list[codec.Response] = []
        deadline = time.monotonic() + READ_TIMEOUT_S
        while len(got) < count:
            assert time.monotonic() < deadline, f"only {len(got)} of {count} messages arrived"
            data = self._read()
            if not data and isinstance(self.link, socket.socket):
                raise ConnectionError(f"connection closed after {len(got)} messages")
            self.raw += data
            got += self.framer.feed(data)
        return got


@pytest.fixture
def server() -> Iterator[FakeScannerServer]:
    with FakeScannerServer(reply_timing="immediate") as running:
        yield running


def test_tcp_answers_byte_for_byte(server: FakeScannerServer) -> None:
    assert server.url.startswith("scip+tcp://127.0.0.1:")
    with connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"BM\nBM\nQT\nPP\n")
        reader.messages(4)
    assert bytes(reader.raw) == (
        b"BM\n00P\n\nBM\n02R\n\nQT\n00P\n\n"
        b"PP\n00P\nMODL:UTM-30LX-EW;I\nDMIN:23;7\nDMAX:60000;J\nARES:1440;^\nAMIN:0;?\n"
        b"AMAX:1080;Z\nAFRT:540;0\nSCAN:2400;U\n\n"
    )


def test_cr_lf_and_crlf_each_end_one_request(server: FakeScannerServer) -> None:
    with connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"\nVV\rPP\r\nQT\n\r\nBM\r")
        sock.sendall(b"\n")  # CRLF split over two segments is still one terminator
        sock.sendall(b"BM\n")
        echoes = [m.echo for m in reader.messages(5)]
        assert echoes == [b"VV", b"PP", b"QT", b"BM", b"BM"]
        sock.sendall(b"QT\n")
        assert reader.messages(1)[0].echo == b"QT"  # no reply was produced for empty lines


def test_stream_over_tcp_decodes_with_the_codec(server: FakeScannerServer) -> None:
    with connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"ME0000108001003;s1\n")
        ack, *scans = reader.messages(4)
    assert ack.to_bytes() == b"ME0000108001003;s1\n00P\n\n"
    assert [m.echo for m in scans] == [b"ME0000108001002;s1", b"ME0000108001001;s1", b"ME0000108001000;s1"]
    stamps = []
    for message in scans:
        assert message.status == b"99"
        decoded = codec.decode_scan_lines(message.data_lines, codec.parse_scan_request(message.echo))
        assert decoded.distances_mm.size == 1081 and decoded.intensities is not None
        stamps.append(decoded.timestamp_ms)
    assert [b - a for a, b in itertools.pairwise(stamps)] == [25, 25]  # absolute 25 ms deadlines


def test_reply_is_never_inside_a_scan_message(server: FakeScannerServer) -> None:
    with connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"MD0000108001000\n")
        reader.messages(2)
        for _ in range(10):
            sock.sendall(b"II\nVV\n")
        messages = reader.messages(22)
        sock.sendall(b"QT\n")
        while not any(m.echo == b"QT" for m in reader.messages(1)):
            pass
    assert reader.framer.discarded_bytes == 0  # every message arrived whole
    assert sum(m.echo == b"II" for m in messages) == 10


def test_cycle_timing_answers_at_revolution_boundaries_and_tm1_at_once() -> None:
    with FakeScannerServer(start_time_ms=1000) as server, connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"TM0\n")
        reader.messages(1)
        sock.sendall(b"TM1\n")
        first = reader.messages(1)[0]
        sock.sendall(b"TM1\n")
        second = reader.messages(1)[0]
        sock.sendall(b"TM2\nII\n")
        _, ii = reader.messages(2)
    t1 = codec.decode_timestamp_line(first.data_lines[0])
    t2 = codec.decode_timestamp_line(second.data_lines[0])
    assert 0 <= t2 - t1 < 25  # TM1 in time-adjust mode is not held to a 25 ms boundary
    time_ms = codec.parse_time_field(codec.parse_parameter_lines(ii.data_lines)["TIME"])
    assert (time_ms - 1000) % 25 == 0  # II processed exactly at a revolution boundary


def test_second_client_is_refused_while_one_is_connected(server: FakeScannerServer) -> None:
    with connect(server) as first:
        reader = Reader(first)
        first.sendall(b"VV\n")
        reader.messages(1)
        with connect(server) as second:
            second.sendall(b"VV\n")
            # closed without an answer: FIN, or RST when the request was already unread there
            with contextlib.suppress(ConnectionResetError):
                assert second.recv(100) == b""
        first.sendall(b"QT\n")
        assert reader.messages(1)[0].echo == b"QT"
    assert server.stats.refused_connections == 1


def test_tcp_disconnect_stops_the_stream_and_switches_the_laser_off(server: FakeScannerServer) -> None:
    with connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"MD0000108001000\n")
        reader.messages(2)
    with connect(server) as sock:
        sock.sendall(b"II\n")
        (ii,) = Reader(sock).messages(1)
    fields = codec.parse_parameter_lines(ii.data_lines)
    assert fields["LASR"] == "OFF" and fields["MESM"] == "000 Idle"
    assert server.stats.connections == 2


def test_pty_serves_pyserial_and_keeps_streaming_without_a_reader() -> None:
    with FakeScannerServer(pty=True, reply_timing="immediate") as server:
        assert server.url.startswith("scip+serial:///dev/")
        path = server.url.removeprefix("scip+serial://")
        with serial.serial_for_url(path, baudrate=115200, timeout=0.5) as port:
            reader = Reader(port)
            port.write(b"VV\r\nPP\nSS019200\rMD0000108001000\n")
            vv, pp, ss, ack, scan = reader.messages(5)
            assert pp.to_bytes().startswith(b"PP\n00P\nMODL:UTM-30LX-EW;I\n")
            assert vv.echo == b"VV" and ss.to_bytes() == b"SS019200\n00P\n\n" and ack.status == b"00"
            assert scan.status == b"99"
        sent_when_closed = server.stats.scans_sent
        assert server.device is not None and server.device.state is SensorState.STREAMING
        with serial.serial_for_url(path, baudrate=115200, timeout=0.5) as port:
            reader = Reader(port)
            reader.messages(2)  # scans keep coming without any request (a serial sensor has no disconnect)
            port.write(b"QT\n")
            while not any(m.echo == b"QT" for m in reader.messages(1)):
                pass
        assert server.stats.scans_sent > sent_when_closed
        assert server.device.state is SensorState.IDLE


def test_corrupted_checksums_are_visible_on_the_wire() -> None:
    faults = ScipFaults(corrupt_every_scans=2)
    with FakeScannerServer(faults=faults, reply_timing="immediate") as server, connect(server) as sock:
        sock.sendall(b"MD0000108001004\n")
        _, *scans = Reader(sock).messages(5)
    bad = []
    for index, message in enumerate(scans):
        request = codec.parse_scan_request(message.echo)
        try:
            codec.decode_scan_lines(message.data_lines, request)
        except codec.DataLineChecksumError as exc:
            assert exc.bad_lines == [0]
            bad.append(index)
    assert bad == [1, 3]


def test_garbage_between_messages_is_visible_and_resynchronisable() -> None:
    faults = ScipFaults(garbage_every_messages=2)
    with FakeScannerServer(faults=faults, reply_timing="immediate") as server, connect(server) as sock:
        reader = Reader(sock)
        sock.sendall(b"VV\nPP\nII\nBM\n")
        messages = reader.messages(4)
    assert [m.echo for m in messages] == [b"VV", b"PP", b"II", b"BM"]
    assert bytes(reader.raw).count(DEFAULT_GARBAGE) == 2
    assert bytes(reader.raw).index(DEFAULT_GARBAGE) == len(messages[0].to_bytes())  # between messages
    assert reader.framer.discarded_bytes == 2 * len(DEFAULT_GARBAGE)


def test_connection_drops_after_n_scans_and_the_server_accepts_again() -> None:
    faults = ScipFaults(drop_after_scans=3)
    with FakeScannerServer(faults=faults, reply_timing="immediate") as server:
        with connect(server) as sock:
            reader = Reader(sock)
            sock.sendall(b"MD0000108001000\n")
            messages = reader.messages(4)
            with pytest.raises(ConnectionError, match="closed after 0"):
                reader.messages(1)
        assert [m.status for m in messages] == [b"00", b"99", b"99", b"99"]
        with connect(server) as sock:
            sock.sendall(b"II\n")
            (ii,) = Reader(sock).messages(1)
        assert codec.parse_parameter_lines(ii.data_lines)["LASR"] == "OFF"


def test_pty_drop_hangs_up_like_an_unplugged_cable() -> None:
    faults = ScipFaults(drop_after_scans=2)
    with FakeScannerServer(pty=True, faults=faults, reply_timing="immediate") as server:
        path = server.url.removeprefix("scip+serial://")
        with serial.serial_for_url(path, timeout=0.5) as port:
            reader = Reader(port)
            port.write(b"MD0000108001000\n")
            with pytest.raises(serial.SerialException):
                reader.messages(100)  # read until the hang-up (bytes in flight may be lost, as on USB)
        assert server.wait(READ_TIMEOUT_S)
        assert server.failure is None and server.stats.scans_sent == 2
        scans = codec.ResponseFramer().feed(bytes(reader.raw))[1:]
        assert len(scans) <= 2 and all(m.status == b"99" for m in scans)


def test_reply_delay_holds_replies_back() -> None:
    faults = ScipFaults(reply_delay_ms=150)
    with FakeScannerServer(faults=faults, reply_timing="immediate") as server, connect(server) as sock:
        started = time.monotonic()
        sock.sendall(b"VV\n")
        Reader(sock).messages(1)
        assert time.monotonic() - started >= 0.150


def test_fault_corruption_touches_only_the_first_data_line_checksum() -> None:
    message = codec.format_response(b"MD0000000100000", b"99", codec.encode_scan_lines(5, [100, 200]))
    corrupted = corrupt_first_data_line(message)
    assert len(corrupted) == len(message)
    differing = [i for i, (a, b) in enumerate(zip(message, corrupted, strict=True)) if a != b]
    lines = message.split(b"\n")
    assert differing == [sum(len(line) + 1 for line in lines[:4]) - 2]  # last char of data line 1


@pytest.mark.parametrize("address", ["0.0.0.0", "192.168.0.10", "example.com", "::"])
def test_non_loopback_addresses_are_refused(address: str) -> None:
    with pytest.raises(ConfigError, match="loopback"):
        FakeScannerServer(address)


def test_loopback_variants_are_accepted() -> None:
    assert loopback_host("localhost") == "127.0.0.1"
    assert loopback_host("127.0.0.5") == "127.0.0.5"


def test_port_in_use_is_a_clear_error(server: FakeScannerServer) -> None:
    _, port = tcp_address(server.url)
    with pytest.raises(ConfigError, match="cannot listen"):
        FakeScannerServer(port=port).start()


def test_stop_is_idempotent_and_releases_the_port() -> None:
    server = FakeScannerServer()
    server.start()
    _, port = tcp_address(server.url)
    server.stop()
    server.stop()
    assert not server.running
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=1.0)
