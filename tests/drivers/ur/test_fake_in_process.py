"""``FakeRobot`` hosted in the test process (as the fake cell hosts it), spoken to with raw
sockets: dashboard replies, RTDE setup rules, and the hooks for other components.

ur_rtde itself must never talk to an in-process fake (its constructors hold the GIL)."""

from __future__ import annotations

import socket
import struct

import numpy as np
import pytest

from fakes.ur_controller.controller import DEFAULT_START_Q_RAD
from fakes.ur_controller.process import DASHBOARD_PORT, RTDE_PORT, FakeRobot
from lasercal_hw.ur_kinematics import forward_kinematics

pytestmark = pytest.mark.timeout(30)


def dashboard(robot: FakeRobot) -> tuple[socket.socket, socket.SocketIO]:
    sock = socket.create_connection((robot.address, DASHBOARD_PORT), timeout=5.0)
    reader = sock.makefile("rb")
    assert reader.readline() == b"Connected: Universal Robots Dashboard Server\n"
    return sock, reader  # type: ignore[return-value]


def ask(sock: socket.socket, reader: socket.SocketIO, command: str) -> str:
    sock.sendall(command.encode() + b"\n")
    line = reader.readline()
    assert line.endswith(b"\n") and not line.endswith(b"\r\n")
    return line.decode()[:-1]


def rtde_request(sock: socket.socket, kind: str, payload: bytes = b"") -> tuple[str, bytes]:
    sock.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)
    size, reply_kind = struct.unpack(">HB", sock.recv(3, socket.MSG_WAITALL))
    return chr(reply_kind), sock.recv(size - 3, socket.MSG_WAITALL) if size > 3 else b""


def test_hooks_expose_the_pose_and_faults_reach_the_dashboard(robot: FakeRobot) -> None:
    expected = forward_kinematics(np.array(DEFAULT_START_Q_RAD))
    assert np.allclose(robot.controller.tcp_pose_matrix(), expected)
    sock, reader = dashboard(robot)
    with sock, reader:
        assert ask(sock, reader, "robotmode") == "Robotmode: RUNNING"
        assert ask(sock, reader, "get serial number") == "20185500042"
        assert ask(sock, reader, "is in remote control") == "true"
        assert ask(sock, reader, "programState") == "STOPPED <unnamed>"
        assert ask(sock, reader, "frobnicate") == "could not understand: 'frobnicate'"
        robot.controller.trigger_protective_stop("test")
        assert ask(sock, reader, "safetystatus") == "Safetystatus: PROTECTIVE_STOP"
        assert ask(sock, reader, "unlock protective stop").startswith("Cannot unlock protective stop")
        robot.drop_connections()
        assert reader.readline() == b""


def test_rtde_setup_replies_once_per_request_and_guards_inputs(robot: FakeRobot) -> None:
    with socket.create_connection((robot.address, RTDE_PORT), timeout=5.0) as first, \
            socket.create_connection((robot.address, RTDE_PORT), timeout=5.0) as second:
        assert rtde_request(first, "V", struct.pack(">H", 2)) == ("V", b"\x01")
        kind, payload = rtde_request(first, "v")
        assert kind == "v" and struct.unpack(">IIII", payload)[:2] == (5, 11)
        kind, payload = rtde_request(first, "O", struct.pack(">d", 500.0) + b"timestamp,no_such_thing,")
        assert kind == "O" and payload[1:] == b"DOUBLE,NOT_FOUND"
        kind, payload = rtde_request(first, "I", b"input_int_register_0,input_double_register_3,")
        assert (kind, payload) == ("I", b"\x01INT32,DOUBLE")
        kind, payload = rtde_request(first, "I", b"input_int_register_0,")
        assert payload == b"\x02INT32"  # same connection may re-use; ids count 1, 2, ...
        kind, payload = rtde_request(second, "I", b"input_int_register_1,input_int_register_0,")
        assert payload[1:] == b"INT32,IN_USE"
        kind, payload = rtde_request(second, "O", struct.pack(">d", 500.0) + b"timestamp,actual_q,")
        assert payload == b"\x01DOUBLE,VECTOR6D"
        assert rtde_request(second, "S") == ("S", b"\x01")
        size, kind = struct.unpack(">HB", second.recv(3, socket.MSG_WAITALL))
        assert (size, chr(kind)) == (3 + 1 + 8 + 48, "U")
        body = second.recv(size - 3, socket.MSG_WAITALL)
        assert np.allclose(struct.unpack(">6d", body[9:]), DEFAULT_START_Q_RAD)
