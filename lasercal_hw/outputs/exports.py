"""Exports of ``T_base_laser`` for ROS: a URDF fixed joint and ``static_transform_publisher``
arguments, every number written with full float precision (``repr``) so that the exported
transform gives back the matrix to 1e-12.

URDF ``rpy`` and tf2's ``--roll --pitch --yaw`` are fixed-axis roll-pitch-yaw, i.e.
``R = Rz(yaw) Ry(pitch) Rx(roll)``: the product's ZYX convention.
"""

from __future__ import annotations

import shlex
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import ArrayLike

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_euler_zyx, matrix_to_quat
from lasercal_hw.models import FloatArray

_ORTHONORMAL_TOLERANCE = 1e-6


def _checked_transform(T_base_laser: ArrayLike) -> FloatArray:
    transform = np.asarray(T_base_laser, dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise ConfigError(f"T_base_laser must be a finite 4x4 matrix, got shape {transform.shape}")
    rotation = transform[:3, :3]
    orthonormal = np.allclose(rotation.T @ rotation, np.eye(3), atol=_ORTHONORMAL_TOLERANCE)
    if not orthonormal or np.linalg.det(rotation) <= 0:
        raise ConfigError("T_base_laser's rotation is not a proper rotation; export a solved transform")
    return transform


def _number(value: float) -> str:
    return repr(float(value))


def scanner_frame(scanner: str | None) -> str:
    """The scanner's frame in the exports: ``laser`` for a one-scanner job's scanner (``default``),
    ``laser_<name>`` for a cell's named one."""
    return "laser" if scanner in (None, DEFAULT_SCANNER_NAME) else f"laser_{scanner}"


def urdf_joint(
    T_base_laser: ArrayLike, *, name: str | None = None, parent: str = "base", child: str = "laser"
) -> str:
    """A URDF fixed joint ``name`` (default ``base_to_<child>``) placing ``child`` (the
    scanner) in ``parent`` (the robot base)."""
    transform = _checked_transform(T_base_laser)
    name = name or f"base_to_{child}"
    yaw, pitch, roll = matrix_to_euler_zyx(transform[:3, :3])
    xyz = " ".join(_number(v) for v in transform[:3, 3])
    rpy = " ".join(_number(v) for v in (roll, pitch, yaw))
    return (
        f'<joint name={quoteattr(name)} type="fixed">\n'
        f"  <parent link={quoteattr(parent)}/>\n"
        f"  <child link={quoteattr(child)}/>\n"
        f'  <origin xyz="{xyz}" rpy="{rpy}"/>\n'
        "</joint>\n"
    )


def static_transform_publisher_args(
    T_base_laser: ArrayLike, *, frame_id: str = "base", child_frame_id: str = "laser", rpy: bool = False
) -> list[str]:
    """Arguments of ``ros2 run tf2_ros static_transform_publisher`` (new-style flags),
    rotation as a quaternion (default) or as ``--roll --pitch --yaw``."""
    transform = _checked_transform(T_base_laser)
    x, y, z = transform[:3, 3]
    args = ["--x", _number(x), "--y", _number(y), "--z", _number(z)]
    if rpy:
        yaw, pitch, roll = matrix_to_euler_zyx(transform[:3, :3])
        args += ["--roll", _number(roll), "--pitch", _number(pitch), "--yaw", _number(yaw)]
    else:
        qx, qy, qz, qw = matrix_to_quat(transform[:3, :3])
        args += ["--qx", _number(qx), "--qy", _number(qy), "--qz", _number(qz), "--qw", _number(qw)]
    return [*args, "--frame-id", frame_id, "--child-frame-id", child_frame_id]


def static_transform_publisher_command(T_base_laser: ArrayLike, **options: Any) -> str:
    """The whole shell command line (options as for ``static_transform_publisher_args``)."""
    args = static_transform_publisher_args(T_base_laser, **options)
    return shlex.join(["ros2", "run", "tf2_ros", "static_transform_publisher", *args])


def exports(T_base_laser: ArrayLike, *, parent: str = "base", child: str = "laser") -> dict[str, str]:
    """All exports as strings, for ``result.json`` and the CLI."""
    frames = {"frame_id": parent, "child_frame_id": child}
    return {
        "urdf_joint": urdf_joint(T_base_laser, parent=parent, child=child),
        "static_transform_publisher": static_transform_publisher_command(T_base_laser, **frames),
        "static_transform_publisher_rpy": static_transform_publisher_command(
            T_base_laser, rpy=True, **frames
        ),
    }
