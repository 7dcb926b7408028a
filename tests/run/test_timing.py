"""The visit's estimate, part by part, against a timeline built here from the fake UR's own
motion profiles (``fakes/ur_controller/motion``, UR's movej/movel) and the run's sequence:
joint move to the retract pose, background, then move, settle margin, dwell and the scan
that closes the window at every waypoint."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.ur_controller.motion import JointPath, TrapezoidProfile
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.run.timing import HOME_POSTURE_RAD, SCAN_PERIOD_S, visit_time_s, visit_timeline
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.ur_kinematics import inverse_kinematics_pose

RETRACT = [0.45, 0.10, 0.55, np.pi, 0.0, 0.0]


def _job(**changes: object) -> JobConfig:
    return job_from_mapping({"dwell_s": 2.0, "background": {"pose": RETRACT, "scans": 40}, **changes})


def _joint_move_s(job: JobConfig, start_rad: np.ndarray, target_rad: np.ndarray) -> float:
    """How long the fake UR's movej from ``start_rad`` to ``target_rad`` lasts."""
    motion = job.motion
    path = JointPath(start_rad, target_rad)
    return TrapezoidProfile(path.length, motion.joint_speed_rad_s, motion.joint_accel_rad_s2).duration_s


def _joint_targets(poses: np.ndarray, near_rad: np.ndarray) -> list[np.ndarray]:
    """Each pose's solution nearest the one before, as the preflight chains them."""
    targets = []
    for pose in poses:
        q = inverse_kinematics_pose(pose, near_rad)
        assert q is not None
        targets.append(q)
        near_rad = q
    return targets


def test_the_visit_starts_with_the_joint_move_from_home_to_the_retract_pose() -> None:
    job = _job()
    poses = job_waypoints(job)[:4]
    retract_rad, *waypoints_rad = _joint_targets(np.vstack([RETRACT, poses]), HOME_POSTURE_RAD)

    timeline = visit_timeline(job, poses)

    assert timeline is not None
    assert timeline.to_retract_s == pytest.approx(_joint_move_s(job, HOME_POSTURE_RAD, retract_rad))
    assert timeline.to_retract_s > 1.0  # a UR5 at home is far from any retract pose
    starts = [retract_rad, *waypoints_rad[:-1]]
    expected_moves_s = [_joint_move_s(job, a, b) for a, b in zip(starts, waypoints_rad, strict=True)]
    assert timeline.moves_s == pytest.approx(expected_moves_s)


def test_an_arm_already_at_the_retract_pose_does_not_move_there() -> None:
    job = _job()
    retract_rad = inverse_kinematics_pose(np.array(RETRACT), HOME_POSTURE_RAD)
    assert retract_rad is not None

    timeline = visit_timeline(job, job_waypoints(job)[:2], start_rad=retract_rad)

    assert timeline is not None
    assert timeline.to_retract_s == pytest.approx(0.0, abs=1e-6)


def test_background_and_dwells_last_until_the_scan_after_them_is_delivered() -> None:
    """The background: the settle margin, then 40 scans from the first one begun after it (half
    a period later on average), the last delivered when complete. A dwell: the margin, the
    window, then the first scan begun after the window, delivered a period after it began."""
    job = _job()
    timeline = visit_timeline(job, job_waypoints(job)[:3])

    assert timeline is not None
    margin_s = job.settle.margin_s
    assert timeline.background_s == pytest.approx(margin_s + 0.5 * SCAN_PERIOD_S + 40 * SCAN_PERIOD_S)
    assert timeline.dwell_each_s == pytest.approx(margin_s + 2.0 + 0.5 * SCAN_PERIOD_S + SCAN_PERIOD_S)


def test_the_visit_time_is_every_part_of_the_timeline() -> None:
    """Home to the retract pose, the background, every move and every dwell: 20 waypoints of
    the paper preset, as a dry run visits them."""
    job = _job()
    poses = job_waypoints(job)
    retract_rad, *waypoints_rad = _joint_targets(np.vstack([RETRACT, poses]), HOME_POSTURE_RAD)
    starts = [retract_rad, *waypoints_rad[:-1]]
    moves_s = sum(_joint_move_s(job, a, b) for a, b in zip(starts, waypoints_rad, strict=True))
    background_s = job.settle.margin_s + 40.5 * SCAN_PERIOD_S
    dwells_s = len(poses) * (job.settle.margin_s + job.dwell_s + 1.5 * SCAN_PERIOD_S)
    to_retract_s = _joint_move_s(job, HOME_POSTURE_RAD, retract_rad)

    assert visit_time_s(job, poses) == pytest.approx(to_retract_s + background_s + moves_s + dwells_s)


def test_linear_moves_last_as_the_tool_path_profile() -> None:
    """``motion.move = "linear"``: movel's trapezoid over the tool's path at the tool's caps
    (the move to the retract pose stays a joint move)."""
    job = _job(motion={"move": "linear", "speed_m_s": 0.1, "accel_m_s2": 0.3})
    poses = job_waypoints(job)[:3]

    timeline = visit_timeline(job, poses)

    assert timeline is not None
    starts = np.vstack([RETRACT, poses[:-1]])
    lengths_m = np.linalg.norm(poses[:, :3] - starts[:, :3], axis=1)
    expected_s = [TrapezoidProfile(length, 0.1, 0.3).duration_s for length in lengths_m]
    assert timeline.moves_s == pytest.approx(expected_s)
