"""The daemon under faults and hostile input (issue 21): every hostile request of
tests/hostile_inputs.py gets its 4xx JSON answer, nothing of a file outside the data
folder leaks, a full disk ends the job cleanly and recovers without a restart, a missing or
damaged history stops the start with one line, and the history rebuilds from the job
folders. The long runs (kill -9 at every state, repeated) are in benchmarks/daemon_faults.py."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.rebuild import rebuild_history
from lasercal_hw.service.store import DB_FILE, SCHEMA_VERSION, HistoryStore
from lasercal_hw.session.reader import read_session
from tests.daemon_helpers import QUICK_DRY_RUN, DaemonProcess, FakeEngine, fake_runners, read_sse, wait_for
from tests.fault_helpers import DAMAGES, FILLER_BYTES, child_pids, follow_to_the_end, small_disk, truncate
from tests.hostile_inputs import CASES, DRY, SECRET, Hostile, send

FINISHED = ("succeeded", "failed", "cancelled", "interrupted")


def _in_process(data_dir: Path) -> tuple[Daemon, FakeEngine]:
    engine = FakeEngine()
    return Daemon(load_daemon_config(None, {"data_dir": data_dir}), runners=fake_runners(engine)), engine


def _finish(client: TestClient | httpx.Client, job_id: str) -> dict[str, Any]:
    return wait_for(client, job_id, lambda job: job["state"] in FINISHED, timeout_s=30.0)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, dict[str, str]]]:
    """One in-process daemon (fake engine) for every hostile case, with a finished job."""
    root = tmp_path_factory.mktemp("hostile")
    outside = root / "outside"
    outside.mkdir()
    (outside / "secret.csv").write_text(f"index,x,y,z,rx,ry,rz\n0,{SECRET},0,0,0,0,0\n")
    daemon, _engine = _in_process(root / "data")
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        job = _finish(client, client.post("/v1/jobs", json=DRY).json()["id"])
        names = {
            "job": job["id"],
            "cal": job["calibration_id"],
            "outside": str(outside),
            "token": daemon.token,
            "token_prefix": daemon.token[:-1],
        }
        yield client, names


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_hostile_request_gets_its_json_answer(
    served: tuple[TestClient, dict[str, str]], case: Hostile
) -> None:
    client, names = served
    answer = send(client, case, names)
    assert (answer.status_code, answer.json()["code"]) == (case.status, case.code), answer.text[:500]
    assert answer.json()["message"] and SECRET not in answer.text


def test_a_file_outside_says_nothing_of_itself(served: tuple[TestClient, dict[str, str]]) -> None:
    client, names = served

    def message(path: str) -> str:
        body = DRY | {"job": {"trajectory": {"preset": None, "waypoints_file": path}}}
        return str(client.post("/v1/jobs", json=body).json()["message"]).replace(path, "PATH")

    secret, missing, unreadable = (
        message(f"{names['outside']}/secret.csv"),
        message(f"{names['outside']}/missing.csv"),
        message("/etc/shadow"),
    )
    assert secret == missing == unreadable and SECRET not in secret
    assert "must be a file under" in secret


def test_a_waypoint_file_in_the_data_folder_is_read(served: tuple[TestClient, dict[str, str]]) -> None:
    client, _names = served
    data_dir = Path(client.get("/v1/status").json()["daemon"]["data_dir"])
    (data_dir / "bad.csv").write_text("index,x,y,z,rx,ry,rz\n0,not_a_number,0,0,0,0,0\n")
    answer = client.post(
        "/v1/jobs",
        json=DRY | {"job": {"trajectory": {"preset": None, "waypoints_file": str(data_dir / "bad.csv")}}},
    )
    assert answer.status_code == 422 and "not_a_number" in answer.json()["message"]


def test_a_relative_waypoint_file_is_told_to_be_named_by_its_full_path(
    served: tuple[TestClient, dict[str, str]],
) -> None:
    """A relative name is read against the daemon's working folder, not its data folder: the
    422 said "copy the file there and name it", and a copy named as the message's folder holds
    it ("bad.csv") was refused again. It says to give the full path, which is read."""
    client, _names = served
    data_dir = Path(client.get("/v1/status").json()["daemon"]["data_dir"])
    (data_dir / "bad.csv").write_text("index,x,y,z,rx,ry,rz\n0,not_a_number,0,0,0,0,0\n")

    def answer(path: str) -> httpx.Response:
        trajectory = {"preset": None, "waypoints_file": path}
        return client.post("/v1/jobs", json=DRY | {"job": {"trajectory": trajectory}})

    refused = answer("bad.csv")
    assert refused.status_code == 422 and "full path" in refused.json()["message"], refused.text
    assert "not_a_number" in answer(str(data_dir / "bad.csv")).json()["message"]


def test_a_verify_without_an_active_calibration_is_refused_at_request_time(tmp_path: Path) -> None:
    engine = FakeEngine()
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "robot_host": "127.0.0.1"})
    daemon = Daemon(config, runners=lambda folder_of: {"verify": engine})
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        answer = client.post("/v1/jobs", json={"kind": "verify", "confirm_motion": True})
        assert (answer.status_code, answer.json()["code"]) == (409, "no_active_calibration")
        assert not engine.contexts and not list((tmp_path / "data" / "jobs").iterdir())


def test_a_configured_host_name_is_served(tmp_path: Path) -> None:
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "allowed_hosts": ["cell-7.local"]})
    with TestClient(create_app(Daemon(config)), base_url="http://cell-7.local:8766") as client:
        assert client.get("/v1/health").status_code == 200
        assert client.get("/v1/health", headers={"Host": "[::1]:8766"}).status_code == 200
        assert client.get("/v1/health", headers={"Host": "other.local"}).status_code == 400


# -- the history at start ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def history_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data folder with two finished jobs (one calibration active) and one cancelled."""
    data_dir = tmp_path_factory.mktemp("history") / "data"
    daemon, engine = _in_process(data_dir)
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        for _ in range(2):
            _finish(client, client.post("/v1/jobs", json=DRY | {"activate_on_pass": True}).json()["id"])
        engine.release.clear()
        running = client.post("/v1/jobs", json=DRY).json()["id"]
        assert engine.started.wait(5.0)
        client.post(f"/v1/jobs/{running}/cancel")
        engine.release.set()
        _finish(client, running)
    return data_dir


