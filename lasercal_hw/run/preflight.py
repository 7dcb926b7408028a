"""Checks before the first motion: the devices are who they say and ready, and every pose
the run will visit is reachable, allowed by the controller's safety limits and inside the
workspace box. Every problem is listed at once, so one fix-and-retry round is enough."""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from lasercal_hw.config import WorkspaceConfig
from lasercal_hw.errors import ConfigError, RobotError
from lasercal_hw.geometry import pose_to_matrix, transform_points
from lasercal_hw.models import FloatArray, RobotIdentity, RodLine, ScannerIdentity
from lasercal_hw.run.devices import Robot, Scanner
from trajectories.checks import check_pose

logger = logging.getLogger(__name__)

_READY_ROBOT_MODE = "RUNNING"
_READY_SAFETY_STATUS = "NORMAL"


@dataclass(frozen=True)
class PreflightReport:
    """What preflight found: device identities and one joint solution per pose."""

    robot: RobotIdentity
    scanner: ScannerIdentity
    joint_solutions_rad: list[FloatArray]


def rod_end_points_m(pose: FloatArray, rod: RodLine) -> FloatArray:
    """The rod's two ends in the base frame (2, 3) for a TCP pose."""
    return transform_points(pose_to_matrix(pose)[None], rod.end_points_m())


def check_robot_state(robot: Robot) -> list[str]:
    """Problems that keep the robot from moving under our control (empty when ready)."""
    state = robot.state()
    problems = []
    if state.emergency_stop:
        problems.append("robot: emergency stop is pressed; release it and re-enable the arm")
    if state.protective_stop:
        problems.append("robot: protective stop is active; clear it on the teach pendant")
    if state.robot_mode.upper() != _READY_ROBOT_MODE:
        problems.append(
            f"robot: mode is {state.robot_mode}, needs {_READY_ROBOT_MODE} (power on and release the brakes)"
        )
    if state.safety_status.upper() != _READY_SAFETY_STATUS:
        problems.append(f"robot: safety status is {state.safety_status}, needs {_READY_SAFETY_STATUS}")
    if not state.remote_control:
        problems.append("robot: not in remote control; switch the teach pendant to Remote Control")
    return problems


def check_poses(
    robot: Robot,
    poses: dict[str, FloatArray],
    rod: RodLine,
    workspace: WorkspaceConfig,
) -> tuple[list[str], list[FloatArray]]:
    """Problems with the named poses (``trajectories.checks.check_pose`` against the
    controller), and each pose's joint solution (empty when unreachable): the first nearest
    the arm's present joints, each next one nearest the one before, so that consecutive
    joint moves stay on one branch and are short (solved each near the start posture, the
    base of a UR5 turned 313 deg between two neighbouring waypoints of the quick preset)."""
    problems: list[str] = []
    solutions: list[FloatArray] = []
    previous: FloatArray | None = None
    for name, pose in poses.items():
        reasons, q = check_pose(
            pose,
            inverse_kinematics=functools.partial(robot.inverse_kinematics, q_near_rad=previous),
            within_safety_limits=robot.is_within_safety_limits,
            workspace=workspace,
            rod=rod,
        )
        problems += [f"{name}: {reason}" for reason in reasons]
        solutions.append(q if q is not None else np.empty(0))
        previous = q if q is not None else previous
    return problems, solutions


def is_clear(robot: Robot, pose: FloatArray, rod: RodLine, workspace: WorkspaceConfig) -> bool:
    """Whether ``pose`` passes every pose check (``check_poses``)."""
    problems, _ = check_poses(robot, {"candidate": pose}, rod, workspace)
    return not problems


def first_clear_pose(
    robot: Robot, candidates: list[FloatArray], rod: RodLine, workspace: WorkspaceConfig
) -> FloatArray | None:
    """The first candidate pose that passes every pose check, or None."""
    return next((pose for pose in candidates if is_clear(robot, pose, rod, workspace)), None)


def run_preflight(
    robot: Robot,
    scanner: Scanner,
    poses: dict[str, FloatArray],
    rod: RodLine,
    workspace: WorkspaceConfig,
) -> PreflightReport:
    """Check the devices and every pose; raise one error that lists every problem.

    Device problems raise ``RobotError`` (exit code 3); pose problems alone raise
    ``ConfigError`` (exit code 2: change the trajectory or the workspace box).
    """
    robot_identity = robot.identity()
    scanner_identity = scanner.identity()
    logger.info("robot %s, scanner %s %s", robot_identity, scanner_identity.product, scanner_identity.serial)
    device_problems = check_robot_state(robot)
    pose_problems, solutions = check_poses(robot, poses, rod, workspace)
    problems = device_problems + pose_problems
    if problems:
        message = f"preflight found {len(problems)} problem(s), nothing moved:\n  " + "\n  ".join(problems)
        raise (RobotError if device_problems else ConfigError)(message)
    return PreflightReport(robot_identity, scanner_identity, solutions)

