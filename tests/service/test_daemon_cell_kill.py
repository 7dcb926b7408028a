"""A real ``lasercal serve --dry-run`` process running a two-scanner dry-run cell job over
HTTP on loopback, killed with SIGKILL during the second scanner's waypoints: after a restart
the job is ``interrupted``, the first scanner's calibration is kept (in the history and on
disk), and resume finishes the second scanner without measuring a waypoint twice (read from
the job's one recording, not from timing), every record of the killed file kept."""

from __future__ import annotations

import contextlib
import json
import logging
import tomllib
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from lasercal_hw.session.reader import read_session
from tests.daemon_helpers import QUICK_DWELL_S, QUICK_JOB, DaemonProcess, read_sse, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(400)]

REPO = Path(__file__).resolve().parents[2]
WAYPOINTS = 7
KILL_AFTER_REAR_OBSERVATIONS = 2


def _cell_body(waypoint_dir: Path) -> dict[str, Any]:
    """examples/cell.toml on the first WAYPOINTS of each scanner's waypoints (files in the
    daemon's data folder, where a request may name them), the quick job's short dwell, the two-scanner
    scene."""
    job = tomllib.loads((REPO / "examples" / "cell.toml").read_text())
    for name, entry in job["scanners"].items():
        rows = (REPO / "examples" / "cell" / f"{name}-waypoints.csv").read_text().splitlines()
        path = waypoint_dir / f"{name}-waypoints.csv"
        path.write_text("\n".join(rows[: WAYPOINTS + 1]) + "\n")
        entry["trajectory"] = {"waypoints_file": str(path)}
    job.pop("dwell_s")
    job["background"]["scans"] = 10  # its table (the cell's retract pose) replaces the quick job's
    job["quality"] = {"max_std_translation_mm": 100.0, "max_std_rotation_deg": 10.0, "min_observations": 6}
    job["output"] = {"report": False}
    scene = tomllib.loads((REPO / "fakes" / "scenes" / "two_scanners.toml").read_text())
    return {"kind": "dry_run", "confirm_motion": True, "dwell_s": QUICK_DWELL_S, "job": QUICK_JOB | job,
            "scene": scene}


@contextlib.contextmanager
def _quiet(logger: logging.Logger) -> Iterator[None]:
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _filed(client: httpx.Client, scanner: str) -> list[dict[str, Any]]:
    """The daemon's calibrations of ``scanner``, newest first."""
    return list(client.get("/v1/calibrations", params={"scanner": scanner}).json()["calibrations"])


def _measured(session: Path, scanner: str = "rear") -> list[int]:
    """The waypoints ``scanner``'s run in a cell job's (possibly cut-off) recording holds a centre
    or a skip for, in order."""
    if not session.is_file():
        return []
    with _quiet(logging.getLogger("lasercal_hw.session.reader")):  # a live recording is "truncated"
        recording = read_session(session)
    if scanner not in recording.scanner_names:
        return []
    recording = recording.for_scanner(scanner)
    events = recording.events_of("observation") + recording.events_of("waypoint_skipped")
    return [int(event["index"]) for event in events]


def test_a_cell_job_killed_in_the_second_scanner_resumes_there(tmp_path: Path) -> None:
    data_dir = tmp_path / "data"
    (data_dir / "waypoints").mkdir(parents=True)
    body = _cell_body(data_dir / "waypoints")
    first = DaemonProcess(data_dir).start()
    try:
        with first.client() as client:
            response = client.post("/v1/jobs", json=body)
            assert response.status_code == 202, response.text
            job_id = response.json()["id"]
            session = data_dir / "jobs" / job_id / "session.mcap"  # the job's one recording
            front_done = data_dir / "jobs" / job_id / "front" / "result.json"
            # until the rear scanner has measured some waypoints (a device error on a loaded machine,
            # the fake robot's RTDE stream stalling, is resumed as wait_for does); the growing recording
            # is read only once the front's result is written (parsing it every poll of the front's
            # run took a good part of a core beside the real-time fakes)
            wait_for(client, job_id, lambda job: job["state"] in ("succeeded", "cancelled") or (
                front_done.is_file() and len(_measured(session)) >= KILL_AFTER_REAR_OBSERVATIONS),
                timeout_s=300.0)
            assert client.get(f"/v1/jobs/{job_id}").json()["state"] not in ("succeeded", "cancelled")
        first.kill()
    finally:
        first.stop()
    out = data_dir / "jobs" / job_id
    front_result = (out / "front" / "result.json").read_bytes()
    measured_before = _measured(session)
    front_before = _measured(session, "front")
    killed_size = session.stat().st_size
    assert len(measured_before) >= KILL_AFTER_REAR_OBSERVATIONS
    assert not (out / "rear" / "result.json").exists()

    second = DaemonProcess(data_dir).start()
    try:
        with second.client() as client:
            job = client.get(f"/v1/jobs/{job_id}").json()
            assert job["state"] == "interrupted", job
            (front,) = _filed(client, "front")
            assert front["job_id"] == job_id and front["scanner"] == "front"
            assert _filed(client, "rear") == []
            resumed = client.post(f"/v1/jobs/{job_id}/resume", json={"confirm_motion": True})
            assert resumed.status_code == 200, resumed.text
            done = wait_for(client, job_id, lambda j: j["state"] in ("succeeded", "failed", "cancelled"))
            assert done["state"] == "succeeded", done
            ids = done["document"]["calibration_ids"]
            assert ids["front"] == front["id"], "the front scanner's calibration was filed again"
            for name in ("front", "rear"):
                (filed,) = _filed(client, name)
                assert filed["id"] == ids[name] and filed["job_id"] == job_id
            with client.stream("GET", f"/v1/jobs/{job_id}/events?last_event_id=0") as stream:
                told = [data for _, kind, data in read_sse(stream) if kind == "pair_agreement"]
    finally:
        second.stop()

    assert (out / "front" / "result.json").read_bytes() == front_result, "the front scanner ran again"
    final = _measured(session)
    assert not list(out.glob("*/session.mcap")), "one recording for the job"
    # the killed file, kept whole beside it (the newest kept: wait_for may have resumed a stall before)
    kept = max(out.glob("session.interrupted-*.mcap"), key=lambda path: int(path.stem.rsplit("-", 1)[1]))
    assert kept.stat().st_size == killed_size and _measured(kept) == measured_before
    assert _measured(session, "front") == front_before, "the front scanner's run is in the one recording"
    assert Counter(final) == Counter(range(WAYPOINTS)), f"a waypoint measured twice or never: {final}"
    assert final[: len(measured_before)] == measured_before, "the waypoints measured before the kill are kept"
    cell = json.loads((out / "cell.json").read_text())
    # both scanners' results and their pair in the job's cell.json; whether a 7-waypoint, 0.5 s
    # job passes its gates on a loaded machine is not what this test is about (tests/run/test_cell.py)
    assert sorted(cell["scanners"]) == ["front", "rear"], cell["scanners"]
    assert [p["from"] + ">" + p["to"] for p in cell["pairs"]] == ["front>rear"]
    # the job's event stream tells the pair's agreement once, as cell.json holds it: the centres
    # it compared (the watchers' after their second pass), not the live first pass
    (agreement,) = told
    assert agreement["from"] == "front" and agreement["to"] == "rear"
    assert {key: agreement[key] for key in cell["pairs"][0]["agreement"]} == cell["pairs"][0]["agreement"]
