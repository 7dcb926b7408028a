"""Forward and closed-form inverse kinematics of a UR5 (CB3), in the controller's frames.

DH parameters: Universal Robots' published table for the UR5 CB3 ("UR5 serie 3"),
Table B.4 of the CB3 user manual appendix "Robot DH Parameter" and UR's support article
"DH parameters for calculations of kinematics and dynamics"
(https://www.universal-robots.com/articles/ur/application-installation/dh-parameters-for-calculations-of-kinematics-and-dynamics/):
``d1 = 0.089159, a2 = -0.425, a3 = -0.39225, d4 = 0.10915, d5 = 0.09465, d6 = 0.0823``,
``alpha = (pi/2, 0, 0, pi/2, -pi/2, 0)``, standard (distal) DH:
``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``.

Base frame: the DH frame 0 of that table *is* the controller's Base frame, i.e. what
``actual_TCP_pose`` is expressed in (with a zero TCP offset the TCP is the flange frame
``tool0``). ROS' ur_description documents its ``base`` frame as "the frame used by the
robot controller", rotated 180 degrees about z from the REP-103 ``base_link`` (which
points along the arm at q = 0); the arm at q = 0 therefore points along -x of the
controller's base, as the DH table gives: q = 0 puts the flange at
``(a2 + a3, -(d4 + d6), d1 - d5) = (-0.81725, -0.19145, -0.005491)`` m, the value UR's
own DH spreadsheet produces (see tests/test_ur5_kinematics.py for the reference pairs).
No extra 180 degree rotation is applied here.

The inverse kinematics is the usual closed-form solution for the UR's geometry (joint 1,
then the wrist joints 5 and 6, then the planar 2-3-4 chain): up to 8 branches
(shoulder left/right x wrist up/down x elbow up/down). Every candidate is checked by
forward kinematics before it is returned, so a branch that a near-singular pose makes
inaccurate is dropped rather than returned wrong.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lasercal_hw.geometry import invert_transform, pose_to_matrix, rotation_angle_rad

FloatArray = NDArray[np.float64]

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class DHParameters:
    """Standard DH parameters of a 6-joint arm (metres, radians), joint 1 first."""

    d_m: tuple[float, float, float, float, float, float]
    a_m: tuple[float, float, float, float, float, float]
    alpha_rad: tuple[float, float, float, float, float, float]


UR5_DH = DHParameters(
    d_m=(0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823),
    a_m=(0.0, -0.425, -0.39225, 0.0, 0.0, 0.0),
    alpha_rad=(np.pi / 2.0, 0.0, 0.0, np.pi / 2.0, -np.pi / 2.0, 0.0),
)

#: Joint position limits (rad), one row ``(min, max)`` per joint: +-360 deg on every UR5 joint.
JOINT_LIMITS_RAD: FloatArray = np.array([[-TWO_PI, TWO_PI]] * 6)

#: Maximum joint speeds (rad/s) of the UR5 CB3: 180 deg/s on every joint (UR5 technical
#: specification; ur_description's UR5 joint_limits.yaml uses the same value).
JOINT_SPEED_LIMITS_RAD_S: FloatArray = np.full(6, np.pi)

#: Maximum TCP speed of the UR5 CB3 from its technical specification (m/s).
TOOL_SPEED_LIMIT_M_S = 1.0

# A candidate solution must reproduce the target this closely to be returned.
_POSITION_TOLERANCE_M = 1e-6
_ROTATION_TOLERANCE_RAD = 1e-6
# acos/asin arguments this far outside [-1, 1] are rounding, not unreachability.
_DOMAIN_SLACK = 1e-9
# Below this |sin(theta5)| the wrist is singular: joints 2, 3, 4 and 6 turn about
# parallel axes and theta6 is free (taken from q_near, or 0).
_WRIST_SINGULAR_SIN = 1e-7


def _link_transforms(theta: ArrayLike, d_m: ArrayLike, a_m: ArrayLike, alpha_rad: ArrayLike) -> FloatArray:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (..., 4, 4), broadcasting over all arguments."""
    theta, d, a, alpha = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (theta, d_m, a_m, alpha_rad))
    )
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    zero = np.zeros_like(theta)
    one = np.ones_like(theta)
    rows = [
        np.stack([ct, -st * ca, st * sa, a * ct], axis=-1),
        np.stack([st, ct * ca, -ct * sa, a * st], axis=-1),
        np.stack([zero, sa, ca, d], axis=-1),
        np.stack([zero, zero, zero, one], axis=-1),
    ]
    return np.stack(rows, axis=-2)


def _dh_transforms(theta: FloatArray, dh: DHParameters) -> FloatArray:
    """Link transforms (..., 6, 4, 4) for joint angles (..., 6)."""
    return _link_transforms(theta, dh.d_m, dh.a_m, dh.alpha_rad)