def _copy(history_dir: Path, tmp_path: Path) -> Path:
    data_dir = tmp_path / "data"
    shutil.copytree(history_dir, data_dir)
    return data_dir


@pytest.mark.parametrize("damage", DAMAGES)
def test_a_lost_or_damaged_history_stops_the_start(history_dir: Path, tmp_path: Path, damage: str) -> None:
    data_dir = _copy(history_dir, tmp_path)
    harm, says = DAMAGES[damage]
    harm(data_dir / DB_FILE)
    with pytest.raises(ConfigError, match="rebuild") as raised:
        Daemon(load_daemon_config(None, {"data_dir": data_dir}))
    assert says in str(raised.value) and "\n" not in str(raised.value)


def serve(data_dir: Path, *options: str) -> subprocess.CompletedProcess[str]:
    """``lasercal serve --data-dir DATA_DIR OPTIONS`` run to its end (a refused start, a rebuild)."""
    command = [sys.executable, "-m", "lasercal_hw.cli.main", "serve", "--data-dir", str(data_dir), *options]
    return subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)


def test_the_cli_refuses_a_damaged_history_in_one_line(history_dir: Path, tmp_path: Path) -> None:
    data_dir = _copy(history_dir, tmp_path)
    truncate(data_dir / DB_FILE)
    done = serve(data_dir, "--listen", "127.0.0.1:0")
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "--rebuild-history" in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_rebuild_history_from_the_job_folders(history_dir: Path, tmp_path: Path) -> None:
    data_dir = _copy(history_dir, tmp_path)
    truncate(data_dir / DB_FILE)
    done = serve(data_dir, "--rebuild-history")
    assert done.returncode == 0, done.stderr
    assert "2 succeeded" in done.stdout and "2 calibrations" in done.stdout
    # the job folders keep neither the calibrations' ids nor who marked one bad: the rebuild says so
    assert "new id" in done.stdout and "marked bad" in done.stdout, done.stdout
    daemon = Daemon(load_daemon_config(None, {"data_dir": data_dir}))
    try:
        assert len(daemon.store.jobs()) == 3 and len(daemon.store.calibrations()) == 2
        newest_first = [summary["job_id"] for summary in daemon.store.calibrations()]
        made = sorted(data_dir.glob("jobs/*/result.json"), key=lambda result: result.stat().st_mtime_ns)
        assert newest_first == [result.parent.name for result in reversed(made)]  # the order they were made
        assert daemon.store.active_calibration_id() is None  # the activation log lived only in the database
    finally:
        daemon.store.close()
    assert list(data_dir.glob(f"{DB_FILE}.before-rebuild-*"))  # the emptied file is kept


