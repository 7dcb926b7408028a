"""The interfaces the sequencer talks to; drivers and test doubles implement them.

The sequencer never imports a driver or a fake: it receives objects that satisfy these
protocols (docs/architecture.md, "The data flow").
"""

from __future__ import annotations

from typing import Protocol

from lasercal_hw.models import (
    FloatArray,
    LaserScan,
    RobotIdentity,
    RobotState,
    ScanGeometry,
    ScannerIdentity,
)


class Scanner(Protocol):
    """A 2D laser scanner streaming scans."""

    def identity(self) -> ScannerIdentity:
        """Vendor, product, firmware, serial and model."""
        ...

    def geometry(self) -> ScanGeometry:
        """Beam layout of the scans ``next_scan`` returns."""
        ...

    def start_streaming(self, *, intensities: bool = False) -> None:
        """Start continuous scanning in a background reader."""
        ...

    def next_scan(self, timeout_s: float) -> LaserScan:
        """The next scan in arrival order; raises ``DeviceTimeoutError`` after ``timeout_s``."""
        ...

    def dropped_scans(self) -> int:
        """Scans lost so far (queue overflow or corrupted blocks)."""
        ...

    def stop_streaming(self) -> None:
        """Stop the stream and the reader."""
        ...

    def close(self) -> None:
        """Release the connection; safe to call twice."""
        ...


class Robot(Protocol):
    """A robot arm that can be asked to move a tool and report where it is."""

    def identity(self) -> RobotIdentity:
        """Model, serial number and software version."""
        ...

    def state(self) -> RobotState:
        """Robot mode, safety status, whether the control program runs."""
        ...

    def tcp_pose(self) -> FloatArray:
        """Actual TCP pose in the base frame, UR pose vector (m, rotation vector)."""
        ...

    def joint_positions_rad(self) -> FloatArray:
        """Actual joint positions (rad)."""
        ...

    def move_linear(self, pose: FloatArray, speed_m_s: float, accel_m_s2: float) -> None:
        """Move the TCP on a straight line; blocks until the motion ends."""
        ...

    def move_joint(self, q_rad: FloatArray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move in joint space; blocks until the motion ends."""
        ...

    def wait_until_steady(self, timeout_s: float) -> None:
        """Block until the arm has stopped moving."""
        ...

    def stop(self) -> None:
        """Decelerate and stop any motion now."""
        ...

    def inverse_kinematics(self, pose: FloatArray, q_near_rad: FloatArray | None = None) -> FloatArray | None:
        """Joint solution for a TCP pose nearest ``q_near_rad`` (default: the arm's present
        joints), or None when it is not reachable."""
        ...

    def is_within_safety_limits(self, pose: FloatArray) -> bool:
        """True when the controller's safety limits allow the pose."""
        ...

    def close(self) -> None:
        """Disconnect cleanly; safe to call twice."""
        ...
