"""``/v1/events`` as a person meets it: every event says when it happened (UTC, ISO 8601), a
plain connect starts at the present, history comes with ``Last-Event-ID`` or ``since``, and
scans are live only (never stored, never replayed), the stored history bounded."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.store import HistoryStore, utc_now
from tests.daemon_helpers import FakeEngine, fake_runners, finish_job, read_sse
from tests.service.test_service import JOB


@pytest.fixture
def daemon_client(tmp_path: Path) -> Iterator[tuple[Daemon, TestClient]]:
    config = load_daemon_config(None, {"data_dir": tmp_path / "data"})
    daemon = Daemon(config, runners=fake_runners(FakeEngine()))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        yield daemon, client


def _daemon_stream(
    daemon: Daemon, client: TestClient, url: str, then: Callable[[], None] = lambda: None, **kwargs: Any
) -> list[tuple[int, str, dict[str, Any]]]:
    """What ``GET url`` (the never-ending daemon stream) sends: once it is open, ``then()``
    runs and the daemon closes its streams (as at shutdown), which ends the response."""

    def act_once_open() -> None:
        for _ in range(1000):
            if daemon.bus.subscribers:
                break
            threading.Event().wait(0.01)
        then()
        daemon.bus.close_streams_soon()

    actor = threading.Thread(target=act_once_open)
    actor.start()
    with client.stream("GET", url, **kwargs) as response:
        events = read_sse(response)
    actor.join()
    return events


def test_a_plain_connect_starts_now_and_history_comes_on_request(
    daemon_client: tuple[Daemon, TestClient],
) -> None:
    daemon, client = daemon_client
    job = client.post("/v1/jobs", json=JOB).json()
    finish_job(client, job["id"])
    stored = _daemon_stream(daemon, client, "/v1/events?last_event_id=0")
    assert len(stored) > 10 and stored[0][1] == "daemon"

    marker = lambda: daemon.bus.publish("daemon", {"message": "marker"})  # noqa: E731
    live = _daemon_stream(daemon, client, "/v1/events", then=marker)
    assert [(kind, data["message"]) for _, kind, data in live] == [("daemon", "marker")]
    stored += live

    middle = stored[len(stored) // 2][0]
    after = _daemon_stream(daemon, client, "/v1/events", headers={"Last-Event-ID": str(middle)})
    assert after == [event for event in stored if event[0] > middle]

    since_job = _daemon_stream(daemon, client, "/v1/events", params={"since": job["created_utc"]})
    first_of_job = min(event[0] for event in stored if event[2].get("job_id") == job["id"])
    assert since_job == [event for event in stored if event[0] >= first_of_job]
    zulu = job["created_utc"].replace("+00:00", "Z")
    assert _daemon_stream(daemon, client, f"/v1/events?since={zulu}") == since_job
    future = (datetime.now(UTC) + timedelta(hours=1)).isoformat()
    assert _daemon_stream(daemon, client, "/v1/events", params={"since": future}) == []

    bad = client.get("/v1/events?since=yesterday")
    assert bad.status_code == 422 and bad.json()["detail"]["field"] == "since"


def test_every_event_carries_the_time_it_happened(daemon_client: tuple[Daemon, TestClient]) -> None:
    _, client = daemon_client
    before = datetime.now(UTC)
    job_id = client.post("/v1/jobs", json=JOB).json()["id"]
    finish_job(client, job_id)
    with client.stream("GET", f"/v1/jobs/{job_id}/events") as response:
        events = read_sse(response)
    times = [datetime.fromisoformat(data["time_utc"]) for _, _, data in events]
    assert all(t.utcoffset() == timedelta(0) for t in times)
    assert before - timedelta(seconds=1) <= times[0] and times == sorted(times)
    assert times[-1] <= datetime.now(UTC)


def test_scans_are_live_only_without_an_id(daemon_client: tuple[Daemon, TestClient]) -> None:
    daemon, client = daemon_client

    def scan_then_marker() -> None:
        assert daemon.bus.publish("scan", {"ranges_m": [1.0] * 1081}, "job-x") is None
        daemon.bus.publish("daemon", {"message": "after the scan"})

    live = _daemon_stream(daemon, client, "/v1/events", then=scan_then_marker)
    assert [kind for _, kind, _ in live] == ["scan", "daemon"]
    replay = _daemon_stream(daemon, client, "/v1/events?last_event_id=0")
    assert "scan" not in [kind for _, kind, _ in replay] and replay[-1][2]["message"] == "after the scan"


def test_the_stored_history_is_bounded_and_holds_no_scan(tmp_path: Path) -> None:
    store = HistoryStore(tmp_path / "history.sqlite3")
    ids = [store.add_event(None, "daemon", {"n": n}, utc_now()) for n in range(10)]
    store.add_event("job-x", "scan", {"ranges_m": [1.0]}, utc_now())  # as an older daemon stored it
    store.prune_events(keep=4)
    kept = store.events_after(0)
    assert [kind for _, kind, _ in kept] == ["daemon"] * 3 and [i for i, _, _ in kept] == ids[-3:]
