"""The fake controller's cheap 500 Hz cycle publishes what the plain computation would:
the pose in floats, the snapshot's layout and the precompiled data packages."""

from __future__ import annotations

import socket
import struct

import numpy as np
import pytest

from fakes.ur_controller import rtde_protocol as rp
from fakes.ur_controller.controller import FakeController
from fakes.ur_controller.pose_floats import pose_of
from fakes.ur_controller.rtde_server import DataPackager, RtdeServer, RtdeSession
from lasercal_hw.geometry import matrix_to_pose, pose_to_matrix

DT = 0.002


def _rotations() -> list[np.ndarray]:
    """Poses over every angle the conversion branches on: none, tiny, ordinary, near and at pi."""
    rng = np.random.default_rng(11)
    poses = [np.zeros(6), np.array([0.1, 0.2, 0.3, np.pi, 0.0, 0.0]), np.array([0, 0, 0, 0, 0, -np.pi])]
    for angle in (1e-12, 1e-9, 1e-7, 0.01, 1.0, 2.5, np.pi - 1e-6, np.pi):
        for _ in range(12):
            axis = rng.normal(size=3)
            poses.append(np.r_[rng.normal(size=3), angle * axis / np.linalg.norm(axis)])
    return [pose_to_matrix(pose) for pose in poses]


@pytest.mark.parametrize("transform", _rotations())
def test_pose_in_floats_is_geometry_to_the_last_bits(transform: np.ndarray) -> None:
    # 2 ulp: numpy's arctan2 and norm need not round as libm's atan2 and a plain sum do.
    np.testing.assert_array_max_ulp(np.array(pose_of(transform)), matrix_to_pose(transform), maxulp=2)


def _moving_controller() -> FakeController:
    controller = FakeController()
    with controller.lock:
        controller.set_tcp_offset(np.array([0.0, 0.0, 0.1, 0.0, 0.0, 0.4]))
        controller.start_joint_move(np.array(controller.config.start_q_rad) + 0.2, 1.0, 2.0)
    for _ in range(60):
        controller.step(DT)
    controller.write_inputs({"input_int_register_3": 77, "input_double_register_47": -2.5})
    controller.write_int(5, 9)
    controller.write_double(0, 1.25)
    controller.step(DT)
    assert controller.motion_active()
    return controller


def test_snapshot_fields_hold_the_controller_state_mid_move() -> None:
    controller = _moving_controller()
    values = controller.snapshot().values
    assert values["timestamp"] == controller.time_s
    assert values["actual_q"] == values["target_q"] == tuple(controller.joint_positions_rad())
    assert values["actual_TCP_pose"] == tuple(matrix_to_pose(controller.tcp_pose_matrix()))
    assert max(abs(v) for v in values["actual_qd"]) > 0.1
    assert values["actual_TCP_speed"] == values["target_TCP_speed"] and any(values["actual_TCP_speed"])
    assert values["robot_status_bits"] == 0x1 and values["safety_status_bits"] == 0x1
    assert values["input_int_register"][3] == 77 and values["input_double_register"][47] == -2.5
    assert values["output_int_register"][5] == 9 and values["output_double_register"][0] == 1.25


def test_data_package_is_the_recipe_packed_by_name() -> None:
    controller = _moving_controller()
    names = ["timestamp", "actual_TCP_pose", "target_qdd", "joint_temperatures", "robot_mode",
             "joint_mode", "actual_digital_input_bits", "input_int_register_3", "output_int_register_5",
             "input_double_register_47", "output_double_register_0", "safety_status_bits", "actual_qd"]
    types, ok = rp.resolve(names, rp.output_type)
    assert ok
    recipe = rp.Recipe(names, types)
    values = controller.snapshot().values
    expected = {
        "timestamp": controller.time_s, "actual_TCP_pose": values["actual_TCP_pose"],
        "target_qdd": (0.0,) * 6, "joint_temperatures": (30.0,) * 6, "robot_mode": 7,
        "joint_mode": (253,) * 6, "actual_digital_input_bits": 0, "input_int_register_3": 77,
        "output_int_register_5": 9, "input_double_register_47": -2.5, "output_double_register_0": 1.25,
        "safety_status_bits": 1, "actual_qd": values["actual_qd"],
    }
    wire = DataPackager(recipe, 1).package(controller.snapshot())
    assert wire == rp.encode_message(rp.DATA_PACKAGE, b"\x01" + recipe.pack(expected))


def test_a_session_streams_the_packages_the_recipe_asks_for() -> None:
    controller = _moving_controller()
    server = RtdeServer(controller)
    ours, theirs = socket.socketpair()
    with ours, theirs:
        session = RtdeSession(server, ours)
        session._handle(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", 250.0) + b"timestamp,actual_q,")
        session._handle(rp.CONTROL_PACKAGE_START, b"")
        theirs.recv(4096)  # the two replies
        for _ in range(3):
            session.send_data(controller.step(DT))
        wire = theirs.recv(4096)
    packages = [wire[k:k + 60] for k in range(0, len(wire), 60)]
    assert len(packages) == 2  # 250 Hz: the first cycle after the start, then every second one
    size, kind, recipe_id, timestamp, *q = struct.unpack(">HBBd6d", packages[-1])
    assert (size, kind, recipe_id) == (60, rp.DATA_PACKAGE, 1)
    assert timestamp == controller.time_s and tuple(q) == tuple(controller.joint_positions_rad())
