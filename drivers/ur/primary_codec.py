"""UR primary client interface wire codec, read side: framing, the version message, the robot
state's sub-packages, the kinematics info and the configuration data.

Pure functions, no I/O (``drivers.ur.primary`` holds the socket). Big-endian throughout.
Every message is ``int32 length`` (the whole message, header included) + ``uint8 type``;
a robot state (type 16) is a row of sub-packages with the same header, so a sub-package
this codec does not read is skipped by its length. The layouts and their sources are in
docs/ur.md ("Primary client interface").
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from lasercal_hw.errors import ProtocolError
from lasercal_hw.models import RobotCalibration

MESSAGE_ROBOT_STATE = 16
MESSAGE_ROBOT_MESSAGE = 20
ROBOT_MESSAGE_VERSION = 3
PACKAGE_KINEMATICS_INFO = 5
PACKAGE_CONFIGURATION_DATA = 6

HEADER = struct.Struct(">iB")
"""``int32 length, uint8 type``: a message's and a sub-package's header."""
MAX_MESSAGE_BYTES = 1 << 20
"""A length beyond this is a garbled stream, not a message (real ones are a few kB)."""
_ROBOT_MESSAGE_HEAD = struct.Struct(">QbB")  # timestamp, source, robot message type
_VERSION_NUMBERS = struct.Struct(">BBii")  # major, minor, bugfix, build
_KINEMATICS = struct.Struct(">6I24dI")  # checksums, theta, a, d, alpha, calibration status
_CONFIGURATION = struct.Struct(">12d12d5d24d4i")
"""Joint limits (min, max per joint), joint motion limits (max speed, max acceleration per
joint), 5 defaults (v/a joint, v/a tool, eq radius), DH a, d, alpha, theta, then masterboard
version, controller box type, robot type, robot sub-type."""

#: Robot type of the configuration data -> model family (docs/ur.md).
ROBOT_TYPES = {1: "UR5", 2: "UR10", 3: "UR3", 4: "UR16", 7: "UR20", 8: "UR30"}


@dataclass(frozen=True)
class VersionMessage:
    """What the controller sends a new client first: its software version."""

    project_name: str
    major: int
    minor: int
    bugfix: int
    build: int

    @property
    def text(self) -> str:
        """``major.minor.bugfix.build``."""
        return f"{self.major}.{self.minor}.{self.bugfix}.{self.build}"


@dataclass(frozen=True)
class KinematicsInfo:
    """Sub-package 5: the calibration checksums and the calibrated DH rows."""

    checksums: tuple[int, ...]
    theta_rad: tuple[float, ...]
    a_m: tuple[float, ...]
    d_m: tuple[float, ...]
    alpha_rad: tuple[float, ...]
    calibration_status: int


@dataclass(frozen=True)
class ConfigurationData:
    """Sub-package 6, the part lasercal reads: the nominal DH rows and the robot's type."""

    dh_a_m: tuple[float, ...]
    dh_d_m: tuple[float, ...]
    dh_alpha_rad: tuple[float, ...]
    dh_theta_rad: tuple[float, ...]
    masterboard_version: int
    controller_box_type: int
    robot_type: int
    robot_sub_type: int


class MessageReader:
    """Cuts a byte stream into ``(type, body)`` messages (body without the header)."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """The messages completed by ``data``; ProtocolError for an impossible length."""
        self._buffer.extend(data)
        messages: list[tuple[int, bytes]] = []
        while len(self._buffer) >= HEADER.size:
            length, kind = HEADER.unpack_from(self._buffer)
            if not HEADER.size <= length <= MAX_MESSAGE_BYTES:
                raise ProtocolError(
                    f"the primary interface sent a message of length {length} (type {kind}): the stream is "
                    "garbled; is this port a UR primary interface (30001, 30011)?"
                )
            if len(self._buffer) < length:
                break
            messages.append((kind, bytes(self._buffer[HEADER.size:length])))
            del self._buffer[:length]
        return messages


def sub_packages(body: bytes) -> list[tuple[int, bytes]]:
    """A robot state's ``(type, body)`` sub-packages; ProtocolError when one overruns it."""
    packages: list[tuple[int, bytes]] = []
    offset = 0
    while offset < len(body):
        if len(body) - offset < HEADER.size:
            raise ProtocolError(f"a robot state ends in {len(body) - offset} stray bytes")
        length, kind = HEADER.unpack_from(body, offset)
        if length < HEADER.size or offset + length > len(body):
            left = len(body) - offset
            raise ProtocolError(f"robot state sub-package {kind} claims {length} bytes, {left} left")
        packages.append((kind, body[offset + HEADER.size:offset + length]))
        offset += length
    return packages


