"""The sequencer end to end against the simulated robot and scanner (tests/doubles.py)."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.calibration.consensus import CONSENSUS_WAYPOINTS
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import (
    ConfigError,
    DeviceError,
    InterruptedRunError,
    ProtectiveStopError,
    RobotError,
)
from lasercal_hw.geometry import matrix_to_euler_zyx
from lasercal_hw.models import RobotState
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.preflight import rod_end_points_m
from lasercal_hw.run.records import Progress, ResumeState
from lasercal_hw.run.replay import solve_recording
from lasercal_hw.run.resume import resume_state
from lasercal_hw.run.retract import NOMINAL_CLEARANCE_M, background_lift_m
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.doubles import (
    PAPER_T_BASE_LASER,
    MemoryRecorder,
    PacedRobot,
    SimClock,
    SimRobot,
    SimScanner,
    run_calibration,
    semicircle_waypoints,
)

FAST_JOB = {"dwell_s": 0.25, "background": {"scans": 10}, "settle": {"margin_s": 0.05}}


def make_cell(job: JobConfig, **robot_options: object) -> tuple[SimClock, SimRobot, SimScanner]:
    clock = SimClock()
    robot = SimRobot(clock, **robot_options)  # type: ignore[arg-type]
    scanner = SimScanner(clock, robot, job.rod.rod_line())
    return clock, robot, scanner


def fast_job(**changes: object) -> JobConfig:
    return job_from_mapping({**FAST_JOB, **changes})


def transform_error(T_estimate: np.ndarray, T_truth: np.ndarray) -> tuple[float, float]:
    translation_mm = 1000.0 * float(np.linalg.norm(T_estimate[:3, 3] - T_truth[:3, 3]))
    relative = T_truth[:3, :3].T @ T_estimate[:3, :3]
    angle_deg = float(np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1))))
    return translation_mm, angle_deg


def test_run_completes_records_and_recovers_the_transform() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    progress: list[Progress] = []
    waypoints = semicircle_waypoints(12)
    outcome = run_calibration(robot, scanner, recorder, job, waypoints, on_progress=progress.append,
                        clock=clock)

    assert [m.index for m in outcome.measurements] == list(range(12))
    assert outcome.skipped == []
    translation_mm, angle_deg = transform_error(outcome.result.matrix(), PAPER_T_BASE_LASER)
    assert translation_mm < 5.0
    assert angle_deg < 0.5
    assert outcome.verdict.passed, outcome.verdict.failures()
    assert "second pass" in outcome.refinement
    # Every waypoint was visited once, after the retract pose for the background.
    assert len(robot.moves) == 13
    assert robot.moves[0][2] == pytest.approx(waypoints[0][2] + job.background_lift_m())
    kinds = recorder.kinds()
    assert kinds.count("dwell_start") == 12 and kinds.count("observation") == 12
    assert kinds[0] == "preflight_ok" and kinds[-1] == "run_end"
    assert [e[2]["pass_number"] for e in recorder.events if e[1] == "solve"] == [1, 2]
    # Only scans acquired after the arm settled were averaged.
    for _, kind, fields in recorder.events:
        if kind == "observation":
            assert fields["window_start_s"] >= _settle_time(robot, fields["index"] + 1)
    assert len(recorder.scans) > 12 * 10
    stages = {p.stage for p in progress}
    assert {"preflight", "background", "move", "dwell", "centre", "solve", "refine", "done"} <= stages
    centre_events = [p for p in progress if p.stage == "centre"]
    assert all(p.scans_averaged and p.scans_averaged >= 9 for p in centre_events)
    # No [scanner.nominal]: nothing to predict from until the first waypoints agree on a pose.
    consensus = CONSENSUS_WAYPOINTS
    assert all(p.expected_uv_m is None for p in centre_events[:consensus])
    assert all(p.expected_uv_m is not None for p in centre_events[consensus:])
    misses_m = [np.hypot(*np.subtract(p.centre_uv_m, p.expected_uv_m)) for p in centre_events[consensus:]]
    assert max(misses_m) < 0.005
    assert progress[-1].time_left_s == pytest.approx(0.0)


def test_centre_progress_says_where_the_nominal_mounting_expected_the_rod() -> None:
    nominal = {"translation_m": [0.30, 0.50, 0.20], "euler_zyx_deg": [5.0, 7.0, 3.0]}  # the truth
    job = fast_job(scanner={"nominal": nominal})
    clock, robot, scanner = make_cell(job)
    progress: list[Progress] = []
    run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(8),
                    on_progress=progress.append, clock=clock)
    centres = [p for p in progress if p.stage == "centre"]
    assert len(centres) == 8 and all(p.expected_uv_m is not None for p in centres)
    # The live page draws these before any solve: the rod's axis crossing, seen within its radius.
    misses_m = [np.hypot(*np.subtract(p.centre_uv_m, p.expected_uv_m)) for p in centres]
    assert max(misses_m) < job.rod.radius_m


def test_a_job_streams_records_and_averages_intensities_unless_it_says_not_to() -> None:
    job = fast_job()  # the default: ME, intensities with the ranges
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, semicircle_waypoints(6), clock=clock)
    assert scanner.with_intensities
    assert recorder.scans and all(s.intensities is not None for s in recorder.scans)
    assert all(m.averaged.intensities is not None for m in outcome.measurements)
    ranges_alone = fast_job(scanner={"intensities": False})
    clock, robot, plain = make_cell(ranges_alone)
    plain_recorder = MemoryRecorder()
    run_calibration(robot, plain, plain_recorder, ranges_alone, semicircle_waypoints(6), clock=clock)
    assert not plain.with_intensities and all(s.intensities is None for s in plain_recorder.scans)


def _settle_time(robot: SimRobot, move_number: int) -> float:
    """End of the robot's ``move_number``-th motion (0 is the retract move)."""
    return robot._path[move_number][1]


