"""The dry run's centres judged against the rod's true crossing, waypoint by waypoint."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.dry_run_accuracy import world_with
from benchmarks.waypoint_errors import waypoint_errors
from fakes.scene import load_scene
from lasercal_hw.config import load_job
from lasercal_hw.models import Observation
from lasercal_hw.run.two_pass import predict_rod
from lasercal_hw.run.waypoints import job_waypoints


def test_a_centre_reads_its_offset_from_the_crossing_along_and_across_the_bearing() -> None:
    job = load_job(None)
    rod = job.rod.rod_line()
    exact_robot = {"robot_position_error_m": 0.0, "robot_rotation_error_deg": 0.0}
    world = world_with(load_scene(None), rod, 1000, **exact_robot)
    pose = job_waypoints(job)[3]
    crossing = predict_rod(world.ground_truth_T_base_laser, pose, rod).expected_uv_m
    bearing = crossing / np.linalg.norm(crossing)
    side = np.array([-bearing[1], bearing[0]])
    centre = crossing + 0.002 * bearing - 0.001 * side
    covariance = np.diag([0.0005, 0.002]) ** 2  # u, v: a bearing at an angle sees a mix of both
    (row,) = waypoint_errors([Observation(3, pose, centre, covariance)], world, rod)
    assert row.index == 3
    assert row.range_m == pytest.approx(np.linalg.norm(crossing))
    np.testing.assert_allclose(row.error_m, [0.002, -0.001], atol=1e-9)
    expected_std = np.sqrt([bearing @ covariance @ bearing, side @ covariance @ side])
    np.testing.assert_allclose(row.std_m, expected_std, rtol=1e-12)
