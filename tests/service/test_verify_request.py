"""A verify job's request (in-process daemon, fake runners): the job and dwell it cannot honour
are refused, and the robot it is checked to have is the one the verify connects to."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.service.app import create_app
from lasercal_hw.service.client import DaemonClient
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.job_request import DeviceAddresses
from lasercal_hw.service.jobs import RunContext, RunResult
from lasercal_hw.service.runners import run_verify
from tests.cli_helpers import run_cli
from tests.daemon_helpers import FakeEngine, finish_job, served_in_thread

DRY_RUN = {"kind": "dry_run", "confirm_motion": True, "job": {"trajectory": {"preset": "quick"}},
           "dwell_s": 0.5}
VERIFY = {"kind": "verify", "confirm_motion": True}


class FakeVerify:
    """A verify runner that notes its context and passes."""

    def __init__(self) -> None:
        self.contexts: list[RunContext] = []

    def __call__(self, ctx: RunContext) -> RunResult:
        self.contexts.append(ctx)
        return RunResult(document={}, passed=True, verdict={"passed": True, "status": "ok", "reason": "fake"})


def _daemon(tmp_path: Path, verifier: FakeVerify, **settings: Any) -> Daemon:
    """A daemon whose calibrations are FakeEngine's and whose verifies are ``verifier``'s; the
    robot's program is noted of the host it is asked of (``daemon.snapshots``), nothing connects."""
    engine = FakeEngine(waypoints=2)
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "status_poll_s": 60.0} | settings)
    runners = {"calibrate": engine, "dry_run": engine, "verify": verifier}
    daemon = Daemon(config, runners=lambda folder_of: runners)
    daemon.snapshots = []  # type: ignore[attr-defined]
    daemon.devices.program_snapshot = lambda host: daemon.snapshots.append(host)  # type: ignore[method-assign]
    return daemon


@pytest.fixture
def verifier() -> FakeVerify:
    return FakeVerify()


@pytest.fixture
def served(tmp_path: Path, verifier: FakeVerify) -> Iterator[tuple[TestClient, Daemon]]:
    """A daemon without a robot_host of its own."""
    daemon = _daemon(tmp_path, verifier)
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        yield client, daemon


def _activate(client: TestClient, recorded_robot: dict[str, Any]) -> tuple[str, Path]:
    """A calibration made active whose result.json records a job with ``recorded_robot`` as its
    robot table (as the engine records the job it ran); its id and result.json."""
    job = finish_job(client, client.post("/v1/jobs", json=DRY_RUN | {"activate_on_pass": True}).json()["id"])
    result_file = Path(job["out_dir"]) / "result.json"
    document = json.loads(result_file.read_text())
    document["run"]["job"] = {"robot": recorded_robot}
    result_file.write_text(json.dumps(document))
    return str(job["calibration_id"]), result_file


@pytest.mark.parametrize(("field", "value"), [("job", {"trajectory": {"preset": "quick"}}), ("dwell_s", 3.0)])
def test_a_verify_refuses_a_job_or_dwell_it_would_not_use(tmp_path: Path, field: str, value: Any) -> None:
    """A verify runs the job recorded with the active calibration: a job or dwell of the request is
    refused naming the field and what to do instead, not dropped without a word."""
    verifier = FakeVerify()
    daemon = _daemon(tmp_path, verifier, robot_host="127.0.0.9")
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        _activate(client, {"host": "127.0.0.9"})
        answer = client.post("/v1/jobs", json=VERIFY | {field: value})
        assert answer.status_code == 422, answer.text
        body = answer.json()
        assert body["code"] == "invalid_request" and body["detail"]["field"] == field
        message = body["message"]
        assert message.startswith(f"{field} applies to calibrate and dry_run jobs only"), message
        assert "the job recorded with the active calibration" in message
        assert "calibrate again" in message and "lasercal verify" in message
        assert not verifier.contexts
        taken = client.post("/v1/jobs", json=VERIFY | {field: None})  # null is leaving it out
        assert taken.status_code == 202, taken.text
        assert finish_job(client, taken.json()["id"])["state"] == "succeeded"


