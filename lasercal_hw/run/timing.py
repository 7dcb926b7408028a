"""How long visiting a list of waypoints takes (motion plus dwell, as ``Timings`` counts
them), estimated before the arm moves: the verify chooses waypoints that fit its time
budget by it, and a running visit's time left starts from it (``run.time_left``).

The timeline follows the run (``run/sequencer``) part by part:

- a joint move from the arm's joints at the start (the UR home posture unless given: an
  estimate made beforehand cannot know where the arm will be) to the retract pose, solved
  nearest them as the preflight does;
- the background: the settle margin, then ``background.scans`` scans from the first one
  acquired after it, the last one delivered a scan period after it began;
- each move to the next pose (the retract pose's solution first), then per waypoint the
  settle margin, the dwell and the scan that ends the dwell's window: the first acquired
  after it, on average half a period after the window's end, delivered once it is complete.

Moves follow UR's profiles (ur_rtde's moveJ and URScript's movej take the speed and
acceleration "of leading axis": a trapezoid of the joint that moves most; movel: of the tool's
path length at the tool's speed and acceleration) at the job's caps; joint targets are the UR5
inverse kinematics solutions nearest the previous target, as the preflight solves them. Not
counted: what is neither motion nor dwell (connecting, the preflight, the extraction) and
each move's command round trip and end detection, about 4 ms of ``Timings`` per move against
the fake UR (0.2 % of a 2.5 s move).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.geometry import pose_to_matrix, rotation_angle_rad
from lasercal_hw.models import FloatArray
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.ur_kinematics import inverse_kinematics_pose, move_duration_s

HOME_POSTURE_RAD = np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
SCAN_PERIOD_S = 0.025
#: A linear move shorter than this is a pure rotation, its length the angle (rad).
_PURE_ROTATION_M = 1e-6


@dataclass(frozen=True)
class VisitTimeline:
    """A visit's estimated motion and dwell, by part (seconds)."""

    #: The joint move from the arm's start to the retract pose.
    to_retract_s: float
    #: Settle margin and background scans at the retract pose.
    background_s: float
    #: Each move: from the retract pose to the first pose, then pose to pose.
    moves_s: tuple[float, ...]
    #: Settle margin, dwell and the scan that ends it, at every waypoint.
    dwell_each_s: float

    @property
    def total_s(self) -> float:
        """The whole visit."""
        waypoints_s = sum(self.moves_s) + len(self.moves_s) * self.dwell_each_s
        return self.to_retract_s + self.background_s + waypoints_s


def background_s(job: JobConfig) -> float:
    """Settle margin and ``background.scans`` scans, the last delivered a period after it began."""
    return job.settle.margin_s + (job.background.scans + 0.5) * SCAN_PERIOD_S


def dwell_each_s(job: JobConfig) -> float:
    """Settle margin, dwell, then the first scan after the window: half a period on average
    until it begins, one period until it is delivered."""
    return job.settle.margin_s + job.dwell_s + 1.5 * SCAN_PERIOD_S


def _joint_move_s(job: JobConfig, start_rad: FloatArray, target_rad: FloatArray) -> float:
    motion = job.motion
    distance_rad = float(np.max(np.abs(target_rad - start_rad)))
    return move_duration_s(distance_rad, motion.joint_speed_rad_s, motion.joint_accel_rad_s2)


def _linear_move_s(job: JobConfig, start: FloatArray, target: FloatArray) -> float:
    motion = job.motion
    start_matrix, target_matrix = pose_to_matrix(start), pose_to_matrix(target)
    length = float(np.linalg.norm(target_matrix[:3, 3] - start_matrix[:3, 3]))
    if length <= _PURE_ROTATION_M:
        length = float(rotation_angle_rad(start_matrix[:3, :3].T @ target_matrix[:3, :3]))
    return move_duration_s(length, motion.speed_m_s, motion.accel_m_s2)


def visit_timeline(
    job: JobConfig, poses: FloatArray, start_rad: FloatArray = HOME_POSTURE_RAD
) -> VisitTimeline | None:
    """The visit of ``poses`` in order by an arm at joints ``start_rad``; None when the UR5
    model cannot reach a pose."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    start_rad = np.asarray(start_rad, dtype=float)
    retract_pose, current = next(
        ((pose, q) for pose in retract_candidates(job, poses)
         if (q := inverse_kinematics_pose(pose, start_rad)) is not None),
        (None, None),
    )
    if retract_pose is None or current is None:
        return None
    to_retract_s = _joint_move_s(job, start_rad, current)  # the background is reached in joint space
    linear = job.motion.move == "linear"
    previous_pose = retract_pose
    moves_s = []
    for pose in poses:  # each target the solution nearest the last, as the preflight solves
        target = inverse_kinematics_pose(pose, current)
        if target is None:
            return None
        move_s = _linear_move_s(job, previous_pose, pose) if linear else _joint_move_s(job, current, target)
        moves_s.append(move_s)
        current, previous_pose = target, pose
    return VisitTimeline(to_retract_s, background_s(job), tuple(moves_s), dwell_each_s(job))


def visit_time_s(job: JobConfig, poses: FloatArray) -> float | None:
    """The whole visit of ``poses`` from the UR home posture (``visit_timeline``); None when
    the UR5 model cannot reach a pose."""
    timeline = visit_timeline(job, poses)
    return None if timeline is None else timeline.total_s
