"""The daemon in-process with a fake engine: auth, validation, one job at a time, cancel,
events with ids and replay, calibration history, store and token files."""

from __future__ import annotations

import json
import socket
import sqlite3
import stat
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.cli.main import main
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.app import create_app
from lasercal_hw.service.auth import ensure_token
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.errors import ServiceError
from lasercal_hw.service.routes.problems import STATUS_OF
from lasercal_hw.service.sd_notify import notify, watchdog_interval_s
from lasercal_hw.service.store import SCHEMA_VERSION, HistoryStore
from tests.daemon_helpers import FakeEngine, fake_runners, finish_job, read_sse

JOB = {"kind": "dry_run", "confirm_motion": True, "job": {"trajectory": {"preset": "quick"}}, "dwell_s": 0.5}


@pytest.fixture
def engine() -> FakeEngine:
    return FakeEngine()


@pytest.fixture
def client(tmp_path: Path, engine: FakeEngine) -> Iterator[TestClient]:
    daemon = Daemon(load_daemon_config(None, {"data_dir": tmp_path / "data"}), runners=fake_runners(engine))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as test_client:
        test_client.headers["Authorization"] = f"Bearer {daemon.token}"
        yield test_client


def test_every_kind_of_service_error_has_its_http_status() -> None:
    assert set(ServiceError.__subclasses__()) == set(STATUS_OF)


def test_token_is_needed_and_checked(client: TestClient) -> None:
    no_token = client.post("/v1/jobs", json=JOB, headers={"Authorization": ""})
    wrong = client.post("/v1/jobs", json=JOB, headers={"Authorization": "Bearer nope"})
    assert (no_token.status_code, no_token.json()["code"]) == (401, "unauthorized")
    assert (wrong.status_code, wrong.json()["code"]) == (403, "forbidden")
    assert client.get("/v1/status", headers={"Authorization": ""}).status_code == 200


@pytest.mark.parametrize(
    ("body", "status", "code", "field"),
    [
        ({**JOB, "confirm_motion": False}, 400, "confirmation_required", "confirm_motion"),
        ({**JOB, "dwell_s": -1}, 422, "invalid_request", "dwell_s"),
        ({**JOB, "job": {"trajectory": {"preset": "nope"}}}, 422, "invalid_request", "job"),
        ({**JOB, "job": {"rod": {"radius": 1}}}, 422, "invalid_request", "job"),
        ({**JOB, "kind": "weld"}, 422, "invalid_request", "kind"),
        ({**JOB, "scene": {"rod": {"radius_m": -1}}}, 422, "invalid_request", "scene"),
    ],
)
def test_bad_requests_name_the_field(
    client: TestClient, body: dict, status: int, code: str, field: str
) -> None:
    answer = client.post("/v1/jobs", json=body)
    assert answer.status_code == status, answer.text
    assert answer.json()["code"] == code and answer.json()["detail"]["field"] == field
    assert answer.json()["message"]


def test_unknown_ids_are_404_json(client: TestClient) -> None:
    for path in ("/v1/jobs/job-x", "/v1/calibrations/cal-x", "/v1/jobs/job-x/events", "/v1/nothing"):
        answer = client.get(path)
        assert answer.status_code == 404 and answer.json()["code"] == "not_found", path
    assert client.get("/v1/calibration").json()["code"] == "no_active_calibration"


def test_openapi_documents_the_api(client: TestClient) -> None:
    paths = client.get("/v1/openapi.json").json()["paths"]
    assert {"/v1/status", "/v1/jobs", "/v1/jobs/{job_id}/events", "/v1/calibrations/{a}/diff/{b}"} <= set(
        paths
    )


def test_a_kind_without_a_runner_answers_501(client: TestClient) -> None:
    answer = client.post("/v1/jobs", json={**JOB, "kind": "verify"})
    assert (answer.status_code, answer.json()["code"]) == (501, "not_implemented")


