"""The daemon's device monitor over every scanner of a cell: each probed on its own, a scanner a
job holds left alone (and marked with the job) while the others are still probed."""

from __future__ import annotations

import time
from typing import Any

from drivers.access import DeviceAccess
from lasercal_hw.service.monitor import DeviceMonitor
from tests.drivers.test_device_access import recording_opener


def _until(monitor: DeviceMonitor, done: Any) -> dict[str, dict[str, Any]]:
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        scanners = {s["name"]: s for s in monitor.snapshot()["scanners"]}
        if done(scanners):
            return scanners
        time.sleep(0.01)
    raise AssertionError(f"the monitor never got there: {monitor.snapshot()}")


def test_every_scanner_of_the_cell_has_its_status_and_a_held_one_is_not_probed() -> None:
    log: list[str] = []
    urls = {"front": "mock://front", "rear": "mock://rear"}
    drivers = {"mock": recording_opener(log, "mock")}
    devices = DeviceAccess(None, None, scanner_urls=urls, scanner_drivers=drivers)
    monitor = DeviceMonitor(devices, poll_s=0.001)
    assert [s["name"] for s in monitor.snapshot()["scanners"]] == ["front", "rear"]
    monitor.start()
    try:
        scanners = _until(monitor, lambda s: all(entry["connected"] for entry in s.values()))
        assert {name: s["identity"]["serial"] for name, s in scanners.items()} == urls
        assert monitor.snapshot()["scanner"]["name"] == "front"  # the first, as a one-scanner daemon's
        devices.claim("job-1", ["mock://rear"])
        _until(monitor, lambda s: s["rear"]["in_use_by_job"] == "job-1")
        probed = len(log)
        scanners = _until(monitor, lambda s: log[probed:].count("mock mock://front") >= 3)
        assert "mock mock://rear" not in log[probed:], "a scanner a job holds is never opened"
        assert scanners["rear"]["connected"] and scanners["front"]["in_use_by_job"] is None
        devices.release("job-1")
        _until(monitor, lambda s: s["rear"]["in_use_by_job"] is None)
    finally:
        monitor.stop()
