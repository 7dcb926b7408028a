"""Robot client over the unmodified ur_rtde 1.6.5: ``URRobot`` implements ``Robot``.

Connections: one ``DashboardClient`` (modes, identity), one ``RTDEReceiveInterface``
(pose, joints, safety bits at 500/125 Hz) and one ``RTDEControlInterface`` (motion,
kinematics queries). Every ur_rtde call goes through ``drivers.ur.calls.ur_call``.

Motion: moves are sent *asynchronously* and then watched: the safety status bits from
the receive interface are polled every ``POLL_S`` while the arm moves, so a protective
or emergency stop raises ``ProtectiveStopError`` within a few milliseconds (one RTDE
package plus one poll). After that the client refuses every further motion command
until a new connection: it never resumes motion by itself. Requested speeds and
accelerations above ``MotionLimits`` raise ``ConfigError``; they are never clamped.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.loopback import check_host
from drivers.ur.calls import ur_call
from drivers.ur.dashboard import DASHBOARD_PORT, after_colon
from lasercal_hw.errors import (
    ConfigError,
    DeviceTimeoutError,
    ProtectiveStopError,
    RobotError,
    TransportError,
)
from lasercal_hw.geometry import invert_transform, matrix_to_pose, pose_to_matrix, rotation_angle_rad
from lasercal_hw.models import FloatArray, RobotIdentity, RobotState
from lasercal_hw.ur_kinematics import move_duration_s

logger = logging.getLogger(__name__)

RTDE_PORT = 30004
POLL_S = 0.002
PROTECTIVE_STOP_BIT = 1 << 2
EMERGENCY_STOP_BITS = (1 << 5) | (1 << 6) | (1 << 7)
_COMMAND_TIMEOUT_S = 10.0
_POSITION_TOLERANCE_M = 1e-4
_ROTATION_TOLERANCE_RAD = 1e-3
_JOINT_TOLERANCE_RAD = 1e-3
_STEADY_SPEED_RAD_S = 1e-3
_MOVE_MARGIN_S = 2.0
STREAM_STALL_S = 0.3
_SETTLE_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class MotionLimits:
    """Caps on what the client will ask of the arm (a request above raises ConfigError)."""

    max_speed_m_s: float = 0.25
    max_accel_m_s2: float = 1.2
    max_joint_speed_rad_s: float = 1.05
    max_joint_accel_rad_s2: float = 1.4

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not value > 0.0:
                raise ConfigError(f"motion limit {name} must be positive, got {value}")

    def check(self, speed: float, accel: float, *, joint: bool) -> None:
        """ConfigError if ``speed``/``accel`` are not positive or exceed the caps."""
        unit = "rad/s" if joint else "m/s"
        max_speed = self.max_joint_speed_rad_s if joint else self.max_speed_m_s
        max_accel = self.max_joint_accel_rad_s2 if joint else self.max_accel_m_s2
        if not 0.0 < speed <= max_speed:
            raise ConfigError(f"speed {speed:g} {unit} is outside (0, {max_speed:g}] {unit}, the configured "
                              "limit; lower the speed or raise the limit in the configuration")
        if not 0.0 < accel <= max_accel:
            raise ConfigError(f"acceleration {accel:g} {unit}² is outside (0, {max_accel:g}] {unit}², the "
                              "configured limit; lower it or raise the limit in the configuration")


def probe_controller(host: str, timeout_s: float) -> tuple[int, int, int, int]:
    """Check that a UR controller answers on ``host`` and return its version.

    Plain sockets with timeouts: the dashboard must send its banner, RTDE must answer a
    protocol-version and a controller-version request. ur_rtde's constructors wait
    without a timeout (and hold the GIL), so this runs first.
    """
    check_host(host, "the UR controller")
    try:
        with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout_s) as dash:
            if not dash.recv(256):
                raise TransportError(f"UR dashboard on {host}:{DASHBOARD_PORT} closed without a banner")
        with socket.create_connection((host, RTDE_PORT), timeout=timeout_s) as rtde:
            rtde.sendall(struct.pack(">HBH", 5, ord("V"), 2))
            _read_rtde_reply(rtde, ord("V"))
            rtde.sendall(struct.pack(">HB", 3, ord("v")))
            payload = _read_rtde_reply(rtde, ord("v"))
    except TimeoutError as exc:
        raise DeviceTimeoutError(f"UR controller on {host} did not answer within {timeout_s:g} s") from exc
    except OSError as exc:
        raise TransportError(f"cannot reach a UR controller on {host}: {exc.strerror or exc}; check the "
                             "address, the cable and that the robot is powered") from exc
    if len(payload) < 16:
        raise TransportError(f"UR controller on {host} sent a short version reply")
    major, minor, bugfix, build = struct.unpack(">IIII", payload[:16])
    return major, minor, bugfix, build


def _read_rtde_reply(sock: socket.socket, package_type: int) -> bytes:
    header = _read_exact(sock, 3)
    size, kind = struct.unpack(">HB", header)
    payload = _read_exact(sock, size - 3)
    if kind != package_type:
        raise TransportError(f"RTDE answered {chr(kind)!r} to a {chr(package_type)!r} request")
    return payload


def _read_exact(sock: socket.socket, count: int) -> bytes:
    data = bytearray()
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise TransportError("RTDE connection closed during the version handshake")
        data += chunk
    return bytes(data)


@dataclass(frozen=True)
class _Stall:
    message: str
    connected: bool


class _StreamWatchdog:
    """Notices when the RTDE receive stream stops (frozen or dropped connection)."""

    def __init__(self, receive: Any) -> None:
        self._receive = receive
        self._last_timestamp = -1.0
        self._last_change = time.monotonic()

    def problem(self) -> _Stall | None:
        """What is wrong with the stream, or None while packages keep arriving."""
        if not ur_call("isConnected", self._receive.isConnected, false_is_error=False):
            return _Stall("the RTDE connection to the robot was lost", connected=False)
        timestamp = float(ur_call("getTimestamp", self._receive.getTimestamp, false_is_error=False))
        now = time.monotonic()
        if timestamp != self._last_timestamp:
            self._last_timestamp, self._last_change = timestamp, now
        elif now - self._last_change > STREAM_STALL_S:
            return _Stall(f"no robot state for {now - self._last_change:.2f} s (RTDE stream stalled)",
                          connected=True)
        return None


class _Unavailable:
    """Stands in for an ur_rtde interface that is not there: after ``close`` (so the real
    ones, their sockets and threads are freed) or on a read-only connection. Every use
    raises RobotError with the reason."""

    def __init__(self, reason: str) -> None:
        self._reason = reason

    def __getattr__(self, name: str) -> Any:
        raise RobotError(f"cannot call {name}: {self._reason}")


class URRobot:
    """A UR arm through ur_rtde; use ``URRobot.connect(host)``."""

    def __init__(self, host: str, limits: MotionLimits, version: tuple[int, int, int, int],
                 dashboard: Any, receive: Any, control: Any | None) -> None:
        self.host = host
        self.limits = limits
        self.version = version
        self._dashboard = dashboard
        self._receive = receive
        self._has_control = control is not None
        self._control = control if control is not None else _Unavailable(
            "this connection is read-only; connect with control=True to move or query kinematics")
        self._halted: str | None = None
        self._broken: tuple[str, type[RobotError | TransportError]] | None = None
        self._closed = False
        self._command_lock = threading.Lock()
        self._tcp_offset = (pose_to_matrix(self._command("getTCPOffset", control.getTCPOffset))
                            if control is not None else None)

    @classmethod
    def connect(cls, host: str, limits: MotionLimits | None = None, *, timeout_s: float = 5.0,
                control: bool = True) -> URRobot:
        """Connect the dashboard, receive and (unless ``control`` is off) control
        interfaces. The control interface uploads ur_rtde's control script, which stops
        any program running on the robot; a read-only connection (``control=False``)
        leaves the robot's program alone but cannot move or query kinematics.
        Raises TransportError/DeviceTimeoutError if nothing answers, RobotError if the
        controller refuses (e.g. remote control off)."""
        import dashboard_client
        import rtde_control
        import rtde_receive

        version = probe_controller(host, timeout_s)
        if version[0] >= 10 or (version[0] in (3, 5) and version[1] < 4):
            raise RobotError(f"controller software {'.'.join(map(str, version))} is not supported "
                             "(use CB3 3.4+ or e-Series 5.4+)")
        opened: list[Any] = []
        try:
            dashboard = dashboard_client.DashboardClient(host)
            ur_call("DashboardClient.connect", dashboard.connect)
            opened.append(dashboard)
            receive = ur_call("RTDEReceiveInterface", lambda: rtde_receive.RTDEReceiveInterface(host))
            opened.append(receive)
            control_interface = None
            if control:
                control_interface = ur_call("RTDEControlInterface",
                                            lambda: rtde_control.RTDEControlInterface(host))
                opened.append(control_interface)
            return cls(host, limits or MotionLimits(), version, dashboard, receive, control_interface)
        except BaseException:
            for interface in reversed(opened):
                try:
                    ur_call("disconnect", interface.disconnect, false_is_error=False)
                except RobotError as exc:
                    logger.debug("disconnect after a failed connect: %s", exc)
            raise

    def _command(self, what: str, fn: Any, *, false_is_error: bool = True,
                 timeout_s: float = _COMMAND_TIMEOUT_S) -> Any:
        """A control-interface command: serialised, with a deadline; a lost control
        connection is a TransportError at once (ur_rtde would spend seconds reconnecting
        and then report a refusal)."""
        if self._has_control and not self._closed and not ur_call(
                "isConnected", self._control.isConnected, false_is_error=False):
            raise self._lost("control", what)
        return ur_call(what, fn, timeout_s=timeout_s, false_is_error=false_is_error, lock=self._command_lock,
                       connected=self._connected)

    def _connected(self) -> bool:
        """Both RTDE connections up (as far as ur_rtde knows)."""
        return bool(self._receive.isConnected()) and bool(self._control.isConnected())

    def _read(self, what: str, fn: Any) -> Any:
        """A receive-interface read (an empty list is a RobotError). ur_rtde keeps answering
        with the last package after its connection is gone, so a lost connection is a
        TransportError, never stale data."""
        if not ur_call("isConnected", self._receive.isConnected, false_is_error=False):
            raise self._lost("RTDE receive", what)
        return ur_call(what, fn, false_is_error=False)

    def _lost(self, interface: str, what: str) -> TransportError:
        """The error for a connection found lost before ``what``; no motion after it."""
        reason = f"the {interface} connection to the robot at {self.host} was lost"
        self._broken = (reason, TransportError)
        return TransportError(f"{what}: {reason} (the controller closed it or is gone); the robot's state "
                              "is unknown: check it and connect again")

    # -- identity and state ----------------------------------------------------------------

    def _e_series_5_6(self) -> bool:
        return self.version[0] == 5 and self.version[1] >= 6

    def identity(self) -> RobotIdentity:
        """Model, serial and software version (model and serial need PolyScope 5.6+)."""
        dash = self._dashboard
        if self._e_series_5_6():
            model = ur_call("getRobotModel", dash.getRobotModel)
            serial = ur_call("getSerialNumber", dash.getSerialNumber)
        else:
            model, serial = "unknown (CB3 dashboard does not report it)", "unknown"
        software = ur_call("polyscopeVersion", dash.polyscopeVersion)
        return RobotIdentity(model=model, serial_number=serial, software_version=software,
                             controller_version=self.version)

    def safety_status_bits(self) -> int:
        """``safety_status_bits`` of the newest RTDE package."""
        return int(self._read("getSafetyStatusBits", self._receive.getSafetyStatusBits))

    def state(self) -> RobotState:
        """Robot mode, safety status, program and remote-control state."""
        dash = self._dashboard
        bits = self.safety_status_bits()
        remote = (bool(ur_call("isInRemoteControl", dash.isInRemoteControl, false_is_error=False))
                  if self._e_series_5_6() else True)
        return RobotState(
            robot_mode=after_colon(ur_call("robotmode", dash.robotmode)),
            safety_status=after_colon(ur_call("safetystatus", dash.safetystatus)),
            program_running=self._program_running(),
            remote_control=remote,
            protective_stop=bool(bits & PROTECTIVE_STOP_BIT),
            emergency_stop=bool(bits & EMERGENCY_STOP_BITS),
        )

    def _program_stops_within(self, timeout_s: float) -> bool:
        """Whether the receive stream shows the program stopped within ``timeout_s``: after a
        refused command, the stream (a connection of its own) may not show it yet."""
        deadline = time.monotonic() + timeout_s
        while self._program_running():
            if time.monotonic() > deadline:
                return False
            time.sleep(POLL_S)
        return True

    def _program_running(self) -> bool:
        """``runtime_state == 2`` (PLAYING) in the receive stream, ur_rtde's own test."""
        return int(self._read("getRuntimeState", self._receive.getRuntimeState)) == 2

    def tcp_pose(self) -> FloatArray:
        """Actual TCP pose (UR pose vector) from the newest RTDE package."""
        return np.array(self._read("getActualTCPPose", self._receive.getActualTCPPose))

    def flange_pose(self) -> FloatArray:
        """Actual flange (tool0) pose: the TCP pose times the inverse TCP offset.

        ur_rtde's getActualToolFlangePose is fire-and-forget in 1.6.5 and reads its
        result registers before the script wrote them, so it is not used. The TCP offset
        comes from the control interface (RobotError on a read-only connection).
        """
        if self._tcp_offset is None:
            raise RobotError("the flange pose needs the TCP offset, which only a control connection reads")
        return matrix_to_pose(pose_to_matrix(self.tcp_pose()) @ invert_transform(self._tcp_offset))

    def joint_positions_rad(self) -> FloatArray:
        """Actual joint positions (rad)."""
        return np.array(self._read("getActualQ", self._receive.getActualQ))

    # -- motion --------------------------------------------------------------------------------

    def _check_may_move(self) -> None:
        if self._closed:
            raise RobotError("the robot connection is closed; connect again")
        if not self._has_control:
            raise RobotError("this connection is read-only; connect with control=True to move the robot")
        if self._halted is not None:
            raise ProtectiveStopError(f"motion refused: {self._halted} earlier on this connection; inspect "
                                      "the cell, unlock the stop on the teach pendant and connect again")
        if self._broken is not None:
            reason, error = self._broken
            raise error(f"motion refused: {reason} earlier on this connection; connect again")
        self._raise_if_stopped()

    def _raise_if_stopped(self) -> None:
        bits = self.safety_status_bits()
        if bits & (PROTECTIVE_STOP_BIT | EMERGENCY_STOP_BITS):
            kind = "protective stop" if bits & PROTECTIVE_STOP_BIT else "emergency stop"
            self._halted = kind
            raise ProtectiveStopError(f"the robot is in a {kind} (safety status bits 0x{bits:x}); the arm "
                                      "is stopped and will not move again on this connection")

    def move_linear(self, pose: FloatArray, speed_m_s: float, accel_m_s2: float) -> None:
        """Straight TCP line to ``pose``; blocks until there (or raises)."""
        self._check_may_move()
        self.limits.check(speed_m_s, accel_m_s2, joint=False)
        target = np.asarray(pose, dtype=float).reshape(6)
        start = pose_to_matrix(self.tcp_pose())
        goal = pose_to_matrix(target)
        distance = max(float(np.linalg.norm(goal[:3, 3] - start[:3, 3])),
                       float(rotation_angle_rad(start[:3, :3].T @ goal[:3, :3])))
        self._run_move("moveL", lambda: self._control.moveL(target.tolist(), speed_m_s, accel_m_s2, True),
                       move_duration_s(distance, speed_m_s, accel_m_s2))
        reached = pose_to_matrix(self.tcp_pose())
        position_error_m = float(np.linalg.norm(reached[:3, 3] - goal[:3, 3]))
        rotation_error_rad = float(rotation_angle_rad(reached[:3, :3].T @ goal[:3, :3]))
        if position_error_m > _POSITION_TOLERANCE_M or rotation_error_rad > _ROTATION_TOLERANCE_RAD:
            raise RobotError(f"moveL ended {position_error_m * 1000:.2f} mm / "
                             f"{np.degrees(rotation_error_rad):.3f} "
                             "deg away from its target")

    def move_joint(self, q_rad: FloatArray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Joint-space move to ``q_rad``; blocks until there (or raises)."""
        self._check_may_move()
        self.limits.check(speed_rad_s, accel_rad_s2, joint=True)
        target = np.asarray(q_rad, dtype=float).reshape(6)
        distance = float(np.max(np.abs(target - self.joint_positions_rad())))
        self._run_move("moveJ", lambda: self._control.moveJ(target.tolist(), speed_rad_s, accel_rad_s2, True),
                       move_duration_s(distance, speed_rad_s, accel_rad_s2))
        error_rad = float(np.max(np.abs(self.joint_positions_rad() - target)))
        if error_rad > _JOINT_TOLERANCE_RAD:
            raise RobotError(f"moveJ ended {np.degrees(error_rad):.3f} deg away from its target")

    def _run_move(self, what: str, start: Any, expected_s: float) -> None:
        """Start an asynchronous move and watch it until it ends."""
        try:
            self._command(what, start)
        except RobotError as exc:
            self._raise_if_stopped()
            if self._program_stops_within(STREAM_STALL_S):
                self._raise_if_stopped()
                self._broken = ("the control program stopped", RobotError)
                raise RobotError(f"{what} failed: the control program on the robot has stopped (for example "
                                 "the target is out of reach or a runtime error occurred); check the robot's "
                                 "log and connect again") from exc
            raise
        allowed_s = 1.5 * expected_s + _MOVE_MARGIN_S
        deadline = time.monotonic() + allowed_s
        watchdog = _StreamWatchdog(self._receive)
        try:
            while True:
                self._raise_if_stopped()
                stall = watchdog.problem()
                if stall is not None:
                    self._broken = (stall.message, TransportError)
                    if stall.connected:
                        # Commands still reach the robot: ask it to stop. On a lost connection
                        # ur_rtde is reconnecting by itself, and a command now can crash it.
                        with contextlib.suppress(RobotError, DeviceTimeoutError):
                            self.stop(timeout_s=STREAM_STALL_S)
                    outcome = ("the arm was told to stop" if stall.connected
                               else "the arm may finish the move")
                    raise DeviceTimeoutError(f"{what}: {stall.message}; {outcome}, check it and "
                                             "connect again")
                if ur_call("getAsyncOperationProgress", self._control.getAsyncOperationProgress,
                           false_is_error=False) < 0:
                    break
                if not self._program_running():
                    # A stop ends the program in the same package that sets its bit; the bits
                    # read at the top of this pass may be one package older.
                    self._raise_if_stopped()
                    self._broken = ("the control program stopped", RobotError)
                    raise RobotError(f"{what}: the control program stopped during the move (a runtime error "
                                     "on the controller, e.g. a singularity); see the robot's log")
                if time.monotonic() > deadline:
                    self.stop()
                    raise RobotError(f"{what} did not finish within {allowed_s:.1f} s (expected "
                                     f"{expected_s:.1f} s); the arm was stopped")
                time.sleep(POLL_S)
        except KeyboardInterrupt:
            with contextlib.suppress(RobotError, TransportError):  # the interrupt is what to report
                self.stop()
            raise
        # The receive stream is a connection of its own and may lag the control one.
        self.wait_until_steady(_SETTLE_TIMEOUT_S)

    def wait_until_steady(self, timeout_s: float) -> None:
        """Block until every joint is at rest; DeviceTimeoutError after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            self._raise_if_stopped()
            qd = np.array(self._read("getActualQd", self._receive.getActualQd))
            if float(np.max(np.abs(qd))) < _STEADY_SPEED_RAD_S:
                return
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(f"the arm was still moving after {timeout_s:g} s")
            time.sleep(POLL_S)

    def stop(self, timeout_s: float = _COMMAND_TIMEOUT_S) -> None:
        """Decelerate any motion to rest (joint deceleration at the configured cap, at
        least 2 rad/s²)."""
        if self._closed or not self._has_control or not self._program_running():
            return
        decel = max(self.limits.max_joint_accel_rad_s2, 2.0)
        control = self._control
        self._command("stopJ", lambda: control.stopJ(decel, False), timeout_s=timeout_s, false_is_error=False)

    # -- kinematics and safety queries -----------------------------------------------------

    def _supports_ik_has_solution(self) -> bool:
        major, minor = self.version[:2]
        return (major == 5 and minor >= 10) or (major == 3 and minor >= 15)

    def inverse_kinematics(self, pose: FloatArray, q_near_rad: FloatArray | None = None) -> FloatArray | None:
        """Controller's joint solution nearest ``q_near_rad`` (default: the current joints), or
        None if unreachable.

        On controllers without ``get_inverse_kin_has_solution`` (before 5.10 / 3.15) an
        unreachable pose stops the control program; that raises RobotError.
        """
        target = np.asarray(pose, dtype=float).reshape(6).tolist()
        near = self.joint_positions_rad() if q_near_rad is None else np.asarray(q_near_rad, dtype=float)
        q_near = near.reshape(6).tolist()
        control = self._control
        if self._supports_ik_has_solution() and not self._command(
                "getInverseKinematicsHasSolution",
                lambda: control.getInverseKinematicsHasSolution(target, q_near), false_is_error=False):
            return None
        return np.array(self._command("getInverseKinematics",
                                      lambda: control.getInverseKinematics(target, q_near)))

    def is_within_safety_limits(self, pose: FloatArray) -> bool:
        """True when the controller's safety limits allow the TCP pose."""
        target = np.asarray(pose, dtype=float).reshape(6).tolist()
        control = self._control
        return bool(self._command("isPoseWithinSafetyLimits",
                                  lambda: control.isPoseWithinSafetyLimits(target),
                                  false_is_error=False))

    # -- shutdown ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the control script, then disconnect all three interfaces; safe twice.

        The two RTDE disconnects each sleep 0.5 s inside ur_rtde (GIL released), so they
        run side by side."""
        if self._closed:
            return
        self._closed = True
        control, receive, dashboard = self._control, self._receive, self._dashboard
        if self._has_control and control.isConnected():  # else ur_rtde spends seconds reconnecting
            self._quietly("stopScript", lambda: control.stopScript() if control.isProgramRunning() else None,
                          self._command_lock)
        receive_thread = threading.Thread(
            target=self._quietly, args=("RTDEReceiveInterface.disconnect", receive.disconnect),
            name="ur-receive-disconnect", daemon=True)
        receive_thread.start()
        if self._has_control and control.isConnected():  # else the lock may be held by an abandoned call
            self._quietly("RTDEControlInterface.disconnect", control.disconnect, self._command_lock)
        receive_thread.join(_COMMAND_TIMEOUT_S)
        self._quietly("DashboardClient.disconnect", dashboard.disconnect)
        # Dropping the last reference destroys the C++ objects and frees their sockets.
        closed = _Unavailable("the robot connection is closed; connect again")
        self._control = self._receive = self._dashboard = closed

    def _quietly(self, what: str, step: Any, lock: threading.Lock | None = None) -> None:
        """One shutdown step; failures are logged, not raised (the rest must still run)."""
        try:
            ur_call(what, step, timeout_s=_COMMAND_TIMEOUT_S, false_is_error=False, lock=lock)
        except (RobotError, DeviceTimeoutError) as exc:
            logger.warning("while disconnecting from %s: %s", self.host, exc)

    def __enter__(self) -> URRobot:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
