"""The measurement model: Jacobian, whitening and Fisher information."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.model import (
    fisher_information,
    left_jacobian_so3,
    plane_crossing,
    residuals_and_jacobian,
    rod_lines_in_base,
    whitening,
)
from lasercal_hw.geometry import rotvec_to_matrix
from lasercal_hw.models import RodLine
from tests.calibration.test_solver_helpers import TRUTH, observations


def _lines() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    obs = observations(points=12)
    poses = np.array([o.tcp_pose for o in obs])
    centres = np.array([o.centre_uv_m for o in obs])
    origins, directions = rod_lines_in_base(poses, RodLine())
    return origins, directions, centres


def test_crossing_lies_on_rod_and_in_scan_plane() -> None:
    origins, directions, _ = _lines()
    rotation, translation = TRUTH[:3, :3], TRUTH[:3, 3]
    crossing, _, s = plane_crossing(rotation, translation, origins, directions)
    in_base = np.column_stack([crossing, np.zeros(len(crossing))]) @ rotation.T + translation
    np.testing.assert_allclose(in_base, origins + s[:, None] * directions, atol=1e-12)


def test_jacobian_matches_finite_differences_of_the_perturbation() -> None:
    origins, directions, centres = _lines()
    rotation, translation = TRUTH[:3, :3], TRUTH[:3, 3]
    residual, jac, _ = residuals_and_jacobian(rotation, translation, origins, directions, centres)
    step = 1e-7
    for k in range(6):
        delta = np.zeros(6)
        delta[k] = step
        moved, _, _ = residuals_and_jacobian(
            rotvec_to_matrix(delta[3:]) @ rotation, translation + delta[:3], origins, directions, centres
        )
        np.testing.assert_allclose((moved - residual) / step, jac[:, :, k], atol=1e-5)


def test_left_jacobian_composes_rotation_vectors() -> None:
    phi = np.array([0.4, -0.7, 0.2])
    d = np.array([1e-6, 2e-6, -1.5e-6])
    lhs = rotvec_to_matrix(phi + d)
    rhs = rotvec_to_matrix(left_jacobian_so3(phi) @ d) @ rotvec_to_matrix(phi)
    np.testing.assert_allclose(lhs, rhs, atol=1e-11)


def test_whitening_inverts_covariance() -> None:
    covariance = np.array([[[4.0, 1.2], [1.2, 2.0]], [[1e-4, 0.0], [0.0, 4e-4]]])
    white = whitening(covariance)
    for w, c in zip(white, covariance, strict=True):
        np.testing.assert_allclose(w.T @ w, np.linalg.inv(c), rtol=1e-12)


def test_fisher_information_scales_with_noise_variance() -> None:
    origins, directions, _ = _lines()
    cov = np.broadcast_to(np.eye(2) * 1e-4, (len(origins), 2, 2))
    f1 = fisher_information(TRUTH[:3, :3], TRUTH[:3, 3], origins, directions, cov, 0.0)
    f4 = fisher_information(TRUTH[:3, :3], TRUTH[:3, 3], origins, directions, 4 * cov, 0.0)
    np.testing.assert_allclose(f1, 4 * f4, rtol=1e-12)
    more_robot_noise = fisher_information(TRUTH[:3, :3], TRUTH[:3, 3], origins, directions, cov, 0.01)
    assert np.trace(np.linalg.inv(more_robot_noise)) > np.trace(np.linalg.inv(f1))