def test_scans_taken_while_moving_are_not_averaged() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, semicircle_waypoints(8), clock=clock)
    windows = [f for _, k, f in recorder.events if k == "observation"]
    for fields, measurement in zip(windows, outcome.measurements, strict=True):
        assert measurement.averaged.scan_count == fields["scans"]
    discarded = sum(f["discarded"] for _, k, f in recorder.events if k == "dwell_end")
    assert discarded > 0, "the doubles queue scans during motion; the sequencer must have dropped them"


def test_waypoint_with_rod_out_of_view_is_skipped_with_reason() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    waypoints = semicircle_waypoints(12)
    waypoints[4, 2] += 0.35  # the rod's lower end is now above the scan plane
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, waypoints, clock=clock)
    assert [s.index for s in outcome.skipped] == [4]
    assert outcome.skipped[0].reason
    assert 4 not in [m.index for m in outcome.measurements]
    skipped_events = [f for _, k, f in recorder.events if k == "waypoint_skipped"]
    assert skipped_events == [{"index": 4, "reason": outcome.skipped[0].reason}]


def test_protective_stop_aborts_without_further_motion() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job, protective_stop_at_move=4)
    recorder = MemoryRecorder()
    with pytest.raises(ProtectiveStopError, match="protective stop at waypoint 3") as caught:
        run_calibration(robot, scanner, recorder, job, semicircle_waypoints(12), clock=clock)
    assert "will not resume by itself" in str(caught.value)
    assert len(robot.moves) == 5  # retract + waypoints 0..3; the fourth raised
    assert robot.stops == 0
    abort = [f for _, k, f in recorder.events if k == "abort"]
    assert abort and abort[0]["cause"] == "protective_stop" and abort[0]["index"] == 3
    assert not scanner.streaming


def test_failed_move_during_a_protective_stop_counts_as_one() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job, protective_stop_at_move=2, stop_reported_late=True)
    with pytest.raises(ProtectiveStopError, match="safety status PROTECTIVE_STOP"):
        run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(6), clock=clock)
    assert len(robot.moves) == 3


