"""A cell job in the daemon (in-process, a fake engine): one calibration per scanner filed
with its scanner, each scanner's active calibration, activation and rollback per scanner,
and a diff across scanners refused."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.job_request import DeviceAddresses
from lasercal_hw.service.jobs import RunContext, RunResult
from lasercal_hw.service.rebuild import rebuild_history
from lasercal_hw.service.store import DB_FILE, HistoryStore
from tests.daemon_helpers import fake_result, finish_job

CELL_JOB = {
    "kind": "dry_run", "confirm_motion": True, "dwell_s": 0.5,
    "job": {"scanners": {"front": {}, "rear": {}}},
}
PLACES_M = {"front": [0.3, 0.5, 0.2], "rear": [-0.45, -0.4, 0.3]}


class FakeCellEngine:
    """Writes a result.json per scanner into ``<out>/<name>/`` and reports the cell, as the
    runner of a cell job does; ``shift_m`` moves the rear scanner in the next job."""

    def __init__(self) -> None:
        self.shift_m = 0.0
        self.jobs: list[dict] = []

    def __call__(self, ctx: RunContext) -> RunResult:
        self.jobs.append(ctx.job.model_dump(mode="json"))
        scanners = {}
        for name in ctx.job.scanner_names():
            (ctx.out_dir / name).mkdir(parents=True, exist_ok=True)
            place = list(PLACES_M[name])
            if name == "rear":
                place[0] += self.shift_m
            (ctx.out_dir / name / "result.json").write_text(json.dumps(fake_result(place)))
            scanners[name] = {"passed": True}
        return RunResult(
            document={"passed": True, "scanners": scanners, "pairs": []},
            passed=True,
            verdict={"passed": True},
            calibration_dirs={name: ctx.out_dir / name for name in scanners},
        )


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    engine = FakeCellEngine()
    runners = lambda folder_of: {"calibrate": engine, "dry_run": engine, "verify": engine}  # noqa: E731
    daemon = Daemon(load_daemon_config(None, {"data_dir": tmp_path / "data"}), runners=runners)
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as test_client:
        test_client.headers["Authorization"] = f"Bearer {daemon.token}"
        test_client.engine = engine  # type: ignore[attr-defined]
        yield test_client


def _run(client: TestClient, body: dict) -> dict:
    answer = client.post("/v1/jobs", json=body)
    assert answer.status_code == 202, answer.text
    return finish_job(client, answer.json()["id"])


def test_a_cell_job_files_and_activates_each_scanner_on_its_own(client: TestClient) -> None:
    first = _run(client, CELL_JOB | {"activate_on_pass": True})
    assert first["state"] == "succeeded", first
    ids = first["document"]["calibration_ids"]
    assert list(ids) == ["front", "rear"] and first["calibration_id"] == ids["front"]
    for name in ("front", "rear"):
        active = client.get("/v1/calibration", params={"scanner": name}).json()
        assert active["id"] == ids[name] and active["scanner"] == name and active["active"]
        assert f'<child link="laser_{name}"/>' in active["exports"]["urdf_joint"]
        assert active["exports"]["static_transform_publisher_args"][-1] == f"laser_{name}"
    client.engine.shift_m = 0.005  # type: ignore[attr-defined]
    second = _run(client, CELL_JOB)["document"]["calibration_ids"]
    # activating the new rear calibration leaves the front's active one alone; rollback is per scanner
    moved = client.post(f"/v1/calibrations/{second['rear']}/activate", json={"reason": "moved"})
    assert moved.status_code == 200
    assert client.get("/v1/calibration", params={"scanner": "rear"}).json()["id"] == second["rear"]
    assert client.get("/v1/calibration", params={"scanner": "front"}).json()["id"] == ids["front"]
    rear_history = client.get("/v1/calibrations", params={"scanner": "rear"}).json()["calibrations"]
    assert [c["id"] for c in rear_history] == [second["rear"], ids["rear"]]
    assert [c["active"] for c in rear_history] == [True, False]
    diff = client.get(f"/v1/calibrations/{ids['rear']}/diff/{second['rear']}").json()
    assert diff["translation_mm"] == pytest.approx([5.0, 0.0, 0.0], abs=1e-9)
    across = client.get(f"/v1/calibrations/{ids['front']}/diff/{ids['rear']}")
    assert across.status_code == 409 and across.json()["code"] == "different_scanners"
    assert client.get("/v1/calibration", params={"scanner": "side"}).status_code == 404
    assert client.get("/v1/calibration", params={"scanner": "Bad Name"}).status_code == 422


def test_a_one_scanner_history_opens_as_the_scanner_default(tmp_path: Path) -> None:
    """A history file of schema 2 (before cells) is migrated: its calibrations are of 'default'."""
    path = tmp_path / DB_FILE
    store = HistoryStore(path)
    store.close()
    with sqlite3.connect(path) as db:  # back to schema 2, one calibration filed then
        db.execute("ALTER TABLE calibrations DROP COLUMN scanner")
        db.execute(
            "INSERT INTO calibrations (id, created_utc, job_id, dry_run, passed, summary, dir) VALUES "
            "('cal-1', '2026-01-01T00:00:00Z', NULL, 1, 1, '{\"id\": \"cal-1\"}', '/nowhere')"
        )
        db.execute("INSERT INTO activations (calibration_id, time_utc, reason) VALUES ('cal-1', 'now', 'x')")
        db.execute("PRAGMA user_version = 2")
    store = HistoryStore(path)
    try:
        assert store.calibrations() == [{"id": "cal-1", "scanner": "default", "bad": None}]
        assert store.active_calibration_id("default") == "cal-1" == store.active_calibration_id()
        assert store.active_calibration_id("front") is None
    finally:
        store.close()


def test_daemon_toml_scanners_point_a_cell_jobs_scanners_and_leave_one_scanner_jobs_alone(
    tmp_path: Path,
) -> None:
    (tmp_path / "daemon.toml").write_text(
        'scanner_url = "scip+tcp://127.0.0.1:10940"\n'
        '[scanners.rear]\nurl = "scip+tcp://127.0.0.2:10940"\n'
    )
    config = load_daemon_config(tmp_path / "daemon.toml", {})
    urls = tuple((name, scanner.url) for name, scanner in config.scanners.items())
    devices = DeviceAddresses("127.0.0.9", config.scanner_url, urls)
    cell = devices.applied_to(JobConfig.model_validate({"scanners": {"front": {}, "rear": {}}}))
    assert cell.robot.host == "127.0.0.9" and cell.scanners["rear"].url == "scip+tcp://127.0.0.2:10940"
    assert cell.scanners["front"].url == JobConfig().scanner.url  # the job's own
    assert devices.applied_to(JobConfig()).scanner.url == "scip+tcp://127.0.0.1:10940"
    (tmp_path / "daemon.toml").write_text('[scanners.rear]\nurl = "http://127.0.0.2"\n')
    with pytest.raises(ConfigError, match=r"scanners\.rear\.url"):
        load_daemon_config(tmp_path / "daemon.toml", {})


def test_a_verify_job_names_the_scanner_whose_calibration_it_checks(client: TestClient) -> None:
    _run(client, {**CELL_JOB, "job": {"scanners": {"front": {}}}, "activate_on_pass": True})
    verify = {"kind": "verify", "confirm_motion": True}  # no robot anywhere: nothing to verify is said first
    refused = client.post("/v1/jobs", json=verify | {"scanner": "rear"})  # never run, not configured
    assert refused.status_code == 422 and "no scanner 'rear'" in refused.json()["message"]
    bad = client.post("/v1/jobs", json=verify | {"scanner": "Rear!"})
    assert bad.status_code == 422


def test_the_history_rebuilds_a_cell_jobs_calibrations_per_scanner(tmp_path: Path) -> None:
    """A lost history rebuilt from the job folders: a whole cell job files each scanner's
    calibration with its scanner; one stopped after its first scanner is interrupted."""
    jobs = tmp_path / "jobs"
    for job_id, names in (("job-whole", ["front", "rear"]), ("job-stopped", ["front"])):
        folder = jobs / job_id
        for name in names:
            (folder / name).mkdir(parents=True)
            (folder / name / "result.json").write_text(json.dumps(fake_result(PLACES_M[name])))
        cell = {"job": {"scanners": {"front": {}, "rear": {}}}, "scanners_run": ["front", "rear"],
                "request": {"dry_run": True, "scene": None}}
        (folder / "cell.json").write_text(json.dumps(cell))
    report = rebuild_history(tmp_path)
    assert report.calibrations == 3
    store = HistoryStore(tmp_path / DB_FILE)
    try:
        assert sorted(c["scanner"] for c in store.calibrations()) == ["front", "front", "rear"]
        assert store.job("job-whole")["state"] == "succeeded"
        stopped = store.job("job-stopped")
        assert stopped["state"] == "interrupted" and stopped["kind"] == "dry_run"
        assert stopped["request"]["resolved_job"]["scanners"] == {"front": {}, "rear": {}}
    finally:
        store.close()


def test_a_job_holds_the_urls_of_the_scanners_it_uses_and_no_other(tmp_path: Path) -> None:
    urls = {name: f"scip+tcp://127.0.0.{2 + i}:10940" for i, name in enumerate(("front", "rear", "side"))}
    engine = FakeCellEngine()
    held: list[dict[str, str | None]] = []

    def holding(ctx: RunContext) -> RunResult:
        probes = {name: daemon.devices.probe_scanner(url, timeout_s=0.2) for name, url in urls.items()}
        held.append({name: probe.in_use_by for name, probe in probes.items()})
        return engine(ctx)

    settings = {"data_dir": tmp_path / "data", "robot_host": "127.0.0.9", "status_poll_s": 60.0,
                "scanners": {name: {"url": url} for name, url in urls.items()}}
    daemon = Daemon(load_daemon_config(None, settings), runners=lambda folder_of: {
        "calibrate": holding, "dry_run": holding, "verify": holding})
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        placed = {name: {"nominal": {"translation_m": PLACES_M[name], "euler_zyx_deg": [0.0, 0.0, 0.0]}}
                  for name in PLACES_M}
        calibrate = {"kind": "calibrate", "activate_on_pass": True, "job": {"scanners": placed}}
        job = _run(client, CELL_JOB | calibrate)
        assert job["state"] == "succeeded", job
        _run(client, {"kind": "verify", "confirm_motion": True, "scanner": "rear"})
        _run(client, CELL_JOB)  # a dry run: its own fake cell, none of the daemon's scanners
        status = client.get("/v1/status").json()
    assert held[0] == {"front": job["id"], "rear": job["id"], "side": None}
    assert held[1]["rear"] is not None and held[1]["front"] is None and held[1]["side"] is None
    assert held[2] == {"front": None, "rear": None, "side": None}
    assert daemon.devices.probe_scanner(urls["front"], timeout_s=0.2).in_use_by is None  # released at the end
    assert [s["name"] for s in status["scanners"]] == ["front", "rear", "side"]
    assert status["scanner"]["url"] == urls["front"]


def test_a_cell_job_reaches_each_scanner_at_the_daemons_url(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The runner hands the cell run daemon.toml's URLs, never the job file's (a real address),
    and shows it in the daemon's Foxglove view (``lasercal serve --foxglove``)."""
    import lasercal_hw.run.cell as cell
    from lasercal_hw.run.cancel import CancelToken
    from lasercal_hw.service.runners import run_engine

    asked: list[JobConfig] = []
    watched: list[object] = []

    class Live:
        def watch_cell(self, request: cell.CellRunRequest, on_event: object) -> object:
            watched.append(request)
            return on_event

    def calibrate_cell(request: cell.CellRunRequest, **_: object) -> None:
        asked.append(request.job)
        raise ConfigError("stop here")

    monkeypatch.setattr(cell, "calibrate_cell", calibrate_cell)
    example_url = "scip+tcp://192.168.0.10:10940"  # never reached: the test stops before any connection
    job = JobConfig.model_validate({"scanners": {"front": {"url": example_url}, "rear": {}}})
    devices = DeviceAddresses("127.0.0.9", None, (("front", "scip+tcp://127.0.0.2:10940"),))
    ctx = RunContext("job-1", "calibrate", job, devices, tmp_path, None, None, lambda e: None, CancelToken(),
                     lambda plan: None)
    with pytest.raises(ConfigError, match="stop here"):
        run_engine(ctx, dry_run=False, live=Live())  # type: ignore[arg-type]
    assert asked[0].scanners["front"].url == "scip+tcp://127.0.0.2:10940"
    assert asked[0].robot.host == "127.0.0.9"
    assert len(watched) == 1
