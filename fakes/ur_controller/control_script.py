"""Emulation of ur_rtde 1.6.5's uploaded control script (``def rtde_control(): ... end``).

The real script is a URScript loop that talks to the client only through RTDE registers
(protocol reference, section 7). This class runs the same loop once per controller
cycle: ``input_int_register_0`` is the command, ``output_int_register_0`` the handshake
(1 ready, 2 done), ``output_int_register_1`` a boolean result, ``output_int_register_2``
the asynchronous progress word, ``output_double_register_0..5`` a vector result.
The script never touches the robot directly: it calls its ``ScriptHost`` (the controller),
always with the controller lock held.
"""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np

from lasercal_hw.models import FloatArray

logger = logging.getLogger(__name__)

READY = 1
DONE = 2

NO_CMD = 0
MOVEJ = 1
MOVEJ_IK = 2
MOVEL = 3
MOVEL_FK = 4
SET_TCP = 29
GET_INVERSE_KINEMATICS_ARGS = 30
PROTECTIVE_STOP = 31
STOPL = 33
STOPJ = 34
IS_POSE_WITHIN_SAFETY_LIMITS = 36
IS_JOINTS_WITHIN_SAFETY_LIMITS = 37
POSE_TRANS = 39
GET_TCP_OFFSET = 40
GET_FORWARD_KINEMATICS_DEFAULT = 43
GET_FORWARD_KINEMATICS_ARGS = 44
GET_INVERSE_KINEMATICS_DEFAULT = 46
IS_STEADY = 47
GET_ACTUAL_TOOL_FLANGE_POSE = 58
GET_IK_HAS_SOLUTION_DEFAULT = 60
GET_IK_HAS_SOLUTION_ARGS = 61
STOP_SCRIPT = 255

#: Commands the script handles on every cycle and answers with "ready", never "done".
REALTIME_COMMANDS = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})

_ASYNC_WRAP = 128
_DEFAULT_STOP_DECEL = 10.0


class ScriptHost(Protocol):
    """What the control script needs from the controller (called with its lock held)."""

    def read_int(self, index: int) -> int: ...
    def read_double(self, index: int) -> float: ...
    def write_int(self, index: int, value: int) -> None: ...
    def write_double(self, index: int, value: float) -> None: ...
    def start_joint_move(self, q_rad: FloatArray, speed: float, accel: float) -> None: ...
    def start_linear_move(self, pose: FloatArray, speed: float, accel: float) -> None: ...
    def motion_active(self) -> bool: ...
    def stop_motion(self, decel: float) -> None: ...
    def inverse_kinematics(self, pose: FloatArray, q_near: FloatArray | None) -> FloatArray | None: ...
    def forward_kinematics(self, q_rad: FloatArray | None, tcp_offset: FloatArray | None) -> FloatArray: ...
    def pose_within_safety_limits(self, pose: FloatArray) -> bool: ...
    def joints_within_safety_limits(self, q_rad: FloatArray) -> bool: ...
    def set_tcp_offset(self, pose: FloatArray) -> None: ...
    def tcp_offset(self) -> FloatArray: ...
    def flange_pose(self) -> FloatArray: ...
    def pose_trans(self, p_from: FloatArray, p_from_to: FloatArray) -> FloatArray: ...
    def is_steady(self) -> bool: ...
    def protective_stop(self, reason: str) -> None: ...
    def runtime_error(self, message: str) -> None: ...


class ScriptRuntimeError(Exception):
    """A URScript runtime error: the real controller halts the program."""


