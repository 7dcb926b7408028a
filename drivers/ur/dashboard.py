"""The UR dashboard server (port 29999) in plain lines over a socket with timeouts: short
read-only conversations for the robot's status, and the program a job leaves as it found
it (noted before, loaded and played again after).

Unlike ur_rtde's control interface these leave the owner's program alone, and unlike its
``DashboardClient`` they cost nothing between conversations (no thread, no GIL held)."""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable
from typing import Any

from drivers.loopback import check_host

logger = logging.getLogger(__name__)

DASHBOARD_PORT = 29999
TIMEOUT_S = 3.0


class DashboardLink:
    """One short dashboard conversation: ``ask(command) -> reply line``."""

    def __init__(self, host: str, port: int = DASHBOARD_PORT, timeout_s: float = TIMEOUT_S) -> None:
        check_host(host, "the robot's dashboard")
        self._sock = socket.create_connection((host, port), timeout=timeout_s)
        self._file = self._sock.makefile("rwb")
        self._file.readline()  # banner

    def ask(self, command: str) -> str:
        """Send one command, return its reply line."""
        self._file.write(command.encode("ascii") + b"\n")
        self._file.flush()
        return self._file.readline().decode("utf-8", "replace").strip()

    def close(self) -> None:
        """Close the connection."""
        self._file.close()
        self._sock.close()


def after_colon(line: str) -> str:
    """The part of a dashboard reply after its ``label:``."""
    return line.split(":", 1)[1].strip() if ":" in line else line.strip()


def robot_unknown(host: str | None, error: str | None) -> dict[str, Any]:
    """The status of a robot that cannot be asked (``error`` says why)."""
    return {
        "connected": False,
        "host": host,
        "mode": None,
        "safety": None,
        "remote_control": None,
        "program_running": None,
        "error": error,
    }


def robot_status(host: str, port: int = DASHBOARD_PORT) -> dict[str, Any]:
    """Robot mode, safety status, remote control and whether a program plays."""
    try:
        link = DashboardLink(host, port)
        try:
            remote = link.ask("is in remote control")
            return {
                "connected": True,
                "host": host,
                "mode": after_colon(link.ask("robotmode")),
                "safety": after_colon(link.ask("safetystatus")),
                "remote_control": None if remote.startswith("could not") else remote == "true",
                "program_running": link.ask("programState").upper().startswith("PLAYING"),
                "error": None,
            }
        finally:
            link.close()
    except OSError as exc:
        return robot_unknown(host, f"the robot's dashboard server on {host} does not answer: {exc}")


def program_snapshot(host: str, port: int = DASHBOARD_PORT) -> Callable[[], str] | None:
    """Note the loaded program and whether it plays; the step that restores it (and says
    what it did), or None when the dashboard cannot be asked (logged)."""
    try:
        link = DashboardLink(host, port)
        try:
            loaded = link.ask("get loaded program")
            playing = link.ask("programState").upper().startswith("PLAYING")
        finally:
            link.close()
    except OSError as exc:
        logger.warning("cannot note the robot's program on %s: %s", host, exc)
        return None
    program = loaded.split(":", 1)[1].strip() if loaded.lower().startswith("loaded program:") else None
    return lambda: restore_program(host, program, playing, port)


def restore_program(host: str, program: str | None, playing: bool, port: int = DASHBOARD_PORT) -> str:
    """Load ``program`` again and play it if it was playing; what was done, in one line."""
    if program is None:
        return "no program was loaded before the job; nothing to restore"
    try:
        link = DashboardLink(host, port)
        try:
            loaded = link.ask(f"load {program}")
            if not loaded.lower().startswith("loading program"):
                return f"could not load {program} again: {loaded}"
            if not playing:
                return f"loaded {program} again (it was not playing)"
            played = link.ask("play")
            return f"loaded and played {program} again: {played}"
        finally:
            link.close()
    except OSError as exc:
        return f"could not restore {program} on {host}: {exc}"
