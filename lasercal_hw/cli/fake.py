"""``lasercal fake ...``: run fake devices that speak the real wire protocols."""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType

import typer

from fakes.scip_faults import ScipFaults
from fakes.scip_identity import IDENTITIES
from fakes.scip_server import DEFAULT_PORT, REPLY_TIMINGS, FakeScannerServer
from lasercal_hw.cli.common import err_console
from lasercal_hw.errors import ConfigError, DeviceError

fake_app = typer.Typer(
    help="Run fake devices (scanner, robot) that speak the exact wire protocols, for dry runs and CI.",
    no_args_is_help=True,
)


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6) into its parts, with a clear error."""
    host, sep, port_text = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ConfigError(f"--listen must be HOST:PORT with PORT 0..65535 (e.g. 127.0.0.1:{DEFAULT_PORT}), "
                          f"got {text!r}")
    return host, int(port_text)


@fake_app.command("scanner")
def fake_scanner(
    listen: str = typer.Option(
        f"127.0.0.1:{DEFAULT_PORT}", "--listen", help="Loopback HOST:PORT (port 0 = any free one)."
    ),
    pty: bool = typer.Option(False, "--pty", help="Serve on a pseudo-terminal (serial path) instead of TCP."),
    start_time_ms: int = typer.Option(
        0, "--start-time-ms", min=0, help="Sensor timer at start (e.g. 16777000 to test the 24-bit wrap)."
    ),
    corrupt_every: int = typer.Option(
        0, "--corrupt-every", min=0, help="Corrupt one data-line checksum in every N-th scan (0 = off)."
    ),
    drop_after: int = typer.Option(
        0, "--drop-after", min=0, help="Drop the connection after N scans of each connection (0 = off)."
    ),
    garbage_every: int = typer.Option(
        0, "--garbage-every", min=0, help="Send garbage bytes before every N-th message (0 = off)."
    ),
    reply_delay_ms: float = typer.Option(
        0.0, "--reply-delay-ms", min=0.0, help="Hold every command reply back this many ms."
    ),
    identity: str = typer.Option(
        "utm-30lx-ew", "--identity", help=f"VV/PP/II identity: {', '.join(IDENTITIES)}."
    ),
    reply_timing: str = typer.Option(
        "cycle", "--reply-timing", help="'cycle': answer at the next 25 ms boundary like a real unit; "
        "'immediate': answer on arrival."
    ),
) -> None:
    """Serve a fake Hokuyo UTM-30LX-EW (SCIP 2.0). Prints its URL on one line when ready
    and runs until SIGINT/SIGTERM."""
    if identity not in IDENTITIES:
        raise ConfigError(f"--identity must be one of {', '.join(IDENTITIES)}, got {identity!r}")
    if reply_timing not in REPLY_TIMINGS:
        raise ConfigError(f"--reply-timing must be one of {', '.join(REPLY_TIMINGS)}, got {reply_timing!r}")
    host, port = parse_listen(listen)
    faults = ScipFaults(
        corrupt_every_scans=corrupt_every,
        garbage_every_messages=garbage_every,
        drop_after_scans=drop_after,
        reply_delay_ms=reply_delay_ms,
    )
    server = FakeScannerServer(
        host,
        port,
        pty=pty,
        faults=faults,
        identity=IDENTITIES[identity],
        start_time_ms=start_time_ms,
        reply_timing=reply_timing,
    )
    stop_requested = threading.Event()

    def _request_stop(signum: int, frame: FrameType | None) -> None:
        stop_requested.set()

    previous = {sig: signal.signal(sig, _request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        url = server.start()
        print(url, flush=True)
        while not stop_requested.wait(0.2):
            if not server.running:
                break
    finally:
        server.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if server.failure is not None:
        raise DeviceError(f"the fake scanner stopped on an error: {server.failure}")
    if not stop_requested.is_set():
        err_console.print("fake scanner: the pseudo-terminal was hung up (--drop-after); exiting")
    sys.stdout.flush()
