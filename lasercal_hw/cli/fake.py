"""``lasercal fake ...``: run wire-faithful fake devices on a loopback address."""

from __future__ import annotations

import typer

from lasercal_hw.cli.common import parse_vector
from lasercal_hw.errors import ConfigError

fake_app = typer.Typer(help="Run fake devices that speak the real wire protocols (loopback only).",
                       no_args_is_help=True)

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
    from fakes.ur_controller.controller import DEFAULT_START_Q_RAD, ControllerConfig, FaultPlan
    from fakes.ur_controller.process import FakeRobot, serve_until_signal

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
