"""Geometry conversions checked against scipy.spatial.transform with property tests."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from lasercal_hw import geometry as g

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
rotvecs = arrays(np.float64, 3, elements=st.floats(-3.1, 3.1, allow_nan=False))
quats = arrays(np.float64, 4, elements=st.floats(-1.0, 1.0, allow_nan=False)).filter(
    lambda q: np.linalg.norm(q) > 0.1
)
poses = arrays(np.float64, 6, elements=st.floats(-3.0, 3.0, allow_nan=False))


@given(rotvecs)
def test_rotvec_to_matrix_matches_scipy(rv: np.ndarray) -> None:
    np.testing.assert_allclose(g.rotvec_to_matrix(rv), Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)


@given(quats)
def test_quaternion_round_trips_match_scipy(q: np.ndarray) -> None:
    expected = Rotation.from_quat(q).as_matrix()
    np.testing.assert_allclose(g.quat_to_matrix(q), expected, atol=1e-12)
    back = g.matrix_to_quat(expected)
    # q and -q are the same rotation; ours keeps w >= 0.
    ref = Rotation.from_matrix(expected).as_quat()
    ref = ref if ref[3] >= 0 else -ref
    if abs(ref[3]) < 1e-9:  # w == 0: sign is free, compare as rotations
        np.testing.assert_allclose(g.quat_to_matrix(back), expected, atol=1e-9)
    else:
        np.testing.assert_allclose(back, ref, atol=1e-9)


@given(rotvecs)
def test_matrix_to_rotvec_inverts_rotvec_to_matrix(rv: np.ndarray) -> None:
    matrix = g.rotvec_to_matrix(rv)
    np.testing.assert_allclose(g.rotvec_to_matrix(g.matrix_to_rotvec(matrix)), matrix, atol=1e-9)
    np.testing.assert_allclose(
        g.matrix_to_rotvec(matrix), Rotation.from_matrix(matrix).as_rotvec(), atol=1e-7
    )


@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_euler_zyx_matches_scipy_intrinsic_ZYX(yaw: float, pitch: float, roll: float) -> None:
    matrix = g.euler_zyx_to_matrix(yaw, pitch, roll)
    expected = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    np.testing.assert_allclose(matrix, expected, atol=1e-12)
    np.testing.assert_allclose(g.euler_zyx_to_matrix(*g.matrix_to_euler_zyx(matrix)), matrix, atol=1e-9)


def test_euler_convention_is_rz_ry_rx() -> None:
    yaw, pitch, roll = np.radians([5.0, 7.0, 3.0])
    rz = Rotation.from_euler("z", yaw).as_matrix()
    ry = Rotation.from_euler("y", pitch).as_matrix()
    rx = Rotation.from_euler("x", roll).as_matrix()
    np.testing.assert_allclose(g.euler_zyx_to_matrix(yaw, pitch, roll), rz @ ry @ rx, atol=1e-15)
    np.testing.assert_allclose(g.matrix_to_euler_zyx(rz @ ry @ rx), [yaw, pitch, roll], atol=1e-12)


def test_euler_gimbal_lock_keeps_the_rotation() -> None:
    matrix = g.euler_zyx_to_matrix(0.3, np.pi / 2, 0.2)
    np.testing.assert_allclose(g.euler_zyx_to_matrix(*g.matrix_to_euler_zyx(matrix)), matrix, atol=1e-9)


@given(poses, poses)
def test_pose_matrix_round_trip_inverse_and_composition(a: np.ndarray, b: np.ndarray) -> None:
    ta, tb = g.pose_to_matrix(a), g.pose_to_matrix(b)
    np.testing.assert_allclose(g.pose_to_matrix(g.matrix_to_pose(ta)), ta, atol=1e-9)
    np.testing.assert_allclose(g.invert_transform(ta) @ ta, np.eye(4), atol=1e-12)
    point = b[:3]
    np.testing.assert_allclose(
        g.transform_points(ta @ tb, point), g.transform_points(ta, g.transform_points(tb, point)), atol=1e-9
    )


@settings(max_examples=20)
@given(arrays(np.float64, (5, 3), elements=st.floats(-3.0, 3.0, allow_nan=False)))
def test_stacked_inputs_match_single_inputs(rvs: np.ndarray) -> None:
    stacked = g.rotvec_to_matrix(rvs)
    for rv, matrix in zip(rvs, stacked, strict=True):
        np.testing.assert_allclose(matrix, g.rotvec_to_matrix(rv), atol=1e-15)
    angles = np.linalg.norm(g.matrix_to_rotvec(stacked), axis=-1)
    np.testing.assert_allclose(g.rotation_angle_rad(stacked), angles)


def test_small_rotation_angle_is_accurate() -> None:
    # arccos of the trace loses everything below ~1e-8 rad; the rotvec path does not.
    assert abs(g.rotation_angle_rad(g.rotvec_to_matrix([1e-9, 0.0, 0.0])) - 1e-9) < 1e-15
