"""Preflight checks: reachability via any IK callable, safety limits, workspace box."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from lasercal_hw.config import WorkspaceConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import RodLine
from lasercal_hw.ur_kinematics import inverse_kinematics_pose
from trajectories.checks import check_waypoints, require_waypoints_ok
from trajectories.waypoint import Waypoint

DOWN = (math.pi, 0.0, 0.0)


def wp(index: int, x: float, y: float, z: float, label: str = "") -> Waypoint:
    return Waypoint(index=index, tcp_pose=(x, y, z, *DOWN), label=label)


def test_reachable_waypoints_inside_the_box_pass_and_keep_joint_solutions() -> None:
    waypoints = [wp(0, 0.45, -0.2, 0.35), wp(1, 0.5, 0.1, 0.4)]
    report = check_waypoints(waypoints, inverse_kinematics=inverse_kinematics_pose)
    assert report.ok, report.summary()
    assert sorted(report.joint_solutions_rad) == [0, 1]
    assert "all 2 waypoints" in report.summary()


def test_every_failure_is_listed_with_its_reason() -> None:
    waypoints = [
        wp(0, 0.45, -0.2, 0.35),
        wp(1, 1.6, 0.0, 0.35, "too far"),  # outside box and out of reach
        wp(2, 0.45, -0.2, -0.15, "under the table"),  # below the box floor
        wp(3, 0.5, 0.1, 0.4),
    ]
    report = check_waypoints(waypoints, inverse_kinematics=inverse_kinematics_pose)
    assert not report.ok
    assert report.failing_indices == [1, 2]
    reasons = [str(p) for p in report.problems]
    assert "waypoint 1 (too far): TCP x = 1.600 m is above the workspace maximum 0.950 m" in reasons
    assert "waypoint 1 (too far): not reachable: no inverse kinematics solution" in reasons
    assert any(r.startswith("waypoint 2 (under the table): TCP z = -0.150 m is below") for r in reasons)


def test_rod_ends_are_checked_against_the_box() -> None:
    # TCP at 0.15 m pointing down with a 0.3 m rod: the rod end is 0.15 m under the table.
    waypoints = [wp(0, 0.45, -0.2, 0.15)]
    assert check_waypoints(waypoints, inverse_kinematics=inverse_kinematics_pose).ok
    report = check_waypoints(waypoints, inverse_kinematics=inverse_kinematics_pose, rod=RodLine())
    assert [str(p) for p in report.problems] == [
        "waypoint 0: rod end z = -0.150 m is below the workspace minimum -0.100 m"
    ]


def test_a_custom_box_and_safety_callable_are_used() -> None:
    waypoints = [wp(0, 0.45, -0.2, 0.35), wp(1, 0.5, 0.1, 0.4)]
    box = WorkspaceConfig(min_m=(0.0, -0.5, 0.0), max_m=(0.48, 0.5, 0.8))
    report = check_waypoints(
        waypoints,
        inverse_kinematics=inverse_kinematics_pose,
        within_safety_limits=lambda pose: pose[1] < 0.0,  # a "controller" that forbids y >= 0
        workspace=box,
    )
    assert [str(p) for p in report.problems] == [
        "waypoint 1: TCP x = 0.500 m is above the workspace maximum 0.480 m",
        "waypoint 1: outside the robot's safety limits",
    ]


def test_ik_callable_receives_the_pose_vector() -> None:
    seen: list[np.ndarray] = []

    def robot_ik(pose: np.ndarray) -> list[float]:
        seen.append(pose)
        return [0.0] * 6

    check_waypoints([wp(4, 0.45, -0.2, 0.35)], inverse_kinematics=robot_ik)
    np.testing.assert_allclose(seen[0], [0.45, -0.2, 0.35, *DOWN])


def test_empty_ik_answer_counts_as_unreachable() -> None:
    # ur_rtde's getInverseKinematics returns an empty list when there is no solution.
    report = check_waypoints([wp(0, 0.45, -0.2, 0.35)], inverse_kinematics=lambda pose: [])
    assert report.failing_indices == [0]


def test_duplicate_indices_are_reported() -> None:
    report = check_waypoints(
        [wp(0, 0.45, -0.2, 0.35), wp(0, 0.5, 0.1, 0.4)], inverse_kinematics=inverse_kinematics_pose
    )
    assert [str(p) for p in report.problems] == ["waypoint 0: duplicate waypoint index"]


def test_require_raises_config_error_listing_all_failures() -> None:
    waypoints = [wp(0, 1.6, 0.0, 0.35), wp(1, 0.45, -0.2, 0.35), wp(2, 0.45, -0.2, 1.2)]
    with pytest.raises(ConfigError) as caught:
        require_waypoints_ok(waypoints, inverse_kinematics=inverse_kinematics_pose)
    message = str(caught.value)
    assert "2 of 3 waypoints fail" in message
    assert "waypoint 0:" in message and "waypoint 2:" in message and "waypoint 1:" not in message
    report = require_waypoints_ok(waypoints[1:2], inverse_kinematics=inverse_kinematics_pose)
    assert report.ok


def test_workspace_box_must_be_ordered() -> None:
    with pytest.raises(ValidationError, match=r"z: min 0\.5 m must be below max 0\.2 m"):
        WorkspaceConfig(min_m=(0.0, 0.0, 0.5), max_m=(1.0, 1.0, 0.2))