def test_one_motion_job_at_a_time_and_cancel_keeps_active_calibration(
    client: TestClient, engine: FakeEngine
) -> None:
    first = client.post("/v1/jobs", json=JOB | {"activate_on_pass": True}).json()
    active = finish_job(client, first["id"])["calibration_id"]
    engine.release.clear()
    engine.started.clear()
    running = client.post("/v1/jobs", json=JOB | {"activate_on_pass": True}).json()
    assert engine.started.wait(5.0)
    second = client.post("/v1/jobs", json=JOB)
    assert second.status_code == 409
    assert second.json()["code"] == "job_running" and second.json()["detail"]["job_id"] == running["id"]
    client.post(f"/v1/jobs/{running['id']}/cancel")
    engine.release.set()
    cancelled = finish_job(client, running["id"])
    assert cancelled["state"] == "cancelled" and cancelled["calibration_id"] is None
    assert client.get("/v1/calibration").json()["id"] == active
    assert client.get(f"/v1/jobs/{running['id']}/files/session.mcap").content == b"recording"
    resumed = client.post(f"/v1/jobs/{running['id']}/resume", json={"confirm_motion": True})
    assert resumed.status_code == 200
    done = finish_job(client, running["id"])
    assert done["state"] == "succeeded" and done["progress"]["completed"] == engine.waypoints
    assert engine.contexts[-1].resume_from is not None
    assert client.get("/v1/calibration").json()["id"] == done["calibration_id"] != active


def test_a_device_failure_is_failed_with_its_code_and_resumable(
    client: TestClient, engine: FakeEngine
) -> None:
    engine.fail = True
    job = finish_job(client, client.post("/v1/jobs", json=JOB).json()["id"])
    assert job["state"] == "failed" and job["error"]["code"] == "device_error"
    engine.fail = False  # the device is back: the recording continues
    assert client.post(f"/v1/jobs/{job['id']}/resume", json={"confirm_motion": True}).status_code == 200
    assert finish_job(client, job["id"])["state"] == "succeeded"
    again = client.post(f"/v1/jobs/{job['id']}/resume", json={"confirm_motion": True})
    assert (again.status_code, again.json()["code"]) == (409, "not_resumable")


