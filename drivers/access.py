"""One door to the devices: the driver for a scanner URL or a robot address chosen from a
registry by scheme (as pyserial chooses a transport by URL), the connections a run opens,
the one-client scanner claim and the status probes a daemon shows.

A cell has one scanner (``scanner_url``, named ``default``) or several (``scanner_urls`` by
name, daemon.toml's ``[scanners.NAME]``). A UTM-30LX-EW serves one client at a time: while
an owner (a daemon job) holds a scanner's URL, ``probe_scanner`` leaves that scanner alone
(the others are still probed), and a probe in progress ends before a claim returns. Robot
probes and program keeping use the dashboard server only
(``drivers.ur.dashboard``), which leaves the owner's program alone.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any
from urllib.parse import urlsplit

from drivers.ur import dashboard
from lasercal_hw.config import DEFAULT_SCANNER_NAME, JobConfig
from lasercal_hw.errors import ConfigError, LasercalError

ScannerOpener = Callable[..., Any]
"""``opener(url, *, timeout_s, **options)`` -> a connected scanner (``run.devices.Scanner``)."""
RobotConnector = Callable[..., Any]
"""``connector(host, *, limits)`` -> a connected robot (``run.devices.Robot``)."""
ROBOT_SCHEME = "ur"
"""The robot driver for an address without a scheme (``HOST`` is ``ur://HOST``)."""


def _hokuyo(url: str, **options: Any) -> Any:
    from drivers.hokuyo.client import HokuyoScanner

    return HokuyoScanner.open(url, **options)


def _universal_robots(host: str, **options: Any) -> Any:
    from drivers.ur.client import URRobot

    return URRobot.connect(host, **options)


def _universal_robots_calibration(host: str, **options: Any) -> Any:
    from drivers.ur.primary import read_robot_calibration

    return read_robot_calibration(host, **options)


SCANNER_DRIVERS: dict[str, ScannerOpener] = {"scip+tcp": _hokuyo, "scip+serial": _hokuyo}
ROBOT_DRIVERS: dict[str, RobotConnector] = {ROBOT_SCHEME: _universal_robots}
ROBOT_CALIBRATION_READERS: dict[str, Callable[..., Any]] = {ROBOT_SCHEME: _universal_robots_calibration}
"""``reader(host, *, timeout_s)`` -> the robot's own kinematics calibration (``models.RobotCalibration``)."""


def _driver(registry: dict[str, Any], scheme: str, what: str, address: str) -> Any:
    driver = registry.get(scheme)
    if driver is None:
        known = ", ".join(f"{s}://" for s in sorted(registry))
        raise ConfigError(f"no driver for the {what} address {address!r}; use one of {known}")
    return driver


@dataclass(frozen=True)
class ScannerProbe:
    """What a scanner probe found: its owner (then nothing was asked), its identity, or an error."""

    in_use_by: str | None = None
    identity: dict[str, Any] | None = None
    error: str | None = None


class DeviceAccess:
    """Where the robot and the scanners are, who holds them, how to reach them."""

    def __init__(
        self,
        robot_host: str | None = None,
        scanner_url: str | None = None,
        *,
        scanner_urls: Mapping[str, str] | None = None,
        scanner_drivers: dict[str, ScannerOpener] | None = None,
        robot_drivers: dict[str, RobotConnector] | None = None,
    ) -> None:
        self.robot_host = robot_host
        self.scanner_url = scanner_url
        #: A cell's scanners by name (``[scanners.NAME]``); empty for a one-scanner cell.
        self.scanner_urls: dict[str, str] = dict(scanner_urls or {})
        self._scanner_drivers = SCANNER_DRIVERS if scanner_drivers is None else scanner_drivers
        self._robot_drivers = ROBOT_DRIVERS if robot_drivers is None else robot_drivers
        self._probing = threading.Lock()  # held through a probe, so a claim waits for it to end
        self._lock = threading.Lock()  # guards _holders only: read at once, even during a probe
        self._holders: dict[str, str] = {}  # scanner URL -> the owner holding it

    def scanners(self) -> list[tuple[str, str | None]]:
        """The cell's scanners ``(name, url)``: the named ones, else ``scanner_url`` named ``default``."""
        return list(self.scanner_urls.items()) or [(DEFAULT_SCANNER_NAME, self.scanner_url)]

    def all_scanner_urls(self) -> set[str]:
        """Every scanner URL the cell knows (the named ones and ``scanner_url``)."""
        urls = [url for _, url in self.scanners()] + [self.scanner_url]
        return {url for url in urls if url}

    # -- connections ---------------------------------------------------------------------------

    def open_scanner(self, url: str, **options: Any) -> Any:
        """The scanner at ``url``, through the driver its scheme names."""
        return _driver(self._scanner_drivers, urlsplit(url.strip()).scheme, "scanner", url)(url, **options)

    def connect_robot(self, address: str, **options: Any) -> Any:
        """The robot at ``address`` (``HOST`` or ``scheme://HOST``), through its driver."""
        scheme, _, host = address.rpartition("://")
        return _driver(self._robot_drivers, scheme or ROBOT_SCHEME, "robot", address)(host, **options)

    def read_robot_calibration(self, address: str, timeout_s: float = 2.0) -> Any:
        """The robot's own kinematics calibration (``models.RobotCalibration``), read only
        (``drivers.ur.primary``); a LasercalError when it cannot be read."""
        scheme, _, host = address.rpartition("://")
        reader = _driver(ROBOT_CALIBRATION_READERS, scheme or ROBOT_SCHEME, "robot calibration", address)
        return reader(host, timeout_s=timeout_s)

    def connect(self, job: JobConfig, stack: contextlib.ExitStack) -> tuple[Any, Any]:
        """The job's robot and scanner, closed by ``stack``. The scanner first: a typo in its
        URL must not touch the robot, whose control interface stops the program running on
        it as soon as it opens."""
        from drivers.ur.client import MotionLimits

        assert job.robot.host is not None, "the run checks for a robot before it connects"
        scanner = self.open_scanner(job.scanner.url, timeout_s=job.scanner.timeout_s)
        stack.callback(scanner.close)
        limits = MotionLimits(
            max_speed_m_s=job.motion.speed_m_s,
            max_accel_m_s2=job.motion.accel_m_s2,
            max_joint_speed_rad_s=job.motion.joint_speed_rad_s,
            max_joint_accel_rad_s2=job.motion.joint_accel_rad_s2,
        )
        robot = self.connect_robot(job.robot.host, limits=limits)
        stack.callback(robot.close)
        return robot, scanner

    # -- the claim -----------------------------------------------------------------------------

    def claim(self, owner: str, urls: Iterable[str] | None = None) -> None:
        """``owner`` holds the scanners at ``urls`` from now (None: every scanner of the cell);
        a scanner probe in progress ends first; a scanner another owner holds stays its."""
        held = self.all_scanner_urls() if urls is None else set(urls)
        with self._probing, self._lock:
            self._holders = dict.fromkeys(held, owner) | self._holders

    def release(self, owner: str) -> None:
        """``owner`` no longer holds any scanner."""
        with self._lock:
            self._holders = {url: held_by for url, held_by in self._holders.items() if held_by != owner}

    def holder(self, url: str | None) -> str | None:
        """Who holds the scanner at ``url`` now (None: nobody); never waits for a probe."""
        with self._lock:
            return self._holders.get(url or "")

    # -- status and the robot's program --------------------------------------------------------

    def probe_robot(self) -> dict[str, Any]:
        """The robot's status from its dashboard server (``drivers.ur.dashboard.robot_status``)."""
        if not self.robot_host:
            return dashboard.robot_unknown(None, "no robot configured")
        return dashboard.robot_status(self.robot_host)

    def probe_scanner(self, url: str | None = None, timeout_s: float = 2.0) -> ScannerProbe:
        """The identity of the scanner at ``url`` (None: ``scanner_url``), opened briefly,
        unless an owner holds it."""
        url = url or self.scanner_url
        if not url:
            return ScannerProbe(error="no scanner configured")
        with self._probing:
            if (owner := self.holder(url)) is not None:
                return ScannerProbe(in_use_by=owner)
            try:
                options = {"timeout_s": timeout_s, "sync_clock": False, "reconnect": False}
                with self.open_scanner(url, **options) as scanner:
                    return ScannerProbe(identity=asdict(scanner.identity()))
            except LasercalError as exc:
                return ScannerProbe(error=str(exc))

    def program_snapshot(self, host: str) -> Callable[[], str] | None:
        """Note the robot's program; the step that restores it (``drivers.ur.dashboard``)."""
        return dashboard.program_snapshot(host)
