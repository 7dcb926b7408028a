"""Device status for ``GET /v1/status``, polled in a background thread so a request never
waits on a device.

The robot is watched through read-only interfaces (dashboard and RTDE receive,
``URRobot.connect(control=False)``): they leave the owner's program running, unlike
ur_rtde's control interface. The scanner is opened briefly for its identity only while
no job runs (a job owns it; a UTM-30LX-EW serves one client at a time).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from lasercal_hw.errors import LasercalError

logger = logging.getLogger(__name__)

SCANNER_EVERY_POLLS = 5


def _robot_unknown(host: str | None, error: str | None) -> dict[str, Any]:
    return {
        "connected": False,
        "host": host,
        "mode": None,
        "safety": None,
        "remote_control": None,
        "program_running": None,
        "error": error,
    }


class DeviceMonitor:
    """Keeps the newest robot and scanner status."""

    def __init__(
        self,
        robot_host: str | None,
        scanner_url: str | None,
        poll_s: float,
        job_running: Callable[[], str | None],
    ) -> None:
        self.robot_host = robot_host
        self.scanner_url = scanner_url
        self._poll_s = poll_s
        self._job_running = job_running
        self._robot: Any = None
        self._lock = threading.Lock()
        self._robot_status = _robot_unknown(robot_host, None if robot_host else "no robot configured")
        self._scanner_status: dict[str, Any] = {
            "connected": False,
            "url": scanner_url,
            "identity": None,
            "error": None if scanner_url else "no scanner configured",
        }
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="device-monitor", daemon=True)

    def start(self) -> None:
        """Start polling."""
        self._thread.start()

    def stop(self) -> None:
        """Stop polling and drop the read-only robot connection."""
        self._stop.set()
        self._thread.join(10.0)
        self._drop_robot()

    def snapshot(self) -> dict[str, dict[str, Any]]:
        """The newest ``{"robot": ..., "scanner": ...}``."""
        with self._lock:
            return {"robot": dict(self._robot_status), "scanner": dict(self._scanner_status)}

    def _loop(self) -> None:
        polls = 0
        while not self._stop.is_set():
            if self.robot_host:
                self._poll_robot(self.robot_host)
            if self.scanner_url and polls % SCANNER_EVERY_POLLS == 0:
                self._poll_scanner(self.scanner_url)
            polls += 1
            self._stop.wait(self._poll_s)

    def _poll_robot(self, host: str) -> None:
        from drivers.ur.client import URRobot

        try:
            if self._robot is None:
                self._robot = URRobot.connect(host, control=False, timeout_s=2.0)
            state = self._robot.state()
            status = {
                "connected": True,
                "host": host,
                "mode": state.robot_mode,
                "safety": state.safety_status,
                "remote_control": state.remote_control,
                "program_running": state.program_running,
                "error": None,
            }
        except LasercalError as exc:
            self._drop_robot()
            status = _robot_unknown(host, str(exc))
        with self._lock:
            self._robot_status = status

    def _drop_robot(self) -> None:
        robot, self._robot = self._robot, None
        if robot is not None:
            robot.close()

    def _poll_scanner(self, url: str) -> None:
        from drivers.hokuyo.client import HokuyoScanner

        job_id = self._job_running()
        if job_id is not None:
            with self._lock:
                self._scanner_status = self._scanner_status | {"error": None, "in_use_by_job": job_id}
            return
        try:
            with HokuyoScanner.open(url, timeout_s=2.0, sync_clock=False, reconnect=False) as scanner:
                identity = asdict(scanner.identity())
            status = {"connected": True, "url": url, "identity": identity, "error": None}
        except LasercalError as exc:
            status = {"connected": False, "url": url, "identity": None, "error": str(exc)}
        with self._lock:
            self._scanner_status = status
