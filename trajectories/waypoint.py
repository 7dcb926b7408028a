"""The value every trajectory source produces: a numbered TCP pose with a label."""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, field_validator

from lasercal_hw.geometry import FloatArray, pose_to_matrix


class Waypoint(BaseModel):
    """One calibration waypoint: where the TCP should dwell while the scanner looks.

    ``tcp_pose`` is a UR pose vector ``[x, y, z, rx, ry, rz]`` in the robot base frame
    (metres, rotation vector in radians); ``label`` says where it came from (arc, angle,
    tilt, or the file row) for logs and reports.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    index: int
    tcp_pose: tuple[float, float, float, float, float, float]
    label: str = ""

    @field_validator("tcp_pose")
    @classmethod
    def _finite(cls, pose: tuple[float, ...]) -> tuple[float, ...]:
        if not all(math.isfinite(v) for v in pose):
            raise ValueError(f"tcp_pose must be finite numbers, got {pose}")
        return pose

    def pose_array(self) -> FloatArray:
        """The pose vector as a float array of shape (6,)."""
        return np.array(self.tcp_pose, dtype=float)

    def matrix(self) -> FloatArray:
        """The pose as a 4x4 base-to-TCP transform."""
        return pose_to_matrix(self.pose_array())


def waypoint_matrices(waypoints: list[Waypoint]) -> FloatArray:
    """Base-to-TCP transforms (n, 4, 4) of a list of waypoints."""
    if not waypoints:
        return np.zeros((0, 4, 4))
    return pose_to_matrix(np.array([w.tcp_pose for w in waypoints], dtype=float))