@pytest.mark.parametrize("kind", ["verify", "calibrate"])
def test_a_scene_is_for_a_dry_run_alone(served: tuple[TestClient, Daemon], kind: str) -> None:
    """Checked with the other per-kind fields, before the job or the devices are looked at."""
    client, _daemon = served
    answer = client.post("/v1/jobs", json={"kind": kind, "confirm_motion": True, "scene": {}})
    assert answer.status_code == 422, answer.text
    assert answer.json()["detail"]["field"] == "scene"
    assert answer.json()["message"] == "scene applies to dry_run jobs only"


def test_the_openapi_says_job_and_dwell_are_for_calibrate_and_dry_run(
    served: tuple[TestClient, Daemon],
) -> None:
    client, _daemon = served
    schema = client.get("/v1/openapi.json").json()["components"]["schemas"]["JobBody"]["properties"]
    for field in ("job", "dwell_s", "scene"):
        assert "only" in schema[field]["description"], field
    assert schema["job"]["description"].startswith("calibrate and dry_run only")
    assert schema["dwell_s"]["description"].startswith("calibrate and dry_run only")


def test_a_verify_reaches_the_robot_recorded_with_the_calibration_when_the_daemon_names_none(
    served: tuple[TestClient, Daemon], verifier: FakeVerify
) -> None:
    """The daemon has no robot_host: the verify connects to the robot of the job recorded with
    the active calibration, so that robot passes the check, and its program is the one kept."""
    client, daemon = served
    _activate(client, {"host": "127.0.0.7"})
    answer = client.post("/v1/jobs", json=VERIFY)
    assert answer.status_code == 202, answer.text
    assert finish_job(client, answer.json()["id"])["state"] == "succeeded"
    assert verifier.contexts[-1].devices.robot_host == "127.0.0.7"
    assert daemon.snapshots[-1] == "127.0.0.7"  # type: ignore[attr-defined]


def test_a_verify_with_no_robot_anywhere_is_refused_up_front(tmp_path: Path) -> None:
    """Neither the daemon nor the job recorded with the calibration names a robot: refused before
    a job exists, naming where to set one, even where the daemon's default job names a robot
    (the verify would not use it)."""
    (tmp_path / "job.toml").write_text('[robot]\nhost = "127.0.0.5"\n[trajectory]\npreset = "quick"\n')
    verifier = FakeVerify()
    daemon = _daemon(tmp_path, verifier, default_job=tmp_path / "job.toml")
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        calibration_id, _result = _activate(client, {})
        jobs_before = len(client.get("/v1/jobs").json()["jobs"])
        answer = client.post("/v1/jobs", json=VERIFY)
        assert answer.status_code == 422, answer.text
        body = answer.json()
        assert body["code"] == "invalid_request" and body["detail"]["field"] == "robot_host"
        assert body["message"].startswith("no robot configured"), body["message"]
        assert "robot_host in the daemon configuration" in body["message"]
        assert calibration_id in body["message"] and "robot.host in the job" not in body["message"]
        assert len(client.get("/v1/jobs").json()["jobs"]) == jobs_before and not verifier.contexts


def test_an_unreadable_active_calibration_is_said_before_anything_runs(
    served: tuple[TestClient, Daemon], verifier: FakeVerify
) -> None:
    """Where the robot must be read from the calibration's recorded job and its result.json is
    gone: a 409 naming the calibration and the file, no job."""
    client, _daemon = served
    calibration_id, result_file = _activate(client, {"host": "127.0.0.7"})
    result_file.unlink()
    answer = client.post("/v1/jobs", json=VERIFY)
    assert (answer.status_code, answer.json()["code"]) == (409, "calibration_unreadable"), answer.text
    message = answer.json()["message"]
    assert calibration_id in message and "result.json does not exist" in message and not verifier.contexts


def test_the_daemons_robot_comes_before_the_recorded_one(tmp_path: Path) -> None:
    verifier = FakeVerify()
    daemon = _daemon(tmp_path, verifier, robot_host="127.0.0.9")
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        _activate(client, {"host": "127.0.0.7"})
        finish_job(client, client.post("/v1/jobs", json=VERIFY).json()["id"])
    assert verifier.contexts[-1].devices.robot_host == "127.0.0.9"
    assert daemon.snapshots[-1] == "127.0.0.9"  # type: ignore[attr-defined]


def test_nothing_to_verify_is_said_before_no_robot(served: tuple[TestClient, Daemon]) -> None:
    """No active calibration and no robot: the 409 says there is nothing to verify."""
    client, _daemon = served
    answer = client.post("/v1/jobs", json=VERIFY)
    assert (answer.status_code, answer.json()["code"]) == (409, "no_active_calibration")