def test_interrupt_from_progress_stops_the_robot_and_keeps_a_readable_recording(tmp_path: Path) -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    waypoints = semicircle_waypoints(12)

    def interrupt_at_waypoint_5(progress: Progress) -> None:
        if progress.stage == "dwell" and progress.waypoint == 5:
            raise KeyboardInterrupt

    session = tmp_path / "session.mcap"
    recorder = SessionRecorder(session, {"job": job.model_dump(mode="json"), "waypoints": waypoints.tolist()})
    try:
        with pytest.raises(InterruptedRunError, match="waypoint 5"):
            run_calibration(robot, scanner, recorder, job, waypoints, on_progress=interrupt_at_waypoint_5,
                      clock=clock)
    finally:
        recorder.close()
    assert robot.stops == 1
    moves_at_interrupt = len(robot.moves)
    recording = read_session(session)
    assert not recording.truncated
    assert [e["index"] for e in recording.events_of("observation")] == [0, 1, 2, 3, 4]
    assert recording.events_of("abort")[0]["cause"] == "interrupted"
    assert len(recording.scans) > 0

    # Resume: only waypoints 5.. are visited, the earlier ones come from the recording.
    state = resume_state(recording)
    assert sorted(state.finished_indices) == [0, 1, 2, 3, 4]
    robot.moves.clear()
    resumed = SessionRecorder.resume(session)
    try:
        outcome = run_calibration(robot, scanner, resumed, job, waypoints, resume=state, clock=clock)
    finally:
        resumed.close()
    assert len(robot.moves) == 7  # waypoints 5..11, no new background
    assert moves_at_interrupt == 7
    assert [m.index for m in outcome.measurements] == list(range(12))
    assert outcome.resumed_from == 5
    translation_mm, angle_deg = transform_error(outcome.result.matrix(), PAPER_T_BASE_LASER)
    assert translation_mm < 5.0 and angle_deg < 0.5
    final = read_session(session)
    assert [e["index"] for e in final.events_of("observation")] == list(range(12))

    # Offline, the same extraction and two-pass solve on the recording give the live result.
    replay = solve_recording(session)
    np.testing.assert_allclose(replay.solution.result.matrix(), outcome.result.matrix(), rtol=0, atol=1e-12)
    assert replay.solution.refinement == outcome.refinement


