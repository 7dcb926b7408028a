"""Forward and closed-form inverse kinematics of the UR5 (CB3) and UR5e, in the controller's frames.

DH parameters: Universal Robots' published tables, standard (distal) DH
``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` with ``alpha = (pi/2, 0, 0, pi/2, -pi/2, 0)``,
from UR's support article "DH parameters for calculations of kinematics and dynamics"
(https://www.universal-robots.com/articles/ur/application-installation/dh-parameters-for-calculations-of-kinematics-and-dynamics/):

- UR5 CB3 ("UR5 serie 3", also Table B.4 of the CB3 user manual): ``d1 = 0.089159,
  a2 = -0.425, a3 = -0.39225, d4 = 0.10915, d5 = 0.09465, d6 = 0.0823``;
- UR5e: ``d1 = 0.1625, a2 = -0.425, a3 = -0.3922, d4 = 0.1333, d5 = 0.0997, d6 = 0.0996``.

Base frame: the DH frame 0 of those tables *is* the controller's Base frame, i.e. what
``actual_TCP_pose`` is expressed in (with a zero TCP offset the TCP is the flange frame
``tool0``). ROS' ur_description documents its ``base`` frame as "the frame used by the
robot controller", rotated 180 degrees about z from the REP-103 ``base_link`` (which
points along the arm at q = 0); the arm at q = 0 therefore points along -x of the
controller's base, as the DH table gives: q = 0 puts the flange at
``(a2 + a3, -(d4 + d6), d1 - d5)``, for the UR5 ``(-0.81725, -0.19145, -0.005491)`` m, the
value UR's own DH spreadsheet produces (see tests/test_ur_kinematics.py for the reference
pairs). No extra 180 degree rotation is applied here.

The inverse kinematics is the usual closed-form solution for the UR's geometry (joint 1,
then the wrist joints 5 and 6, then the planar 2-3-4 chain), vectorised over poses: up to
8 branches, numbered ``4 * shoulder + 2 * wrist + elbow`` (shoulder 0: theta1 = psi + phi +
pi/2, 1: psi - phi + pi/2; wrist 0: sin(theta5) >= 0, 1: < 0; elbow 0: theta3 >= 0, 1: < 0).
Every candidate is checked by forward kinematics before it is returned, so a branch that
a near-singular pose makes inaccurate is dropped rather than returned wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import invert_transform, pose_to_matrix, rotation_angle_rad
from lasercal_hw.models import RobotCalibration, RobotIdentity

FloatArray = NDArray[np.float64]

TWO_PI = 2.0 * np.pi
#: Number of closed-form IK branches (shoulder x wrist x elbow).
BRANCH_COUNT = 8


@dataclass(frozen=True)
class DHParameters:
    """Standard DH parameters of a 6-joint arm (metres, radians), joint 1 first."""

    d_m: tuple[float, float, float, float, float, float]
    a_m: tuple[float, float, float, float, float, float]
    alpha_rad: tuple[float, float, float, float, float, float]
    #: Joint zero offsets: a robot's own calibration has small ones, the published tables none.
    theta_offset_rad: tuple[float, ...] = (0.0,) * 6


_UR_ALPHA_RAD = (np.pi / 2.0, 0.0, 0.0, np.pi / 2.0, -np.pi / 2.0, 0.0)


@dataclass(frozen=True)
class URModel:
    """One robot model: its DH table and the limits of its technical specification."""

    name: str
    dh: DHParameters
    #: Joint position limits (rad), one row ``(min, max)`` per joint.
    joint_limits_rad: FloatArray
    #: Maximum joint speeds (rad/s).
    joint_speed_limits_rad_s: FloatArray
    #: Maximum TCP speed (m/s).
    tool_speed_limit_m_s: float
    #: The published table the closed-form IK starts from when ``dh`` is a robot's own
    #: calibration (then refined on ``dh``); None: ``dh`` is the published table.
    nominal: DHParameters | None = None
    #: The robot calibration's checksum (``models.RobotCalibration.checksum``) ``dh`` came from.
    calibration_checksum: str | None = None


def _ur_arm(name: str, d_m: tuple[float, ...], a_m: tuple[float, ...]) -> URModel:
    """A UR arm with the limits the UR5 and the UR5e share (their technical specifications;
    ur_description's joint_limits.yaml uses the same values): +-360 deg and 180 deg/s on
    every joint, 1 m/s at the TCP."""
    return URModel(
        name=name,
        dh=DHParameters(d_m=d_m, a_m=a_m, alpha_rad=_UR_ALPHA_RAD),  # type: ignore[arg-type]
        joint_limits_rad=np.array([[-TWO_PI, TWO_PI]] * 6),
        joint_speed_limits_rad_s=np.full(6, np.pi),
        tool_speed_limit_m_s=1.0,
    )


#: UR5 CB3.
UR5 = _ur_arm("ur5", (0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823), (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0))
#: UR5e.
UR5E = _ur_arm("ur5e", (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996), (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0))

#: The models this module knows, by the name a job's ``robot.model`` uses.
MODELS: dict[str, URModel] = {model.name: model for model in (UR5, UR5E)}


def robot_model(name: str) -> URModel:
    """The model called ``name`` (``ur5`` or ``ur5e``, any case), or ConfigError."""
    try:
        return MODELS[name.strip().lower()]
    except KeyError:
        raise ConfigError(
            f"unknown robot model {name!r}; the offline kinematics know {', '.join(MODELS)}"
        ) from None


def model_from_robot_calibration(calibration: RobotCalibration) -> URModel:
    """The kinematics of one robot from its own calibration (its primary interface's DH rows),
    with the limits of the published model whose table is nearest (the closed-form IK starts
    there and is refined on the robot's rows)."""
    rows = {"d_m": calibration.dh_d_m, "a_m": calibration.dh_a_m, "alpha_rad": calibration.dh_alpha_rad}

    def distance(model: URModel) -> float:
        pairs = (zip(values, getattr(model.dh, key), strict=True) for key, values in rows.items())
        return max(abs(v - n) for row in pairs for v, n in row)

    base = min(MODELS.values(), key=distance)
    if distance(base) <= _SAME_TABLE and max(map(abs, calibration.dh_theta_rad)) <= _SAME_TABLE:
        return replace(base, calibration_checksum=calibration.checksum)  # the published table itself
    dh = DHParameters(
        d_m=tuple(rows["d_m"]), a_m=tuple(rows["a_m"]), alpha_rad=tuple(rows["alpha_rad"]),  # type: ignore[arg-type]
        theta_offset_rad=tuple(calibration.dh_theta_rad),
    )
    return replace(base, dh=dh, nominal=base.dh, calibration_checksum=calibration.checksum)


def offline_model(
    calibration: RobotCalibration | None, identity: RobotIdentity | None = None, named: str | None = None
) -> URModel:
    """The kinematics offline design and checks use: the robot's own calibration when it is
    known; else the model a job or option ``named``; else the model the robot reports (UR5 or
    UR5e by its software generation); else the UR5."""
    if calibration is not None:
        return model_from_robot_calibration(calibration)
    if named:
        return robot_model(named)
    if identity is not None and identity.model.strip().lower() in ("ur5", "ur5e"):
        return model_of_controller(identity.model, identity.controller_version)
    return UR5


def model_of_controller(reported_model: str, controller_version: tuple[int, ...]) -> URModel:
    """The model of a connected robot: the dashboard's "get robot model" answer (``UR5``
    on both generations) and the controller's software version (5.x: e-Series)."""
    name = reported_model.strip().lower()
    if name == "ur5" and controller_version and controller_version[0] >= 5:
        name = "ur5e"
    return robot_model(name)


# Newton steps from the published table's IK to a robot's own calibrated rows.
_REFINE_STEPS = 4
_JACOBIAN_STEP_RAD = 1e-7
_DAMPING = 1e-12
# A robot's rows this close to a published table are that table (no refinement needed).
_SAME_TABLE = 1e-12
# A candidate solution must reproduce the target this closely to be returned.
_POSITION_TOLERANCE_M = 1e-6
_ROTATION_TOLERANCE_RAD = 1e-6
# acos/asin arguments this far outside [-1, 1] are rounding, not unreachability.
_DOMAIN_SLACK = 1e-9
# Below this |sin(theta5)| the wrist is singular: joints 2, 3, 4 and 6 turn about
# parallel axes and theta6 is free (taken from q_near, or 0).
_WRIST_SINGULAR_SIN = 1e-7


def _link_transforms(theta: ArrayLike, d_m: ArrayLike, a_m: ArrayLike, alpha_rad: ArrayLike) -> FloatArray:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (..., 4, 4), broadcasting over all arguments.

    Filled in place rather than stacked: half the time for one joint vector (the fake
    controller calls this every 2 ms cycle of a move), the same values.
    """
    theta, d, a, alpha = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (theta, d_m, a_m, alpha_rad))
    )
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    links = np.zeros((*theta.shape, 4, 4))
    links[..., 0, 0], links[..., 0, 1], links[..., 0, 2], links[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    links[..., 1, 0], links[..., 1, 1], links[..., 1, 2], links[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    links[..., 2, 1], links[..., 2, 2], links[..., 2, 3] = sa, ca, d
    links[..., 3, 3] = 1.0
    return links


def _tcp_matrix(tcp_offset_pose: ArrayLike | None) -> FloatArray | None:
    return None if tcp_offset_pose is None else pose_to_matrix(np.asarray(tcp_offset_pose, dtype=float))


def forward_kinematics(
    q_rad: ArrayLike, *, tcp_offset_pose: ArrayLike | None = None, model: URModel = UR5
) -> FloatArray:
    """Base-to-flange (``tool0``) transforms (..., 4, 4) for joint angles (..., 6).

    With ``tcp_offset_pose`` (a UR pose vector of the TCP in the flange frame, as
    ``set_tcp`` takes it) the result is base-to-TCP, i.e. what ``actual_TCP_pose`` reports.
    """
    q = np.asarray(q_rad, dtype=float)
    if q.shape[-1:] != (6,):
        raise ValueError(f"joint vector must have 6 entries, got shape {q.shape}")
    dh = model.dh
    links = _link_transforms(q + np.asarray(dh.theta_offset_rad), dh.d_m, dh.a_m, dh.alpha_rad)
    transform = links[..., 0, :, :]
    for i in range(1, 6):
        transform = transform @ links[..., i, :, :]
    tcp = _tcp_matrix(tcp_offset_pose)
    return transform if tcp is None else transform @ tcp


def _wrap_pi(angle: FloatArray) -> FloatArray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % TWO_PI - np.pi


def _acos_in_domain(x: FloatArray) -> FloatArray:
    """arccos, NaN where ``x`` is outside [-1, 1] by more than rounding."""
    return np.where(np.abs(x) > 1.0 + _DOMAIN_SLACK, np.nan, np.arccos(np.clip(x, -1.0, 1.0)))


def _inverse_link(theta: FloatArray, i: int, dh: DHParameters) -> FloatArray:
    return invert_transform(_link_transforms(theta, dh.d_m[i], dh.a_m[i], dh.alpha_rad[i]))


def _candidate_solutions(flange: FloatArray, theta6_free: FloatArray, dh: DHParameters) -> FloatArray:
    """Closed-form candidates (N, 8, 6) for base-to-flange transforms (N, 4, 4), unchecked;
    NaN where a branch has no solution. Branch order: see the module docstring."""
    d4, d6 = dh.d_m[3], dh.d_m[5]
    a2, a3 = dh.a_m[1], dh.a_m[2]
    n = len(flange)
    rot, pos = flange[:, :3, :3], flange[:, :3, 3]
    wrist = pos - d6 * rot[:, :, 2]  # origin of frame 5 (centre of wrist 2 / wrist 3 axes)
    radius_xy = np.hypot(wrist[:, 0], wrist[:, 1])
    inside = (radius_xy < abs(d4) * (1.0 - _DOMAIN_SLACK)) | (radius_xy == 0.0)
    phi = _acos_in_domain(d4 / np.where(inside, np.nan, radius_xy))
    psi = np.arctan2(wrist[:, 1], wrist[:, 0])
    theta1 = np.stack([psi + phi, psi - phi], axis=1) + np.pi / 2.0  # (N, 2): shoulder
    s1, c1 = np.sin(theta1), np.cos(theta1)
    # The tool z axis splits into its part along joint 2's axis (cos theta5) and its part
    # in the arm's plane (|sin theta5|); atan2 keeps theta5 accurate near 0 and pi.
    tool_z = rot[:, :, 2]
    cos5 = tool_z[:, 0, None] * s1 - tool_z[:, 1, None] * c1
    sin5_abs = np.hypot(tool_z[:, 0, None] * c1 + tool_z[:, 1, None] * s1, tool_z[:, 2, None])
    theta5 = np.stack([np.arctan2(sin5_abs, cos5), np.arctan2(-sin5_abs, cos5)], axis=2)  # (N, 2, 2)
    s5 = np.sin(theta5)
    base_to_6 = invert_transform(flange)[:, None, None]  # axes of frame 0 seen from frame 6
    s1w, c1w = s1[:, :, None], c1[:, :, None]
    sign = np.sign(s5)
    theta6 = np.where(
        np.abs(s5) < _WRIST_SINGULAR_SIN,
        np.asarray(theta6_free, dtype=float).reshape(-1, 1, 1),
        np.arctan2(
            sign * (-base_to_6[..., 1, 0] * s1w + base_to_6[..., 1, 1] * c1w),
            sign * (base_to_6[..., 0, 0] * s1w - base_to_6[..., 0, 1] * c1w),
        ),
    )
    theta1w = np.broadcast_to(theta1[:, :, None], theta5.shape)
    t14 = (
        _inverse_link(theta1w, 0, dh)
        @ flange[:, None, None]
        @ _inverse_link(theta6, 5, dh)
        @ _inverse_link(theta5, 4, dh)
    )
    # Joints 2 and 3 turn about z1: a planar two-link arm in the x1-y1 plane.
    p14 = t14[..., :3, 3]
    reach_sq = p14[..., 0] ** 2 + p14[..., 1] ** 2
    acos3 = _acos_in_domain((reach_sq - a2**2 - a3**2) / (2.0 * a2 * a3))
    theta3 = np.stack([acos3, -acos3], axis=-1)  # (N, 2, 2, 2): elbow
    theta2 = np.arctan2(p14[..., 1], p14[..., 0])[..., None] - np.arctan2(
        a3 * np.sin(theta3), a2 + a3 * np.cos(theta3)
    )
    t34 = _inverse_link(theta3, 2, dh) @ _inverse_link(theta2, 1, dh) @ t14[:, :, :, None]
    theta4 = np.arctan2(t34[..., 1, 0], t34[..., 0, 0])
    shape = theta3.shape
    return np.stack(
        [
            np.broadcast_to(theta1[:, :, None, None], shape),
            theta2,
            theta3,
            theta4,
            np.broadcast_to(theta5[..., None], shape),
            np.broadcast_to(theta6[..., None], shape),
        ],
        axis=-1,
    ).reshape(n, BRANCH_COUNT, 6)


def _flange_targets(T_base_tcp: ArrayLike, tcp_offset_pose: ArrayLike | None) -> FloatArray:
    target = np.asarray(T_base_tcp, dtype=float)
    if target.shape[-2:] != (4, 4):
        raise ValueError(f"target must be 4x4 transforms, got shape {target.shape}")
    tcp = _tcp_matrix(tcp_offset_pose)
    return target if tcp is None else target @ invert_transform(tcp)


def _pose_error(reached: FloatArray, target: FloatArray) -> FloatArray:
    """(..., 6): target minus reached position, and the small rotation taking reached to target."""
    rotation = target[..., :3, :3] @ np.swapaxes(reached[..., :3, :3], -1, -2)
    turn = 0.5 * np.stack(
        [rotation[..., 2, 1] - rotation[..., 1, 2], rotation[..., 0, 2] - rotation[..., 2, 0],
         rotation[..., 1, 0] - rotation[..., 0, 1]], axis=-1,
    )
    return np.concatenate([target[..., :3, 3] - reached[..., :3, 3], turn], axis=-1)


def _refined(q: FloatArray, flange: FloatArray, model: URModel) -> FloatArray:
    """Newton steps from the nominal table's solutions (N, 8, 6) to the robot's own rows
    (calibration corrections are sub-millimetre: a few steps reach 1e-9)."""
    finite = np.all(np.isfinite(q), axis=-1)
    q = np.where(finite[..., None], q, 0.0)
    target = np.broadcast_to(flange[:, None], (*q.shape[:2], 4, 4))
    for _ in range(_REFINE_STEPS):
        error = _pose_error(forward_kinematics(q, model=model), target)
        steps = _JACOBIAN_STEP_RAD * np.eye(6)
        columns = [
            (_pose_error(forward_kinematics(q + steps[j], model=model), target) - error) / _JACOBIAN_STEP_RAD
            for j in range(6)
        ]
        jacobian = np.stack(columns, axis=-1)  # d error / d q
        transposed = np.swapaxes(jacobian, -1, -2)
        normal = transposed @ jacobian + _DAMPING * np.eye(6)  # damped: a singular pose stays finite
        q = q - np.linalg.solve(normal, transposed @ error[..., None])[..., 0]
    return np.where(finite[..., None], _wrap_pi(q), np.nan)


def inverse_kinematics_branches(
    T_base_tcp: ArrayLike,
    *,
    tcp_offset_pose: ArrayLike | None = None,
    theta6_if_singular_rad: ArrayLike = 0.0,
    model: URModel = UR5,
) -> FloatArray:
    """Every branch's solution (N, 8, 6) for targets (N, 4, 4), angles in [-pi, pi); a row
    of NaN where that branch cannot reach the pose (or does not reproduce it)."""
    flange = _flange_targets(T_base_tcp, tcp_offset_pose).reshape(-1, 4, 4)
    with np.errstate(invalid="ignore", divide="ignore"):
        theta6_free = np.broadcast_to(np.asarray(theta6_if_singular_rad, dtype=float), len(flange))
        q = _wrap_pi(_candidate_solutions(flange, theta6_free, model.nominal or model.dh))
        if model.nominal is not None:
            q = _refined(q, flange, model)
        finite = np.all(np.isfinite(q), axis=-1)
        reached = forward_kinematics(np.where(finite[..., None], q, 0.0), model=model)
    position_error = np.linalg.norm(reached[..., :3, 3] - flange[:, None, :3, 3], axis=-1)
    relative = np.swapaxes(reached[..., :3, :3], -1, -2) @ flange[:, None, :3, :3]
    rotation_error = rotation_angle_rad(relative)
    good = finite & (position_error <= _POSITION_TOLERANCE_M) & (rotation_error <= _ROTATION_TOLERANCE_RAD)
    return np.where(good[..., None], q, np.nan)


def inverse_kinematics_all(
    T_base_tcp: ArrayLike,
    *,
    tcp_offset_pose: ArrayLike | None = None,
    theta6_if_singular_rad: float = 0.0,
    model: URModel = UR5,
) -> FloatArray:
    """Every distinct closed-form solution (k, 6), k <= 8, angles in [-pi, pi).

    Returns an empty (0, 6) array when the pose is out of reach. At the wrist singularity
    (theta5 = 0) theta6 is set to ``theta6_if_singular_rad`` and the rest follows.
    """
    target = np.asarray(T_base_tcp, dtype=float)
    if target.shape != (4, 4):
        raise ValueError(f"target must be one 4x4 transform, got shape {target.shape}")
    branches = inverse_kinematics_branches(
        target, tcp_offset_pose=tcp_offset_pose, theta6_if_singular_rad=theta6_if_singular_rad, model=model
    )[0]
    solutions: list[FloatArray] = []
    for q in branches[np.all(np.isfinite(branches), axis=1)]:
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
    limits_rad: ArrayLike | None = None,
    model: URModel = UR5,
) -> FloatArray | None:
    """The solution closest to ``q_near`` (joint space, Euclidean), or None if unreachable.

    Each joint is placed on the turn (angle + k * 2 pi) nearest to ``q_near`` that lies
    inside ``limits_rad`` (default: the model's joint limits); ``q_near`` defaults to zeros.
    """
    near = np.zeros(6) if q_near is None else np.asarray(q_near, dtype=float)
    limits = model.joint_limits_rad if limits_rad is None else np.asarray(limits_rad, dtype=float)
    best: FloatArray | None = None
    best_distance = np.inf
    for q in inverse_kinematics_all(
        T_base_tcp, tcp_offset_pose=tcp_offset_pose, theta6_if_singular_rad=float(near[5]), model=model
    ):
        placed = _nearest_representation(q, near, limits)
        if placed is None:
            continue
        distance = float(np.linalg.norm(placed - near))
        if distance < best_distance:
            best, best_distance = placed, distance
    return best


def inverse_kinematics_pose(
    tcp_pose: ArrayLike,
    q_near: ArrayLike | None = None,
    *,
    tcp_offset_pose: ArrayLike | None = None,
    model: URModel = UR5,
) -> FloatArray | None:
    """:func:`inverse_kinematics` for a UR pose vector ``[x, y, z, rx, ry, rz]``."""
    return inverse_kinematics(pose_to_matrix(tcp_pose), q_near, tcp_offset_pose=tcp_offset_pose, model=model)


def move_duration_s(distance: float, speed: float, accel: float) -> float:
    """How long a UR move over ``distance`` lasts at ``speed`` and ``accel`` caps: a trapezoid
    (a triangle when too short to reach ``speed``). ur_rtde's moveJ and URScript's movej take
    the speed and acceleration "of leading axis" (rad, the joint that moves most), moveL/movel
    the tool's (m); any consistent unit."""
    ramp = speed**2 / accel
    if distance <= ramp:
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel
