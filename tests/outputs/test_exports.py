"""URDF and static_transform_publisher exports reproduce the transform to 1e-12."""

from __future__ import annotations

import shlex
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, quat_to_matrix, rotvec_to_matrix
from lasercal_hw.outputs.exports import exports, static_transform_publisher_args, urdf_joint

PAPER_T = make_transform(euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])), [0.30, 0.50, 0.20])


def _from_urdf(snippet: str) -> np.ndarray:
    joint = ET.fromstring(snippet)
    assert joint.tag == "joint" and joint.get("type") == "fixed"
    origin = joint.find("origin")
    xyz = [float(v) for v in origin.get("xyz").split()]
    roll, pitch, yaw = (float(v) for v in origin.get("rpy").split())
    # URDF: fixed-axis roll about x, then pitch about y, then yaw about z.
    rx = rotvec_to_matrix([roll, 0, 0])
    ry = rotvec_to_matrix([0, pitch, 0])
    rz = rotvec_to_matrix([0, 0, yaw])
    return make_transform(rz @ ry @ rx, xyz)


def _from_args(args: list[str]) -> tuple[np.ndarray, dict[str, str]]:
    flags = dict(zip(args[::2], args[1::2], strict=True))
    xyz = [float(flags[f"--{k}"]) for k in "xyz"]
    if "--qw" in flags:
        rotation = quat_to_matrix([float(flags[f"--q{k}"]) for k in "xyzw"])
    else:
        rotation = euler_zyx_to_matrix(float(flags["--yaw"]), float(flags["--pitch"]), float(flags["--roll"]))
    return make_transform(rotation, xyz), flags


def test_urdf_joint_of_the_paper_transform():
    snippet = urdf_joint(PAPER_T)
    joint = ET.fromstring(snippet)
    assert joint.get("name") == "base_to_laser"
    assert joint.find("parent").get("link") == "base"
    assert joint.find("child").get("link") == "laser"
    roll, pitch, yaw = (float(v) for v in joint.find("origin").get("rpy").split())
    assert np.degrees([roll, pitch, yaw]) == pytest.approx([3.0, 7.0, 5.0], abs=1e-12)
    np.testing.assert_allclose(_from_urdf(snippet), PAPER_T, atol=1e-12)


def test_urdf_rpy_is_the_zyx_convention():
    """Independent check: URDF's fixed-axis rpy composed from elementary rotations equals
    geometry.euler_zyx_to_matrix(yaw, pitch, roll)."""
    rng = np.random.default_rng(3)
    for yaw, pitch, roll in rng.uniform(-1.4, 1.4, (20, 3)):
        transform = make_transform(euler_zyx_to_matrix(yaw, pitch, roll), [0.0, 0.0, 0.0])
        np.testing.assert_allclose(_from_urdf(urdf_joint(transform)), transform, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    rotvec=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
    translation=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
)
def test_every_export_reproduces_the_matrix(rotvec, translation):
    transform = make_transform(rotvec_to_matrix(rotvec), translation)
    np.testing.assert_allclose(_from_urdf(urdf_joint(transform)), transform, atol=1e-12)
    for rpy in (False, True):
        back, flags = _from_args(static_transform_publisher_args(transform, rpy=rpy))
        np.testing.assert_allclose(back, transform, atol=1e-12)
        assert flags["--frame-id"] == "base" and flags["--child-frame-id"] == "laser"


def test_command_lines_are_shell_ready():
    commands = exports(PAPER_T, parent="base_link", child="laser_frame")
    for key in ("static_transform_publisher", "static_transform_publisher_rpy"):
        words = shlex.split(commands[key])
        assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
        back, flags = _from_args(words[4:])
        np.testing.assert_allclose(back, PAPER_T, atol=1e-12)
        assert flags["--frame-id"] == "base_link" and flags["--child-frame-id"] == "laser_frame"
    assert '<parent link="base_link"/>' in commands["urdf_joint"]


@pytest.mark.parametrize("bad", [np.eye(3), np.full((4, 4), np.nan), np.diag([1.0, 1.0, -1.0, 1.0]),
                                 np.diag([2.0, 1.0, 1.0, 1.0])])
def test_not_a_rigid_transform_is_refused(bad):
    with pytest.raises(ConfigError, match="T_base_laser"):
        urdf_joint(bad)


@pytest.mark.parametrize("pitch_from_vertical_rad", [1e-3, 1e-6, 1e-9, 1e-12, 0.0])
def test_exports_stay_exact_next_to_gimbal_lock(pitch_from_vertical_rad):
    """A scanner mounted vertically has pitch near 90 degrees, where ZYX angles are fragile."""
    for sign in (1.0, -1.0):
        rotation = euler_zyx_to_matrix(0.3, sign * (np.pi / 2 - pitch_from_vertical_rad), -0.2)
        transform = make_transform(rotation, [0.1, 0.2, 0.3])
        np.testing.assert_allclose(_from_urdf(urdf_joint(transform)), transform, atol=1e-12)
        back, _ = _from_args(static_transform_publisher_args(transform, rpy=True))
        np.testing.assert_allclose(back, transform, atol=1e-12)
