"""How long visiting a list of waypoints takes (motion plus dwell), estimated before the
arm moves: the verify chooses waypoints that fit its time budget by it, and a run's
time-left estimate uses it until the arm has made its first move.

Joint moves (the default ``motion.move``) last as long as the largest joint's trapezoid
profile at the job's joint speed and acceleration caps; joint targets are the UR5 inverse
kinematics solutions nearest the previous target, from the retract pose's solution nearest
the UR home posture (the preflight solves near the arm's joints at that time, which an
estimate made beforehand cannot know). Add the background
scans, and per waypoint the settle margin and the dwell. An estimate, used to compare
subsets with each other and with the calibration's own trajectory.
"""

from __future__ import annotations

import math

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.models import FloatArray
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.ur_kinematics import inverse_kinematics_pose

HOME_POSTURE_RAD = np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
SCAN_PERIOD_S = 0.025


def joint_move_s(distance_rad: float, speed_rad_s: float, accel_rad_s2: float) -> float:
    """Duration of a trapezoidal (or triangular) profile over ``distance_rad``."""
    ramp_rad = speed_rad_s**2 / accel_rad_s2
    if distance_rad <= ramp_rad:
        return 2.0 * math.sqrt(distance_rad / accel_rad_s2)
    return distance_rad / speed_rad_s + speed_rad_s / accel_rad_s2


def move_times_s(job: JobConfig, poses: FloatArray) -> list[float] | None:
    """Each joint move's duration: from the retract pose to the first pose, then pose to pose;
    None when the UR5 model cannot reach a pose."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    reachable = (inverse_kinematics_pose(c, HOME_POSTURE_RAD) for c in retract_candidates(job, poses))
    current = next((q for q in reachable if q is not None), None)
    if current is None:
        return None
    motion = job.motion
    durations_s = []
    for pose in poses:  # each target the solution nearest the last, as the preflight solves
        target = inverse_kinematics_pose(pose, current)
        if target is None:
            return None
        distance = float(np.max(np.abs(target - current)))
        durations_s.append(joint_move_s(distance, motion.joint_speed_rad_s, motion.joint_accel_rad_s2))
        current = target
    return durations_s


def visit_time_s(job: JobConfig, poses: FloatArray) -> float | None:
    """Background, then each pose in order; None when the UR5 model cannot reach a pose."""
    moves_s = move_times_s(job, poses)
    if moves_s is None:
        return None
    per_waypoint_s = job.settle.margin_s + job.dwell_s
    return job.background.scans * SCAN_PERIOD_S + sum(moves_s) + len(moves_s) * per_waypoint_s
