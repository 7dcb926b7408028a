"""The simulated paper protocol and the Monte Carlo bookkeeping."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.simulate import (
    Protocol,
    crb_covariance,
    metric_table,
    paper_ground_truth,
    pose_errors,
    protocol_tcp_poses,
    simulate_observations,
)
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, pose_to_matrix
from lasercal_hw.models import RodLine


def test_ground_truth_is_the_papers() -> None:
    truth = paper_ground_truth()
    np.testing.assert_allclose(truth[:3, 3], [0.30, 0.50, 0.20])
    np.testing.assert_allclose(truth[:3, :3], euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])))


def test_protocol_poses_follow_the_circle_height_and_tilt_limits() -> None:
    protocol = Protocol()
    tcp = pose_to_matrix(protocol_tcp_poses(protocol, np.random.default_rng(4)))
    assert len(tcp) == 75
    np.testing.assert_allclose(np.linalg.norm(tcp[:, :2, 3], axis=1), 0.8)
    assert tcp[:, 2, 3].min() >= 0.45 and tcp[:, 2, 3].max() <= 0.65
    tool_z = tcp[:, :3, 2]
    assert (tool_z[:, 2] < 0).all()  # pointing down
    tilt_deg = np.degrees(np.arccos(-tool_z[:, 2]))
    assert tilt_deg.max() <= np.degrees(np.arccos(np.cos(np.radians(20.0)) ** 2)) + 1e-9
    assert tilt_deg.max() > 15.0


def test_rods_cross_the_plane_in_their_positive_direction_near_the_circle() -> None:
    truth = paper_ground_truth()
    obs, poses = simulate_observations(truth, RodLine(), Protocol(), np.random.default_rng(5))
    origins, directions = rod_lines_in_base(poses, RodLine())
    crossing, _, s = plane_crossing(truth[:3, :3], truth[:3, 3], origins, directions)
    assert (s > 0).all()
    in_base = np.column_stack([crossing, np.zeros(len(s))]) @ truth[:3, :3].T + truth[:3, 3]
    assert np.abs(np.linalg.norm(in_base[:, :2], axis=1) - 0.8).max() < 0.3
    noise = np.array([o.centre_uv_m for o in obs]) - crossing
    assert 0.005 < noise.std() < 0.015


def test_pose_errors_are_zyx_differences_in_roll_pitch_yaw_order() -> None:
    truth = paper_ground_truth()
    yaw, pitch, roll = np.radians([5.0, 7.0, 3.0])
    estimate = make_transform(euler_zyx_to_matrix(yaw + 0.01, pitch - 0.02, roll + 0.03), [0.301, 0.5, 0.198])
    errors = pose_errors(truth, estimate)
    np.testing.assert_allclose(errors, [-1.0, 0.0, 2.0, *np.degrees([-0.03, 0.02, -0.01])], atol=1e-9)
    table = metric_table(errors[None])
    np.testing.assert_allclose(table[0, 3], np.sqrt(5.0))


def test_crb_covariance_is_positive_definite_and_z_is_weakest() -> None:
    protocol = Protocol()
    truth = paper_ground_truth()
    poses = protocol_tcp_poses(protocol, np.random.default_rng(6))
    crb = crb_covariance(truth, poses, RodLine(), protocol)
    assert np.all(np.linalg.eigvalsh(crb) > 0)
    std = np.sqrt(np.diag(crb))
    assert std[2] > std[0] and std[2] > std[1]
