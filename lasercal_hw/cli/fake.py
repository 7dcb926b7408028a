"""``lasercal fake ...``: run fake devices that speak the real wire protocols."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from types import FrameType

import typer

from fakes.scip_faults import ScipFaults
from fakes.scip_identity import IDENTITIES
from fakes.scip_server import DEFAULT_PORT, REPLY_TIMINGS, FakeScannerServer
from lasercal_hw.cli.common import err_console, parse_vector
from lasercal_hw.errors import ConfigError, DeviceError

fake_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed


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


_VERSIONS = {"5.11": (5, 11, 6, 108949), "3.15": (3, 15, 7, 106331)}


@fake_app.command("robot")
def fake_robot(
    address: str = typer.Option(..., "--address", help="Loopback address to serve on, e.g. 127.0.0.2."),
    version: str = typer.Option("5.11", "--version", help="Controller software: 5.11 (e-Series, 500 Hz) "
                                "or 3.15 (CB3, 125 Hz)."),
    serial_number: str = typer.Option("20185500042", "--serial-number", help="Serial number (digits)."),
    start_q: str = typer.Option("", "--start-q", help="Start joint positions, 6 comma-separated radians."),
    tcp_offset: str = typer.Option("", "--tcp-offset", help="TCP offset pose x,y,z,rx,ry,rz (m, rad)."),
    protective_stop_at_move: int | None = typer.Option(
        None, "--protective-stop-at-move", min=1, help="Protective stop during move command K (1-based)."),
    protective_stop_at_s: float | None = typer.Option(
        None, "--protective-stop-at-s", min=0.0, help="Protective stop this many seconds after start."),
    unlock_delay_s: float = typer.Option(5.0, "--unlock-delay-s", min=0.0,
                                         help="Seconds before a protective stop can be unlocked."),
    freeze_at_move: int | None = typer.Option(None, "--freeze-at-move", min=1,
                                              help="Stop streaming RTDE data during move command K ..."),
    freeze_at_s: float | None = typer.Option(None, "--freeze-at-s", min=0.0, help="... or at this time ..."),
    freeze_s: float = typer.Option(1.0, "--freeze-s", min=0.0, help="... for this many seconds."),
    drop_at_move: int | None = typer.Option(None, "--drop-at-move", min=1,
                                            help="Close every client connection during move command K ..."),
    drop_at_s: float | None = typer.Option(None, "--drop-at-s", min=0.0, help="... or at this time."),
    move_fraction: float = typer.Option(0.5, "--fault-move-fraction", min=0.0, max=1.0,
                                        help="How far through move K the *-at-move faults hit."),
    local_control: bool = typer.Option(False, "--local-control",
                                       help="Report remote control off (ur_rtde control then refuses)."),
) -> None:
    """Serve a fake UR controller (dashboard 29999, RTDE 30004, script 30003) until Ctrl-C."""
    from fakes.serving import serve_until_signal
    from fakes.ur_controller.controller import DEFAULT_START_Q_RAD, ControllerConfig, FaultPlan
    from fakes.ur_controller.process import FakeRobot

    if version not in _VERSIONS:
        raise ConfigError(f"--version must be one of {', '.join(_VERSIONS)}, got {version!r}")
    if not serial_number.isdigit():
        raise ConfigError(f"--serial-number must be digits only (ur_rtde requires it), got {serial_number!r}")
    config = ControllerConfig(
        version=_VERSIONS[version],
        serial_number=serial_number,
        start_q_rad=tuple(parse_vector(start_q, 6, "--start-q")) if start_q else DEFAULT_START_Q_RAD,
        tcp_offset_pose=tuple(parse_vector(tcp_offset, 6, "--tcp-offset")) if tcp_offset else (0.0,) * 6,
        remote_control=not local_control,
        faults=FaultPlan(
            protective_stop_at_move=protective_stop_at_move,
            protective_stop_at_s=protective_stop_at_s,
            freeze_at_move=freeze_at_move,
            freeze_at_s=freeze_at_s,
            freeze_duration_s=freeze_s,
            drop_at_move=drop_at_move,
            drop_at_s=drop_at_s,
            move_fraction=move_fraction,
            unlock_delay_s=unlock_delay_s,
        ),
    )
    serve_until_signal(FakeRobot(address, config))


@fake_app.command("cell")
def fake_cell(
    address: str = typer.Option(..., "--address", help="Loopback address to serve on, e.g. 127.0.0.7."),
    scene: Path | None = typer.Option(None, "--scene", help="Scene file (TOML); default: the packaged one."),  # noqa: B008
    seed: int = typer.Option(0, "--seed", help="Seed of the scanner's noise."),
    lifeline_stdin: bool = typer.Option(
        False, "--lifeline-stdin", help="Also stop when standard input closes (the parent died)."
    ),
) -> None:
    """Serve a fake UR controller and a fake UTM-30LX-EW sharing one simulated world; prints
    'fake cell ready: {json}' (addresses and the ground-truth T_base_laser) when ready."""
    from fakes.cell import FakeCell
    from fakes.serving import serve_until_signal

    serve_until_signal(FakeCell(address, scene, seed), sys.stdin.buffer if lifeline_stdin else None)
