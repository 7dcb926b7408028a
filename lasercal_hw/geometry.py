"""Rigid-body conversions between the representations the product speaks.

Conventions (part of the interface):

* UR pose vector: ``[x, y, z, rx, ry, rz]`` in metres and a rotation vector in radians
  (axis times angle), as ``getActualTCPPose`` returns it.
* 4x4 homogeneous matrices, ``p_a = T_a_b @ p_b``.
* Quaternions in ``(x, y, z, w)`` order (ROS, scipy).
* ZYX Euler angles ``(yaw, pitch, roll)`` with ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``;
  this is the paper's "ZYX" ``[phi, theta, psi]``.

Every function accepts a single value or a stack (leading dimensions) of values.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

_SMALL_ANGLE_RAD = 1e-8


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrices ``[v]x`` of shape (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [
            np.stack([zero, -z, y], axis=-1),
            np.stack([z, zero, -x], axis=-1),
            np.stack([-y, x, zero], axis=-1),
        ],
        axis=-2,
    )


def rotvec_to_matrix(rotvec: ArrayLike) -> FloatArray:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3) by Rodrigues' formula."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    k = skew(rotvec)
    small = angle < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, angle)
    # sin(a)/a and (1-cos(a))/a^2 with their Taylor series near zero.
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a * k + b * (k @ k)


def matrix_to_rotvec(rotation: ArrayLike) -> FloatArray:
    """Rotation vectors (..., 3) with angle in [0, pi] from rotation matrices (..., 3, 3)."""
    return quat_to_rotvec(matrix_to_quat(rotation))


def quat_to_rotvec(quat_xyzw: ArrayLike) -> FloatArray:
    """Rotation vectors from quaternions ``(x, y, z, w)``; the angle is kept in [0, pi]."""
    q = np.asarray(quat_xyzw, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:4] < 0.0, -q, q)
    vec = q[..., :3]
    sin_half = np.linalg.norm(vec, axis=-1)
    angle = 2.0 * np.arctan2(sin_half, q[..., 3])
    small = sin_half < _SMALL_ANGLE_RAD
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, sin_half))
    return vec * scale[..., None]


def rotvec_to_quat(rotvec: ArrayLike) -> FloatArray:
    """Quaternions ``(x, y, z, w)`` with w >= 0 from rotation vectors."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1)
    small = angle < _SMALL_ANGLE_RAD
    half_sinc = np.where(small, 0.5 - angle**2 / 48.0, np.sin(angle / 2.0) / np.where(small, 1.0, angle))
    return np.concatenate([rotvec * half_sinc[..., None], np.cos(angle / 2.0)[..., None]], axis=-1)


def quat_to_matrix(quat_xyzw: ArrayLike) -> FloatArray:
    """Rotation matrices from quaternions ``(x, y, z, w)`` (normalised first)."""
    q = np.asarray(quat_xyzw, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def matrix_to_quat(rotation: ArrayLike) -> FloatArray:
    """Quaternions ``(x, y, z, w)`` with w >= 0 from rotation matrices (Shepperd's method)."""
    m = np.asarray(rotation, dtype=float)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Four candidate solutions; pick the numerically largest denominator per matrix.
    candidates = np.stack(
        [
            np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                      m[..., 1, 0] - m[..., 0, 1], 1.0 + trace], -1),
            np.stack([1.0 + 2 * m[..., 0, 0] - trace, m[..., 0, 1] + m[..., 1, 0],
                      m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] - m[..., 1, 2]], -1),
            np.stack([m[..., 0, 1] + m[..., 1, 0], 1.0 + 2 * m[..., 1, 1] - trace,
                      m[..., 1, 2] + m[..., 2, 1], m[..., 0, 2] - m[..., 2, 0]], -1),
            np.stack([m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
                      1.0 + 2 * m[..., 2, 2] - trace, m[..., 1, 0] - m[..., 0, 1]], -1),
        ],
        axis=-2,
    )
    pivots = np.stack([trace, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.argmax(pivots, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def euler_zyx_to_matrix(yaw_rad: ArrayLike, pitch_rad: ArrayLike, roll_rad: ArrayLike) -> FloatArray:
    """``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (the paper's ZYX convention)."""
    cz, sz = np.cos(yaw_rad), np.sin(yaw_rad)
    cy, sy = np.cos(pitch_rad), np.sin(pitch_rad)
    cx, sx = np.cos(roll_rad), np.sin(roll_rad)
    return np.stack(
        [
            np.stack([cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx], -1),
            np.stack([sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx], -1),
            np.stack([-sy, cy * sx, cy * cx], -1),
        ],
        axis=-2,
    )


def matrix_to_euler_zyx(rotation: ArrayLike) -> FloatArray:
    """``(yaw, pitch, roll)`` in radians with pitch in [-pi/2, pi/2]; inverse of the above.

    At gimbal lock (``|pitch| = pi/2``) roll is set to zero and yaw takes the whole angle.
    """
    m = np.asarray(rotation, dtype=float)
    cos_pitch = np.hypot(m[..., 0, 0], m[..., 1, 0])
    # atan2, not arcsin: arcsin loses half the digits near pitch = +-pi/2 (1e-8 at 1e-8 rad).
    pitch = np.arctan2(-m[..., 2, 0], cos_pitch)
    locked = cos_pitch < 1e-9
    yaw = np.where(locked, np.arctan2(-m[..., 0, 1], m[..., 1, 1]), np.arctan2(m[..., 1, 0], m[..., 0, 0]))
    roll = np.where(locked, 0.0, np.arctan2(m[..., 2, 1], m[..., 2, 2]))
    return np.stack([yaw, pitch, roll], axis=-1)


def make_transform(rotation: ArrayLike, translation_m: ArrayLike) -> FloatArray:
    """4x4 (or stacked) homogeneous transforms from rotations and translations."""
    rotation = np.asarray(rotation, dtype=float)
    translation_m = np.asarray(translation_m, dtype=float)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation_m.shape[:-1])
    transform = np.zeros((*shape, 4, 4))
    transform[..., :3, :3] = rotation
    transform[..., :3, 3] = translation_m
    transform[..., 3, 3] = 1.0
    return transform


def invert_transform(transform: ArrayLike) -> FloatArray:
    """Inverse of rigid transforms without a general matrix inverse."""
    t = np.asarray(transform, dtype=float)
    rot_t = np.swapaxes(t[..., :3, :3], -1, -2)
    return make_transform(rot_t, -(rot_t @ t[..., :3, 3:4])[..., 0])


def pose_to_matrix(pose: ArrayLike) -> FloatArray:
    """4x4 transforms from UR pose vectors ``[x, y, z, rx, ry, rz]``."""
    pose = np.asarray(pose, dtype=float)
    return make_transform(rotvec_to_matrix(pose[..., 3:6]), pose[..., 0:3])


def matrix_to_pose(transform: ArrayLike) -> FloatArray:
    """UR pose vectors from 4x4 transforms."""
    t = np.asarray(transform, dtype=float)
    return np.concatenate([t[..., :3, 3], matrix_to_rotvec(t[..., :3, :3])], axis=-1)


def transform_points(transform: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply transforms (..., 4, 4) to points (..., 3)."""
    t = np.asarray(transform, dtype=float)
    p = np.asarray(points, dtype=float)
    return (t[..., :3, :3] @ p[..., None])[..., 0] + t[..., :3, 3]


def rotation_angle_rad(rotation: ArrayLike) -> FloatArray:
    """Angle of rotations (..., 3, 3), in [0, pi]; the geodesic distance to identity."""
    return np.linalg.norm(matrix_to_rotvec(rotation), axis=-1)
