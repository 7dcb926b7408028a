"""The one door to the devices: drivers chosen by URL scheme, the scanner left alone while
a job holds the devices, and the robot's status from its dashboard server."""

from __future__ import annotations

import socket
import threading
from typing import Any

import pytest

from drivers.access import DeviceAccess
from drivers.ur.dashboard import robot_status
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import ScannerIdentity


class _Opened:
    def __init__(self, address: str, options: dict[str, Any]) -> None:
        self.address, self.options = address, options

    def __enter__(self) -> _Opened:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def identity(self) -> ScannerIdentity:
        return ScannerIdentity("v", "p", "f", "SCIP 2.0", serial=self.address, model="UTM-30LX-EW")


def recording_opener(log: list[str], name: str) -> Any:
    """A driver that opens a stand-in device and logs ``"NAME ADDRESS"`` for each opening."""
    def open_device(address: str, **options: Any) -> _Opened:
        log.append(f"{name} {address}")
        return _Opened(address, options)

    return open_device


def test_drivers_are_chosen_by_the_scheme_of_the_address() -> None:
    log: list[str] = []
    access = DeviceAccess(
        scanner_drivers={"scip+tcp": recording_opener(log, "tcp"), "mock": recording_opener(log, "mock")},
        robot_drivers={"ur": recording_opener(log, "ur"), "sim": recording_opener(log, "sim")},
    )
    access.open_scanner("mock://a", timeout_s=1.0)
    access.open_scanner("scip+tcp://127.0.0.1:10940", timeout_s=1.0)
    access.connect_robot("127.0.0.9")
    access.connect_robot("sim://127.0.0.9")
    assert log == ["mock mock://a", "tcp scip+tcp://127.0.0.1:10940", "ur 127.0.0.9", "sim 127.0.0.9"]
    with pytest.raises(ConfigError, match=r"no driver for the scanner address 'lidar://x'; use one of"):
        access.open_scanner("lidar://x")


def test_a_claimed_scanner_is_not_probed() -> None:
    log: list[str] = []
    access = DeviceAccess(None, "mock://s", scanner_drivers={"mock": recording_opener(log, "mock")})
    access.claim("job-1")
    assert access.probe_scanner().in_use_by == "job-1" and log == []
    access.release("job-1")
    probe = access.probe_scanner()
    assert probe.in_use_by is None and probe.identity is not None and probe.identity["serial"] == "mock://s"
    assert DeviceAccess().probe_scanner().error == "no scanner configured"


def test_each_scanner_of_a_cell_is_claimed_and_probed_on_its_own() -> None:
    log: list[str] = []
    urls = {"front": "mock://front", "rear": "mock://rear"}
    drivers = {"mock": recording_opener(log, "mock")}
    access = DeviceAccess(None, "mock://one", scanner_urls=urls, scanner_drivers=drivers)
    assert access.scanners() == [("front", "mock://front"), ("rear", "mock://rear")]
    access.claim("job-1", ["mock://rear"])
    assert access.probe_scanner("mock://rear").in_use_by == "job-1"
    assert access.probe_scanner("mock://front").identity["serial"] == "mock://front"  # type: ignore[index]
    access.claim("job-2")  # every scanner the cell knows, scanner_url too; rear stays job-1's
    assert {access.probe_scanner(url).in_use_by for url in ("mock://front", "mock://one")} == {"job-2"}
    access.release("job-2")
    assert access.probe_scanner("mock://rear").in_use_by == "job-1"
    assert access.probe_scanner().in_use_by is None
    access.release("job-1")
    assert access.probe_scanner("mock://rear").in_use_by is None
    assert log == ["mock mock://front", "mock mock://one", "mock mock://rear"]  # never a held one
    assert DeviceAccess(None, "mock://one").scanners() == [("default", "mock://one")]


def test_robot_status_comes_from_the_dashboard_server() -> None:
    replies = {
        "is in remote control": "true",
        "robotmode": "Robotmode: RUNNING",
        "safetystatus": "Safetystatus: NORMAL",
        "programState": "STOPPED <unnamed>",
    }
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]

        def serve() -> None:
            connection, _ = server.accept()
            with connection, connection.makefile("rwb") as stream:
                stream.write(b"Connected: Universal Robots Dashboard Server\n")
                stream.flush()
                for line in stream:
                    stream.write(replies[line.decode().strip()].encode() + b"\n")
                    stream.flush()

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        status = robot_status("127.0.0.1", port)
    assert status == {
        "connected": True, "host": "127.0.0.1", "mode": "RUNNING", "safety": "NORMAL",
        "remote_control": True, "program_running": False, "error": None,
    }
    assert DeviceAccess().probe_robot()["error"] == "no robot configured"
