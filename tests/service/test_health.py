"""``GET /v1/health`` and marking a calibration bad, over real sockets: an in-process daemon
(fake engine) served by uvicorn on a loopback port, its device monitor reading a fake UR
controller's dashboard and primary interface on another loopback address."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from fakes.ur_controller.process import FakeRobot
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.store import DB_FILE, utc_now
from tests.daemon_helpers import QUICK_DRY_RUN, FakeEngine, fake_runners, served_in_thread, wait_for
from tests.drivers.ur.robot_process import in_process_robot
from tests.verify_helpers import fake_robot_calibration

pytestmark = pytest.mark.timeout(60)


def _until(read: Callable[[], dict[str, Any]], done: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        document = read()
        if done(document):
            return document
        time.sleep(0.05)
    raise AssertionError(f"never got there: {document}")


def _calibrate(client: httpx.Client) -> str:
    """A (fake-engine) calibration, activated on pass: its id."""
    job = client.post("/v1/jobs", json=QUICK_DRY_RUN | {"activate_on_pass": True}).json()
    finished = wait_for(client, job["id"], lambda j: j["state"] == "succeeded", timeout_s=20.0)
    return str(finished["calibration_id"])


@pytest.fixture
def engine() -> FakeEngine:
    """The daemon's calibration runner (a fake engine writing result.json)."""
    return FakeEngine(waypoints=2)


@pytest.fixture
def cell(tmp_path: Path, engine: FakeEngine) -> Iterator[tuple[httpx.Client, Daemon, FakeRobot]]:
    """A client with the token, the daemon and the fake robot its monitor reads."""
    with in_process_robot() as robot:
        config = load_daemon_config(
            None, {"data_dir": tmp_path / "data", "robot_host": robot.address, "status_poll_s": 0.05}
        )
        daemon = Daemon(config, runners=fake_runners(engine))
        with served_in_thread(daemon) as url, httpx.Client(base_url=url, timeout=10.0) as client:
            client.headers["Authorization"] = f"Bearer {daemon.token}"
            yield client, daemon, robot


def test_health_says_age_verdict_and_whether_the_robots_calibration_still_matches(
    cell: tuple[httpx.Client, Daemon, FakeRobot],
) -> None:
    client, daemon, robot = cell
    health = client.get("/v1/health", headers={"Authorization": ""}).json()  # no token needed
    assert health["ok"] is True and health["api_version"] == 1
    (scanner,) = health["scanners"]
    assert scanner["name"] == "default" and scanner["active_calibration"] is False
    assert scanner["robot_calibration_matches"] == "unknown" and scanner["passed"] is None

    calibration_id = _calibrate(client)
    recorded = fake_robot_calibration()
    health = _until(lambda: client.get("/v1/health").json(), lambda h: h["robot_calibration"]["known"])
    (scanner,) = health["scanners"]
    assert scanner["active_calibration"] is True and scanner["calibration_id"] == calibration_id
    assert scanner["passed"] is True and 0.0 <= scanner["age_s"] < 30.0 and scanner["last_verify"] is None
    assert health["robot_calibration"]["calibration"]["checksum"] == recorded.checksum
    assert scanner["robot_calibration_matches"] is True, scanner["robot_calibration_note"]

    verified = {"created_utc": utc_now(), "calibration_id": calibration_id, "verdict": "degraded"}
    daemon.history.record_verify("job-by-hand", verified | {"reason": "moved 0.3 mm"})
    verify = client.get("/v1/health").json()["scanners"][0]["last_verify"]
    assert verify["verdict"] == "degraded" and verify["reason"] == "moved 0.3 mm" and verify["age_s"] < 30.0

    replaced = robot.controller.replace_joint(4)
    now = fake_robot_calibration(replaced).checksum
    scanner = _until(
        lambda: client.get("/v1/health").json()["scanners"][0],
        lambda s: s["robot_calibration_matches"] is False,
    )
    assert scanner["robot_calibration_note"] == (
        "the robot's kinematics calibration changed since the calibration: "
        f"checksum {recorded.checksum} -> {now}"
    )


