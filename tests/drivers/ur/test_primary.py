"""The UR primary interface, read only: the codec against a packet built by hand from the
published layout (docs/ur.md), the fake's bytes read by the client, a changed calibration,
and what the client says when it cannot read."""

from __future__ import annotations

import socket
import struct
import threading
from collections.abc import Iterator

import pytest

from drivers.ur.primary import read_robot_calibration
from drivers.ur.primary_codec import (
    MessageReader,
    decode_configuration_data,
    decode_kinematics_info,
    decode_version,
    model_name,
    sub_packages,
)
from fakes.ur_controller.controller import ControllerConfig
from fakes.ur_controller.kinematics_calibration import DEFAULT_CHECKSUMS, REPLACED_JOINT_THETA_RAD
from fakes.ur_controller.process import DASHBOARD_PORT, FakeRobot
from lasercal_hw.errors import DeviceTimeoutError, ProtocolError, TransportError
from lasercal_hw.ur_kinematics import UR5
from tests.drivers.ur.robot_process import in_process_robot

pytestmark = pytest.mark.timeout(30)

# A UR5e-like calibration: nominal rows plus small corrections, as a captured packet would carry.
THETA = (1.2e-5, -3.4e-4, 2.1e-4, 5e-6, -7e-6, 0.0)
A = (1.5e-4, -0.42488, -0.39237, 6e-5, -2e-5, 0.0)
D = (0.16252, 1.2e-4, -1.3e-4, 0.13342, 0.09969, 0.09962)
ALPHA = (1.57077, 2.1e-4, -1.1e-4, 1.57081, -1.57080, 0.0)
CHECKSUMS = (0x9A3F1C02, 0x0BADF00D, 0x7E5A6B4C, 0x12345678, 0xDEADBEEF, 0xFFFFFFFF)


def _head(length_of_body: int, kind: int) -> bytes:
    return struct.pack(">i", 5 + length_of_body) + bytes([kind])


def hand_built_stream() -> bytes:
    """Version 5.11.6.108949, then one robot state: an unknown sub-package (type 3, 20 bytes),
    the kinematics info (type 5) and the configuration data (type 6), field by field."""
    version_body = (
        (123456789).to_bytes(8, "big") + (-2).to_bytes(1, "big", signed=True) + bytes([3])
        + bytes([9]) + b"URControl" + bytes([5, 11]) + (6).to_bytes(4, "big") + (108949).to_bytes(4, "big")
        + b"01-02-2024, 10:00:00"
    )
    kinematics_body = b"".join(c.to_bytes(4, "big") for c in CHECKSUMS)
    kinematics_body += b"".join(struct.pack(">d", v) for row in (THETA, A, D, ALPHA) for v in row)
    kinematics_body += (1).to_bytes(4, "big")
    configuration_body = b"".join(struct.pack(">d", v) for v in [0.0] * 29)
    configuration_body += b"".join(struct.pack(">d", v) for row in (A, D, ALPHA, THETA) for v in row)
    configuration_body += b"".join(v.to_bytes(4, "big") for v in (3, 5, 1, 4))  # board, box, UR5, sub-type
    unknown = b"\x01" * 20
    state_body = (_head(len(unknown), 3) + unknown + _head(len(kinematics_body), 5) + kinematics_body
                  + _head(len(configuration_body), 6) + configuration_body)
    return _head(len(version_body), 20) + version_body + _head(len(state_body), 16) + state_body