def test_events_have_ids_and_replay_after_last_event_id(client: TestClient) -> None:
    job_id = client.post("/v1/jobs", json=JOB).json()["id"]
    finish_job(client, job_id)
    with client.stream("GET", f"/v1/jobs/{job_id}/events") as response:
        assert response.headers["content-type"].startswith("text/event-stream")
        events = read_sse(response)
    ids = [event_id for event_id, _, _ in events]
    assert ids == sorted(set(ids)) and all(data["job_id"] == job_id for _, _, data in events)
    assert events[-1][1] == "state" and events[-1][2]["state"] == "succeeded"
    assert [e[2]["completed"] for e in events if e[1] == "progress"] == [0, 1, 2, 3, 4, 4]
    states = [e[2]["state"] for e in events if e[1] == "state"]
    assert states == ["queued", "preflight", "running", "solving", "succeeded"]
    middle = ids[len(ids) // 2]
    with client.stream(
        "GET", f"/v1/jobs/{job_id}/events", headers={"Last-Event-ID": str(middle)}
    ) as response:
        rest = read_sse(response)
    assert [e[0] for e in rest] == [i for i in ids if i > middle]
    with client.stream("GET", f"/v1/jobs/{job_id}/events?last_event_id={middle}") as response:
        assert read_sse(response) == rest
    with client.stream(
        "GET", f"/v1/jobs/{job_id}/events", headers={"Last-Event-ID": str(ids[-1])}
    ) as response:
        assert read_sse(response) == []  # after the final state: the stream ends at once


def test_history_activate_rollback_and_diff(client: TestClient, engine: FakeEngine) -> None:
    a = finish_job(client, client.post("/v1/jobs", json=JOB).json()["id"])["calibration_id"]
    engine.translation_m = [0.305, 0.5, 0.2]
    b = finish_job(client, client.post("/v1/jobs", json=JOB).json()["id"])["calibration_id"]
    assert [c["id"] for c in client.get("/v1/calibrations").json()["calibrations"]] == [b, a]
    for calibration_id in (b, a):
        assert (
            client.post(f"/v1/calibrations/{calibration_id}/activate", json={"reason": "test"}).status_code
            == 200
        )
    active = client.get("/v1/calibration").json()
    assert active["id"] == a and active["active"]
    assert (
        "<joint" in active["exports"]["urdf_joint"]
        and "--qw" in active["exports"]["static_transform_publisher_args"]
    )
    assert len(client.get("/v1/calibrations").json()["activations"]) == 2
    diff = client.get(f"/v1/calibrations/{a}/diff/{b}").json()
    assert diff["translation_mm"] == pytest.approx([5.0, 0.0, 0.0], abs=1e-9)
    assert diff["translation_norm_mm"] == pytest.approx(5.0) and diff["rotation_angle_deg"] == pytest.approx(
        0.0
    )
    assert diff["combined_std_translation_mm"] == pytest.approx([0.5 * 2**0.5] * 3)
    assert diff["significant"] is True
    assert client.get(f"/v1/calibrations/{a}/diff/{a}").json()["significant"] is False
    assert json.loads(client.get(f"/v1/calibrations/{a}/files/result.json").content)["translation_m"] == [
        0.3,
        0.5,
        0.2,
    ]
    assert client.get(f"/v1/calibrations/{a}/files/..%2Ftoken").status_code == 404


def test_store_survives_reopen_and_marks_running_jobs_interrupted(tmp_path: Path) -> None:
    store = HistoryStore(tmp_path / "h.sqlite3")
    for job_id, kind in (("job-1", "dry_run"), ("job-2", "verify")):
        store.insert_job(
            {
                "id": job_id,
                "kind": kind,
                "state": "running",
                "created_utc": "t",
                "request": {},
                "progress": {},
                "out_dir": "x",
            }
        )
    store.add_event("job-1", "progress", {"completed": 1}, "t")
    # no close: as after SIGKILL
    reopened = HistoryStore(tmp_path / "h.sqlite3")
    assert sorted(reopened.mark_unfinished_interrupted()) == ["job-1", "job-2"]
    dry_run, verify = reopened.job("job-1"), reopened.job("job-2")
    assert dry_run["state"] == verify["state"] == "interrupted"
    assert "resume it with POST /v1/jobs/{id}/resume" in dry_run["error"]["message"]
    # a verify is never resumed (POST .../resume refuses it): its message says to start a new one
    assert "resume it" not in verify["error"]["message"]
    assert "start a new verify" in verify["error"]["message"]
    assert reopened.events_after(0, "job-1")[0][1] == "progress"
    with sqlite3.connect(tmp_path / "h.sqlite3") as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_store_refuses_a_newer_schema(tmp_path: Path) -> None:
    with sqlite3.connect(tmp_path / "h.sqlite3") as db:
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(ConfigError, match="newer"):
        HistoryStore(tmp_path / "h.sqlite3")


def test_token_file_is_private_and_stable(tmp_path: Path) -> None:
    path = tmp_path / "token"
    token = ensure_token(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(token) >= 32
    assert ensure_token(path) == token
    path.chmod(0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        ensure_token(path)


def test_non_loopback_listen_needs_a_configured_token(tmp_path: Path) -> None:
    config = load_daemon_config(None, {"data_dir": tmp_path, "listen": "0.0.0.0:8766"})
    with pytest.raises(ConfigError, match="not loopback"):
        Daemon(config)
    with pytest.raises(ConfigError, match="listen"):
        load_daemon_config(None, {"listen": "localhost"})


def test_sd_notify_sends_one_datagram_to_the_notify_socket(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as receiver:
        receiver.bind(str(path))
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        assert notify("READY=1")
        assert receiver.recv(100) == b"READY=1"
    monkeypatch.setenv("WATCHDOG_USEC", "30000000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    assert watchdog_interval_s() == 15.0
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert notify("READY=1") is False


def test_remote_refuses_to_start_motion_without_yes(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.setattr(sys, "argv", ["lasercal", "remote", "calibrate", "--daemon", "http://127.0.0.1:9"])
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code == 2 and "--yes" in capsys.readouterr().err


def test_remote_says_when_the_daemon_is_not_there(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.setattr(sys, "argv", ["lasercal", "remote", "status", "--daemon", "http://127.0.0.1:9"])
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code == 3 and "cannot reach the lasercal daemon" in capsys.readouterr().err


def test_a_cancelled_verify_is_not_resumed_but_started_anew(tmp_path: Path, engine: FakeEngine) -> None:
    """A verify's runner measures its waypoints afresh (it takes no recording to go on from): a
    resume would run it again into a folder with a recording. The 409 says to start a new one."""
    settings = {"data_dir": tmp_path / "data", "robot_host": "127.0.0.1"}
    daemon = Daemon(
        load_daemon_config(None, settings),
        runners=lambda folder_of: {"calibrate": engine, "dry_run": engine, "verify": engine},
    )
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        finish_job(client, client.post("/v1/jobs", json=JOB | {"activate_on_pass": True}).json()["id"])
        engine.release.clear()
        engine.started.clear()
        verify = client.post("/v1/jobs", json={"kind": "verify", "confirm_motion": True})
        assert verify.status_code == 202, verify.text
        assert engine.started.wait(5.0)
        client.post(f"/v1/jobs/{verify.json()['id']}/cancel")
        engine.release.set()
        assert finish_job(client, verify.json()["id"])["state"] == "cancelled"
        resumed = client.post(f"/v1/jobs/{verify.json()['id']}/resume", json={"confirm_motion": True})
    assert (resumed.status_code, resumed.json()["code"]) == (409, "not_resumable")
    assert "start a new verify" in resumed.json()["message"]