def _read_number_in_dwell(waypoint: int) -> int:
    """The scanner read that falls in the middle of ``waypoint``'s dwell in an undisturbed run."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    reads: list[int] = []

    def note(progress: Progress) -> None:
        if progress.stage == "centre" and progress.waypoint == waypoint:
            reads.append(scanner.reads)

    run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(8), on_progress=note,
              clock=clock)
    return reads[0] - 5  # the dwell's last ~10 reads come just before its centre


@pytest.mark.parametrize("fault", ["timeout", "gap"])
def test_scanner_drop_repeats_the_waypoint(fault: str) -> None:
    read = _read_number_in_dwell(3)
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    if fault == "timeout":
        scanner.fail_reads_at = {read}
    else:
        scanner.gap_at_reads = {read}
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, semicircle_waypoints(8), clock=clock)
    retries = [f for _, k, f in recorder.events if k == "waypoint_retry"]
    assert [(r["index"], r["attempt"]) for r in retries] == [(3, 1)]
    assert "scanner" in retries[0]["reason"]
    assert [m.index for m in outcome.measurements] == list(range(8))
    assert len(robot.moves) == 10  # retract, 8 waypoints, waypoint 3 once more


def test_scanner_that_keeps_failing_aborts_with_a_device_error() -> None:
    job = fast_job(acquisition={"max_attempts": 2})
    clock, robot, scanner = make_cell(job)
    scanner.fail_reads_at = set(range(30, 10_000))
    with pytest.raises(DeviceError, match="scanner failed 2 times"):
        run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(8), clock=clock)
    assert robot.stops == 1


def test_preflight_lists_every_problem_and_moves_nothing() -> None:
    job = fast_job(workspace={"min_m": [-0.9, -0.9, 0.0], "max_m": [0.9, 0.9, 1.0]})
    waypoints = semicircle_waypoints(8)
    waypoints[2, :3] = [1.5, 0.0, 0.4]  # unreachable and outside the box
    clock, robot, scanner = make_cell(job, forbidden_poses=[waypoints[5]])
    with pytest.raises(ConfigError) as caught:
        run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, clock=clock)
    message = str(caught.value)
    assert "waypoint 2: not reachable" in message
    assert "waypoint 2: TCP x = 1.500 m is above the workspace maximum 0.900 m" in message
    assert "waypoint 5: outside the robot's safety limits" in message
    assert robot.moves == []


def test_preflight_refuses_a_robot_not_in_remote_control() -> None:
    job = fast_job()
    clock, robot, scanner = make_cell(
        job, state_value=RobotState("IDLE", "PROTECTIVE_STOP", False, False, True, False)
    )
    with pytest.raises(RobotError) as caught:
        run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(8), clock=clock)
    message = str(caught.value)
    for expected in ("protective stop", "mode is IDLE", "safety status is PROTECTIVE_STOP", "remote control"):
        assert expected in message
    assert robot.moves == []


def test_background_pose_falls_back_to_another_lifted_waypoint() -> None:
    job = fast_job()
    waypoints = semicircle_waypoints(8)
    first_lifted = waypoints[0].copy()
    first_lifted[2] += job.background_lift_m()
    clock, robot, scanner = make_cell(job, forbidden_poses=[first_lifted])
    run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, clock=clock)
    nearest = min(range(1, 8), key=lambda i: np.linalg.norm(waypoints[i][:3]))
    expected = waypoints[nearest].copy()
    expected[2] += job.background_lift_m()
    assert np.allclose(robot.moves[0], expected)


def test_nominal_mounting_lifts_the_rod_just_clear_of_the_plane() -> None:
    yaw, pitch, roll = np.degrees(matrix_to_euler_zyx(PAPER_T_BASE_LASER[:3, :3]))
    nominal = {"translation_m": PAPER_T_BASE_LASER[:3, 3].tolist(), "euler_zyx_deg": [yaw, pitch, roll]}
    job = fast_job(scanner={"nominal": nominal})
    pose = semicircle_waypoints(8)[0]
    lift_m = background_lift_m(job, pose)
    assert 0.0 < lift_m < job.background_lift_m()
    lifted = pose.copy()
    lifted[2] += lift_m
    ends = rod_end_points_m(lifted, job.rod.rod_line())
    heights = (ends - PAPER_T_BASE_LASER[:3, 3]) @ PAPER_T_BASE_LASER[:3, 2]
    assert heights.min() == pytest.approx(NOMINAL_CLEARANCE_M)


def test_nominal_pose_predicts_where_to_look() -> None:
    yaw, pitch, roll = np.degrees(matrix_to_euler_zyx(PAPER_T_BASE_LASER[:3, :3]))
    nominal = {"translation_m": [0.32, 0.48, 0.21], "euler_zyx_deg": [yaw, pitch, roll]}
    job = fast_job(scanner={"nominal": nominal})
    clock, robot, scanner = make_cell(job)
    outcome = run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(10), clock=clock)
    assert len(outcome.measurements) == 10
    translation_mm, _ = transform_error(outcome.result.matrix(), PAPER_T_BASE_LASER)
    assert translation_mm < 5.0


def test_the_robots_stated_accuracy_is_in_the_solvers_noise_model() -> None:
    results = {}
    for accuracy_mm in (0.0, 3.0):
        job = fast_job(robot={"position_accuracy_mm": accuracy_mm})
        clock, robot, scanner = make_cell(job)
        waypoints = semicircle_waypoints(12)
        outcome = run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, clock=clock)
        for solved in (outcome.first_pass, outcome.result):
            assert solved.provenance.solver_options["robot_sigma_m"] == pytest.approx(accuracy_mm / 1000.0)
        results[accuracy_mm] = outcome.result
    # A less accurate robot widens the bound of the same waypoints.
    assert results[3.0].crb_translation_mm[2] > 1.5 * results[0.0].crb_translation_mm[2]


def test_cancel_from_another_thread_stops_the_arm_and_keeps_the_recording() -> None:
    """A cancel token (the daemon's cancel request) acts as Ctrl-C does: the arm is told to
    stop at once, the run ends with InterruptedRunError at its next checkpoint, and every
    waypoint measured before it stays in the recording."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    cancel = CancelToken()
    stops_at_cancel: list[int] = []

    def cancel_at_waypoint_3(progress: Progress) -> None:
        if progress.stage == "dwell" and progress.waypoint == 3:
            worker = threading.Thread(target=cancel.cancel, args=("operator pressed cancel",))
            worker.start()
            worker.join()
            stops_at_cancel.append(robot.stops)

    with pytest.raises(InterruptedRunError, match="waypoint 3 \\(operator pressed cancel\\)"):
        run_calibration(robot, scanner, recorder, job, semicircle_waypoints(8),
                        on_progress=cancel_at_waypoint_3, cancel=cancel, clock=clock)
    assert stops_at_cancel == [1]  # stopped by the cancel itself, before the run noticed it
    assert [e["index"] for _, kind, e in recorder.events if kind == "observation"] == [0, 1, 2]
    assert recorder.kinds()[-1] == "abort"


def test_waypoints_go_by_their_names_in_messages_and_by_position_in_the_recording() -> None:
    """Verify visits waypoints 10, 14, 18, 19 of a calibration's trajectory: its progress says so."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    progress: list[Progress] = []
    recorder = MemoryRecorder()
    names = [10, 14, 18, 19, 21, 23]
    run_calibration(robot, scanner, recorder, job, semicircle_waypoints(6), on_progress=progress.append,
                    clock=clock, waypoint_names=names)
    moves = [p.message for p in progress if p.stage == "move"]
    assert moves[0] == "moving to waypoint 10 (1 of 6)" and moves[-1] == "moving to waypoint 23 (6 of 6)"
    assert any(p.message.startswith("waypoint 14: rod at") for p in progress if p.stage == "centre")
    assert [fields["index"] for _, kind, fields in recorder.events if kind == "dwell_start"] == list(range(6))


def test_time_left_is_the_planned_visit_before_the_arm_has_moved() -> None:
    """Until the first move the time left is the whole planned visit: the move to the retract
    pose, the background and every waypoint (``run.timing``)."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    progress: list[Progress] = []
    waypoints = semicircle_waypoints(6)
    run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, on_progress=progress.append,
                    clock=clock)

    first = progress[0]
    planned_s = visit_time_s(job, waypoints)
    assert planned_s is not None
    assert first.completed == 0
    assert first.time_left_s == pytest.approx(planned_s, rel=1e-6)


