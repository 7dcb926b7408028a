"""Device status for ``GET /v1/status``, polled in a background thread so a request never
waits on a device.

The robot is asked through its dashboard server only (robot mode, safety status, remote
control, program state): a read-only conversation that leaves the owner's program alone,
unlike ur_rtde's control interface, and that costs the daemon nothing between polls (no
500 Hz RTDE stream, no ur_rtde constructor holding the GIL on the daemon's threads). The
scanner is opened briefly for its identity only while no job runs (a job owns it; a
UTM-30LX-EW serves one client at a time).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from lasercal_hw.errors import LasercalError
from lasercal_hw.service.dashboard import DashboardLink

logger = logging.getLogger(__name__)

SCANNER_EVERY_POLLS = 5


def _after_colon(line: str) -> str:
    return line.split(":", 1)[1].strip() if ":" in line else line.strip()


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
        device_lock: threading.Lock,
    ) -> None:
        """``job_running()`` names the job that owns the devices; ``device_lock`` is held by a
        job taking them (``JobManager.device_lock``) and by the scanner probe."""
        self.robot_host = robot_host
        self.scanner_url = scanner_url
        self._poll_s = poll_s
        self._job_running = job_running
        self._device_lock = device_lock
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
        """Stop polling."""
        self._stop.set()
        self._thread.join(10.0)

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
        try:
            link = DashboardLink(host)
            try:
                remote = link.ask("is in remote control")
                status = {
                    "connected": True,
                    "host": host,
                    "mode": _after_colon(link.ask("robotmode")),
                    "safety": _after_colon(link.ask("safetystatus")),
                    "remote_control": None if remote.startswith("could not") else remote == "true",
                    "program_running": link.ask("programState").upper().startswith("PLAYING"),
                    "error": None,
                }
            finally:
                link.close()
        except OSError as exc:
            status = _robot_unknown(host, f"the robot's dashboard server on {host} does not answer: {exc}")
        with self._lock:
            self._robot_status = status

    def _poll_scanner(self, url: str) -> None:
        from drivers.hokuyo.client import HokuyoScanner

        with self._device_lock:
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
