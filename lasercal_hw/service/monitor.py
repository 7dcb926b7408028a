"""Device status for ``GET /v1/status``, polled in a background thread so a request never
waits on a device.

The probes are the device door's (``drivers.access.DeviceAccess``): the robot through its
dashboard server only (robot mode, safety status, remote control, program state), which
leaves the owner's program alone and costs nothing between polls; the robot's kinematics
calibration from its read-only primary interface (``GET /v1/health`` compares it with the
active calibration's); the scanner opened briefly for its identity, and only while no job
holds the devices.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any, Literal

from lasercal_hw.errors import LasercalError
from lasercal_hw.service.daemon_log import device_summary, log_device
from lasercal_hw.service.store import utc_now

if TYPE_CHECKING:
    from drivers.access import DeviceAccess

logger = logging.getLogger(__name__)

SCANNER_EVERY_POLLS = 5


class DeviceMonitor:
    """Keeps the newest robot and scanner status."""

    def __init__(self, devices: DeviceAccess, poll_s: float) -> None:
        self._devices = devices
        self._poll_s = poll_s
        self._lock = threading.Lock()
        from drivers.ur.dashboard import robot_unknown  # the status of a robot not asked yet

        self._robot_status = robot_unknown(
            devices.robot_host, None if devices.robot_host else "no robot configured"
        )
        self._scanner_status: dict[str, Any] = {
            "connected": False,
            "url": devices.scanner_url,
            "identity": None,
            "error": None if devices.scanner_url else "no scanner configured",
        }
        self._robot_calibration: dict[str, Any] = {
            "known": False, "calibration": None, "read_utc": None,
            "error": None if devices.robot_host else "no robot configured",
        }
        self._logged: dict[str, tuple[Any, ...]] = {}
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

    def robot_calibration(self) -> dict[str, Any]:
        """The last reading of the robot's kinematics calibration: ``known``, ``calibration``
        (``RobotCalibration.as_dict``), ``read_utc`` and the ``error`` that left it unknown."""
        with self._lock:
            return dict(self._robot_calibration)

    def _loop(self) -> None:
        polls = 0
        while not self._stop.is_set():
            if self._devices.robot_host:
                status = self._devices.probe_robot()
                with self._lock:
                    self._robot_status = status
                self._log_if_changed("robot", status)
                if polls % SCANNER_EVERY_POLLS == 0:
                    self._read_robot_calibration(self._devices.robot_host)
            if self._devices.scanner_url and polls % SCANNER_EVERY_POLLS == 0:
                self._poll_scanner(self._devices.scanner_url)
            polls += 1
            self._stop.wait(self._poll_s)

    def _read_robot_calibration(self, host: str) -> None:
        """Read the primary interface (read only: it never disturbs a job's program)."""
        reading: dict[str, Any] = {"known": False, "calibration": None, "read_utc": utc_now(), "error": None}
        try:
            reading |= {"known": True, "calibration": self._devices.read_robot_calibration(host).as_dict()}
        except LasercalError as exc:
            reading["error"] = str(exc)
        with self._lock:
            self._robot_calibration = reading

    def _poll_scanner(self, url: str) -> None:
        probe = self._devices.probe_scanner()
        with self._lock:
            if probe.in_use_by is not None:
                held = {"error": None, "in_use_by_job": probe.in_use_by}
                self._scanner_status = self._scanner_status | held
            else:
                self._scanner_status = {
                    "connected": probe.identity is not None,
                    "url": url,
                    "identity": probe.identity,
                    "error": probe.error,
                }
        if probe.in_use_by is None:
            self._log_if_changed("scanner", self._scanner_status)

    def _log_if_changed(self, device: Literal["robot", "scanner"], status: dict[str, Any]) -> None:
        """One log line when a device connects, is lost or changes mode or safety."""
        summary = device_summary(status)
        if self._logged.get(device) != summary:
            self._logged[device] = summary
            log_device(device, status)