def test_a_rebuild_files_a_finished_verify_as_a_verify_not_a_calibration_to_resume(tmp_path: Path) -> None:
    """A verify's folder holds its recording too: it is the verify's, with ``verify.json``
    beside it, and must not come back as an interrupted calibration that resume would re-run."""
    for job_id, verify in (("job-verify", '{"verdict": "inconclusive", "reason": "too little data"}'),
                           ("job-torn", '{"verdict": ')):
        folder = tmp_path / "jobs" / job_id
        folder.mkdir(parents=True)
        (folder / "session.mcap").write_bytes(b"not read: the verify.json decides")
        (folder / "verify.json").write_text(verify, encoding="utf-8")
    report = rebuild_history(tmp_path)
    assert report.jobs == {"failed": 1, "succeeded": 1} and report.calibrations == 0
    store = HistoryStore(tmp_path / DB_FILE)
    try:
        done, torn = store.job("job-verify"), store.job("job-torn")
    finally:
        store.close()
    assert (done["kind"], done["state"]) == ("verify", "succeeded")
    assert done["verdict"] == {"passed": False, "status": "inconclusive", "reason": "too little data"}
    assert (torn["kind"], torn["state"]) == ("verify", "failed")
    assert "verify.json unreadable" in torn["error"]["message"]


def test_a_rebuild_tells_an_interrupted_verify_from_an_interrupted_calibration(tmp_path: Path) -> None:
    """Two recordings without an answer beside them: the one whose meta says a verify wrote it
    comes back as an interrupted verify that says to start a new one (a verify is not
    resumed); the other, written before the meta said, as a calibration to resume."""
    from lasercal_hw.run.resume import META_PROCEDURE, Procedure
    from lasercal_hw.session.recorder import SessionRecorder

    for job_id, said in (("job-calibration", {}), ("job-verify", {META_PROCEDURE: Procedure.VERIFY.value})):
        folder = tmp_path / "jobs" / job_id
        folder.mkdir(parents=True)
        with SessionRecorder(folder / "session.mcap", {"job": {}, "waypoints": []} | said):
            pass
    report = rebuild_history(tmp_path)
    assert report.jobs == {"interrupted": 2}
    store = HistoryStore(tmp_path / DB_FILE)
    try:
        calibration, verify = store.job("job-calibration"), store.job("job-verify")
    finally:
        store.close()
    assert calibration["kind"] == "calibrate"
    assert "POST /v1/jobs/{id}/resume" in calibration["error"]["message"]
    assert verify["kind"] == "verify" and "start a new verify" in verify["error"]["message"]


