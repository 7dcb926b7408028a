"""Test doubles for the sequencer: a simulated robot and scanner sharing a simulated clock.

Nothing here is product code. The robot "moves" by advancing the shared clock by the
motion's duration and remembers its path, so the scanner can ray-cast the rod where the
robot held it when each scan was acquired (scans taken during a move see a moving rod).
Scans carry their acquisition time (``device_time_s``) and a later read time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lasercal_hw.errors import DeviceTimeoutError, ProtectiveStopError, RobotError
from lasercal_hw.geometry import (
    euler_zyx_to_matrix,
    invert_transform,
    make_transform,
    matrix_to_pose,
    pose_to_matrix,
    transform_points,
)
from lasercal_hw.models import (
    FloatArray,
    LaserScan,
    RobotIdentity,
    RobotState,
    RodLine,
    ScanGeometry,
    ScannerIdentity,
)
from lasercal_hw.run.outcome import solve_run
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.timing import HOME_POSTURE_RAD
from lasercal_hw.ur_kinematics import forward_kinematics, inverse_kinematics_pose, move_duration_s

PAPER_T_BASE_LASER = make_transform(
    euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])), [0.30, 0.50, 0.20]
)
UTM_GEOMETRY = ScanGeometry(
    first_step=0, last_step=1080, cluster=1, front_step=540, steps_per_revolution=1440,
    min_range_m=0.023, max_range_m=60.0, scan_period_s=0.025,
)


class SimClock:
    """A clock that only moves when a double says so."""

    def __init__(self, start_s: float = 1_000.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s

    def advance_to(self, t_s: float) -> None:
        self.now_s = max(self.now_s, t_s)


@dataclass
class SimRobot:
    """A robot that moves in straight lines at the commanded speed, on the shared clock."""

    clock: SimClock
    pose: FloatArray = field(default_factory=lambda: np.array([0.4, 0.0, 0.6, np.pi, 0.0, 0.0]))
    reach_m: float = 1.2
    settle_s: float = 0.2
    protective_stop_at_move: int | None = None
    stop_reported_late: bool = False
    forbidden_poses: list[FloatArray] = field(default_factory=list)
    state_value: RobotState = field(
        default_factory=lambda: RobotState("RUNNING", "NORMAL", True, True, False, False)
    )
    on_move: object = None
    moves: list[FloatArray] = field(default_factory=list)
    stops: int = 0
    _path: list[tuple[float, float, FloatArray, FloatArray]] = field(default_factory=list)
    _stopped_for_good: bool = False

    def identity(self) -> RobotIdentity:
        return RobotIdentity("UR5", "sim-0001", "5.11.0", (5, 11, 0, 0))

    def state(self) -> RobotState:
        return self.state_value

    def pose_at(self, t_s: float) -> FloatArray:
        """Where the TCP was at time ``t_s``."""
        for t0, t1, start, end in reversed(self._path):
            if t_s >= t1:
                return end
            if t_s >= t0:
                return start + (end - start) * (t_s - t0) / (t1 - t0)
        return self._path[0][2] if self._path else self.pose

    def tcp_pose(self) -> FloatArray:
        return self.pose_at(self.clock()).copy()

    def joint_positions_rad(self) -> FloatArray:
        return self.tcp_pose()

    def move_linear(self, pose: FloatArray, speed_m_s: float, accel_m_s2: float) -> None:
        end = self._begin_move(pose)
        start = self.tcp_pose()
        self._travel(start, end, max(float(np.linalg.norm(end[:3] - start[:3])) / speed_m_s, 0.05))

    def _begin_move(self, pose: FloatArray) -> FloatArray:
        """What every move does first: refuse in a stop, tell ``on_move``, remember the target,
        stop where told to; returns the target."""
        if self._stopped_for_good:
            raise RobotError("robot is in a protective stop")
        if callable(self.on_move):
            self.on_move(len(self.moves))
        self.moves.append(np.asarray(pose, dtype=float).copy())
        if self.protective_stop_at_move is not None and len(self.moves) > self.protective_stop_at_move:
            self._stopped_for_good = True
            self.state_value = RobotState("RUNNING", "PROTECTIVE_STOP", False, True, True, False)
            if self.stop_reported_late:  # the move only sees its program end, like ur_rtde can
                raise RobotError("moveJ: the control program stopped during the move")
            raise ProtectiveStopError("robot entered a protective stop (C153A1: collision detected)")
        return np.asarray(pose, dtype=float).copy()

    def _travel(self, start: FloatArray, end: FloatArray, duration_s: float) -> None:
        t0 = self.clock()
        self._path.append((t0, t0 + duration_s, start, end))
        self.pose = end
        self.clock.advance_to(t0 + duration_s)

    def move_joint(self, q_rad: FloatArray, speed_rad_s: float, accel_rad_s2: float) -> None:
        # This double's "joint positions" are the pose itself (see inverse_kinematics).
        self.move_linear(np.asarray(q_rad, dtype=float), 0.1, 0.3)

    def wait_until_steady(self, timeout_s: float) -> None:
        self.clock.advance_to(self.clock() + self.settle_s)

    def stop(self) -> None:
        self.stops += 1

    def inverse_kinematics(self, pose: FloatArray, q_near_rad: FloatArray | None = None) -> FloatArray | None:
        p = np.asarray(pose[:3], dtype=float)
        if np.linalg.norm(p) > self.reach_m or p[2] < -0.1:
            return None
        return np.asarray(pose, dtype=float).copy()

    def is_within_safety_limits(self, pose: FloatArray) -> bool:
        return not any(np.allclose(pose, f) for f in self.forbidden_poses)

    def close(self) -> None:
        pass


@dataclass
class PacedRobot(SimRobot):
    """A SimRobot with a UR5's joints: it solves and moves as the UR5 model does (from the home
    posture), each move lasting ``slowdown`` times the UR trapezoid at the commanded caps, as a
    speed slider below 100 % stretches every move alike; it settles at once."""

    slowdown: float = 1.0
    settle_s: float = 0.0
    joints_rad: FloatArray = field(default_factory=lambda: HOME_POSTURE_RAD.copy())

    def __post_init__(self) -> None:
        self.pose = matrix_to_pose(forward_kinematics(self.joints_rad))

    def joint_positions_rad(self) -> FloatArray:
        return self.joints_rad.copy()

    def inverse_kinematics(self, pose: FloatArray, q_near_rad: FloatArray | None = None) -> FloatArray | None:
        return inverse_kinematics_pose(pose, self.joints_rad if q_near_rad is None else q_near_rad)

    def move_joint(self, q_rad: FloatArray, speed_rad_s: float, accel_rad_s2: float) -> None:
        q = np.asarray(q_rad, dtype=float)
        end = self._begin_move(matrix_to_pose(forward_kinematics(q)))
        distance_rad = float(np.max(np.abs(q - self.joints_rad)))
        self._travel(self.pose, end, self.slowdown * move_duration_s(distance_rad, speed_rad_s, accel_rad_s2))
        self.joints_rad = q

    def move_linear(self, pose: FloatArray, speed_m_s: float, accel_m_s2: float) -> None:
        q = self.inverse_kinematics(pose)
        assert q is not None, "PacedRobot: a linear move to a pose the UR5 model cannot reach"
        end = self._begin_move(pose)
        length_m = float(np.linalg.norm(end[:3] - self.pose[:3]))
        self._travel(self.pose, end, self.slowdown * move_duration_s(length_m, speed_m_s, accel_m_s2))
        self.joints_rad = q


def _cylinder_hits_m(directions: FloatArray, origin: FloatArray, axis: FloatArray,
                     radius_m: float, length_m: float) -> FloatArray:
    """Range along each unit ray from the scanner origin to a finite cylinder (inf: miss)."""
    d_perp = directions - np.outer(directions @ axis, axis)
    a_perp = origin - (origin @ axis) * axis
    qa = np.einsum("ij,ij->i", d_perp, d_perp)
    qb = -2.0 * d_perp @ a_perp
    qc = a_perp @ a_perp - radius_m**2
    disc = qb**2 - 4 * qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-qb - np.sqrt(disc)) / (2 * qa)
    hit_points = t[:, None] * directions
    along = (hit_points - origin) @ axis
    ok = (disc >= 0) & (t > 0) & (along >= 0) & (along <= length_m)
    return np.where(ok, t, np.inf)


@dataclass
class SimScanner:
    """A scanner at ``T_base_laser`` seeing a round room and the rod the robot holds."""

    clock: SimClock
    robot: SimRobot
    rod: RodLine
    T_base_laser: FloatArray = field(default_factory=lambda: PAPER_T_BASE_LASER.copy())
    noise_m: float = 0.002
    latency_s: float = 0.004
    queue_scans: int = 80
    fail_reads_at: set[int] = field(default_factory=set)
    gap_at_reads: set[int] = field(default_factory=set)
    seed: int = 1
    geometry_used: ScanGeometry = UTM_GEOMETRY
    reads: int = 0
    streaming: bool = False
    with_intensities: bool = False
    closed: bool = False
    _next_k: int = 0
    _dropped: int = 0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._angles = self.geometry_used.angles_rad()
        self._rays = np.stack([np.cos(self._angles), np.sin(self._angles), np.zeros_like(self._angles)], 1)

    def identity(self) -> ScannerIdentity:
        return ScannerIdentity("Hokuyo", "UTM-30LX-EW", "1.0", "SCIP 2.0", "sim-9", "UTM-30LX-EW")

    def geometry(self) -> ScanGeometry:
        return self.geometry_used

    def start_streaming(self, *, intensities: bool = False) -> None:
        self.streaming = True
        self.with_intensities = intensities
        self._next_k = int(np.ceil(self.clock() / self.geometry_used.scan_period_s))

    def ranges_at(self, t_s: float) -> FloatArray:
        """Noise-free ranges for the scene at time ``t_s``."""
        room = 3.0 + 0.4 * np.sin(3.0 * self._angles)
        T_laser_tcp = invert_transform(self.T_base_laser) @ pose_to_matrix(self.robot.pose_at(t_s))
        origin = transform_points(T_laser_tcp, self.rod.origin_m)
        axis = T_laser_tcp[:3, :3] @ self.rod.unit_direction()
        rod = _cylinder_hits_m(self._rays, origin, axis, self.rod.radius_m, self.rod.length_m)
        return np.minimum(room, rod)

    def next_scan(self, timeout_s: float) -> LaserScan:
        assert self.streaming, "next_scan before start_streaming"
        self.reads += 1
        if self.reads in self.fail_reads_at:
            self.clock.advance_to(self.clock() + timeout_s)
            raise DeviceTimeoutError("no scan within the timeout (simulated drop)")
        period = self.geometry_used.scan_period_s
        if self.reads in self.gap_at_reads:  # a reconnect: half a second of scans never arrives
            self._next_k += 20
            self.clock.advance_to(self._next_k * period)
        newest_k = int(np.floor((self.clock() - self.latency_s) / period))
        oldest_kept = newest_k - self.queue_scans + 1
        if self._next_k < oldest_kept:
            self._dropped += oldest_kept - self._next_k
            self._next_k = oldest_kept
        k = self._next_k
        self._next_k += 1
        acquired_s = k * period
        self.clock.advance_to(acquired_s + self.latency_s)
        ranges = self.ranges_at(acquired_s) + self._rng.normal(0.0, self.noise_m, self._angles.size)
        raw = np.round(ranges * 1000).astype(np.int64)
        return LaserScan(
            sequence=k,
            geometry=self.geometry_used,
            ranges_m=raw / 1000.0,
            raw_ranges_mm=raw,
            intensities=np.where(ranges < 2.5, 6000, 1500) if self.with_intensities else None,
            device_time_s=acquired_s,
            host_time_s=acquired_s + self.latency_s,
        )

    def dropped_scans(self) -> int:
        return self._dropped

    def stop_streaming(self) -> None:
        self.streaming = False

    def close(self) -> None:
        self.closed = True


@dataclass
class MemoryRecorder:
    """Keeps what the sequencer records, in order."""

    scans: list[LaserScan] = field(default_factory=list)
    watcher_scans: dict[str, list[LaserScan]] = field(default_factory=dict)
    poses: list[tuple[float, FloatArray]] = field(default_factory=list)
    joints: list[tuple[float, FloatArray]] = field(default_factory=list)
    events: list[tuple[float, str, dict]] = field(default_factory=list)

    def write_scan(self, scan: LaserScan, scanner: str | None = None) -> None:
        if scanner is None:
            self.scans.append(scan)
        else:
            self.watcher_scans.setdefault(scanner, []).append(scan)

    def write_tcp_pose(self, host_time_s: float, pose: FloatArray) -> None:
        self.poses.append((host_time_s, pose))

    def write_joint_state(self, host_time_s: float, q_rad: FloatArray) -> None:
        self.joints.append((host_time_s, q_rad))

    def write_event(self, host_time_s: float, kind: str, **fields: object) -> None:
        self.events.append((host_time_s, kind, fields))

    def kinds(self) -> list[str]:
        return [kind for _, kind, _ in self.events]


def rod_down_pose(xyz_m: FloatArray, tilt_x_rad: float = 0.0, tilt_y_rad: float = 0.0) -> FloatArray:
    """A TCP pose with the tool z axis pointing down, tilted about base x and y."""
    from lasercal_hw.geometry import matrix_to_rotvec, rotvec_to_matrix

    rotation = rotvec_to_matrix([tilt_x_rad, 0, 0]) @ rotvec_to_matrix([0, tilt_y_rad, 0]) @ \
        rotvec_to_matrix([np.pi, 0, 0])
    return np.concatenate([np.asarray(xyz_m, dtype=float), matrix_to_rotvec(rotation)])


def semicircle_waypoints(count: int = 12, tilt_rad: float = 0.4) -> FloatArray:
    """Two arcs in front of the scanner with varied heights and tilts (well conditioned)."""
    poses = []
    rng = np.random.default_rng(7)
    for k in range(count):
        radius_m = 0.45 if k % 2 == 0 else 0.75
        angle = np.radians(-70 + 100 * k / max(count - 1, 1))
        xyz = [radius_m * np.cos(angle), radius_m * np.sin(angle), 0.25 + 0.07 * (k % 3)]
        tilt_x, tilt_y = rng.uniform(-tilt_rad, tilt_rad, 2)
        poses.append(rod_down_pose(xyz, tilt_x, tilt_y))
    return np.array(poses)


def run_calibration(robot: Any, scanner: Any, recorder: Any, job: Any, waypoints: FloatArray,
                    **options: Any) -> RunOutcome:
    """Measure with a ``Sequencer`` and solve as the engine does (``run/outcome.solve_run``)."""
    sequencer = Sequencer(robot, scanner, recorder, job, waypoints, **options)
    solve_options = {key: options[key] for key in ("on_progress", "cancel", "clock") if key in options}
    return solve_run(sequencer.measure(), job, recorder, **solve_options)