def _tcp_matrix(tcp_offset_pose: ArrayLike | None) -> FloatArray | None:
    return None if tcp_offset_pose is None else pose_to_matrix(np.asarray(tcp_offset_pose, dtype=float))


def forward_kinematics(
    q_rad: ArrayLike, *, tcp_offset_pose: ArrayLike | None = None, dh: DHParameters = UR5_DH
) -> FloatArray:
    """Base-to-flange (``tool0``) transforms (..., 4, 4) for joint angles (..., 6).

    With ``tcp_offset_pose`` (a UR pose vector of the TCP in the flange frame, as
    ``set_tcp`` takes it) the result is base-to-TCP, i.e. what ``actual_TCP_pose`` reports.
    """
    q = np.asarray(q_rad, dtype=float)
    if q.shape[-1:] != (6,):
        raise ValueError(f"joint vector must have 6 entries, got shape {q.shape}")
    links = _dh_transforms(q, dh)
    transform = links[..., 0, :, :]
    for i in range(1, 6):
        transform = transform @ links[..., i, :, :]
    tcp = _tcp_matrix(tcp_offset_pose)
    return transform if tcp is None else transform @ tcp


def _wrap_pi(angle: FloatArray) -> FloatArray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % TWO_PI - np.pi


def _safe_acos(x: float) -> float | None:
    if abs(x) > 1.0 + _DOMAIN_SLACK:
        return None
    return float(np.arccos(np.clip(x, -1.0, 1.0)))


def _single_link(theta: float, i: int, dh: DHParameters) -> FloatArray:
    return _link_transforms(theta, dh.d_m[i], dh.a_m[i], dh.alpha_rad[i])


def _candidate_solutions(flange: FloatArray, theta6_free: float, dh: DHParameters) -> list[FloatArray]:
    """All closed-form candidates (unchecked) for one base-to-flange transform."""
    d4, d6 = dh.d_m[3], dh.d_m[5]
    a2, a3 = dh.a_m[1], dh.a_m[2]
    rot, pos = flange[:3, :3], flange[:3, 3]
    wrist = pos - d6 * rot[:, 2]  # origin of frame 5 (centre of wrist 2 / wrist 3 axes)
    radius_xy = float(np.hypot(wrist[0], wrist[1]))
    if radius_xy < abs(d4) * (1.0 - _DOMAIN_SLACK) or radius_xy == 0.0:
        return []
    phi = _safe_acos(d4 / radius_xy)
    if phi is None:
        return []
    psi = float(np.arctan2(wrist[1], wrist[0]))
    base_to_6 = invert_transform(flange)  # axes of frame 0 seen from frame 6
    candidates: list[FloatArray] = []
    for theta1 in (psi + phi + np.pi / 2.0, psi - phi + np.pi / 2.0):
        s1, c1 = np.sin(theta1), np.cos(theta1)
        # The tool z axis splits into its part along joint 2's axis (cos theta5) and its
        # part in the arm's plane (|sin theta5|); atan2 keeps theta5 accurate near 0 and pi.
        tool_z = rot[:, 2]
        cos5 = tool_z[0] * s1 - tool_z[1] * c1
        sin5_abs = np.hypot(tool_z[0] * c1 + tool_z[1] * s1, tool_z[2])
        for theta5 in (float(np.arctan2(sin5_abs, cos5)), float(np.arctan2(-sin5_abs, cos5))):
            s5 = np.sin(theta5)
            if abs(s5) < _WRIST_SINGULAR_SIN:
                theta6 = theta6_free
            else:
                sign = np.sign(s5)
                theta6 = float(
                    np.arctan2(
                        sign * (-base_to_6[1, 0] * s1 + base_to_6[1, 1] * c1),
                        sign * (base_to_6[0, 0] * s1 - base_to_6[0, 1] * c1),
                    )
                )
            t14 = (
                invert_transform(_single_link(theta1, 0, dh))
                @ flange
                @ invert_transform(_single_link(theta6, 5, dh))
                @ invert_transform(_single_link(theta5, 4, dh))
            )
            # Joints 2 and 3 turn about z1: a planar two-link arm in the x1-y1 plane.
            p14 = t14[:3, 3]
            reach_sq = p14[0] ** 2 + p14[1] ** 2
            acos3 = _safe_acos(float((reach_sq - a2**2 - a3**2) / (2.0 * a2 * a3)))
            if acos3 is None:
                continue
            for theta3 in (acos3, -acos3):
                theta2 = float(
                    np.arctan2(p14[1], p14[0]) - np.arctan2(a3 * np.sin(theta3), a2 + a3 * np.cos(theta3))
                )
                t34 = (
                    invert_transform(_single_link(theta3, 2, dh))
                    @ invert_transform(_single_link(theta2, 1, dh))
                    @ t14
                )
                theta4 = float(np.arctan2(t34[1, 0], t34[0, 0]))
                candidates.append(np.array([theta1, theta2, theta3, theta4, theta5, theta6]))
    return candidates


