"""Shared state of the fake UR controller and its simulation cycle.

One ``FakeController`` holds everything a real controller would: joint state, registers,
modes, the running control program and the motion in progress. ``step`` advances it by
one controller cycle (500 Hz e-Series, 125 Hz CB3); ``run`` calls it at that rate with
absolute deadlines and hands each cycle's ``Snapshot`` to the listeners (the RTDE
streamer). Every mutation happens under one lock, so another component in the same
process (the fake cell's scanner) can read the TCP pose or trigger a fault at any time
with the public methods (``tcp_pose_matrix``, ``trigger_protective_stop``, ...).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fakes.ur_controller.control_script import ControlScript, ScriptRuntimeError
from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from fakes.ur_controller.motion import JointPath, LinearPath, Motion, track_pose
from fakes.ur_controller.pose_floats import pose_of, rotvec_of
from fakes.ur_controller.rtde_protocol import REGISTER_COUNT
from lasercal_hw.geometry import invert_transform, matrix_to_pose, pose_to_matrix
from lasercal_hw.models import FloatArray
from lasercal_hw.ur_kinematics import UR5, forward_kinematics, inverse_kinematics

logger = logging.getLogger(__name__)

#: UR5 "home" posture used when no start configuration is given.
DEFAULT_START_Q_RAD = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)

ROBOT_MODE_NAMES = {
    -1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE",
}
SAFETY_MODE_NAMES = {
    1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
}
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_IDLE = 5
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL = 1
SAFETY_PROTECTIVE_STOP = 3
SAFETY_ROBOT_EMERGENCY_STOP = 7
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2

_SAFETY_BITS = {SAFETY_NORMAL: 0x1, SAFETY_PROTECTIVE_STOP: 0x4, SAFETY_ROBOT_EMERGENCY_STOP: 0x80 | 0x40}
_STATUS_POWER_ON = 0x1
_STATUS_PROGRAM_RUNNING = 0x2
_AT_REST = (0.0,) * 6
_SCRIPT_START_DELAY_S = 0.03
_STEADY_SPEED_RAD_S = 1e-4
_MAX_CYCLE_DT_S = 0.05
# A cycle thread this many cycles late (process suspended) skips ahead instead of catching up.
_RESYNC_CYCLES = 50
# A linear move whose joints would have to exceed their speed limit by this factor in one
# cycle passes (close to) a singularity; the real controller stops there too.
_SINGULARITY_SPEED_FACTOR = 1.5


@dataclass
class FaultPlan:
    """Faults the fake injects by itself. Each fires once, either at a controller time
    (``*_at_s``, seconds after start) or during move command k (``*_at_move``, 1-based,
    when that move is ``move_fraction`` of the way through its duration). The fake cell
    may also call the trigger methods of ``FakeController`` directly."""

    protective_stop_at_move: int | None = None
    protective_stop_at_s: float | None = None
    freeze_at_move: int | None = None
    freeze_at_s: float | None = None
    freeze_duration_s: float = 1.0
    """Length of an RTDE stream freeze (>= 2.5 s makes ur_rtde reconnect, and can crash it)."""
    drop_at_move: int | None = None
    drop_at_s: float | None = None
    """Close every client connection (dashboard, RTDE, script)."""
    move_fraction: float = 0.5
    unlock_delay_s: float = 5.0
    """A protective stop can be unlocked this long after it happened (5 s on a real robot)."""


@dataclass
class ControllerConfig:
    """Identity and start state of one fake controller."""

    version: tuple[int, int, int, int] = (5, 11, 6, 108949)
    serial_number: str = "20185500042"
    model: str = "UR5"
    start_q_rad: tuple[float, ...] = DEFAULT_START_Q_RAD
    tcp_offset_pose: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    remote_control: bool = True
    safety_box_m: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    """Axis-aligned box (min corner, max corner) the TCP must stay in, or None."""
    faults: FaultPlan = field(default_factory=FaultPlan)
    kinematics: KinematicsCalibration = field(default_factory=KinematicsCalibration)
    """The kinematics calibration the primary interface reports (a new client sees a change)."""

    @property
    def cycle_hz(self) -> float:
        """Controller cycle: 500 Hz on e-Series (major > 3), 125 Hz on CB3."""
        return 500.0 if self.version[0] > 3 else 125.0

    @property
    def version_text(self) -> str:
        """``major.minor.bugfix.build``."""
        return ".".join(str(v) for v in self.version)


#: What a cycle publishes, in the order of ``Snapshot.state``: each output's name and its
#: number of scalars, then the four register banks (``output_int_register`` holds
#: ``output_int_register_0`` to ``_47``). ``FakeController._build_snapshot`` fills it.
SNAPSHOT_FIELDS: tuple[tuple[str, int], ...] = (
    ("timestamp", 1),
    ("target_q", 6), ("target_qd", 6), ("actual_q", 6), ("actual_qd", 6),
    ("actual_TCP_pose", 6), ("target_TCP_pose", 6), ("actual_TCP_speed", 6), ("target_TCP_speed", 6),
    ("robot_mode", 1), ("safety_mode", 1), ("safety_status", 1), ("runtime_state", 1),
    ("robot_status_bits", 1), ("safety_status_bits", 1),
    ("output_int_register", REGISTER_COUNT), ("output_double_register", REGISTER_COUNT),
    ("input_int_register", REGISTER_COUNT), ("input_double_register", REGISTER_COUNT),
)


def _field_slices() -> dict[str, slice]:
    slices: dict[str, slice] = {}
    start = 0
    for name, count in SNAPSHOT_FIELDS:
        slices[name] = slice(start, start + count)
        start += count
    return slices


#: Where each of ``SNAPSHOT_FIELDS`` lies in ``Snapshot.state``.
SNAPSHOT_SLICES = _field_slices()


@dataclass(frozen=True)
class Snapshot:
    """The controller state of one cycle, as RTDE publishes it: every field of
    ``SNAPSHOT_FIELDS`` flat in one tuple, built in one go each cycle (the RTDE server
    picks a recipe's values from it by index)."""

    state: tuple[float | int, ...]

    @property
    def values(self) -> dict[str, object]:
        """Each field by name: a scalar, or a tuple for a vector or register bank."""
        return {name: self.state[where] if (where.stop - where.start) > 1 else self.state[where.start]
                for name, where in SNAPSHOT_SLICES.items()}


def _limits_array() -> FloatArray:
    limits = np.asarray(UR5.joint_limits_rad, dtype=float)
    return limits if limits.shape == (6, 2) else limits.T


class FakeController:
    """The simulated controller: state, control program, motion, faults."""

    def __init__(self, config: ControllerConfig | None = None) -> None:
        self.config = config or ControllerConfig()
        self.lock = threading.RLock()
        self._limits = _limits_array()
        self._tcp_offset = np.array(self.config.tcp_offset_pose, dtype=float)
        self._T_flange_tcp = pose_to_matrix(self._tcp_offset)
        self._place_arm(np.array(self.config.start_q_rad, dtype=float))
        self._qd: tuple[float, ...] = _AT_REST
        self._tcp_speed: tuple[float, ...] = _AT_REST
        self._motion: Motion | None = None
        self._move_index = 0
        self._moves_completed = 0
        self._script: ControlScript | None = None
        self._script_start_at: float | None = None
        self._script_offset = 0
        self.program_name = "<unnamed>"
        self.runtime_state = RUNTIME_STOPPED
        self.robot_mode = ROBOT_MODE_RUNNING
        self.safety_mode = SAFETY_NORMAL
        self.remote_control = self.config.remote_control
        self._protective_stop_time: float | None = None
        self.last_error = ""
        self._kinematics = self.config.kinematics
        self.in_int = [0] * REGISTER_COUNT
        self.in_double = [0.0] * REGISTER_COUNT
        self.out_int = [0] * REGISTER_COUNT
        self.out_double = [0.0] * REGISTER_COUNT
        self._frozen_until = -1.0
        self._drop_listeners: list[Callable[[], None]] = []
        self._tick_listeners: list[Callable[[Snapshot], None]] = []
        self._faults_fired: set[str] = set()
        self._start = time.monotonic()
        self._time_s = 0.0
        self._stop_event = threading.Event()
        self._snapshot = self._build_snapshot()

    # -- kinematics helpers (lock held) ---------------------------------------------------

    def _fk(self, q: FloatArray, tcp_offset: FloatArray | None = None) -> FloatArray:
        if tcp_offset is None:  # the TCP's own matrix, made once per set_tcp
            return forward_kinematics(q) @ self._T_flange_tcp
        return forward_kinematics(q, tcp_offset_pose=tcp_offset)

    def _place_arm(self, q: FloatArray, T_tcp: FloatArray | None = None) -> None:
        """Joints and TCP (forward kinematics of ``q`` unless given), with the tuples the
        snapshot publishes made once here, not every cycle."""
        self._q = q
        self._T_tcp = self._fk(q) if T_tcp is None else T_tcp
        self._q_published = tuple(q.tolist())
        self._pose_published = pose_of(self._T_tcp)

    def _ik(self, T_tcp: FloatArray, q_near: FloatArray) -> FloatArray | None:
        return inverse_kinematics(T_tcp, q_near, tcp_offset_pose=self._tcp_offset, limits_rad=self._limits)

    def _track(self, T_tcp: FloatArray, q_previous: FloatArray) -> FloatArray | None:
        q = track_pose(lambda qs: self._fk(qs), T_tcp, q_previous)
        return q if q is not None else self._ik(T_tcp, q_previous)

    def _within_limits(self, q: FloatArray) -> bool:
        return bool(np.all(q >= self._limits[:, 0]) and np.all(q <= self._limits[:, 1]))

    # -- public, thread-safe API for the fake cell and the servers -----------------------

    @property
    def time_s(self) -> float:
        """Controller time (s since start), as RTDE ``timestamp``."""
        return self._time_s

    def tcp_pose_matrix(self) -> FloatArray:
        """Actual TCP pose, 4x4 in the base frame (a copy)."""
        with self.lock:
            return self._T_tcp.copy()

    def tcp_pose(self) -> FloatArray:
        """Actual TCP pose as a UR pose vector."""
        return matrix_to_pose(self.tcp_pose_matrix())

    def joint_positions_rad(self) -> FloatArray:
        """Actual joint positions (a copy)."""
        with self.lock:
            return self._q.copy()

    @property
    def moves_completed(self) -> int:
        """Move commands that ran to their target (the fake cell's waypoint count)."""
        return self._moves_completed

    def kinematics_calibration(self) -> KinematicsCalibration:
        """The kinematics calibration the primary interface reports now."""
        with self.lock:
            return self._kinematics

    def replace_joint(self, joint: int) -> KinematicsCalibration:
        """A joint was replaced and the arm calibrated again (``with_joint_replaced``);
        ValueError for a joint that does not exist."""
        with self.lock:
            self._kinematics = self._kinematics.with_joint_replaced(joint)
            logger.warning("joint %d replaced: kinematics checksums %s", joint,
                           " ".join(f"{c:08x}" for c in self._kinematics.checksums))
            return self._kinematics

    def snapshot(self) -> Snapshot:
        """The newest published cycle."""
        return self._snapshot

    def add_tick_listener(self, listener: Callable[[Snapshot], None]) -> None:
        """Call ``listener(snapshot)`` after every cycle, on the cycle thread."""
        self._tick_listeners.append(listener)

    def add_drop_listener(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` when the dropped-connection fault fires."""
        self._drop_listeners.append(listener)

    def streaming_frozen(self) -> bool:
        """True while the frozen-connection fault holds back RTDE data."""
        return self._time_s < self._frozen_until

    def freeze_streams(self, duration_s: float) -> None:
        """Stop RTDE data for ``duration_s`` (the connections stay open)."""
        with self.lock:
            self._frozen_until = self._time_s + duration_s
        logger.warning("fault: RTDE streams frozen for %.2f s", duration_s)

    def drop_connections(self) -> None:
        """Close every client connection (dashboard, RTDE, script)."""
        logger.warning("fault: dropping every client connection")
        for listener in list(self._drop_listeners):
            listener()

    def trigger_protective_stop(self, reason: str = "injected fault") -> None:
        """Protective stop now: the arm halts, the program stops, bit 2 of
        ``safety_status_bits`` is set until ``unlock protective stop``."""
        with self.lock:
            self.protective_stop(reason)

    def trigger_emergency_stop(self, reason: str = "injected fault") -> None:
        """Robot emergency stop: like a protective stop, but only ``release_emergency_stop``
        (the physical button) clears it."""
        with self.lock:
            self._halt(f"emergency stop: {reason}")
            self.safety_mode = SAFETY_ROBOT_EMERGENCY_STOP

    def release_emergency_stop(self) -> None:
        """Twist the emergency button out: safety back to normal, robot powered off."""
        with self.lock:
            if self.safety_mode == SAFETY_ROBOT_EMERGENCY_STOP:
                self.safety_mode = SAFETY_NORMAL
                self.robot_mode = ROBOT_MODE_POWER_OFF

    def unlock_protective_stop(self) -> str | None:
        """Clear a protective stop; an error text if the unlock delay has not passed."""
        with self.lock:
            if self.safety_mode != SAFETY_PROTECTIVE_STOP:
                return None
            since_s = self._time_s - (self._protective_stop_time or 0.0)
            if since_s < self.config.faults.unlock_delay_s:
                return (
                    f"Cannot unlock protective stop until {self.config.faults.unlock_delay_s:g}s after "
                    "occurrence. Always inspect cause of protective stop before unlocking"
                )
            self.safety_mode = SAFETY_NORMAL
            self._protective_stop_time = None
            logger.info("protective stop unlocked")
            return None

    def set_robot_mode(self, mode: int) -> None:
        """Power off / on / brake release from the dashboard."""
        with self.lock:
            if mode != ROBOT_MODE_RUNNING:
                self._halt("robot not running")
            self.robot_mode = mode

    def load_program(self, name: str, text: str) -> None:
        """A complete program arrived on the script port; start it if it is the ur_rtde
        control script and the robot may run programs."""
        with self.lock:
            if not self.remote_control:
                logger.warning("program %r ignored: the robot is in local control", name)
                return
            if self.robot_mode != ROBOT_MODE_RUNNING or self.safety_mode != SAFETY_NORMAL:
                logger.warning("program %r ignored: robot mode %s, safety %s", name,
                               ROBOT_MODE_NAMES[self.robot_mode], SAFETY_MODE_NAMES[self.safety_mode])
                return
            if name != "rtde_control":
                logger.warning("program %r ignored: the fake runs only ur_rtde's control script", name)
                return
            self._end_program()
            self._script_offset = _register_offset(text)
            self.program_name = name
            self._script_start_at = self._time_s + _SCRIPT_START_DELAY_S
            self.runtime_state = RUNTIME_PLAYING

    def stop_program(self) -> None:
        """Dashboard ``stop``: end the running program and halt the arm."""
        with self.lock:
            self._stop_motion_now()
            self._end_program()

    def program_running(self) -> bool:
        """True while a program is playing."""
        return self.runtime_state == RUNTIME_PLAYING

    def write_inputs(self, values: dict[str, object]) -> None:
        """Apply an RTDE input package (registers; other inputs are accepted and dropped)."""
        with self.lock:
            for name, value in values.items():
                if name.startswith("input_int_register_"):
                    self.in_int[int(name[19:])] = int(value)  # type: ignore[call-overload]
                elif name.startswith("input_double_register_"):
                    self.in_double[int(name[22:])] = float(value)  # type: ignore[arg-type]

    # -- ScriptHost (lock held by the caller) --------------------------------------------

    def read_int(self, index: int) -> int:
        return self.in_int[index]

    def read_double(self, index: int) -> float:
        return self.in_double[index]

    def write_int(self, index: int, value: int) -> None:
        self.out_int[index] = value

    def write_double(self, index: int, value: float) -> None:
        self.out_double[index] = value

    def _begin_move(self) -> None:
        self._move_index += 1
        if self.robot_mode != ROBOT_MODE_RUNNING or self.safety_mode != SAFETY_NORMAL:
            raise ScriptRuntimeError("the robot cannot move in its current mode")

    def start_joint_move(self, q_rad: FloatArray, speed: float, accel: float) -> None:
        self._begin_move()
        target = np.asarray(q_rad, dtype=float)
        if not self._within_limits(target):
            raise ScriptRuntimeError(f"movej: target {np.round(target, 4).tolist()} is outside the "
                                     "joint limits")
        if speed <= 0.0 or accel <= 0.0:
            raise ScriptRuntimeError("movej: speed and acceleration must be positive")
        self._motion = Motion(JointPath(self._q, target), speed, accel)

    def start_linear_move(self, pose: FloatArray, speed: float, accel: float) -> None:
        self._begin_move()
        T_target = pose_to_matrix(pose)
        if self._ik(T_target, self._q) is None:
            raise ScriptRuntimeError("movel: no inverse kinematics solution for "
                                     f"{np.round(pose, 4).tolist()}")
        if speed <= 0.0 or accel <= 0.0:
            raise ScriptRuntimeError("movel: speed and acceleration must be positive")
        self._motion = Motion(LinearPath(self._T_tcp, T_target, self._track), speed, accel)

    def motion_active(self) -> bool:
        return self._motion is not None

    def stop_motion(self, decel: float) -> None:
        if self._motion is not None and not self._motion.stopping:
            self._motion.stop(decel)

    def inverse_kinematics(self, pose: FloatArray, q_near: FloatArray | None) -> FloatArray | None:
        return self._ik(pose_to_matrix(pose), self._q if q_near is None else q_near)

    def forward_kinematics(self, q_rad: FloatArray | None, tcp_offset: FloatArray | None) -> FloatArray:
        q = self._q if q_rad is None else q_rad
        return matrix_to_pose(self._fk(q, tcp_offset))

    def pose_within_safety_limits(self, pose: FloatArray) -> bool:
        box = self.config.safety_box_m
        if box is not None:
            position = np.asarray(pose[:3])
            if np.any(position < box[0]) or np.any(position > box[1]):
                return False
        return self.inverse_kinematics(pose, None) is not None

    def joints_within_safety_limits(self, q_rad: FloatArray) -> bool:
        return self._within_limits(np.asarray(q_rad)) and self.pose_within_safety_limits(
            self.forward_kinematics(q_rad, None))

    def set_tcp_offset(self, pose: FloatArray) -> None:
        self._tcp_offset = np.asarray(pose, dtype=float).copy()
        self._T_flange_tcp = pose_to_matrix(self._tcp_offset)
        self._place_arm(self._q)

    def tcp_offset(self) -> FloatArray:
        return self._tcp_offset.copy()

    def flange_pose(self) -> FloatArray:
        return matrix_to_pose(self._fk(self._q, np.zeros(6)))

    def pose_trans(self, p_from: FloatArray, p_from_to: FloatArray) -> FloatArray:
        return matrix_to_pose(pose_to_matrix(p_from) @ pose_to_matrix(p_from_to))

    def is_steady(self) -> bool:
        return self._motion is None and max(abs(speed) for speed in self._qd) < _STEADY_SPEED_RAD_S

    def protective_stop(self, reason: str) -> None:
        """Protective stop with the lock held."""
        if self.safety_mode == SAFETY_PROTECTIVE_STOP:
            return
        logger.warning("protective stop: %s", reason)
        self._halt(f"protective stop: {reason}")
        self.safety_mode = SAFETY_PROTECTIVE_STOP
        self._protective_stop_time = self._time_s

    def runtime_error(self, message: str) -> None:
        """The control program hit a runtime error: it stops, and so does the arm."""
        logger.warning("control program stopped by a runtime error: %s", message)
        self._halt(message)

    # -- internals (lock held) ------------------------------------------------------------

    def _halt(self, message: str) -> None:
        self.last_error = message
        self._stop_motion_now()
        self._end_program()

    def _stop_motion_now(self) -> None:
        self._motion = None
        self._qd = self._tcp_speed = _AT_REST

    def _end_program(self) -> None:
        self._script = None
        self._script_start_at = None
        self.runtime_state = RUNTIME_STOPPED

    def _advance_motion(self, dt_s: float) -> None:
        motion = self._motion
        if motion is None:
            self._qd = self._tcp_speed = _AT_REST
            return
        q = motion.advance(dt_s, self._q)
        if q is None or (dt_s > 0.0 and np.any(
                np.abs(q - self._q) > _SINGULARITY_SPEED_FACTOR * UR5.joint_speed_limits_rad_s * dt_s)):
            self.runtime_error("movel: the path passes a singularity or leaves the workspace")
            return
        T_new = self._fk(q)
        if dt_s > 0.0:
            self._qd = tuple(((q - self._q) / dt_s).tolist())
            rotation = rotvec_of(T_new @ invert_transform(self._T_tcp))
            translation = ((T_new[:3, 3] - self._T_tcp[:3, 3]) / dt_s).tolist()
            self._tcp_speed = (*translation, *(angle / dt_s for angle in rotation))
        self._place_arm(q, T_new)
        if motion.finished:
            if not motion.stopping:
                self._moves_completed += 1
            self._motion = None

    def _fault_due(self, at_s: float | None, at_move: int | None) -> bool:
        if at_s is not None and self._time_s >= at_s:
            return True
        motion = self._motion
        return (at_move is not None and motion is not None and not motion.stopping
                and self._move_index == at_move
                and motion.elapsed_s >= self.config.faults.move_fraction * motion.profile.duration_s)

    def _check_faults(self) -> None:
        faults = self.config.faults
        if self._fault_due(faults.protective_stop_at_s, faults.protective_stop_at_move):
            self._fire_once("protective_stop", lambda: self.protective_stop("injected fault"))
        if self._fault_due(faults.freeze_at_s, faults.freeze_at_move):
            self._fire_once("freeze", lambda: self.freeze_streams(faults.freeze_duration_s))
        if self._fault_due(faults.drop_at_s, faults.drop_at_move):
            self._fire_once("drop", lambda: threading.Thread(
                target=self.drop_connections, name="fake-ur-drop", daemon=True).start())

    def _fire_once(self, key: str, action: Callable[[], None]) -> None:
        if key not in self._faults_fired:
            self._faults_fired.add(key)
            action()

    def _step_script(self) -> None:
        if self._script_start_at is not None and self._time_s >= self._script_start_at:
            self._script_start_at = None
            self._script = ControlScript(self, self._script_offset)
        script = self._script
        if script is None:
            return
        script.step()
        if script.ended and self._script is script:
            self._end_program()

    def step(self, dt_s: float) -> Snapshot:
        """Advance the controller by one cycle of ``dt_s`` seconds and publish it."""
        with self.lock:
            self._time_s += dt_s
            self._advance_motion(dt_s)
            self._check_faults()
            self._step_script()
            self._snapshot = self._build_snapshot()
            return self._snapshot

    def _build_snapshot(self) -> Snapshot:
        """This cycle's ``Snapshot``, in the order of ``SNAPSHOT_FIELDS``."""
        q, qd, pose, speed = self._q_published, self._qd, self._pose_published, self._tcp_speed
        status = _STATUS_POWER_ON if self.robot_mode >= 4 else 0
        if self.runtime_state == RUNTIME_PLAYING:
            status |= _STATUS_PROGRAM_RUNNING
        return Snapshot((
            self._time_s, *q, *qd, *q, *qd, *pose, *pose, *speed, *speed,
            self.robot_mode, self.safety_mode, self.safety_mode, self.runtime_state,
            status, _SAFETY_BITS.get(self.safety_mode, 0),
            *self.out_int, *self.out_double, *self.in_int, *self.in_double,
        ))

    # -- the cycle thread -----------------------------------------------------------------

    def cycle(self, dt_s: float) -> None:
        """One controller cycle: ``step``, then the snapshot to every tick listener."""
        snapshot = self.step(dt_s)
        for listener in self._tick_listeners:
            listener(snapshot)

    def run(self) -> None:
        """Run cycles at ``config.cycle_hz`` until ``stop``; absolute deadlines, so a late
        cycle does not shift the ones after it."""
        period_s = 1.0 / self.config.cycle_hz
        next_deadline = time.monotonic()
        last = next_deadline
        while not self._stop_event.is_set():
            now = time.monotonic()
            self.cycle(min(now - last, _MAX_CYCLE_DT_S))
            last = now
            next_deadline += period_s
            delay = next_deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -_RESYNC_CYCLES * period_s:
                next_deadline = time.monotonic()  # far behind (suspended?): resynchronise

    def stop(self) -> None:
        """Make ``run`` return."""
        self._stop_event.set()


def _register_offset(script_text: str) -> int:
    """The register offset ur_rtde injected into its control script (0 or 24)."""
    marker = "# int register offset\n"
    position = script_text.find(marker)
    if position < 0:
        return 0
    digits = ""
    for char in script_text[position + len(marker):]:
        if not char.isdigit():
            break
        digits += char
    return int(digits) if digits else 0