def decode_version(body: bytes) -> VersionMessage | None:
    """The version message in a robot message's body, or None for another robot message."""
    if len(body) < _ROBOT_MESSAGE_HEAD.size + 1:
        raise ProtocolError(f"a robot message of {len(body)} bytes is too short for its header")
    _, _, message_type = _ROBOT_MESSAGE_HEAD.unpack_from(body)
    if message_type != ROBOT_MESSAGE_VERSION:
        return None
    offset = _ROBOT_MESSAGE_HEAD.size
    name_length = body[offset]
    offset += 1
    if len(body) < offset + name_length + _VERSION_NUMBERS.size:
        raise ProtocolError(f"a version message of {len(body)} bytes is too short")
    name = body[offset:offset + name_length].decode("ascii", "replace")
    major, minor, bugfix, build = _VERSION_NUMBERS.unpack_from(body, offset + name_length)
    return VersionMessage(name, major, minor, bugfix, build)


def _rows(values: tuple[float, ...], count: int) -> list[tuple[float, ...]]:
    return [tuple(values[i:i + 6]) for i in range(0, 6 * count, 6)]


def decode_kinematics_info(body: bytes) -> KinematicsInfo:
    """Sub-package 5 (its body); ProtocolError when too short."""
    if len(body) < _KINEMATICS.size:
        raise ProtocolError(f"kinematics info of {len(body)} bytes, {_KINEMATICS.size} expected")
    values = _KINEMATICS.unpack_from(body)
    theta, a, d, alpha = _rows(values[6:30], 4)  # type: ignore[arg-type]
    return KinematicsInfo(tuple(values[:6]), theta, a, d, alpha, int(values[30]))


def decode_configuration_data(body: bytes) -> ConfigurationData:
    """Sub-package 6 (its body); ProtocolError when too short."""
    if len(body) < _CONFIGURATION.size:
        raise ProtocolError(f"configuration data of {len(body)} bytes, {_CONFIGURATION.size} expected")
    values = _CONFIGURATION.unpack_from(body)
    a, d, alpha, theta = _rows(values[29:53], 4)  # type: ignore[arg-type]
    masterboard, box, robot_type, sub_type = values[53:57]
    return ConfigurationData(a, d, alpha, theta, masterboard, box, robot_type, sub_type)


def model_name(robot_type: int | None, software_major: int) -> str:
    """``UR5`` on CB3 (3.x), ``UR5e`` on e-Series (5.x); ``unknown`` for a type not listed."""
    family = ROBOT_TYPES.get(robot_type) if robot_type is not None else None
    if family is None:
        return "unknown"
    return f"{family}e" if software_major >= 5 and family in ("UR3", "UR5", "UR10", "UR16") else family


def robot_calibration(
    version: VersionMessage, kinematics: KinematicsInfo, configuration: ConfigurationData | None
) -> RobotCalibration:
    """What lasercal records of a robot's calibration, from the three messages."""
    robot_type = None if configuration is None else configuration.robot_type
    return RobotCalibration(
        checksums=kinematics.checksums, dh_theta_rad=kinematics.theta_rad, dh_a_m=kinematics.a_m,
        dh_d_m=kinematics.d_m, dh_alpha_rad=kinematics.alpha_rad,
        calibration_status=kinematics.calibration_status,
        model=model_name(robot_type, version.major), software_version=version.text,
    )
