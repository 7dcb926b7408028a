"""Primary client interface (ports 30001 and 30011), the part lasercal reads: the version
message a new client gets first, then robot states at 10 Hz. The first robot state carries
the kinematics info and the configuration data as well as the joint data; later ones carry
the joint data only, as a real controller leaves the static packages out after the first
(docs/ur.md). Read only: whatever a client writes is read and dropped.

The bytes are written here with ``struct`` from the published layout, independently of the
client's codec (``drivers/ur/primary_codec.py``), so the tests hold one against the other.
"""

from __future__ import annotations

import socket
import struct

from fakes.ur_controller.controller import FakeController

PRIMARY_PORT = 30001
PRIMARY_READ_ONLY_PORT = 30011
STATE_PERIOD_S = 0.1
_SOURCE_CONTROLLER = -2
_ROBOT_TYPE_UR5 = 1
_BUILD_DATE = b"27-01-2022, 10:11:13"


def _package(kind: int, body: bytes) -> bytes:
    """``int32 length`` (header included) + ``uint8 type`` + body."""
    return struct.pack(">iB", 5 + len(body), kind) + body


def version_message(version: tuple[int, int, int, int], timestamp_us: int) -> bytes:
    """Robot message (20) of type version (3)."""
    major, minor, bugfix, build = version
    name = b"URControl"
    body = (struct.pack(">QbB", timestamp_us, _SOURCE_CONTROLLER, 3) + struct.pack(">b", len(name)) + name
            + struct.pack(">BBii", major, minor, bugfix, build) + _BUILD_DATE)
    return _package(20, body)


def joint_data(q_rad: list[float]) -> bytes:
    """Sub-package 1: per joint q actual, q target, qd actual (double), current, voltage,
    motor and micro temperature (float), joint mode (uint8; 253 running)."""
    body = b"".join(struct.pack(">dddffffB", q, q, 0.0, 0.0, 48.0, 30.0, 35.0, 253) for q in q_rad)
    return _package(1, body)


def kinematics_info(controller: FakeController) -> bytes:
    """Sub-package 5: 6 x uint32 checksums, DH theta, a, d, alpha (6 doubles each),
    uint32 calibration status."""
    calibration = controller.kinematics_calibration()
    theta, a, d, alpha = calibration.rows()
    body = struct.pack(">6I", *calibration.checksums) + struct.pack(">24d", *theta, *a, *d, *alpha)
    return _package(5, body + struct.pack(">I", 0))


def configuration_data(controller: FakeController) -> bytes:
    """Sub-package 6: joint limits, joint motion limits, defaults, the nominal DH rows
    a, d, alpha, theta, then masterboard version, controller box type, robot type and
    sub-type (placeholders 0 for the two the fake has no real value for)."""
    theta, a, d, alpha = controller.kinematics_calibration().rows()
    limits = [v for _ in range(6) for v in (-2 * 3.141592653589793, 2 * 3.141592653589793)]
    motion = [v for _ in range(6) for v in (3.141592653589793, 40.0)]
    defaults = [1.05, 1.4, 0.25, 1.2, 0.0]
    doubles = struct.pack(">53d", *limits, *motion, *defaults, *a, *d, *alpha, *theta)
    major = controller.config.version[0]
    return _package(6, doubles + struct.pack(">4i", 0, 0, _ROBOT_TYPE_UR5, major))


def robot_state(*packages: bytes) -> bytes:
    """Robot state message (16) of the given sub-packages."""
    return _package(16, b"".join(packages))


class PrimaryServer:
    """Serves one client: version, the full first state, then joint data at 10 Hz."""

    def __init__(self, controller: FakeController) -> None:
        self.controller = controller

    def serve(self, sock: socket.socket) -> None:
        """Until the client leaves or the fake closes the connection."""
        ctrl = self.controller
        timestamp_us = int(ctrl.time_s * 1e6)
        q = ctrl.joint_positions_rad().tolist()
        sock.sendall(version_message(ctrl.config.version, timestamp_us)
                     + robot_state(joint_data(q), kinematics_info(ctrl), configuration_data(ctrl)))
        sock.settimeout(STATE_PERIOD_S)
        while True:
            try:
                if sock.recv(4096) == b"":
                    return  # the client closed
            except TimeoutError:
                pass
            sock.sendall(robot_state(joint_data(ctrl.joint_positions_rad().tolist())))