class ControlScript:
    """One running instance of the control program."""

    def __init__(self, host: ScriptHost, register_offset: int = 0) -> None:
        self._host = host
        self._offset = register_offset
        self._executing = False
        self._blocked = False
        self._async_move = False
        self._async_stop = False
        self._write_counter = 0
        self._operation_id = 0
        self.ended = False
        self._write_progress(-1)
        self._out_int(0, READY)

    # -- registers (with the script's register offset) ---------------------------------

    def _in_int(self, index: int) -> int:
        return self._host.read_int(index + self._offset)

    def _in_vector(self, first: int, count: int = 6) -> FloatArray:
        return np.array([self._host.read_double(first + k + self._offset) for k in range(count)])

    def _out_int(self, index: int, value: int) -> None:
        self._host.write_int(index + self._offset, value)

    def _out_vector(self, values: FloatArray) -> None:
        for k, value in enumerate(values):
            self._host.write_double(k + self._offset, float(value))

    def _write_progress(self, value: int) -> None:
        """Async progress word (reference 7.5); value -1 means finished, >= 0 running."""
        self._write_counter = (self._write_counter + 1) % _ASYNC_WRAP
        if value == 0:
            self._operation_id = (self._operation_id + 1) % _ASYNC_WRAP
        word = self._write_counter * 65536 + self._operation_id * 16777216
        if value >= 0:
            word += 32768 + value
        self._out_int(2, word)

    # -- main loop -----------------------------------------------------------------------

    def step(self) -> None:
        """One controller cycle of the script's main loop."""
        if self.ended:
            return
        try:
            self._step()
        except ScriptRuntimeError as exc:
            self.ended = True
            self._host.runtime_error(str(exc))

    def _step(self) -> None:
        moving = self._host.motion_active()
        if (self._async_move or self._async_stop) and not moving:
            self._async_move = self._async_stop = False
            self._write_progress(-1)
        if self._blocked:
            if moving:
                return
            self._blocked = False
            self._out_int(0, DONE)
            return
        command = self._in_int(0)
        if command in REALTIME_COMMANDS:
            self._realtime(command)
            self._out_int(0, READY)
        elif command == NO_CMD:
            self._executing = False
            self._out_int(0, READY)
        elif not self._executing:
            self._executing = True
            if command == STOP_SCRIPT:
                logger.info("control script received stop script")
                self._host.stop_motion(_DEFAULT_STOP_DECEL)
                self.ended = True
                return
            if self._process(command):
                self._out_int(0, DONE)

    def _realtime(self, command: int) -> None:
        if command == GET_ACTUAL_TOOL_FLANGE_POSE:
            self._out_vector(self._host.flange_pose())

    def _kill_async(self) -> None:
        if self._async_move or self._async_stop:
            self._async_move = self._async_stop = False
            self._write_progress(-1)

    def _process(self, command: int) -> bool:
        """Run one command; True when it is done now, False when it blocks on motion."""
        host = self._host
        if command in (MOVEJ, MOVEJ_IK, MOVEL, MOVEL_FK):
            return self._move(command)
        if command in (STOPL, STOPJ):
            return self._stop()
        if command in (GET_INVERSE_KINEMATICS_DEFAULT, GET_INVERSE_KINEMATICS_ARGS):
            q_near = self._in_vector(6) if command == GET_INVERSE_KINEMATICS_ARGS else None
            q = host.inverse_kinematics(self._in_vector(0), q_near)
            if q is None:
                raise ScriptRuntimeError("get_inverse_kin: no solution for the pose")
            self._out_vector(q)
        elif command in (GET_IK_HAS_SOLUTION_DEFAULT, GET_IK_HAS_SOLUTION_ARGS):
            q_near = self._in_vector(6) if command == GET_IK_HAS_SOLUTION_ARGS else None
            self._out_int(1, int(host.inverse_kinematics(self._in_vector(0), q_near) is not None))
        elif command == IS_POSE_WITHIN_SAFETY_LIMITS:
            self._out_int(1, int(host.pose_within_safety_limits(self._in_vector(0))))
        elif command == IS_JOINTS_WITHIN_SAFETY_LIMITS:
            self._out_int(1, int(host.joints_within_safety_limits(self._in_vector(0))))
        elif command == SET_TCP:
            host.set_tcp_offset(self._in_vector(0))
        elif command == GET_TCP_OFFSET:
            self._out_vector(host.tcp_offset())
        elif command == POSE_TRANS:
            self._out_vector(host.pose_trans(self._in_vector(0), self._in_vector(6)))
        elif command == GET_FORWARD_KINEMATICS_DEFAULT:
            self._out_vector(host.forward_kinematics(None, None))
        elif command == GET_FORWARD_KINEMATICS_ARGS:
            self._out_vector(host.forward_kinematics(self._in_vector(0), self._in_vector(6)))
        elif command == IS_STEADY:
            self._out_int(1, int(host.is_steady()))
        elif command == PROTECTIVE_STOP:
            host.protective_stop("protective_stop() called by the control script")
        else:
            logger.debug("control script acknowledges command %d without emulating it", command)
        return True

    def _move(self, command: int) -> bool:
        host = self._host
        self._kill_async()
        target = self._in_vector(0)
        speed, accel = self._host.read_double(6 + self._offset), self._host.read_double(7 + self._offset)
        asynchronous = self._in_int(1) == 1
        if command == MOVEJ_IK:
            solution = host.inverse_kinematics(target, None)
            if solution is None:
                raise ScriptRuntimeError("movej: inverse kinematics found no solution for the pose")
            target = solution
        elif command == MOVEL_FK:
            target = host.forward_kinematics(target, None)
        if command in (MOVEJ, MOVEJ_IK):
            host.start_joint_move(target, speed, accel)
        else:
            host.start_linear_move(target, speed, accel)
        if asynchronous:
            self._async_move = True
            self._write_progress(0)
            return True
        self._blocked = True
        return False

    def _stop(self) -> bool:
        decel = self._host.read_double(self._offset)
        asynchronous = self._in_int(1) == 1
        self._kill_async()
        self._host.stop_motion(decel if decel > 0.0 else _DEFAULT_STOP_DECEL)
        if asynchronous:
            if self._host.motion_active():
                self._async_stop = True
                self._write_progress(0)
            return True
        self._blocked = True
        return False