def test_a_verify_whose_calibration_left_the_history_names_it(tmp_path: Path) -> None:
    """The runner of a verify whose calibration is no longer on record says which one is gone,
    not that no calibration is active (one may well be)."""
    gone = "20261129-093000-ab12"
    ctx = RunContext("job-1", "verify", JobConfig(), DeviceAddresses(), tmp_path, None, None,
                     lambda event: None, CancelToken(), lambda plan: None, calibration_id=gone)
    with pytest.raises(ConfigError, match=rf"calibration {gone} .* no longer in the history"):
        run_verify(ctx, folder_of=lambda calibration_id: None)


def test_remote_verify_sends_no_job_or_dwell(tmp_path: Path) -> None:
    """``lasercal remote verify`` over a real socket: accepted, its request carries neither."""
    verifier = FakeVerify()
    daemon = _daemon(tmp_path, verifier, robot_host="127.0.0.9")
    with served_in_thread(daemon) as url:
        client = DaemonClient(url, daemon.token)
        started = client.start_job(DRY_RUN | {"activate_on_pass": True})
        client.wait(started["id"])
        env = {"LASERCAL_TOKEN": daemon.token}
        result = run_cli("remote", "verify", "--yes", "--json", "--daemon", url, env=env)
        assert result.returncode == 0, result.stderr
        job = json.loads(result.stdout)
        client.wait(job["id"])
    assert job["kind"] == "verify"
    assert job["request"]["job"] is None and job["request"]["dwell_s"] is None


def test_a_scanner_the_daemon_does_not_have_is_named_as_such(served: tuple[TestClient, Daemon]) -> None:
    """A one-scanner daemon asked of the scanner 'rear': the answer says it has no such scanner
    and names the one it has, not that nothing is active for it (which sends the caller to
    calibrate a scanner that is not there); its own scanner, with nothing active, is told so."""
    client, _daemon = served
    answer = client.post("/v1/jobs", json=VERIFY | {"scanner": "rear"})
    assert answer.status_code == 422, answer.text
    assert answer.json()["detail"]["field"] == "scanner"
    assert "no scanner 'rear'" in answer.json()["message"] and "default" in answer.json()["message"]
    answer = client.get("/v1/calibration", params={"scanner": "rear"})
    assert (answer.status_code, answer.json()["code"]) == (404, "unknown_scanner"), answer.text
    answer = client.get("/v1/calibration", params={"scanner": "default"})
    assert (answer.status_code, answer.json()["code"]) == (404, "no_active_calibration"), answer.text
    _activate(client, {"host": "127.0.0.7"})
    assert client.get("/v1/calibration", params={"scanner": "default"}).status_code == 200


def test_a_verify_jobs_record_holds_the_job_it_runs(served: tuple[TestClient, Daemon]) -> None:
    """The job recorded with the calibration, which the verify runs, is the job's
    ``resolved_job`` (pointed at the robot it connects to), not the daemon's default job."""
    client, _daemon = served
    _, result_file = _activate(client, {"host": "127.0.0.7"})
    document = json.loads(result_file.read_text())
    document["run"]["job"]["verify"] = {"waypoints": 3}
    result_file.write_text(json.dumps(document))
    job = finish_job(client, client.post("/v1/jobs", json=VERIFY).json()["id"])
    resolved = job["request"]["resolved_job"]
    assert resolved["verify"]["waypoints"] == 3 and resolved["robot"]["host"] == "127.0.0.7"


def test_a_verify_checks_the_calibration_active_when_it_was_requested(
    served: tuple[TestClient, Daemon], verifier: FakeVerify
) -> None:
    """The runner is handed the id of the calibration active at the request (recorded with the
    job), not whatever is active when it starts."""
    client, _daemon = served
    first, _ = _activate(client, {"host": "127.0.0.7"})
    job = finish_job(client, client.post("/v1/jobs", json=VERIFY).json()["id"])
    assert job["request"]["active_calibration_id"] == first
    assert verifier.contexts[-1].calibration_id == first
    second, _ = _activate(client, {"host": "127.0.0.7"})
    finish_job(client, client.post("/v1/jobs", json=VERIFY).json()["id"])
    assert second != first and verifier.contexts[-1].calibration_id == second
