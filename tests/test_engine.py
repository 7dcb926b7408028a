"""The engine from Python: a dry run against a fake cell gives the document and the files
`lasercal run --dry-run --json` gives, and reports its progress as numbered events."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError, InterruptedRunError
from lasercal_hw.run.engine import CancelToken, RunEvent, RunRequest, calibrate
from tests.conftest import DryRunResult
from tests.test_dry_run import write_job

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]


def test_engine_and_cli_give_the_same_document_and_files(
    tmp_path: Path, scanner_drop_dry_run: DryRunResult
) -> None:
    """The engine's dry run against the CLI's of the same job and scene (that one also
    rides out a dropped scanner connection: tests/conftest.py)."""
    job_file = write_job(tmp_path)
    events: list[RunEvent] = []
    report = calibrate(
        RunRequest(job=load_job(job_file), out_dir=tmp_path / "engine", dry_run=True), on_event=events.append
    )
    _, cli = scanner_drop_dry_run
    assert cli.returncode == 0, cli.stderr[-3000:]
    from_cli, from_engine = json.loads(cli.stdout), report.document()
    assert from_engine.keys() == from_cli.keys()
    assert from_engine["passed"] and from_cli["passed"]
    assert {Path(p).name for p in from_engine["outputs"].values()} == {
        Path(p).name for p in from_cli["outputs"].values()
    }
    # Two runs of one scene differ only by scan noise: within a few reported std.
    difference_mm = 1000 * np.abs(np.subtract(from_engine["translation_m"], from_cli["translation_m"]))
    combined_std_mm = np.hypot(from_engine["std_translation_mm"], from_cli["std_translation_mm"])
    assert np.all(difference_mm < 4 * combined_std_mm + 0.5)
    assert from_engine["ground_truth"]["error"]["translation_mm"] < 5.0

    seqs = [event.seq for event in events]
    assert seqs == list(range(1, len(events) + 1))
    kinds = {event.kind for event in events}
    assert {"stage", "progress", "centre", "scan", "result"} <= kinds
    scans = [event for event in events if event.kind == "scan"]
    assert len(scans) == from_engine["observations"] + len(from_engine["skipped"])
    picture = scans[0].data
    assert len(picture["ranges_m"]) == 1081 and picture["rod_beams"] and picture["circle"] is not None
    json.dumps([event.as_dict() for event in events], allow_nan=False)  # every event is JSON-ready
    last_progress = [event for event in events if event.kind == "progress"][-1].data
    assert last_progress["completed"] == last_progress["waypoint_count"]
    assert events[-1].kind == "result" and events[-1].data["passed"] is True


def _live_job() -> JobConfig:
    """A job for a live run: it says where the scanner roughly is."""
    return with_overrides(load_job(None), {"scanner.nominal": {"translation_m": [0.3, 0.5, 0.2]}})


def test_a_live_run_without_any_scanner_pose_points_to_trajectory_design(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match=r"no scanner pose.*lasercal trajectory design --scanner-pose"):
        calibrate(RunRequest(job=load_job(None), out_dir=out, robot_host="127.0.0.9"))
    assert not out.exists()


def test_a_cancelled_run_before_connecting_leaves_no_empty_folder(tmp_path: Path) -> None:
    cancel = CancelToken()
    cancel.cancel("test")
    out = tmp_path / "out"
    with pytest.raises(InterruptedRunError, match="test"):
        calibrate(RunRequest(job=_live_job(), out_dir=out, robot_host="127.0.0.9"), cancel=cancel)
    assert not out.exists()


def test_a_folder_holding_a_session_is_refused(tmp_path: Path) -> None:
    (tmp_path / "session.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="already exists"):
        calibrate(RunRequest(job=_live_job(), out_dir=tmp_path, robot_host="127.0.0.9"))
