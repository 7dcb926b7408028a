"""Scanner-to-scanner transforms of a cell, with their covariance.

Each scanner's ``T_base_laser`` comes with a 6x6 covariance of (tx, ty, tz [m], rotation
about the base x, y, z [rad]; the left perturbation ``R' = exp([e]x) R``, as in
``result.json``). The transform from scanner ``a`` to scanner ``b`` is
``T_a_b = inv(T_base_a) T_base_b``; its covariance, in the same convention about ``a``'s
axes, follows to first order from the two poses' covariances taken as independent (each
scanner is solved from its own waypoints; the robot's repeatable kinematic error, shared by
both, is not in either covariance). Where both scanners saw the rod at the same waypoints
(and agree there), ``joint_relative_pose`` uses those centres jointly with the two poses.
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.agreement import SharedCentre, shared_residuals
from lasercal_hw.geometry import invert_transform, make_transform, matrix_to_rotvec, rotvec_to_matrix
from lasercal_hw.models import FloatArray

_STEP = 1e-7
#: Gauss-Newton steps of the joint refinement (the poses move by millimetres: two suffice).
_JOINT_ITERATIONS = 5


def pose_difference(T_estimate: FloatArray, T_reference: FloatArray) -> FloatArray:
    """(dt [m], rotation [rad]) with ``T_estimate = [exp(rot) R_ref, t_ref + dt]``."""
    estimate, reference = np.asarray(T_estimate, dtype=float), np.asarray(T_reference, dtype=float)
    rotation = matrix_to_rotvec(estimate[:3, :3] @ reference[:3, :3].T)
    return np.concatenate([estimate[:3, 3] - reference[:3, 3], rotation])


def _perturbed(T: FloatArray, delta: FloatArray) -> FloatArray:
    return make_transform(rotvec_to_matrix(delta[3:]) @ T[:3, :3], T[:3, 3] + delta[:3])


def _independent(covariance_a: FloatArray, covariance_b: FloatArray) -> FloatArray:
    """The 12x12 covariance of (a's pose, b's pose), the two independent."""
    joint = np.zeros((12, 12))
    joint[:6, :6] = np.asarray(covariance_a, dtype=float)
    joint[6:, 6:] = np.asarray(covariance_b, dtype=float)
    return joint


def relative_pose_of(
    T_base_a: FloatArray, T_base_b: FloatArray, joint: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``T_a_b`` and its 6x6 covariance (translation in ``a``'s frame, rotation about ``a``'s
    axes) from the 12x12 covariance ``joint`` of the two poses."""
    T_a, T_b = np.asarray(T_base_a, dtype=float), np.asarray(T_base_b, dtype=float)
    T_ab = invert_transform(T_a) @ T_b
    jacobian = np.zeros((6, 12))
    for column in range(12):
        delta = np.zeros(12)
        delta[column] = _STEP
        moved = invert_transform(_perturbed(T_a, delta[:6])) @ _perturbed(T_b, delta[6:])
        jacobian[:, column] = pose_difference(moved, T_ab) / _STEP
    covariance = jacobian @ np.asarray(joint, dtype=float) @ jacobian.T
    return T_ab, 0.5 * (covariance + covariance.T)


def relative_pose(
    T_base_a: FloatArray, covariance_a: FloatArray, T_base_b: FloatArray, covariance_b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``T_a_b`` and its 6x6 covariance, the two poses' errors independent."""
    return relative_pose_of(T_base_a, T_base_b, _independent(covariance_a, covariance_b))


def joint_relative_pose(
    T_base_a: FloatArray, covariance_a: FloatArray, T_base_b: FloatArray, covariance_b: FloatArray,
    shared: list[SharedCentre],
) -> tuple[FloatArray, FloatArray]:
    """``T_a_b`` and its covariance with the shared waypoints used jointly: the two poses
    (each its solve's estimate and covariance, a prior) refined together so that the two
    centres of every shared waypoint lie on one rod line (their difference across the rod,
    ``agreement.shared_residuals``, weighted with the centres' covariance), by Gauss-Newton;
    the refined poses' 12x12 covariance correlates them, and ``T_a_b``'s follows from it."""
    T_a, T_b = np.asarray(T_base_a, dtype=float), np.asarray(T_base_b, dtype=float)
    prior_information = np.linalg.inv(_independent(covariance_a, covariance_b))
    x = np.zeros(12)
    information = prior_information
    for _ in range(_JOINT_ITERATIONS):
        residual, noise, jacobian_a, jacobian_b = shared_residuals(
            _perturbed(T_a, x[:6]), _perturbed(T_b, x[6:]), shared
        )
        jacobian = np.hstack([jacobian_a, jacobian_b])
        weighted = np.linalg.solve(noise, jacobian)
        information = prior_information + jacobian.T @ weighted
        step = -np.linalg.solve(information, prior_information @ x + weighted.T @ residual)
        x = x + step
        if np.max(np.abs(step)) < 1e-10:
            break
    return relative_pose_of(_perturbed(T_a, x[:6]), _perturbed(T_b, x[6:]), np.linalg.inv(information))


def error_in_std(T_estimate: FloatArray, covariance: FloatArray, T_truth: FloatArray) -> dict[str, float]:
    """How far an estimate is from the truth: in mm and deg, per axis in its own std (the
    largest of the six), and the Mahalanobis distance over all six (chi-square, 6 dof)."""
    error = pose_difference(T_estimate, T_truth)
    covariance = np.asarray(covariance, dtype=float)
    std = np.sqrt(np.clip(np.diag(covariance), 1e-30, None))
    return {
        "translation_mm": 1000.0 * float(np.linalg.norm(error[:3])),
        "rotation_deg": float(np.degrees(np.linalg.norm(error[3:]))),
        "max_axis_in_std": float(np.max(np.abs(error) / std)),
        "mahalanobis": float(np.sqrt(error @ np.linalg.solve(covariance, error))),
    }