def test_the_codec_reads_a_hand_built_packet_skipping_the_unknown_sub_package() -> None:
    stream = hand_built_stream()
    reader = MessageReader()
    messages = reader.feed(stream[:7]) + reader.feed(stream[7:200]) + reader.feed(stream[200:])
    assert [kind for kind, _ in messages] == [20, 16]
    version = decode_version(messages[0][1])
    assert version is not None and version.text == "5.11.6.108949" and version.project_name == "URControl"
    packages = sub_packages(messages[1][1])
    assert [kind for kind, _ in packages] == [3, 5, 6]
    kinematics = decode_kinematics_info(packages[1][1])
    assert kinematics.checksums == CHECKSUMS and kinematics.calibration_status == 1
    rows = (kinematics.theta_rad, kinematics.a_m, kinematics.d_m, kinematics.alpha_rad)
    assert rows == (THETA, A, D, ALPHA)
    configuration = decode_configuration_data(packages[2][1])
    assert configuration.robot_type == 1 and configuration.robot_sub_type == 4
    assert configuration.dh_d_m == D and configuration.controller_box_type == 5
    assert model_name(configuration.robot_type, version.major) == "UR5e"
    assert model_name(1, 3) == "UR5" and model_name(99, 5) == "unknown"


def test_garbled_and_short_bytes_are_protocol_errors() -> None:
    with pytest.raises(ProtocolError, match="garbled"):
        MessageReader().feed(struct.pack(">iB", 2, 16))
    with pytest.raises(ProtocolError, match="claims"):
        sub_packages(_head(200, 5) + b"\x00" * 10)
    with pytest.raises(ProtocolError, match="kinematics info of 100 bytes"):
        decode_kinematics_info(b"\x00" * 100)


def _dashboard(robot: FakeRobot, command: str) -> str:
    with socket.create_connection((robot.address, DASHBOARD_PORT), timeout=5.0) as sock:
        reader = sock.makefile("rb")
        reader.readline()
        sock.sendall(command.encode() + b"\n")
        return reader.readline().decode().strip()


def test_the_client_reads_the_fake_and_sees_a_replaced_joint(robot: FakeRobot) -> None:
    before = read_robot_calibration(robot.address, timeout_s=5.0)
    assert before.checksums == DEFAULT_CHECKSUMS
    assert before.dh_d_m == UR5.dh.d_m and before.dh_a_m == UR5.dh.a_m
    assert before.model == "UR5e" and before.software_version == "5.11.6.108949"
    assert "Joint 2 replaced" in _dashboard(robot, "fake replace joint 2")
    after = read_robot_calibration(robot.address, timeout_s=5.0)
    assert after.checksums[0] == before.checksums[0] and after.checksums[1] != before.checksums[1]
    assert after.dh_theta_rad[1] == pytest.approx(REPLACED_JOINT_THETA_RAD)
    change = after.change_from(before)
    assert change == f"checksum {before.checksum} -> {after.checksum}"
    assert before.change_from(before) is None
    assert "could not understand" in _dashboard(robot, "fake replace joint 7")


def test_a_cb3_controller_reports_the_same_layout_as_a_ur5() -> None:
    with in_process_robot(ControllerConfig(version=(3, 15, 7, 106331))) as robot:
        calibration = read_robot_calibration(robot.address, timeout_s=5.0)
    assert calibration.model == "UR5" and calibration.software_version == "3.15.7.106331"
    assert calibration.checksums == DEFAULT_CHECKSUMS and calibration.dh_a_m == UR5.dh.a_m


@pytest.fixture
def version_only_server() -> Iterator[int]:
    """A primary interface on 127.0.0.1 that sends the version message and then nothing."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    stream = hand_built_stream()
    version_length = struct.unpack(">i", stream[:4])[0]

    def serve() -> None:
        client, _ = server.accept()
        with client:
            client.sendall(stream[:version_length])
            client.recv(1)  # until the client leaves

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield server.getsockname()[1]
    server.close()


def test_a_silent_or_absent_primary_interface_is_a_clear_device_error(version_only_server: int) -> None:
    with pytest.raises(DeviceTimeoutError, match=r"sent no kinematics info within 0\.3 s"):
        read_robot_calibration("127.0.0.1", port=version_only_server, timeout_s=0.3)
    with pytest.raises(TransportError, match="cannot reach the robot's primary interface"):
        read_robot_calibration("127.0.0.1", port=1, timeout_s=0.5)

