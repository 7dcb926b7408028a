"""Read the robot's identity and its kinematics calibration from the UR primary client
interface, read only.

The client connects to the read-only primary port 30011 (``PRIMARY_READ_ONLY_PORT``), which
sends what port 30001 sends but ignores anything a client writes, and it never writes a
byte. A controller sends a new client its version message first, then robot states; the
kinematics info and the configuration data come in the first robot state (later ones leave
them out), so one short connection reads everything. docs/ur.md has the byte layout.
"""

from __future__ import annotations

import socket
import time

from drivers.loopback import check_host
from drivers.ur.primary_codec import (
    MESSAGE_ROBOT_MESSAGE,
    MESSAGE_ROBOT_STATE,
    PACKAGE_CONFIGURATION_DATA,
    PACKAGE_KINEMATICS_INFO,
    ConfigurationData,
    KinematicsInfo,
    MessageReader,
    VersionMessage,
    decode_configuration_data,
    decode_kinematics_info,
    decode_version,
    robot_calibration,
    sub_packages,
)
from lasercal_hw.errors import DeviceTimeoutError, TransportError
from lasercal_hw.models import RobotCalibration

PRIMARY_READ_ONLY_PORT = 30011
TIMEOUT_S = 3.0


def read_robot_calibration(
    host: str, *, port: int = PRIMARY_READ_ONLY_PORT, timeout_s: float = TIMEOUT_S
) -> RobotCalibration:
    """The robot's calibration as its controller reports it. TransportError when nothing
    answers, DeviceTimeoutError when the messages do not all come within ``timeout_s``,
    ProtocolError for a garbled stream."""
    check_host(host, "the robot's primary interface")
    deadline = time.monotonic() + timeout_s
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as exc:
        raise TransportError(
            f"cannot reach the robot's primary interface at {host}:{port}: {exc.strerror or exc}"
        ) from exc
    reader = MessageReader()
    version: VersionMessage | None = None
    kinematics: KinematicsInfo | None = None
    configuration: ConfigurationData | None = None
    with sock:
        while version is None or kinematics is None:
            remaining_s = deadline - time.monotonic()
            if remaining_s <= 0:
                missing = "no version message" if version is None else "no kinematics info"
                raise DeviceTimeoutError(
                    f"the robot's primary interface at {host}:{port} sent {missing} within {timeout_s:g} s"
                )
            sock.settimeout(remaining_s)
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as exc:
                raise TransportError(f"the robot's primary interface at {host}:{port} failed: {exc}") from exc
            if not data:
                raise TransportError(f"the robot's primary interface at {host}:{port} closed the connection")
            for kind, body in reader.feed(data):
                if kind == MESSAGE_ROBOT_MESSAGE:
                    version = decode_version(body) or version
                elif kind == MESSAGE_ROBOT_STATE:
                    for package, content in sub_packages(body):
                        if package == PACKAGE_KINEMATICS_INFO:
                            kinematics = decode_kinematics_info(content)
                        elif package == PACKAGE_CONFIGURATION_DATA:
                            configuration = decode_configuration_data(content)
    assert version is not None and kinematics is not None  # the loop ends only with both
    return robot_calibration(version, kinematics, configuration)
