"""``lasercal fake scanner`` as a process: URL on stdout when ready, clean exit on signals."""

from __future__ import annotations

import select
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import serial

from drivers.hokuyo import codec

pytestmark = [pytest.mark.timeout(60), pytest.mark.integration]
READY_TIMEOUT_S = 20.0


@contextmanager
def fake_scanner(*args: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """Start the CLI, wait for its URL line, and make sure the process is gone afterwards."""
    process = subprocess.Popen(
        [sys.executable, "-m", "lasercal_hw.cli.main", "fake", "scanner", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], READY_TIMEOUT_S)
        assert ready, "the fake scanner printed no URL"
        yield process, process.stdout.readline().strip()
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate(timeout=10)


def read_messages(sock: socket.socket, count: int) -> tuple[list[codec.Response], bytes]:
    framer, raw, got = codec.ResponseFramer(), b"", []
    while len(got) < count:
        data = sock.recv(65536)
        assert data, "connection closed early"
        raw += data
        got += framer.feed(data)
    return got, raw


def test_tcp_url_is_printed_and_sigterm_exits_cleanly() -> None:
    with fake_scanner("--listen", "127.0.0.1:0") as (process, url):
        assert url.startswith("scip+tcp://127.0.0.1:")
        host, port = url.removeprefix("scip+tcp://").rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=5) as sock:
            sock.sendall(b"PP\n")
            (pp,), _ = read_messages(sock, 1)
            assert pp.data_lines[0] == b"MODL:UTM-30LX-EW;I"
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0


def test_pty_url_works_with_pyserial_and_sigint_exits_cleanly() -> None:
    with fake_scanner("--pty", "--identity", "utm-30lx") as (process, url):
        assert url.startswith("scip+serial:///dev/")
        with serial.serial_for_url(url.removeprefix("scip+serial://"), timeout=5) as port:
            port.write(b"VV\n")
            framer, got = codec.ResponseFramer(), []
            while not got:
                got = framer.feed(port.read(max(1, port.in_waiting)))
            assert got[0].data_lines[1] == b"PROD:SOKUIKI Sensor TOP-URG UTM-30LX;P"
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=10) == 0


def test_fault_flags_show_on_the_wire() -> None:
    args = ("--listen", "127.0.0.1:0", "--reply-timing", "immediate", "--start-time-ms", "16777000",
            "--corrupt-every", "1", "--garbage-every", "1", "--drop-after", "2", "--reply-delay-ms", "10")
    with fake_scanner(*args) as (process, url):
        host, port = url.removeprefix("scip+tcp://").rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=5) as sock:
            sock.sendall(b"MD0000108001000\n")
            (ack, first, second), raw = read_messages(sock, 3)
            while data := sock.recv(65536):  # the fake drops the link after 2 scans
                raw += data
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0
    assert ack.status == b"00" and raw.count(b"garbage") == 3
    for scan in (first, second):
        assert 16777000 <= codec.decode_timestamp_line(scan.data_lines[0]) < 1 << 24
        with pytest.raises(codec.DataLineChecksumError):
            codec.decode_data_lines(scan.data_lines[1:])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--listen", "192.168.0.10:10940"), "loopback"),
        (("--listen", "127.0.0.1"), "HOST:PORT"),
        (("--identity", "ust-10lx"), "--identity"),
        (("--reply-timing", "late"), "--reply-timing"),
    ],
)
def test_bad_options_are_one_line_errors(args: tuple[str, ...], message: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", "fake", "scanner", *args],
        capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert result.stdout == ""
