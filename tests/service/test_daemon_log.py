"""The daemon's log a person follows in journalctl: one line per job state, calibration,
activation and device change, with ids; JSON lines when asked."""

from __future__ import annotations

import io
import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.errors import ConfigError, TransportError
from lasercal_hw.service import daemon_log
from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.monitor import DeviceMonitor
from tests.daemon_helpers import FakeEngine, fake_runners, finish_job
from tests.service.test_service import JOB


@pytest.fixture(params=["text", "json"])
def logged(request: pytest.FixtureRequest) -> Iterator[tuple[str, io.StringIO]]:
    """The daemon log configured as ``text`` or ``json`` into a buffer."""
    stream = io.StringIO()
    handler = daemon_log.configure(request.param, stream)
    try:
        yield request.param, stream
    finally:
        daemon_log.unconfigure(handler)


def _lines(log_format: str, stream: io.StringIO) -> list[str]:
    """The log's messages (a JSON line's ``message``), each line checked for its format."""
    lines = stream.getvalue().splitlines()
    if log_format == "json":
        return [json.loads(line)["message"] for line in lines]
    assert all(line[:4].isdigit() and line[19] == "Z" for line in lines), lines
    return [line.split(" ", 2)[2] for line in lines]


def test_a_job_and_an_activation_are_one_line_each_with_their_ids(
    tmp_path: Path, logged: tuple[str, io.StringIO]
) -> None:
    log_format, stream = logged
    config = load_daemon_config(None, {"data_dir": tmp_path / "data"})
    daemon = Daemon(config, runners=fake_runners(FakeEngine()))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        job_id = client.post("/v1/jobs", json=JOB).json()["id"]
        calibration_id = finish_job(client, job_id)["calibration_id"]
        activated = client.post(f"/v1/calibrations/{calibration_id}/activate", json={"reason": "first"})
        assert activated.status_code == 200
        bad = {"by": "qa", "reason": "rod bent"}
        assert client.post(f"/v1/calibrations/{calibration_id}/mark-bad", json=bad).status_code == 200
    lines = _lines(log_format, stream)
    assert lines[0].startswith("lasercal ") and lines[0].endswith("daemon started")
    assert lines[1:] == [
        f"job {job_id} queued",
        f"job {job_id} preflight",
        f"job {job_id} running",
        f"job {job_id} solving",
        f"job {job_id} filed calibration {calibration_id} (passed its gates)",
        f"job {job_id} succeeded",
        f"calibration {calibration_id} activated: first",
        f"calibration {calibration_id} marked bad by qa: rod bent",
        f"calibration {calibration_id} deactivated: marked bad by qa: rod bent",
    ]
    if log_format == "json":
        records = [json.loads(line) for line in stream.getvalue().splitlines()]
        assert records[1]["event"] == "state" and records[1]["job_id"] == job_id
        assert records[1]["level"] == "info" and records[1]["time_utc"].endswith("+00:00")


class _Devices:
    """A device door whose robot answers from a list (then as the last answer)."""

    def __init__(self, answers: list[dict[str, Any]]) -> None:
        self.robot_host, self.scanner_url = "127.0.0.1", None
        self.answers, self.asked = answers, threading.Event()

    def scanners(self) -> list[tuple[str, str | None]]:
        return [("default", None)]

    def holder(self, url: str | None) -> str | None:
        return None

    def probe_robot(self) -> dict[str, Any]:
        if len(self.answers) == 1:
            self.asked.set()
        return self.answers.pop(0) if len(self.answers) > 1 else self.answers[0]

    def read_robot_calibration(self, host: str) -> Any:
        raise TransportError(f"no primary interface at {host}")


def test_a_device_change_is_one_line(logged: tuple[str, io.StringIO]) -> None:
    log_format, stream = logged
    up = {"connected": True, "host": "127.0.0.1", "mode": "RUNNING", "safety": "NORMAL",
          "remote_control": True, "program_running": False, "error": None}
    playing = up | {"program_running": True}  # not a device change worth a line
    lost = up | {"connected": False, "mode": None, "safety": None, "error": "connection refused"}
    devices = _Devices([up, playing, up, lost, lost, up])
    monitor = DeviceMonitor(devices, poll_s=0.001)  # type: ignore[arg-type]
    monitor.start()
    assert devices.asked.wait(10.0)
    monitor.stop()
    assert _lines(log_format, stream) == [
        "robot 127.0.0.1 connected, mode RUNNING, safety NORMAL, remote control on",
        "robot 127.0.0.1 not reachable: connection refused",
        "robot 127.0.0.1 connected, mode RUNNING, safety NORMAL, remote control on",
    ]


def test_the_log_format_is_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="log_format"):
        load_daemon_config(None, {"log_format": "xml"})
    assert load_daemon_config(None, {"log_format": "json"}).log_format == "json"