def test_time_left_keeps_to_a_robot_slower_than_planned() -> None:
    """A robot whose every move takes twice the UR trapezoid (a speed slider at 50 %): from
    the first move on, the time left is the moves ahead at the pace the moves so far set, the
    background and the dwells, so it tells what is really left at every step, through the
    background and with a waypoint's move counted until the arm is there and not after."""
    job = fast_job()
    clock = SimClock()
    robot = PacedRobot(clock, slowdown=2.0)
    scanner = SimScanner(clock, robot, job.rod.rod_line())
    seen: list[tuple[float, Progress]] = []
    run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(6),
                    on_progress=lambda p: seen.append((clock(), p)), clock=clock)

    end_s = next(t for t, p in seen if p.stage == "solve")
    moved = [(t, p) for t, p in seen if t > seen[0][0] and t < end_s]
    assert [p.stage for _, p in moved][:2] == ["background", "move"]  # from the background on
    for t, p in moved:
        assert p.time_left_s == pytest.approx(end_s - t, rel=0.03, abs=0.1), p.message


IkAsk = tuple[np.ndarray, np.ndarray | None]


def _record_inverse_kinematics(robot: SimRobot) -> tuple[list[IkAsk], Callable[..., np.ndarray | None]]:
    """Every (pose, q_near) the robot's inverse kinematics is asked from now on, and the solver."""
    asked: list[IkAsk] = []
    solve = robot.inverse_kinematics

    def recording_ik(pose: np.ndarray, q_near_rad: np.ndarray | None = None) -> np.ndarray | None:
        asked.append((np.asarray(pose, dtype=float), q_near_rad))
        return solve(pose, q_near_rad)

    robot.inverse_kinematics = recording_ik  # type: ignore[method-assign]
    return asked, solve


