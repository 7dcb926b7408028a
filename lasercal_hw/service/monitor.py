"""Device status for ``GET /v1/status``, polled in a background thread so a request never
waits on a device.

The probes are the device door's (``drivers.access.DeviceAccess``): the robot through its
dashboard server only (robot mode, safety status, remote control, program state), which
leaves the owner's program alone and costs nothing between polls; the robot's kinematics
calibration from its read-only primary interface (``GET /v1/health`` compares it with the
active calibration's); every scanner of the cell opened briefly for its identity, each only
while no job holds its URL.
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


def _scanner_unknown(name: str, url: str | None) -> dict[str, Any]:
    """A scanner's status before its first probe."""
    return {"name": name, "connected": False, "url": url, "identity": None,
            "error": None if url else "no scanner configured", "in_use_by_job": None}


class DeviceMonitor:
    """Keeps the newest robot status and every scanner's."""

    def __init__(self, devices: DeviceAccess, poll_s: float) -> None:
        self._devices = devices
        self._poll_s = poll_s
        self._lock = threading.Lock()
        from drivers.ur.dashboard import robot_unknown  # the status of a robot not asked yet

        self._robot_status = robot_unknown(
            devices.robot_host, None if devices.robot_host else "no robot configured"
        )
        self._scanner_status = {name: _scanner_unknown(name, url) for name, url in devices.scanners()}
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

    def snapshot(self) -> dict[str, Any]:
        """The newest ``{"robot": ..., "scanner": ..., "scanners": [...]}``: every scanner of
        the cell in its order, and ``scanner`` the first one (a one-scanner cell's)."""
        with self._lock:
            # who holds a scanner is read now: a job's end shows at once, not at the next probe
            scanners = [status | {"in_use_by_job": self._devices.holder(status["url"])}
                        for status in self._scanner_status.values()]
            return {"robot": dict(self._robot_status), "scanner": scanners[0], "scanners": scanners}

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
            if polls % SCANNER_EVERY_POLLS == 0:
                for name, url in self._devices.scanners():
                    self._poll_scanner(name, url)
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

    def _poll_scanner(self, name: str, url: str | None) -> None:
        """Probe one scanner (a held one keeps its last identity, marked with its job)."""
        if not url:
            return
        probe = self._devices.probe_scanner(url)
        with self._lock:
            status = self._scanner_status.get(name) or _scanner_unknown(name, url)
            if probe.in_use_by is not None:
                status = status | {"url": url, "error": None, "in_use_by_job": probe.in_use_by}
            else:
                status = _scanner_unknown(name, url) | {
                    "connected": probe.identity is not None, "identity": probe.identity, "error": probe.error,
                }
            self._scanner_status[name] = status
        if probe.in_use_by is None:
            self._log_if_changed("scanner", status, key=f"scanner {name}")

    def _log_if_changed(
        self, device: Literal["robot", "scanner"], status: dict[str, Any], key: str = ""
    ) -> None:
        """One log line when a device (``key``: which scanner) connects, is lost or changes
        mode or safety."""
        summary = device_summary(status)
        if self._logged.get(key or device) != summary:
            self._logged[key or device] = summary
            log_device(device, status)
