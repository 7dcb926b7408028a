"""The agreement test of two scanners that saw the rod at the same waypoints: agreeing poses
pass at about the stated false-alarm rate, a scanner moved 3 mm fails, the robot's position
error (common to both centres) does not matter, and too few shared waypoints say so; and the
scanner-to-scanner transform with the shared centres used jointly: smaller std, still honest."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.agreement import MIN_SHARED_WAYPOINTS, SharedCentre, agreement_test
from lasercal_hw.calibration.pairs import joint_relative_pose, pose_difference, relative_pose
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, rotvec_to_matrix

T_A = make_transform(euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])), np.array([0.30, 0.50, 0.20]))
T_B = make_transform(euler_zyx_to_matrix(*np.radians([45.0, -6.0, 5.0])), np.array([-0.45, -0.40, 0.30]))
CENTRE_STD_M = 0.0003
POSE_COVARIANCE = np.diag([1e-6] * 3 + [np.radians(0.05) ** 2] * 3)


def _crossing(T: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(u, v) where the line crosses the scanner's plane."""
    normal, point = T[:3, 2], T[:3, 3]
    s = normal @ (point - origin) / (normal @ direction)
    local = T[:3, :3].T @ (origin + s * direction - point)
    return local[:2]


def _shared(rng: np.random.Generator, count: int, T_b_seen: np.ndarray = T_B, robot_error_m: float = 0.0):
    """``count`` nearly vertical rod lines between the two scanners, centres with noise; the
    rod is where the robot's error puts it (the same for both scanners)."""
    shared = []
    for k in range(count):
        origin = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1), 0.0]) + robot_error_m
        direction = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.0])
        direction /= np.linalg.norm(direction)
        noise = np.eye(2) * CENTRE_STD_M**2
        shared.append(SharedCentre(
            f"a {k}",
            _crossing(T_A, origin, direction) + rng.normal(0.0, CENTRE_STD_M, 2), noise,
            _crossing(T_b_seen, origin, direction) + rng.normal(0.0, CENTRE_STD_M, 2), noise,
            direction,
        ))
    return shared


def test_agreeing_poses_agree_at_about_the_stated_rate() -> None:
    rng = np.random.default_rng(1)
    verdicts = [agreement_test(T_A, POSE_COVARIANCE, T_B, POSE_COVARIANCE, _shared(rng, 6))["verdict"]
                for _ in range(200)]
    assert verdicts.count("disagree") <= 8  # 1 % expected; the pose covariance makes it rarer


def test_a_scanner_moved_3_mm_disagrees() -> None:
    rng = np.random.default_rng(2)
    moved = T_B.copy()
    moved[:3, 3] += [0.003, 0.0, 0.0]
    tight = POSE_COVARIANCE / 100.0
    result = agreement_test(T_A, tight, T_B, tight, _shared(rng, 6, T_b_seen=moved))
    assert result["verdict"] == "disagree" and result["chi_square"] > result["threshold"], result
    assert 1.0 < result["rms_across_rod_mm"] < 4.0


def test_the_robots_position_error_drops_out() -> None:
    rng = np.random.default_rng(3)
    tight = POSE_COVARIANCE / 100.0
    result = agreement_test(T_A, tight, T_B, tight, _shared(rng, 6, robot_error_m=0.01))
    assert result["verdict"] == "agree", result


def test_too_few_shared_waypoints_are_inconclusive() -> None:
    rng = np.random.default_rng(4)
    few = _shared(rng, MIN_SHARED_WAYPOINTS - 1)
    result = agreement_test(T_A, POSE_COVARIANCE, T_B, POSE_COVARIANCE, few)
    assert result["verdict"] == "inconclusive" and result["chi_square"] is None
    assert result["reason"].startswith(f"{MIN_SHARED_WAYPOINTS - 1} waypoints seen by both")


def _sampled(rng: np.random.Generator, T: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """A pose estimate: ``T`` moved by a draw from ``covariance`` (left perturbation)."""
    delta = rng.multivariate_normal(np.zeros(6), covariance)
    return make_transform(rotvec_to_matrix(delta[3:]) @ T[:3, :3], T[:3, 3] + delta[:3])


def test_the_shared_centres_used_jointly_shrink_the_transforms_std_and_keep_it_honest() -> None:
    """Over 100 draws of the two poses' estimates (each from its covariance) and of the shared
    centres' noise: the joint T_a_b's squared Mahalanobis error averages its 6 dof (honest std),
    and its std are below the independent ones, clearly so across the rod."""
    rng = np.random.default_rng(5)
    truth = np.linalg.inv(T_A) @ T_B
    squared, shrink = [], []
    for _ in range(100):
        estimate_a, estimate_b = _sampled(rng, T_A, POSE_COVARIANCE), _sampled(rng, T_B, POSE_COVARIANCE)
        T_ab, covariance = joint_relative_pose(
            estimate_a, POSE_COVARIANCE, estimate_b, POSE_COVARIANCE, _shared(rng, 8)
        )
        _, independent = relative_pose(estimate_a, POSE_COVARIANCE, estimate_b, POSE_COVARIANCE)
        error = pose_difference(T_ab, truth)
        squared.append(float(error @ np.linalg.solve(covariance, error)))
        shrink.append(np.sqrt(np.diag(covariance) / np.diag(independent)))
    assert 4.8 < np.mean(squared) < 7.2, np.mean(squared)
    ratio = np.median(shrink, axis=0)
    assert np.all(ratio <= 1.0 + 1e-9) and ratio.min() < 0.6, ratio
