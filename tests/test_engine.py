"""The engine from Python: a dry run against a fake cell gives the document and the files
`lasercal run --dry-run --json` gives, and reports its progress as numbered events."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.config import load_job
from lasercal_hw.errors import ConfigError, InterruptedRunError
from lasercal_hw.run.engine import CancelToken, RunEvent, RunRequest, calibrate
from tests.test_dry_run import write_job

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]


def test_engine_and_cli_give_the_same_document_and_files(tmp_path: Path) -> None:
    job_file = write_job(tmp_path)
    events: list[RunEvent] = []
    report = calibrate(
        RunRequest(job=load_job(job_file), out_dir=tmp_path / "engine", dry_run=True), on_event=events.append
    )
    cli = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", "run", "--dry-run", "--json",
         "--config", str(job_file), "--out", str(tmp_path / "cli")],
        capture_output=True, text=True, timeout=200, stdin=subprocess.DEVNULL, cwd=tmp_path,
    )
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


def test_a_cancelled_run_before_connecting_leaves_no_empty_folder(tmp_path: Path) -> None:
    cancel = CancelToken()
    cancel.cancel("test")
    out = tmp_path / "out"
    with pytest.raises(InterruptedRunError, match="test"):
        calibrate(RunRequest(job=load_job(None), out_dir=out, robot_host="127.0.0.9"), cancel=cancel)
    assert not out.exists()


def test_a_folder_holding_a_session_is_refused(tmp_path: Path) -> None:
    (tmp_path / "session.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="already exists"):
        calibrate(RunRequest(job=load_job(None), out_dir=tmp_path, robot_host="127.0.0.9"))