def _curve(worst_mm: float) -> dict[str, Any]:
    """A result's range-error curve whose largest |error| over the crossings is ``worst_mm``."""
    return {"offset_mm": worst_mm / 2, "std_mm": 1.0, "basis": "log_distance",
            "terms_mm": [worst_mm / 2, 5.0], "terms_std_mm": [1.0, 2.0], "worst_mm": worst_mm}


def test_health_gives_the_range_error_against_the_data_sheet_and_its_change(
    cell: tuple[httpx.Client, Daemon, FakeRobot], engine: FakeEngine
) -> None:
    client, _daemon, _robot = cell
    _calibrate(client)
    (scanner,) = client.get("/v1/health").json()["scanners"]
    assert scanner["range_error"]["state"] == "unknown" and scanner["range_error"]["worst_mm"] is None

    engine.range_offset = _curve(12.0)
    first = _calibrate(client)
    health = client.get("/v1/health").json()["scanners"][0]["range_error"]
    assert health["state"] == "within_data_sheet" and health["worst_mm"] == 12.0
    assert health["limit_mm"] == 30.0
    assert health["previous"] is None, "the earlier calibration estimated no curve"

    engine.range_offset = _curve(34.5)
    _calibrate(client)
    health = client.get("/v1/health").json()["scanners"][0]["range_error"]
    assert health["state"] == "beyond_data_sheet"
    assert health["previous"] == {"calibration_id": first, "worst_mm": 12.0, "change_mm": 22.5}
    assert "+22.5 mm since " + first in health["note"] and "replace the unit" in health["note"]


def test_a_bad_calibration_is_never_active(
    cell: tuple[httpx.Client, Daemon, FakeRobot], tmp_path: Path
) -> None:
    client, _daemon, _robot = cell
    older, newer = _calibrate(client), _calibrate(client)
    body = {"by": "qa@cell-7", "reason": "the rod was bent"}
    anonymous = client.post(f"/v1/calibrations/{newer}/mark-bad", json=body, headers={"Authorization": ""})
    assert anonymous.status_code == 401 and anonymous.json()["code"]
    refused = client.post(f"/v1/calibrations/{newer}/mark-bad", json={"by": "", "reason": "x"})
    assert refused.status_code == 422 and refused.json()["message"]
    assert client.post("/v1/calibrations/cal-nope/mark-bad", json=body).status_code == 404

    with client.stream("GET", "/v1/events") as stream:
        marked = client.post(f"/v1/calibrations/{newer}/mark-bad", json=body)
        assert marked.status_code == 200
        kinds = []
        for line in stream.iter_lines():
            if line.startswith("event: "):
                kinds.append(line[7:])
            if "deactivation" in kinds:
                break
    assert "calibration_marked_bad" in kinds
    bad = marked.json()["bad"]
    assert bad["by"] == "qa@cell-7" and bad["reason"] == "the rod was bent" and bad["time_utc"]
    assert marked.json()["active"] is False
    assert client.get("/v1/calibration").status_code == 404
    assert client.get("/v1/health").json()["scanners"][0]["active_calibration"] is False

    again = client.post(f"/v1/calibrations/{newer}/activate", json={"reason": "try", "force": True})
    assert again.status_code == 409 and again.json()["code"] == "calibration_marked_bad"
    assert "marked bad by qa@cell-7" in again.json()["message"]
    twice = client.post(f"/v1/calibrations/{newer}/mark-bad", json=body)
    assert twice.status_code == 409 and twice.json()["code"] == "already_marked_bad"
    assert client.post(f"/v1/calibrations/{older}/activate", json={"reason": "roll back"}).status_code == 200
    assert client.get("/v1/calibration").json()["id"] == older

    with sqlite3.connect(tmp_path / "data" / DB_FILE) as db:
        row = db.execute(
            "SELECT bad_by, bad_reason, robot_calibration_checksum FROM calibrations WHERE id = ?", (newer,)
        ).fetchone()
    assert row == ("qa@cell-7", "the rod was bent", fake_robot_calibration().checksum)
