"""Scanner URLs and the TCP / serial (pseudo-terminal) transports."""

from __future__ import annotations

import os
import socket
import threading
import tty

import pytest

from drivers.hokuyo.transport import (
    SerialTransport,
    TcpTransport,
    TransportUrl,
    open_transport,
    parse_url,
)
from lasercal_hw.errors import ConfigError, DeviceTimeoutError, TransportError

pytestmark = pytest.mark.timeout(30)


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("scip+tcp://192.168.0.10", TransportUrl("tcp", host="192.168.0.10", port=10940)),
        ("scip+tcp://127.0.0.2:12345", TransportUrl("tcp", host="127.0.0.2", port=12345)),
        ("scip+tcp://[::1]:10940/", TransportUrl("tcp", host="::1", port=10940)),
        ("scip+serial:///dev/ttyACM0", TransportUrl("serial", device="/dev/ttyACM0", baud=115200)),
        ("scip+serial:///dev/pts/3?baud=19200", TransportUrl("serial", device="/dev/pts/3", baud=19200)),
    ],
)
def test_parse_url(url: str, expected: TransportUrl) -> None:
    assert parse_url(url) == expected
    assert parse_url(str(expected)) == expected


@pytest.mark.parametrize(
    "url",
    [
        "tcp://127.0.0.1:10940",
        "127.0.0.1",
        "scip+tcp://",
        "scip+tcp://127.0.0.1:99999",
        "scip+tcp://127.0.0.1:10940/path",
        "scip+serial://dev/ttyACM0",
        "scip+serial:///dev/ttyACM0?baud=fast",
        "scip+serial:///dev/ttyACM0?baud=0",
        "scip+serial:///dev/ttyACM0?parity=N",
        "scip+serial://",
        "scip+tcp://[::1",  # urlsplit raises ValueError itself
    ],
)
def test_bad_urls_name_the_accepted_forms(url: str) -> None:
    with pytest.raises(ConfigError, match=r"scip\+tcp://HOST\[:PORT\].*scip\+serial:///dev/ttyACM0"):
        parse_url(url)


@pytest.fixture
def tcp_peer():
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []
    ready = threading.Event()

    def accept() -> None:
        conn, _ = listener.accept()
        accepted.append(conn)
        ready.set()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    transport = open_transport(f"scip+tcp://127.0.0.1:{listener.getsockname()[1]}")
    assert ready.wait(5)
    yield transport, accepted[0]
    transport.close()
    accepted[0].close()
    listener.close()
    thread.join(5)


def test_tcp_reads_what_arrives_times_out_and_detects_close(tcp_peer) -> None:
    transport, peer = tcp_peer
    assert isinstance(transport, TcpTransport)
    assert transport._sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    transport.write(b"VV\n")
    assert peer.recv(10) == b"VV\n"
    peer.sendall(b"VV\n00P\n")
    received = b""
    while len(received) < 7:
        received += transport.read_some(1.0)
    assert received == b"VV\n00P\n"
    with pytest.raises(DeviceTimeoutError, match=r"no data within 0\.05 s"):
        transport.read_some(0.05)
    peer.close()
    with pytest.raises(TransportError, match="closed by the scanner"):
        transport.read_some(1.0)
    transport.close()
    transport.close()  # twice is fine
    with pytest.raises(TransportError, match="closed"):
        transport.write(b"QT\n")


def test_tcp_connection_refused_says_what_to_check() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    pattern = r"cannot connect to scip\+tcp://127.0.0.1:\d+: .*powered and reachable"
    with pytest.raises(TransportError, match=pattern):
        open_transport(f"scip+tcp://127.0.0.1:{port}")


def test_serial_over_a_pseudo_terminal() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    transport = open_transport(f"scip+serial://{os.ttyname(slave)}?baud=19200")
    try:
        assert isinstance(transport, SerialTransport)
        transport.write(b"PP\n")
        assert os.read(master, 10) == b"PP\n"
        os.write(master, b"PP\n00P\n\n")
        received = b""
        while len(received) < 8:
            received += transport.read_some(1.0)
        assert received == b"PP\n00P\n\n"
        with pytest.raises(DeviceTimeoutError):
            transport.read_some(0.05)
        transport.set_baud(115200)
        os.close(slave)
        os.close(master)  # hang up
        with pytest.raises(TransportError):
            transport.read_some(1.0)
    finally:
        transport.close()
        transport.close()


def test_serial_device_missing() -> None:
    with pytest.raises(TransportError, match="cannot open scip\\+serial:///dev/does-not-exist"):
        open_transport("scip+serial:///dev/does-not-exist")