def test_a_migration_backs_the_database_up_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from lasercal_hw.service import store as store_module

    HistoryStore(tmp_path / DB_FILE).close()
    monkeypatch.setattr(store_module, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    monkeypatch.setitem(store_module._MIGRATIONS, SCHEMA_VERSION + 1, "CREATE TABLE later (id INTEGER)")
    HistoryStore(tmp_path / DB_FILE).close()
    backup = tmp_path / f"{DB_FILE}.v{SCHEMA_VERSION}.bak"
    with sqlite3.connect(backup) as connection:
        assert connection.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


# -- a full disk, for real --------------------------------------------------------------------


def test_a_full_disk_mid_job_fails_it_cleanly_and_recovers_without_a_restart(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small") as disk:
        if disk.how == "tmpfs":
            disk.filler.write_bytes(b"\0" * FILLER_BYTES)
        daemon = DaemonProcess(disk.root / "data", file_size_limit_bytes=disk.file_size_limit_bytes).start()
        try:
            with daemon.client() as client:
                job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
                job, followed = follow_to_the_end(client, job_id)
                assert followed[-1][1] == "state" and followed[-1][2]["state"] == "failed"  # followers told
                assert job["state"] == "failed" and job["error"]["code"] == "storage_full", job["error"]
                assert "stopped" in job["error"]["message"]
                stops = [data for _id, kind, data in followed if kind == "stopped"]
                assert stops, "no stopped event: the follower was not told the recording is kept"
                recording = read_session(disk.root / "data" / "jobs" / job_id / "session.mcap")
                assert recording.metas  # what was written is kept and readable
                if disk.how == "tmpfs":
                    refused = client.post("/v1/jobs", json=QUICK_DRY_RUN)
                    assert (refused.status_code, refused.json()["code"]) == (507, "storage_full"), (
                        refused.text
                    )
                    assert len(list((disk.root / "data" / "jobs").iterdir())) == 1  # no empty job folder
                    disk.filler.unlink()
                    again = client.post("/v1/jobs", json=QUICK_DRY_RUN)
                    assert again.status_code == 202, again.text
                    client.post(f"/v1/jobs/{again.json()['id']}/cancel")
                    wait_for(
                        client, again.json()["id"], lambda job: job["state"] in FINISHED, timeout_s=120.0
                    )
                assert client.get(f"/v1/jobs/{job_id}").json()["error"]["code"] == "storage_full"
        finally:
            daemon.stop()
    print(f"full disk made by {disk.how}")


def test_starting_on_a_full_disk_is_one_line(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small") as disk:
        if disk.how != "tmpfs":
            pytest.skip("a file system full at start needs a tmpfs (mount refused here)")
        data_dir = disk.root / "data"
        daemon, _engine = _in_process(data_dir)
        daemon.store.insert_job(
            {
                "id": "job-x",
                "kind": "dry_run",
                "state": "running",
                "created_utc": "2026-01-01T00:00:00",
                "request": {},
                "progress": {},
                "out_dir": str(data_dir / "jobs" / "job-x"),
            }
        )
        daemon.store.close()
        with disk.filler.open("wb", buffering=0) as filler, contextlib.suppress(OSError):  # to the last byte
            while True:
                filler.write(b"\0" * 4096)
        with pytest.raises(ConfigError, match="full") as raised:
            _in_process(data_dir)
        assert "\n" not in str(raised.value)


# -- the process under signals ----------------------------------------------------------------


@pytest.fixture(scope="module")
def dry_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """One dry-run daemon for the signal tests: its cell is killed first, SIGTERM ends it last."""
    daemon = DaemonProcess(tmp_path_factory.mktemp("signals") / "data").start()
    try:
        yield daemon
    finally:
        daemon.stop()


def test_the_idle_fake_cell_killed_is_said_truly_and_started_again(dry_daemon: DaemonProcess) -> None:
    daemon = dry_daemon
    with daemon.client() as client:
        before = client.get("/v1/status").json()["robot"]["host"]
        (cell,) = [
            pid
            for pid in child_pids(daemon.pid)
            if b"fakes.cell" in Path(f"/proc/{pid}/cmdline").read_bytes()
        ]
        os.kill(cell, signal.SIGKILL)
        deadline = time.monotonic() + 60.0
        while "started a new one" not in daemon.log.read_text() and time.monotonic() < deadline:
            time.sleep(0.2)
        log = daemon.log.read_text()
        assert f"(pid {cell}) was killed by signal 9 serving the dry-run daemon" in log
        assert "during the run" not in log
        while time.monotonic() < deadline:
            robot = client.get("/v1/status").json()["robot"]
            if robot["host"] != before and robot["connected"]:
                break
            time.sleep(0.3)
        assert robot["host"] != before and robot["connected"], robot


def test_sigterm_sends_followers_the_interrupted_state(dry_daemon: DaemonProcess) -> None:
    daemon = dry_daemon  # the last test of this daemon: SIGTERM ends it
    try:
        with daemon.client() as client:
            job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
            followed: list[tuple[int, str, dict[str, Any]]] = []

            def follow() -> None:
                with httpx.stream("GET", f"{daemon.url}/v1/jobs/{job_id}/events", timeout=60.0) as stream:
                    followed.extend(read_sse(stream))

            follower = threading.Thread(target=follow)
            follower.start()
            wait_for(client, job_id, lambda job: job["progress"]["completed"] >= 1, timeout_s=120.0)
            daemon.process.send_signal(signal.SIGTERM)  # type: ignore[union-attr]
            follower.join(30.0)
            assert not follower.is_alive()
            assert followed[-1][1] == "state" and followed[-1][2]["state"] == "interrupted", followed[-3:]
    finally:
        daemon.stop()


@pytest.mark.parametrize(
    ("host", "shown"), [("127.0.0.1", "127.0.0.1"), ("::1", "[::1]"), ("localhost", "localhost")]
)
def test_the_ready_line_brackets_an_ipv6_host(host: str, shown: str) -> None:
    from lasercal_hw.cli.serve import url_host

    assert url_host(host) == shown
