"""Leave the robot as the job found it: before a job, note the program loaded on the
controller and whether it was playing; afterwards load it again and, if it was playing,
play it. Plain dashboard-server lines (port 29999) over a socket with timeouts."""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable

logger = logging.getLogger(__name__)

DASHBOARD_PORT = 29999
TIMEOUT_S = 3.0


class DashboardLink:
    """One short dashboard conversation: ``ask(command) -> reply line``."""

    def __init__(self, host: str, port: int = DASHBOARD_PORT, timeout_s: float = TIMEOUT_S) -> None:
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


class ProgramKeeper:
    """``snapshot(host)`` notes the robot's program; the callable it returns restores it."""

    def __init__(self, port: int = DASHBOARD_PORT) -> None:
        self._port = port

    def snapshot(self, host: str) -> Callable[[], str] | None:
        """The restore step, or None when the dashboard cannot be asked (logged)."""
        try:
            link = DashboardLink(host, self._port)
            try:
                loaded = link.ask("get loaded program")
                playing = link.ask("programState").upper().startswith("PLAYING")
            finally:
                link.close()
        except OSError as exc:
            logger.warning("cannot note the robot's program on %s: %s", host, exc)
            return None
        program = loaded.split(":", 1)[1].strip() if loaded.lower().startswith("loaded program:") else None
        return lambda: self._restore(host, program, playing)

    def _restore(self, host: str, program: str | None, playing: bool) -> str:
        if program is None:
            return "no program was loaded before the job; nothing to restore"
        try:
            link = DashboardLink(host, self._port)
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
