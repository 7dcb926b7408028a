"""``lasercal solve session.mcap`` records the poses the live run commanded (``run.waypoints``)
as its recording holds them, every design of an adaptive run included, and leaves them out,
saying so, where the recording does not hold a pose for every waypoint it measured."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.config import job_from_mapping
from lasercal_hw.run.adaptive import run_second_design
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.replay import solve_recording
from lasercal_hw.run.resume import DESIGN_EVENT
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.session.format import TOPIC_EVENT
from lasercal_hw.session.recorder import SessionRecorder
from tests.doubles import run_calibration
from tests.run.test_adaptive import ADAPTIVE
from tests.run.test_replay import _copy
from tests.run.test_sequencer import make_cell


@pytest.fixture(scope="module")
def adaptive_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RunOutcome]:
    """An adaptive run on the doubles (6 waypoints designed first, 6 from its estimate), recorded."""
    job = job_from_mapping(ADAPTIVE)
    first = job_waypoints(job)
    clock, robot, scanner = make_cell(job)
    path = tmp_path_factory.mktemp("adaptive") / "session.mcap"
    recorder = SessionRecorder(path, {"job": job.model_dump(mode="json"), "waypoints": first.tolist()})
    try:
        outcome = run_calibration(robot, scanner, recorder, job, first, clock=clock)
        final = run_second_design(robot, scanner, recorder, job, first, outcome, clock=clock)
    finally:
        recorder.close()
    return path, final


def test_a_replay_records_both_designs_poses(adaptive_recording: tuple[Path, RunOutcome]) -> None:
    path, live = adaptive_recording
    replay = solve_recording(path)
    assert replay.waypoints is not None and replay.waypoints.shape == (12, 6)
    np.testing.assert_array_equal(replay.waypoints, live.waypoints)


def test_a_recording_without_the_second_design_leaves_the_record_out(
    adaptive_recording: tuple[Path, RunOutcome], tmp_path: Path
) -> None:
    def without_designs(topic: str, data: bytes) -> bytes | None:
        is_design = topic == TOPIC_EVENT and json.loads(data).get("kind") == DESIGN_EVENT
        return None if is_design else data

    path, _ = adaptive_recording
    replay = solve_recording(_copy(path, tmp_path / "session.mcap", without_designs))
    assert replay.waypoints is None
    assert any("run.waypoints is left out" in message for message in replay.messages)
