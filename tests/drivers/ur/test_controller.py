"""The fake controller in-process, cycle by cycle (no sockets, no threads): the emulated
control-script protocol, faults and the hooks the fake cell uses."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest

from fakes.ur_controller.controller import (
    DEFAULT_START_Q_RAD,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    ControllerConfig,
    FakeController,
    FaultPlan,
)
from lasercal_hw.geometry import matrix_to_pose
from lasercal_hw.ur_kinematics import forward_kinematics

DT = 0.002
PROGRAM = "def rtde_control():\n    global reg_offset_int = # int register offset\n{offset}    x = 1\nend\n"


def started(config: ControllerConfig | None = None, offset: int = 0) -> FakeController:
    controller = FakeController(config)
    controller.load_program("rtde_control", PROGRAM.format(offset=offset))
    run_until(controller, lambda: controller.out_int[offset] == 1)
    return controller


def run_until(controller: FakeController, condition: Callable[[], bool], max_cycles: int = 5000) -> int:
    for cycle in range(max_cycles):
        if condition():
            return cycle
        controller.step(DT)
    raise AssertionError("condition not reached")


def command(controller: FakeController, cmd: int, doubles: Sequence[float] = (),
            ints: dict[int, int] | None = None, offset: int = 0) -> None:
    """What ur_rtde does: wait for ready, write the command, wait for done, clear."""
    run_until(controller, lambda: controller.out_int[offset] == 1)
    values: dict[str, object] = {f"input_double_register_{k + offset}": v for k, v in enumerate(doubles)}
    values.update({f"input_int_register_{k + offset}": v for k, v in (ints or {}).items()})
    values[f"input_int_register_{offset}"] = cmd
    controller.write_inputs(values)
    run_until(controller,
              lambda: controller.out_int[offset] == 2 or controller.runtime_state != RUNTIME_PLAYING)
    controller.write_inputs({f"input_int_register_{offset}": 0})
    controller.step(DT)


def test_program_start_reports_playing_and_ready() -> None:
    controller = started()
    assert controller.runtime_state == RUNTIME_PLAYING
    assert controller.snapshot().values["robot_status_bits"] == 0x3
    assert controller.out_int[2] & 0x8000 == 0  # no async operation running


def test_sync_movej_blocks_until_the_target_and_counts_the_move() -> None:
    controller = started()
    target = np.array(DEFAULT_START_Q_RAD) + 0.2
    command(controller, 1, [*target, 1.0, 2.0], {1: 0})
    assert np.allclose(controller.joint_positions_rad(), target)
    assert controller.moves_completed == 1
    assert np.allclose(controller.tcp_pose_matrix(), forward_kinematics(target))


def test_async_progress_word_counts_operations() -> None:
    controller = started()
    target = np.array(DEFAULT_START_Q_RAD) + 0.3
    command(controller, 1, [*target, 1.0, 2.0], {1: 1})
    word = controller.out_int[2]
    assert word & 0x8000 and word & 0x7FFF == 0  # running, progress 0
    operation = (word >> 24) & 0x7F
    run_until(controller, lambda: not controller.out_int[2] & 0x8000)
    finished = controller.out_int[2]
    assert (finished >> 24) & 0x7F == operation  # same operation, now finished
    assert ((finished >> 16) & 0xFF) == ((word >> 16) & 0xFF) + 1  # one more write
    assert np.allclose(controller.joint_positions_rad(), target)


def test_inverse_kinematics_failure_stops_the_program_like_urscript() -> None:
    controller = started()
    command(controller, 46, [2.0, 0.0, 0.3, 0.0, 3.14, 0.0])
    assert controller.runtime_state == RUNTIME_STOPPED
    assert "no solution" in controller.last_error


def test_upper_range_register_offset_is_honoured() -> None:
    controller = started(offset=24)
    q = np.array([0.3, -1.2, 1.4, -1.8, -1.5, 0.4])
    command(controller, 46, list(matrix_to_pose(forward_kinematics(q))), offset=24)
    solution = np.array(controller.out_double[24:30])
    assert np.allclose(matrix_to_pose(forward_kinematics(solution)), matrix_to_pose(forward_kinematics(q)))


def test_protective_stop_at_move_k_halts_midway_and_needs_unlock_after_delay() -> None:
    config = ControllerConfig(faults=FaultPlan(protective_stop_at_move=2, unlock_delay_s=0.1))
    controller = started(config)
    command(controller, 1, [*(np.array(DEFAULT_START_Q_RAD) + 0.1), 1.0, 2.0], {1: 0})
    target = np.array(DEFAULT_START_Q_RAD) + 0.5
    command(controller, 1, [*target, 1.0, 2.0], {1: 0})
    q = controller.joint_positions_rad()
    assert np.allclose(q, np.array(DEFAULT_START_Q_RAD) + 0.3, atol=0.01)  # half of 0.4 rad, by symmetry
    assert controller.safety_mode == SAFETY_PROTECTIVE_STOP
    assert controller.snapshot().values["safety_status_bits"] == 0x4
    assert controller.runtime_state == RUNTIME_STOPPED
    for _ in range(10):
        controller.step(DT)
    assert np.allclose(controller.joint_positions_rad(), q)  # stays put
    assert controller.unlock_protective_stop() is not None  # too early
    for _ in range(60):
        controller.step(DT)
    assert controller.unlock_protective_stop() is None
    assert controller.safety_mode == SAFETY_NORMAL
    assert controller.moves_completed == 1


def test_freeze_fault_holds_back_streaming_for_its_duration() -> None:
    controller = FakeController(ControllerConfig(faults=FaultPlan(freeze_at_s=0.01, freeze_duration_s=0.1)))
    frozen = []
    for _ in range(100):
        controller.step(DT)
        frozen.append(controller.streaming_frozen())
    assert 45 <= sum(frozen) <= 55


def test_program_is_ignored_in_local_control() -> None:
    controller = FakeController(ControllerConfig(remote_control=False))
    controller.load_program("rtde_control", PROGRAM.format(offset=0))
    for _ in range(50):
        controller.step(DT)
    assert controller.runtime_state == RUNTIME_STOPPED


@pytest.mark.parametrize("version", [(5, 11, 6, 1), (3, 15, 7, 1)])
def test_cycle_rate_follows_the_controller_generation(version: tuple[int, int, int, int]) -> None:
    assert ControllerConfig(version=version).cycle_hz == (500.0 if version[0] == 5 else 125.0)


def test_protective_stop_at_a_given_time_fires_once() -> None:
    controller = started(ControllerConfig(faults=FaultPlan(protective_stop_at_s=0.1, unlock_delay_s=0.0)))
    cycles = run_until(controller, lambda: controller.safety_mode == SAFETY_PROTECTIVE_STOP)
    assert 0.1 <= controller.time_s < 0.2 and cycles > 0
    assert controller.unlock_protective_stop() is None
    for _ in range(20):
        controller.step(DT)
    assert controller.safety_mode == SAFETY_NORMAL


def test_emergency_stop_sets_the_emergency_bits_until_released() -> None:
    controller = started()
    controller.trigger_emergency_stop()
    controller.step(DT)
    bits = controller.snapshot().values["safety_status_bits"]
    assert isinstance(bits, int) and bits & 0x80 and not bits & 0x1
    assert controller.runtime_state == RUNTIME_STOPPED
    assert controller.unlock_protective_stop() is None  # the dashboard cannot clear an e-stop
    controller.step(DT)
    assert controller.snapshot().values["safety_status_bits"] == bits
    controller.release_emergency_stop()
    controller.step(DT)
    assert controller.snapshot().values["safety_status_bits"] == 0x1
