"""The unmodified ur_rtde 1.6.5 client against the fake controller (each fake in its own
process on its own loopback address)."""

from __future__ import annotations

import time
from contextlib import ExitStack

import dashboard_client
import numpy as np
import pytest
import rtde_control

from fakes.ur_controller.controller import DEFAULT_START_Q_RAD
from lasercal_hw.geometry import matrix_to_pose, pose_to_matrix
from lasercal_hw.ur_kinematics import forward_kinematics
from tests.drivers.ur.conftest import StartFake, control_interface, eventually, receive_interface

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

VERSIONS = ["5.11", "3.15"]


@pytest.mark.parametrize("version", VERSIONS)
def test_receive_and_dashboard_report_the_start_pose(start_fake: StartFake, version: str) -> None:
    fake = start_fake("--version", version)
    dash = dashboard_client.DashboardClient(fake.address)
    dash.connect()
    try:
        assert dash.robotmode() == "Robotmode: RUNNING"
        assert dash.safetystatus() == "Safetystatus: NORMAL"
        assert dash.polyscopeVersion().startswith(version)
        with receive_interface(fake.address) as receive:
            expected = matrix_to_pose(forward_kinematics(np.array(DEFAULT_START_Q_RAD)))
            assert np.allclose(receive.getActualTCPPose(), expected, atol=1e-9)
            assert np.allclose(receive.getActualQ(), DEFAULT_START_Q_RAD)
            first = receive.getTimestamp()
            assert eventually(lambda: receive.getTimestamp() > first)
            assert receive.getSafetyStatusBits() == 1 and receive.getRobotMode() == 7
    finally:
        dash.disconnect()


@pytest.mark.parametrize("version", VERSIONS)
def test_sync_movel_and_movej_reach_their_targets(start_fake: StartFake, version: str) -> None:
    fake = start_fake("--version", version)
    with receive_interface(fake.address) as receive, control_interface(fake.address) as control:
        target = receive.getActualTCPPose()
        target[0] += 0.04
        target[2] -= 0.03
        assert control.moveL(target, 0.5, 3.0)
        assert eventually(lambda: np.allclose(receive.getActualTCPPose(), target, atol=1e-6))
        q_target = receive.getActualQ()
        q_target[0] += 0.2
        q_target[5] -= 0.3
        assert control.moveJ(q_target, 2.0, 8.0)
        assert eventually(lambda: np.allclose(receive.getActualQ(), q_target, atol=1e-9))


def test_async_movel_stopped_halfway(start_fake: StartFake) -> None:
    fake = start_fake()
    with receive_interface(fake.address) as receive, control_interface(fake.address) as control:
        start = np.array(receive.getActualTCPPose())
        target = start.copy()
        target[1] += 0.3
        assert control.moveL(target.tolist(), 0.2, 1.0, True)
        assert control.getAsyncOperationProgress() == 0  # running, single move
        time.sleep(0.6)
        control.stopL(2.0)
        assert control.getAsyncOperationProgress() < 0
        assert eventually(lambda: np.allclose(receive.getActualQd(), 0.0))
        stopped = np.array(receive.getActualTCPPose())
        assert start[1] + 0.02 < stopped[1] < target[1] - 0.02
        time.sleep(0.05)
        assert np.allclose(receive.getActualTCPPose(), stopped)  # at rest


def test_inverse_kinematics_and_safety_limits(start_fake: StartFake) -> None:
    fake = start_fake()
    with control_interface(fake.address) as control:
        q = np.array([0.3, -1.2, 1.4, -1.8, -1.5, 0.4])
        pose = matrix_to_pose(forward_kinematics(q)).tolist()
        solution = control.getInverseKinematics(pose, q.tolist())
        assert np.allclose(solution, q, atol=1e-8)
        default = control.getInverseKinematics(pose)
        assert np.allclose(pose_to_matrix(pose), forward_kinematics(np.array(default)), atol=1e-8)
        assert control.isPoseWithinSafetyLimits(pose)
        assert control.getInverseKinematicsHasSolution(pose)
        far = [2.0, 0.0, 0.3, 0.0, 3.14, 0.0]
        assert not control.isPoseWithinSafetyLimits(far)
        assert not control.getInverseKinematicsHasSolution(far)
        assert control.isProgramRunning()


@pytest.mark.slow
def test_second_and_third_connection_after_disconnect(start_fake: StartFake) -> None:
    fake = start_fake()
    for attempt in range(3):
        # The first disconnect leaves the script running: the next constructor kills it.
        with control_interface(fake.address, stop_script=attempt > 0) as control:
            assert control.isProgramRunning()
            q = np.array(DEFAULT_START_Q_RAD)
            q[0] = 0.05 * (attempt + 1)
            assert control.moveJ(q.tolist(), 1.0, 2.0)


def test_second_control_interface_while_connected_is_refused(start_fake: StartFake) -> None:
    fake = start_fake()
    with control_interface(fake.address), pytest.raises(RuntimeError, match="already in use"):
        rtde_control.RTDEControlInterface(fake.address)


def test_local_control_refuses_the_control_interface(start_fake: StartFake) -> None:
    fake = start_fake("--local-control")
    with pytest.raises(RuntimeError, match="remote control"):
        rtde_control.RTDEControlInterface(fake.address)


@pytest.mark.slow
def test_several_fakes_side_by_side(start_fake: StartFake) -> None:
    fakes = [start_fake() for _ in range(3)]
    assert len({fake.address for fake in fakes}) == 3
    with ExitStack() as stack:
        controls = [stack.enter_context(control_interface(fake.address)) for fake in fakes]
        targets = []
        for k, control in enumerate(controls):
            q = np.array(DEFAULT_START_Q_RAD)
            q[0] = 0.1 * (k + 1)
            targets.append(q)
            assert control.moveJ(q.tolist(), 1.05, 1.4, True)
        for control, q in zip(controls, targets, strict=True):
            assert eventually(lambda c=control: c.getAsyncOperationProgress() < 0)
            # getForwardKinematics() without arguments: the TCP pose of the current joints.
            expected = matrix_to_pose(forward_kinematics(q))
            assert np.allclose(control.getForwardKinematics(), expected, atol=1e-9)


def test_upper_range_registers(start_fake: StartFake) -> None:
    fake = start_fake()
    flags = int(rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT) | int(
        rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS)
    control = rtde_control.RTDEControlInterface(fake.address, 500.0, flags)
    try:
        q = np.array(DEFAULT_START_Q_RAD)
        q[0] = 0.2
        assert control.moveJ(q.tolist(), 2.0, 8.0)
        pose = matrix_to_pose(forward_kinematics(q)).tolist()
        assert np.allclose(control.getInverseKinematics(pose), q, atol=1e-8)
    finally:
        control.stopScript()
        control.disconnect()