def _reproduces(q: FloatArray, flange: FloatArray, dh: DHParameters) -> bool:
    reached = forward_kinematics(q, dh=dh)
    position_error = float(np.linalg.norm(reached[:3, 3] - flange[:3, 3]))
    rotation_error = float(rotation_angle_rad(reached[:3, :3].T @ flange[:3, :3]))
    return position_error <= _POSITION_TOLERANCE_M and rotation_error <= _ROTATION_TOLERANCE_RAD


def _flange_target(T_base_tcp: ArrayLike, tcp_offset_pose: ArrayLike | None) -> FloatArray:
    target = np.asarray(T_base_tcp, dtype=float)
    if target.shape != (4, 4):
        raise ValueError(f"target must be one 4x4 transform, got shape {target.shape}")
    tcp = _tcp_matrix(tcp_offset_pose)
    return target if tcp is None else target @ invert_transform(tcp)


def inverse_kinematics_all(
    T_base_tcp: ArrayLike,
    *,
    tcp_offset_pose: ArrayLike | None = None,
    theta6_if_singular_rad: float = 0.0,
    dh: DHParameters = UR5_DH,
) -> FloatArray:
    """Every distinct closed-form solution (k, 6), k <= 8, angles in [-pi, pi).

    Returns an empty (0, 6) array when the pose is out of reach. At the wrist singularity
    (theta5 = 0) theta6 is set to ``theta6_if_singular_rad`` and the rest follows.
    """
    flange = _flange_target(T_base_tcp, tcp_offset_pose)
    solutions: list[FloatArray] = []
    for candidate in _candidate_solutions(flange, theta6_if_singular_rad, dh):
        q = _wrap_pi(candidate)
        if not np.all(np.isfinite(q)) or not _reproduces(q, flange, dh):
            continue
        if all(np.max(np.abs(_wrap_pi(q - other))) > 1e-9 for other in solutions):
            solutions.append(q)
    return np.array(solutions).reshape(-1, 6)


def _nearest_representation(q: FloatArray, q_near: FloatArray, limits_rad: FloatArray) -> FloatArray | None:
    """Shift each joint by whole turns to come closest to ``q_near`` inside the limits."""
    shifted = q + TWO_PI * np.round((q_near - q) / TWO_PI)
    # If the closest turn falls outside a limit, try the neighbouring turns.
    result = np.empty(6)
    for j in range(6):
        options = shifted[j] + TWO_PI * np.array([0.0, -1.0, 1.0])
        inside = options[(options >= limits_rad[j, 0] - 1e-12) & (options <= limits_rad[j, 1] + 1e-12)]
        if inside.size == 0:
            return None
        result[j] = inside[np.argmin(np.abs(inside - q_near[j]))]
    return result


def inverse_kinematics(
    T_base_tcp: ArrayLike,
    q_near: ArrayLike | None = None,
    *,
    tcp_offset_pose: ArrayLike | None = None,
    limits_rad: ArrayLike = JOINT_LIMITS_RAD,
    dh: DHParameters = UR5_DH,
) -> FloatArray | None:
    """The solution closest to ``q_near`` (joint space, Euclidean), or None if unreachable.

    Each joint is placed on the turn (angle + k * 2 pi) nearest to ``q_near`` that lies
    inside ``limits_rad``; ``q_near`` defaults to all zeros.
    """
    near = np.zeros(6) if q_near is None else np.asarray(q_near, dtype=float)
    limits = np.asarray(limits_rad, dtype=float)
    best: FloatArray | None = None
    best_distance = np.inf
    for q in inverse_kinematics_all(
        T_base_tcp, tcp_offset_pose=tcp_offset_pose, theta6_if_singular_rad=float(near[5]), dh=dh
    ):
        placed = _nearest_representation(q, near, limits)
        if placed is None:
            continue
        distance = float(np.linalg.norm(placed - near))
        if distance < best_distance:
            best, best_distance = placed, distance
    return best


def inverse_kinematics_pose(
    tcp_pose: ArrayLike, q_near: ArrayLike | None = None, *, tcp_offset_pose: ArrayLike | None = None
) -> FloatArray | None:
    """:func:`inverse_kinematics` for a UR pose vector ``[x, y, z, rx, ry, rz]``."""
    return inverse_kinematics(pose_to_matrix(tcp_pose), q_near, tcp_offset_pose=tcp_offset_pose)
