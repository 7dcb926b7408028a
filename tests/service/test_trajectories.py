"""``GET /v1/trajectories``: every preset and the default job's designed waypoint file, each
with the job fragment that runs it (the operator page's trajectory list)."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from tests.daemon_helpers import FakeEngine, fake_runners, finish_job
from trajectories.presets import preset_names

DRILL_JOB = Path(__file__).resolve().parents[2] / "examples" / "drill.toml"


def test_the_daemon_lists_its_presets_and_designed_waypoints(tmp_path: Path) -> None:
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "default_job": DRILL_JOB})
    daemon = Daemon(config, runners=fake_runners(FakeEngine(waypoints=2)))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        known = client.get("/v1/trajectories").json()["trajectories"]
        designed, *presets = known
        assert (designed["name"], designed["kind"]) == ("drill-waypoints.csv", "waypoints_file")
        assert designed["job"] == {}
        # The drill job spins its bit first: 12 spin dwells, then the file's 40 (said 12 before).
        assert designed["waypoints"] == 12 + 40 and "drill.toml" in designed["description"]
        assert [p["name"] for p in presets] == preset_names() and all(p["kind"] == "preset" for p in presets)
        _start_and_finish(client, designed["job"])
        # A preset replaces the job's waypoint file (not "give either preset or waypoints_file");
        # the drill's rod is too short for the presets' heights, which the daemon says in one line.
        refused = client.post("/v1/jobs", json=_body(presets[0]["job"]))
        assert refused.status_code == 422 and "does not cross the scan plane" in refused.json()["message"]


def _body(job: dict) -> dict:
    return {"kind": "dry_run", "confirm_motion": True, "job": job, "dwell_s": 0.5}


def _start_and_finish(client: TestClient, job: dict) -> None:
    started = client.post("/v1/jobs", json=_body(job))
    assert started.status_code == 202, started.json()
    finish_job(client, started.json()["id"])


def test_without_a_default_job_only_presets(tmp_path: Path) -> None:
    config = load_daemon_config(None, {"data_dir": tmp_path / "data"})
    daemon = Daemon(config, runners=fake_runners(FakeEngine()))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        known = client.get("/v1/trajectories").json()["trajectories"]
        assert [t["name"] for t in known] == preset_names()
        _start_and_finish(client, next(t for t in known if t["name"] == "quick")["job"])


def test_a_cell_jobs_own_trajectories_alone_are_listed(tmp_path: Path) -> None:
    """Its scanners visit their own waypoints: a preset would be refused (the page offered
    presets, which the cell then ignored without a word)."""
    cell_job = DRILL_JOB.parent / "cell.toml"
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "default_job": cell_job})
    daemon = Daemon(config, runners=fake_runners(FakeEngine()))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        own, *presets = client.get("/v1/trajectories").json()["trajectories"]
    assert (own["kind"], own["job"]) == ("cell", {}) and presets == []
    assert "front 16 waypoints, rear 20 waypoints" in own["description"] and own["waypoints"] == 36