def test_preflight_solves_each_pose_nearest_the_one_before() -> None:
    """Consecutive joint moves stay short: the retract pose is solved near the arm's present
    joints, every waypoint near the solution before it, in the order they are visited."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    asked, solve = _record_inverse_kinematics(robot)
    waypoints = semicircle_waypoints(6)
    run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, clock=clock)

    start = next(i for i, (pose, _) in enumerate(asked) if np.allclose(pose, waypoints[0])) - 1
    chain = asked[start : start + 1 + len(waypoints)]  # the preflight's retract, then every waypoint
    assert chain[0][1] is None
    for (previous_pose, _), (_, near) in itertools.pairwise(chain):
        assert near is not None and np.allclose(near, solve(previous_pose))
    assert [pose.tolist() for pose, _ in chain[1:]] == waypoints.tolist()


def test_a_resumed_run_chains_its_joint_targets_from_where_the_arm_is() -> None:
    """An adaptive run's second part (or a run resumed with its background) moves from where the
    arm stopped to the next waypoint: that one is solved nearest the arm's present joints and the
    rest after it, not through the finished waypoints' chain from the retract pose, which can
    land the next move on another branch (an adaptive dry run: 6.7 s moves where 3.3 s did)."""
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    waypoints = semicircle_waypoints(10)
    first = run_calibration(robot, scanner, MemoryRecorder(), job, waypoints[:6], clock=clock)
    asked, solve = _record_inverse_kinematics(robot)
    resume = ResumeState(first.measurements, first.skipped, first.background)
    run_calibration(robot, scanner, MemoryRecorder(), job, waypoints, resume=resume, clock=clock)

    start = next(i for i, (pose, _) in enumerate(asked) if np.allclose(pose, waypoints[6]))
    chain = asked[start : start + 4]  # the preflight's waypoints 6..9, in the order visited
    assert [pose.tolist() for pose, _ in chain] == waypoints[6:].tolist()
    assert chain[0][1] is None  # nearest the arm's present joints (the robot's own choice)
    for (previous_pose, _), (_, near) in itertools.pairwise(chain):
        assert near is not None and np.allclose(near, solve(previous_pose))
    assert len(robot.moves) == 6 + 1 + 4  # no new background: straight on to waypoint 6


def test_centre_warnings_reach_the_progress_the_recording_and_the_result(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    import lasercal_hw.run.sequencer as sequencer_module
    import lasercal_hw.run.two_pass as two_pass_module
    from lasercal_hw.run.outputs import result_document

    doubt = "the rod's beams blend it with the background behind it"
    real = sequencer_module.find_rod_centre

    def doubtful(*args: object, **kwargs: object) -> object:
        centre = real(*args, **kwargs)  # type: ignore[arg-type]
        return replace(centre, warnings=(doubt,)) if centre.centre_uv_m[0] > 0.0 else centre

    monkeypatch.setattr(sequencer_module, "find_rod_centre", doubtful)
    monkeypatch.setattr(two_pass_module, "find_rod_centre", doubtful)
    job = fast_job()
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    progress: list[Progress] = []
    outcome = run_calibration(robot, scanner, recorder, job, semicircle_waypoints(12),
                              on_progress=progress.append, clock=clock)

    events = recorder.events
    observed = {fields["index"]: fields["warnings"] for _, kind, fields in events if kind == "observation"}
    warned = sorted(index for index, warnings in observed.items() if warnings)
    assert 0 < len(warned) < 12, [f["centre_uv_m"] for _, k, f in events if k == "observation"]
    lines = [p.message for p in progress if p.stage == "centre"]
    assert sum(f"warning: {doubt}" in line for line in lines) == len(warned)
    solved = sorted(index for index, _ in outcome.centre_warnings)
    assert solved and set(solved) <= set(observed)
    assert [e[2]["index"] for e in recorder.events if e[1] == "centre_warning"] == solved
    assert f"{len(solved)} centres carry a warning" in progress[-1].message
    document = result_document(outcome, job)
    assert document["run"]["centre_warnings"] == [{"index": i, "warning": doubt} for i in solved]
