"""A verify chooses among every pose the calibration visited (``result.json``'s
``run.waypoints``: both designs of an adaptive run, a spun drill's spin and turned waypoints),
weighs each with the residual and centre covariance recorded there and counts them all in its
time budget; an older result.json without the record falls back to the job's waypoints and says
so in the selection."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.run import flute_spin
from lasercal_hw.run.adaptive import run_second_design
from lasercal_hw.run.flute_spin import SpinPhase, run_turned_waypoints, turned_about_bit
from lasercal_hw.run.outputs import result_document
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.replay import solve_recording
from lasercal_hw.run.resume import DESIGN_EVENT
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.run.waypoints import job_waypoints, listed_waypoints
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from lasercal_hw.verify.active import load_active_calibration
from lasercal_hw.verify.procedure import plan_active, time_budget_s, verify_job
from tests.doubles import run_calibration
from tests.run.test_adaptive import ADAPTIVE
from tests.run.test_flute_spin import _spun_job
from tests.run.test_sequencer import make_cell


@dataclass(frozen=True)
class AdaptiveRun:
    """An adaptive calibration on the doubles' cell: its job, outcome, recording and result.json."""

    job: JobConfig
    outcome: RunOutcome
    session: Path
    result: Path


@pytest.fixture(scope="module")
def adaptive_run(tmp_path_factory: pytest.TempPathFactory) -> AdaptiveRun:
    """Six waypoints of a first design from a rough pose 4 cm / 4 deg off, six designed from its
    estimate, one solve over all twelve, recorded and written as ``lasercal run`` does."""
    job = job_from_mapping(ADAPTIVE)
    folder = tmp_path_factory.mktemp("adaptive")
    first = job_waypoints(job)
    clock, robot, scanner = make_cell(job)
    session = folder / "session.mcap"
    recorder = SessionRecorder(session, {"job": job.model_dump(mode="json"), "waypoints": first.tolist()})
    try:
        outcome = run_calibration(robot, scanner, recorder, job, first, clock=clock)
        final = run_second_design(robot, scanner, recorder, job, first, outcome, clock=clock)
    finally:
        recorder.close()
    result = folder / "result.json"
    result.write_text(json.dumps(result_document(final, job)), encoding="utf-8")
    return AdaptiveRun(job, final, session, result)


def _visited(run: AdaptiveRun) -> np.ndarray:
    """Every pose the run commanded: the first design, then the second as the recording's
    design event holds it."""
    event = read_session(run.session, include_scans=False).events_of(DESIGN_EVENT)[-1]
    assert event["first_index"] == 6
    return np.vstack([job_waypoints(run.job), np.asarray(event["waypoints"], dtype=float)])


def test_result_json_records_every_pose_the_adaptive_run_commanded(adaptive_run: AdaptiveRun) -> None:
    recorded = json.loads(adaptive_run.result.read_text(encoding="utf-8"))["run"].get("waypoints")
    np.testing.assert_array_equal(np.asarray(recorded), _visited(adaptive_run))
    assert sorted(r.index for r in adaptive_run.outcome.result.residuals) == list(range(12))


def test_a_replay_of_the_recording_records_both_designs(adaptive_run: AdaptiveRun) -> None:
    replay = solve_recording(adaptive_run.session)
    np.testing.assert_array_equal(getattr(replay, "waypoints", None), _visited(adaptive_run))


def test_verify_chooses_among_both_designs_with_their_recorded_residuals(adaptive_run: AdaptiveRun) -> None:
    """Every visited pose is a candidate, each with the residual the calibration saw there
    (on main: the first design re-made from the calibrated pose, none of them a pose the
    calibration visited, so no residual at all), and the choice takes second-design waypoints."""
    active = load_active_calibration(adaptive_run.result)
    plan = plan_active(active, adaptive_run.job)
    np.testing.assert_array_equal(plan.waypoints, _visited(adaptive_run))
    used = sorted(r.index for r in adaptive_run.outcome.result.residuals if r.used)
    assert np.flatnonzero(np.isfinite(plan.reference).all(axis=1)).tolist() == used
    assert any(index >= 6 for index in plan.selection.indices), plan.selection.indices
    assert "run.waypoints" in plan.selection.candidates_source


def test_the_time_budget_counts_both_designs(adaptive_run: AdaptiveRun) -> None:
    active = load_active_calibration(adaptive_run.result)
    job = adaptive_run.job
    both = visit_time_s(job, _visited(adaptive_run))
    first = visit_time_s(job, job_waypoints(job))
    assert both is not None and first is not None and both > first
    assert time_budget_s(active, job) == pytest.approx(job.verify.max_time_fraction * both)


def test_an_older_result_json_without_the_record_still_verifies(
    adaptive_run: AdaptiveRun, tmp_path: Path
) -> None:
    document = json.loads(adaptive_run.result.read_text(encoding="utf-8"))
    document["run"].pop("waypoints", None)
    older = tmp_path / "result.json"
    older.write_text(json.dumps(document), encoding="utf-8")
    active = load_active_calibration(older)
    plan = plan_active(active, adaptive_run.job)
    checking = verify_job(adaptive_run.job, active.T_base_laser)
    np.testing.assert_array_equal(plan.waypoints, job_waypoints(checking))
    assert "does not record the poses its run commanded" in plan.selection.candidates_source
    assert len(plan.selection.indices) == adaptive_run.job.verify.waypoints


def test_a_spun_drills_verify_matches_each_residual_to_the_pose_it_was_measured_at(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``flute_phase_deg`` run visits the spin, then its waypoints turned to the phase: the
    candidates are those poses, each with its own residual (main: the listed waypoints, the
    residual of the run's k-th visit, a spin dwell for k < 12, at the k-th listed pose)."""
    job = _spun_job(tmp_path)
    spin = job_waypoints(job)
    told = SpinPhase(phase_deg=60.0, phase_std_deg=3.0, gain=20.0, shift_deg=30.0, centres=9)
    monkeypatch.setattr(flute_spin, "phase_from_spin", lambda *args: told)
    clock, robot, scanner = make_cell(job)
    recorder = SessionRecorder(
        tmp_path / "session.mcap", {"job": job.model_dump(mode="json"), "waypoints": spin.tolist()}
    )
    try:
        spun = Sequencer(robot, scanner, recorder, job, spin, clock=clock).measure()
        outcome = run_turned_waypoints(robot, scanner, recorder, job, spin, spun, clock=clock)
    finally:
        recorder.close()
    result = tmp_path / "result.json"
    result.write_text(json.dumps(result_document(outcome, job)), encoding="utf-8")
    plan = plan_active(load_active_calibration(result), job)
    turned = turned_about_bit(listed_waypoints(job), job.rod.rod_line(), 30.0)
    np.testing.assert_array_equal(plan.waypoints, np.vstack([spin, turned]))
    used = {row.index: (row.du_mm / 1e3, row.dv_mm / 1e3) for row in outcome.result.residuals if row.used}
    for index in used:  # a pose visited twice (the spin's 30 deg turn is waypoint 0 turned): either visit's
        same = np.flatnonzero(np.abs(plan.waypoints - plan.waypoints[index]).max(axis=1) < 1e-6)
        assert any(np.allclose(plan.reference[index], used[k]) for k in same if k in used), index
