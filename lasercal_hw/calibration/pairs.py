"""Scanner-to-scanner transforms of a cell, with their covariance.

Each scanner's ``T_base_laser`` comes with a 6x6 covariance of (tx, ty, tz [m], rotation
about the base x, y, z [rad]; the left perturbation ``R' = exp([e]x) R``, as in
``result.json``). The transform from scanner ``a`` to scanner ``b`` is
``T_a_b = inv(T_base_a) T_base_b``; its covariance, in the same convention about ``a``'s
axes, follows to first order from the two poses' covariances taken as independent (each
scanner is solved from its own waypoints; the robot's repeatable kinematic error, shared by
both, is not in either covariance).
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.geometry import invert_transform, make_transform, matrix_to_rotvec, rotvec_to_matrix
from lasercal_hw.models import FloatArray

_STEP = 1e-7


def pose_difference(T_estimate: FloatArray, T_reference: FloatArray) -> FloatArray:
    """(dt [m], rotation [rad]) with ``T_estimate = [exp(rot) R_ref, t_ref + dt]``."""
    estimate, reference = np.asarray(T_estimate, dtype=float), np.asarray(T_reference, dtype=float)
    rotation = matrix_to_rotvec(estimate[:3, :3] @ reference[:3, :3].T)
    return np.concatenate([estimate[:3, 3] - reference[:3, 3], rotation])


def _perturbed(T: FloatArray, delta: FloatArray) -> FloatArray:
    return make_transform(rotvec_to_matrix(delta[3:]) @ T[:3, :3], T[:3, 3] + delta[:3])


def relative_pose(
    T_base_a: FloatArray, covariance_a: FloatArray, T_base_b: FloatArray, covariance_b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``T_a_b`` and its 6x6 covariance (translation in ``a``'s frame, rotation about ``a``'s
    axes), the two poses' errors independent."""
    T_a, T_b = np.asarray(T_base_a, dtype=float), np.asarray(T_base_b, dtype=float)
    T_ab = invert_transform(T_a) @ T_b
    jacobian = np.zeros((6, 12))
    for column in range(12):
        delta = np.zeros(12)
        delta[column] = _STEP
        moved = invert_transform(_perturbed(T_a, delta[:6])) @ _perturbed(T_b, delta[6:])
        jacobian[:, column] = pose_difference(moved, T_ab) / _STEP
    joint = np.zeros((12, 12))
    joint[:6, :6] = np.asarray(covariance_a, dtype=float)
    joint[6:, 6:] = np.asarray(covariance_b, dtype=float)
    covariance = jacobian @ joint @ jacobian.T
    return T_ab, 0.5 * (covariance + covariance.T)


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
