"""UR5 (CB3) and UR5e kinematics: forward kinematics against published reference values, and the
closed-form inverse kinematics against forward kinematics on every branch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_pose, pose_to_matrix, rotation_angle_rad
from lasercal_hw.models import RobotCalibration, RobotIdentity
from lasercal_hw.ur_kinematics import (
    UR5,
    UR5E,
    URModel,
    forward_kinematics,
    inverse_kinematics,
    inverse_kinematics_all,
    inverse_kinematics_branches,
    inverse_kinematics_pose,
    model_from_robot_calibration,
    model_of_controller,
    offline_model,
    robot_model,
)

JOINT_LIMITS_RAD = UR5.joint_limits_rad
MODELS = pytest.mark.parametrize("model", [UR5, UR5E], ids=["ur5", "ur5e"])

# Reference pairs q -> flange position (m) computed with Universal Robots' own DH
# spreadsheet from the support article "DH parameters for calculations of kinematics and
# dynamics" (universal-robots.com/articles/ur/application-installation/
# dh-parameters-for-calculations-of-kinematics-and-dynamics/), UR5 CB3 parameters, as
# quoted (5 decimals) in public test data that checks a UR5 FK against that tool.
UR_SPREADSHEET_PAIRS = [
    ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [-0.81725, -0.19145, -0.00549]),
    (
        [1.658062789, 5.235987756, 2.844886681, 4.01425728, 2.00712864, 0.523598776],
        [0.09445, -0.22632, 0.02455],
    ),
    ([0.0, 1.623156204, 2.862339973, 5.585053606, 4.36332313, 2.862339973], [-0.00825, -0.08100, 0.07599]),
]

joint_angles = arrays(np.float64, 6, elements=st.floats(-np.pi, np.pi, allow_nan=False))
# Away from the elbow (theta3 = 0, pi) and wrist (theta5 = 0, pi) singularities the
# solution is isolated, so IK must give back the very angles FK started from. At the
# singularities a continuum of angles gives the same pose (tested separately below).
regular_joint_angles = joint_angles.filter(lambda q: abs(np.sin(q[2])) > 1e-3 and abs(np.sin(q[4])) > 1e-3)


def assert_same_pose(actual: np.ndarray, expected: np.ndarray, tol: float = 1e-9) -> None:
    np.testing.assert_allclose(actual[:3, 3], expected[:3, 3], atol=tol)
    assert rotation_angle_rad(actual[:3, :3].T @ expected[:3, :3]) < tol


def same_angles(a: np.ndarray, b: np.ndarray, tol: float = 1e-6) -> bool:
    return bool(np.all(np.abs((a - b + np.pi) % (2 * np.pi) - np.pi) < tol))


def test_dh_table_is_the_published_ur5_cb3_table() -> None:
    assert UR5.dh.d_m == (0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823)
    assert UR5.dh.a_m == (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(UR5.dh.alpha_rad, [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0])
    np.testing.assert_allclose(JOINT_LIMITS_RAD, [[-2 * np.pi, 2 * np.pi]] * 6)
    np.testing.assert_allclose(UR5.joint_speed_limits_rad_s, np.deg2rad(180.0))


def test_dh_table_is_the_published_ur5e_table() -> None:
    # UR's support article, UR5e column: d1 0.1625, a2 -0.425, a3 -0.3922, d4 0.1333,
    # d5 0.0997, d6 0.0996; joint ranges +-360 deg and speeds 180 deg/s (UR5e specification).
    assert UR5E.dh.d_m == (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
    assert UR5E.dh.a_m == (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(UR5E.dh.alpha_rad, [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0])
    np.testing.assert_allclose(UR5E.joint_limits_rad, [[-2 * np.pi, 2 * np.pi]] * 6)
    np.testing.assert_allclose(UR5E.joint_speed_limits_rad_s, np.deg2rad(180.0))


def test_models_are_chosen_by_name_or_by_the_controller() -> None:
    assert robot_model("UR5e") is UR5E and robot_model(" ur5 ") is UR5
    with pytest.raises(ConfigError, match=r"unknown robot model 'ur10'.*ur5, ur5e"):
        robot_model("ur10")
    # The dashboard says "UR5" on both generations; e-Series controllers run software 5.x.
    assert model_of_controller("UR5", (5, 11, 6, 108949)) is UR5E
    assert model_of_controller("UR5", (3, 15, 7, 0)) is UR5


@pytest.mark.parametrize(("q", "position_m"), UR_SPREADSHEET_PAIRS)
def test_forward_kinematics_matches_ur_dh_spreadsheet(q: list[float], position_m: list[float]) -> None:
    np.testing.assert_allclose(forward_kinematics(q)[:3, 3], position_m, atol=6e-6)


def test_ur5e_zero_pose_follows_its_own_table() -> None:
    # q = 0 puts the flange at (a2 + a3, -(d4 + d6), d1 - d5), facing -y.
    pose = matrix_to_pose(forward_kinematics(np.zeros(6), model=UR5E))
    np.testing.assert_allclose(pose[:3], [-(0.425 + 0.3922), -(0.1333 + 0.0996), 0.1625 - 0.0997])
    np.testing.assert_allclose(pose[3:], [np.pi / 2, 0.0, 0.0], atol=1e-12)
    # A bent arm differs between the two models by more than a centimetre.
    q = np.array([0.4, -1.2, 1.3, -1.6, -1.4, 0.5])
    assert np.linalg.norm(forward_kinematics(q, model=UR5E)[:3, 3] - forward_kinematics(q)[:3, 3]) > 0.01


def test_zero_pose_is_the_controller_base_frame_pose() -> None:
    # At q = 0 the arm points along -x of the controller's Base frame (ur_description:
    # "base" is the controller frame, rotated 180 deg about z from base_link which points
    # along the arm), the flange faces -y, and tool x stays along base x.
    pose = matrix_to_pose(forward_kinematics(np.zeros(6)))
    np.testing.assert_allclose(pose[:3], [-(0.425 + 0.39225), -(0.10915 + 0.0823), 0.089159 - 0.09465])
    np.testing.assert_allclose(pose[3:], [np.pi / 2, 0.0, 0.0], atol=1e-12)


def test_base_joint_turns_the_whole_arm_about_base_z() -> None:
    q = np.array([0.0, -1.0, 1.2, -0.4, 0.7, 0.3])
    turned = q + np.array([np.pi / 2, 0, 0, 0, 0, 0])
    rz90 = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    assert_same_pose(forward_kinematics(turned), rz90 @ forward_kinematics(q))


def test_forward_kinematics_is_vectorised_over_stacks() -> None:
    rng = np.random.default_rng(3)
    qs = rng.uniform(-np.pi, np.pi, (4, 5, 6))
    stacked = forward_kinematics(qs)
    assert stacked.shape == (4, 5, 4, 4)
    np.testing.assert_allclose(stacked[2, 3], forward_kinematics(qs[2, 3]), atol=1e-15)


def test_tcp_offset_moves_the_reported_point_along_the_flange_axes() -> None:
    q = np.array([0.3, -1.1, 1.4, -1.8, -1.5, 0.2])
    flange = forward_kinematics(q)
    tcp = forward_kinematics(q, tcp_offset_pose=[0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(tcp[:3, 3], flange[:3, 3] + 0.3 * flange[:3, 2], atol=1e-12)
    back = inverse_kinematics(tcp, q, tcp_offset_pose=[0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
    assert back is not None
    np.testing.assert_allclose(back, q, atol=1e-8)


@MODELS
@settings(max_examples=100, deadline=None)
@given(q=joint_angles)
def test_every_ik_branch_reproduces_the_pose(model: URModel, q: np.ndarray) -> None:
    target = forward_kinematics(q, model=model)
    solutions = inverse_kinematics_all(target, theta6_if_singular_rad=float(q[5]), model=model)
    assert 1 <= len(solutions) <= 8
    assert np.all(np.isfinite(solutions))
    for solution in solutions:
        assert_same_pose(forward_kinematics(solution, model=model), target, tol=2e-6)


@MODELS
@settings(max_examples=100, deadline=None)
@given(q=regular_joint_angles)
def test_one_ik_branch_is_the_original_angles(model: URModel, q: np.ndarray) -> None:
    solutions = inverse_kinematics_all(forward_kinematics(q, model=model), model=model)
    assert any(same_angles(solution, q) for solution in solutions)


@MODELS
def test_branches_are_numbered_by_shoulder_wrist_and_elbow(model: URModel) -> None:
    rng = np.random.default_rng(5)
    qs = rng.uniform(-np.pi, np.pi, (200, 6))
    qs = qs[(np.abs(np.sin(qs[:, 2])) > 0.05) & (np.abs(np.sin(qs[:, 4])) > 0.05)]
    branches = inverse_kinematics_branches(forward_kinematics(qs, model=model), model=model)
    assert branches.shape == (len(qs), 8, 6)
    for q, solutions in zip(qs, branches, strict=True):
        matches = [b for b in range(8) if np.all(np.isfinite(solutions[b])) and same_angles(solutions[b], q)]
        assert len(matches) == 1
        wrist, elbow = (matches[0] // 2) % 2, matches[0] % 2
        assert wrist == int(np.sin(q[4]) < 0) and elbow == int(np.sin(q[2]) < 0)
    # Out of reach: every branch is NaN.
    far = inverse_kinematics_branches(pose_to_matrix([2.0, 0.0, 0.3, np.pi, 0.0, 0.0])[None], model=model)
    assert np.all(np.isnan(far))


@settings(max_examples=100, deadline=None)
@given(regular_joint_angles)
def test_nearest_solution_to_the_original_is_the_original(q: np.ndarray) -> None:
    solution = inverse_kinematics(forward_kinematics(q), q_near=q)
    assert solution is not None
    np.testing.assert_allclose(solution, q, atol=1e-6)


def test_generic_pose_has_eight_distinct_branches() -> None:
    q = np.array([0.4, -1.2, 1.3, -1.6, -1.4, 0.5])
    solutions = inverse_kinematics_all(forward_kinematics(q))
    assert len(solutions) == 8
    # shoulder left/right x wrist up/down x elbow up/down: theta1, theta5, theta3 signs differ
    assert len({(round(s[0], 6), np.sign(s[4]), np.sign(s[2])) for s in solutions}) == 8


def test_solution_is_placed_on_the_turn_nearest_q_near_within_limits() -> None:
    q = np.array([0.4, -1.2, 1.3, -1.6, -1.4, 0.5])
    near = q + np.array([-2 * np.pi, 0.0, 0.0, 2 * np.pi, 0.0, -2 * np.pi])
    solution = inverse_kinematics(forward_kinematics(q), q_near=near)
    assert solution is not None
    np.testing.assert_allclose(solution, near, atol=1e-8)
    assert np.all(solution >= JOINT_LIMITS_RAD[:, 0]) and np.all(solution <= JOINT_LIMITS_RAD[:, 1])


def test_joint_limits_exclude_branches_outside_them() -> None:
    q = np.array([0.4, -1.2, 1.3, -1.6, -1.4, 0.5])
    target = forward_kinematics(q)
    nowhere = np.array([[1.0, 1.1]] + [[-np.pi, np.pi]] * 5)  # no branch has theta1 in there
    assert inverse_kinematics(target, q, limits_rad=nowhere) is None
    only_theta1 = inverse_kinematics(target, q, limits_rad=np.array([[0.3, 0.5]] + [[-np.pi, np.pi]] * 5))
    assert only_theta1 is not None
    assert 0.3 <= only_theta1[0] <= 0.5


@pytest.mark.parametrize(
    "pose",
    [
        [2.0, 0.0, 0.3, np.pi, 0.0, 0.0],  # beyond reach (max ~0.95 m from the shoulder)
        [0.0, 0.0, 1.5, np.pi, 0.0, 0.0],  # above reach
        [0.02, 0.0, 0.4, 0.0, 0.0, 0.0],  # wrist centre inside the d4 cylinder around joint 1
    ],
)
def test_unreachable_pose_gives_none(pose: list[float]) -> None:
    assert inverse_kinematics_pose(pose) is None
    assert inverse_kinematics_all(pose_to_matrix(pose)).shape == (0, 6)


@pytest.mark.parametrize(
    "q",
    [
        [0.1, -1.2, 1.5, -0.3, 0.0, 0.4],  # wrist singular: theta5 = 0
        [0.1, -1.2, 1.5, -0.3, 1e-10, 0.4],  # wrist nearly singular
        [0.1, -1.2, 1e-9, -0.3, 0.8, 0.4],  # elbow stretched
        [0.1, -1.2, 0.0, -0.3, np.pi, 0.4],  # elbow stretched and wrist flipped
    ],
)
def test_singular_and_near_singular_poses_give_finite_exact_solutions(q: list[float]) -> None:
    target = forward_kinematics(q)
    solutions = inverse_kinematics_all(target)
    assert len(solutions) >= 1 and np.all(np.isfinite(solutions))
    for solution in solutions:
        assert_same_pose(forward_kinematics(solution), target, tol=2e-6)
    nearest = inverse_kinematics(target, q_near=q)
    assert nearest is not None
    assert_same_pose(forward_kinematics(nearest), target, tol=2e-6)


def test_shoulder_singularity_gives_finite_solution() -> None:
    # Wrist centre exactly d4 from the base axis: the two shoulder branches coincide.
    flange = np.eye(4)
    flange[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # tool pointing down
    flange[:3, 3] = [0.0, -0.10915, 0.3 - 0.0823]  # wrist centre (flange + d6 up) at (0, -d4, 0.3)
    solution = inverse_kinematics(flange)
    assert solution is not None and np.all(np.isfinite(solution))
    assert_same_pose(forward_kinematics(solution), flange, tol=2e-6)


def test_malformed_inputs_are_rejected() -> None:
    with pytest.raises(ValueError, match="6 entries"):
        forward_kinematics([0.0, 1.0])
    with pytest.raises(ValueError, match="4x4"):
        inverse_kinematics(np.eye(3))


def _robot_calibration(base: URModel, spread: float, seed: int = 1, model: str = "UR5e") -> RobotCalibration:
    """A robot's own calibration: ``base``'s table with corrections of about ``spread``."""
    rng = np.random.default_rng(seed)

    def off(values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(float(v) for v in np.asarray(values) + rng.normal(0.0, spread, 6))

    return RobotCalibration(
        checksums=(11, 22, 33, 44, 55, 66), dh_theta_rad=off((0.0,) * 6), dh_a_m=off(base.dh.a_m),
        dh_d_m=off(base.dh.d_m), dh_alpha_rad=off(base.dh.alpha_rad), calibration_status=0, model=model,
        software_version="5.11.6.108949",
    )


def test_the_robots_own_rows_move_the_flange_and_the_ik_solves_them() -> None:
    """Sub-millimetre corrections (as a factory calibration has) move the flange by about as
    much; the IK starts on the published table and lands on the robot's rows."""
    model = model_from_robot_calibration(_robot_calibration(UR5E, 3e-4))
    assert model.name == "ur5e" and model.nominal == UR5E.dh
    assert model.calibration_checksum == "0000000b-00000016-00000021-0000002c-00000037-00000042"
    q = np.random.default_rng(2).uniform(-2.5, 2.5, (100, 6))
    flange_m = forward_kinematics(q, model=model)[:, :3, 3]
    moved_m = np.linalg.norm(flange_m - forward_kinematics(q, model=UR5E)[:, :3, 3], axis=1)
    assert 1e-4 < np.median(moved_m) < 5e-3
    solutions = inverse_kinematics_branches(forward_kinematics(q, model=model), model=model)
    found = np.isfinite(solutions).all(axis=-1)
    assert found.sum(axis=1).mean() > 6.0  # as many branches as the published table gives
    difference = np.abs(_wrap(solutions - q[:, None]))
    recovered = np.min(np.where(found, difference.max(axis=-1), np.inf), axis=1) < 1e-6
    assert recovered.mean() > 0.95
    reached = forward_kinematics(np.where(found[..., None], solutions, 0.0), model=model)[found]
    target = np.broadcast_to(forward_kinematics(q, model=model)[:, None], (*found.shape, 4, 4))[found]
    assert np.max(np.linalg.norm(reached[:, :3, 3] - target[:, :3, 3], axis=1)) < 1e-6


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def test_which_kinematics_offline_design_and_checks_use() -> None:
    """The robot's own rows when known (a fake's exact CB3 table stays the published UR5 one,
    whatever model it reports); else the named model; else the reported one; else the UR5."""
    exact = _robot_calibration(UR5, 0.0, model="UR5e")
    assert offline_model(exact) == dataclasses.replace(UR5, calibration_checksum=exact.checksum)
    assert offline_model(_robot_calibration(UR5E, 2e-4)).nominal == UR5E.dh
    e_series = RobotIdentity("UR5", "20185500042", "5.11.6", (5, 11, 6, 108949))
    assert offline_model(None, e_series) == UR5E
    assert offline_model(None, e_series, named="ur5") == UR5
    assert offline_model(None, RobotIdentity("unknown", "", "3.15", (3, 15, 7, 0))) == UR5
