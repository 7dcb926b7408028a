"""The motion of a run: preflight, background, move-settle-dwell at every waypoint and the
rod centre of each dwell (``Sequencer.measure``). It moves and measures; the solve is
``run/two_pass`` and ``run/outcome``.

The sequencer talks to the ``Robot`` and ``Scanner`` protocols and to a recorder; it never
prints (progress goes to a callback a front end renders) and never imports a driver or a
fake. Everything it sees is written to the recorder as it happens, so an interrupted run
keeps its data and can be resumed (``ResumeState``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from lasercal_hw.calibration.consensus import CONSENSUS_WAYPOINTS, provisional_pose
from lasercal_hw.config import JobConfig
from lasercal_hw.errors import (
    DeviceError,
    InterruptedRunError,
    LasercalError,
    ProtectiveStopError,
    RobotError,
    TransportError,
)
from lasercal_hw.models import FloatArray, LaserScan
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.dwell import DwellCapture, collect_count, collect_window
from lasercal_hw.run.preflight import PreflightReport, first_clear_pose, run_preflight
from lasercal_hw.run.records import (
    Measured,
    Progress,
    ProgressCallback,
    ResumeState,
    RunRecorder,
    SkippedWaypoint,
    Timings,
    WaypointMeasurement,
    record_event,
)
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.run.time_left import TimeLeft
from lasercal_hw.run.two_pass import predict_rod
from lasercal_hw.run.watchers import Watcher, watch_waypoint
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

RETRACT = "retract pose (for the background; see background.pose)"


def _pair(point: FloatArray | None) -> tuple[float, float] | None:
    """A 2-vector as plain floats (None stays None)."""
    return None if point is None else (float(point[0]), float(point[1]))


class _RetryError(Exception):
    """One attempt at a waypoint failed in a way that repeating it may fix."""

    def __init__(self, reason: str, scanner_fault: bool) -> None:
        super().__init__(reason)
        self.reason = reason
        self.scanner_fault = scanner_fault


class Sequencer:
    """Runs one calibration job against a robot and a scanner."""

    def __init__(
        self,
        robot: Robot,
        scanner: Scanner,
        recorder: RunRecorder,
        job: JobConfig,
        waypoints: FloatArray,
        *,
        on_progress: ProgressCallback | None = None,
        before_motion: Callable[[PreflightReport], None] | None = None,
        resume: ResumeState | None = None,
        cancel: CancelToken | None = None,
        clock: Callable[[], float] = time.time,
        waypoint_names: Sequence[int] | None = None,
        watchers: Sequence[Watcher] = (),
    ) -> None:
        """``before_motion`` is called once preflight passed and before the first motion
        (the CLI asks the operator there; raising from it aborts with nothing moved).
        ``cancel`` stops the run from another thread as Ctrl-C does: the arm is told to
        stop at once, the run raises InterruptedRunError at its next checkpoint.
        ``waypoint_names``: the number each waypoint goes by in messages (verify visits a few
        waypoints of a calibration's trajectory and names them by their index there); the
        recording always counts positions. ``watchers``: the cell's other scanners, each
        measuring the rod at the waypoints where it sees it (``run/watchers``)."""
        self._robot = robot
        self._scanner = scanner
        self._recorder = recorder
        self._job = job
        self._waypoints = np.asarray(waypoints, dtype=float).reshape(-1, 6)
        self._rod = job.rod.rod_line()
        self._on_progress = on_progress
        self._before_motion = before_motion
        self._resume = resume or ResumeState()
        self._cancel = cancel or CancelToken()
        self._clock = clock
        self._waypoint_names = None if waypoint_names is None else list(waypoint_names)
        self._watchers = tuple(watchers)
        self._background: AveragedScan | None = self._resume.background
        self._measurements: list[WaypointMeasurement] = list(self._resume.measurements)
        self._skipped: list[SkippedWaypoint] = list(self._resume.skipped)
        self._timings = Timings()
        self._joint_targets: dict[int, FloatArray] = {}
        self._current: int | None = None
        self._time_plan: TimeLeft | None = None
        self._moved_to: set[int | None] = set()  # None: the retract pose
        self._consensus: tuple[tuple[int, ...], FloatArray | None] | None = None

    # -- public -------------------------------------------------------------------------

    def measure(self) -> Measured:
        """Preflight, background and every waypoint not yet measured; raises on abort and
        never leaves the arm moving. A calibration solves the result (``run/outcome``),
        verify compares the centres with a calibration instead."""
        started_s = self._clock()
        report = self._guarded(self._measure_all)
        self._timings.wall_s = self._clock() - started_s
        self._event(
            "measure_end",
            measured=len(self._measurements),
            skipped=len(self._skipped),
            wall_s=self._timings.wall_s,
            motion_s=self._timings.motion_s,
            dwell_s=self._timings.dwell_s,
        )
        return Measured(
            preflight=report,
            measurements=sorted(self._measurements, key=lambda m: m.index),
            skipped=sorted(self._skipped, key=lambda s: s.index),
            background=self._background,
            timings=self._timings,
            waypoints=self._waypoints.copy(),
            resumed_from=len(self._resume.measurements) + len(self._resume.skipped),
        )

    def _guarded(self, body: Callable[[], _T]) -> _T:
        """Run ``body`` so that any way out of it stops the arm and says where (Ctrl-C,
        cancel, protective stop, errors) and the scanner stream is closed."""
        remove_listener = self._cancel.on_cancel(self._stop_arm)
        try:
            return body()
        except (KeyboardInterrupt, InterruptedRunError) as exc:
            reason = str(exc) or "Ctrl-C"
            self._halt("interrupted", reason)
            raise InterruptedRunError(
                f"run interrupted{self._where()} ({reason}): the arm was stopped and the recording kept; "
                "resume this run from its recording"
            ) from None
        except ProtectiveStopError as exc:
            # The controller already stopped the arm; no command is sent to it any more.
            self._event("abort", cause="protective_stop", index=self._current, message=str(exc))
            raise ProtectiveStopError(
                f"protective stop{self._where()}: {exc}. The run is aborted and will not resume by "
                "itself: find the cause, clear the stop on the teach pendant, then resume this run from "
                "its recording"
            ) from exc
        except BaseException as exc:
            self._halt("error", f"{type(exc).__name__}: {exc}")
            raise
        finally:
            remove_listener()
            self._stop_streaming()

    # -- the run ------------------------------------------------------------------------

    def _measure_all(self) -> PreflightReport:
        count = len(self._waypoints)
        self._progress("preflight", f"checking devices and {count} waypoints")
        candidates = retract_candidates(self._job, self._waypoints)
        retract = first_clear_pose(self._robot, candidates, self._rod, self._job.workspace)
        if retract is None:  # preflight lists why the preferred one fails
            retract = candidates[0]
        order = self._chain_order()
        poses = {(RETRACT if i is None else f"waypoint {i}"): (retract if i is None else self._waypoints[i])
                 for i in order}
        report = run_preflight(self._robot, self._scanner, poses, self._rod, self._job.workspace)
        solutions = dict(zip(order, report.joint_solutions_rad, strict=True))
        retract_q = solutions.pop(None)
        self._joint_targets = {i: q for i, q in solutions.items() if i is not None}
        self._event(
            "preflight_ok",
            robot=report.robot,
            scanner=report.scanner,
            waypoints=count,
            already_done=sorted(self._resume.finished_indices),
        )
        if self._before_motion is not None:
            self._before_motion(report)
        self._scanner.start_streaming(intensities=self._job.scanner.intensities)
        if self._background is None:
            self._capture_background(retract, retract_q)
        for index in range(count):
            if index in self._resume.finished_indices:
                continue
            self._current = index
            self._measure_waypoint(index)
        self._current = None
        return report

    def _chain_order(self) -> list[int | None]:
        """The poses in the order the arm visits them (None: the retract pose), each solved nearest
        the one before from the arm's present joints: the retract pose when the background is
        still to take, then the waypoints not yet done; after them what the arm does not visit
        (checked, off the chain), so that a resumed run's first move starts where the arm is
        rather than where a chain through the finished waypoints would have left it."""
        pending = self._pending_at_start()
        finished = [i for i in range(len(self._waypoints)) if i not in pending]
        if self._background is None:
            return [None, *pending, *finished]
        return [*pending, *finished, None]

    def _capture_background(self, pose: FloatArray, q_rad: FloatArray) -> None:
        self._progress("background", "moving to the retract pose for the background")
        attempts = self._job.acquisition.max_attempts
        for attempt in range(1, attempts + 1):
            # The arm may start anywhere: reach the retract pose in joint space (the preflight
            # solution nearest the current joints), which no singularity can stop.
            settled_s = self._go(None, pose, q_rad, joint=True)
            count = self._job.background.scans
            self._progress("background", f"averaging {count} background scans (rod out of the plane)")
            dwell_started_s = self._clock()
            try:
                capture = collect_count(
                    self._scanner,
                    start_host_s=settled_s + self._job.settle.margin_s,
                    count=count,
                    scan_timeout_s=self._job.acquisition.scan_timeout_s,
                    on_scan=self._on_scan,
                )
            except TransportError as exc:
                self._event("fault", device="scanner", index=None, attempt=attempt, message=str(exc))
                if attempt == attempts:
                    raise DeviceError(
                        f"background: the scanner failed {attempts} times ({exc}); check its cable and power"
                    ) from exc
                continue
            finally:
                self._timings.dwell_s += self._clock() - dwell_started_s
            self._background = average_scans(capture.scans)
            self._event(
                "background",
                tcp_pose=pose,
                scans=len(capture.scans),
                window_start_s=capture.window_start_host_s,
                window_end_s=capture.window_end_host_s,
            )
            return

    def _measure_waypoint(self, index: int) -> None:
        attempts = self._job.acquisition.max_attempts
        last: _RetryError | None = None
        for attempt in range(1, attempts + 1):
            try:
                self._attempt_waypoint(index, attempt)
                return
            except _RetryError as retry:
                last = retry
                logger.warning("waypoint %d attempt %d: %s", index, attempt, retry.reason)
                self._event("waypoint_retry", index=index, attempt=attempt, reason=retry.reason)
                message = f"waypoint {self._name(index)}: {retry.reason}; repeating"
                self._progress("retry", message, waypoint=index)
        assert last is not None
        if last.scanner_fault:
            raise DeviceError(
                f"waypoint {self._name(index)}: the scanner failed {attempts} times ({last.reason}); "
                "check its cable and power, then resume this run from its recording"
            )
        self._skip(index, f"{last.reason} ({attempts} attempts)")

    def _attempt_waypoint(self, index: int, attempt: int) -> None:
        count = len(self._waypoints)
        name = self._name(index)
        self._progress("move", f"moving to waypoint {name} ({index + 1} of {count})", waypoint=index)
        settled_s = self._go(index, self._waypoints[index], self._joint_targets[index])
        tcp_start = self._read_tcp(settled_s)
        self._progress("dwell", f"dwelling {self._job.dwell_s:g} s at waypoint {name}", waypoint=index)
        capture = self._dwell(index, attempt, settled_s, tcp_start)
        tcp_end = self._read_tcp(self._clock())
        drift_mm = 1000.0 * float(np.linalg.norm(tcp_end[:3] - tcp_start[:3]))
        self._event(
            "dwell_end",
            index=index,
            attempt=attempt,
            tcp_pose=tcp_end,
            scans=len(capture.scans),
            discarded=capture.discarded_before_start,
            missed=capture.missed_scans,
            dropped_total=self._scanner.dropped_scans(),
            drift_mm=drift_mm,
        )
        self._check_capture(capture, drift_mm)
        averaged = average_scans(capture.scans)
        expected_uv_m = self._nominal_expected_uv(tcp_start)
        try:
            centre = find_rod_centre(
                averaged,
                radius_m=self._rod.radius_m,
                background=self._background,
                expected_uv_m=expected_uv_m,
                fluted=self._rod.fluted,
            )
        except RodNotFoundError as exc:
            self._skip(index, str(exc), averaged)
            self._watch(index, tcp_start)
            return
        self._measurements.append(WaypointMeasurement(index, tcp_start, averaged, centre))
        u, v = (float(c) for c in centre.centre_uv_m)
        self._event(
            "observation",
            index=index,
            tcp_pose=tcp_start,
            centre_uv_m=[u, v],
            covariance_uv_m2=centre.covariance_uv_m2,
            quality=centre.quality,
            warnings=list(centre.warnings),
            scans=len(capture.scans),
            window_start_s=capture.window_start_host_s,
            window_end_s=capture.window_end_host_s,
        )
        self._progress(
            "centre",
            f"waypoint {name}: rod at ({u:+.4f}, {v:+.4f}) m from {len(capture.scans)} scans"
            + "".join(f"; warning: {warning}" for warning in centre.warnings),
            waypoint=index,
            scans_averaged=len(capture.scans),
            centre_uv_m=(u, v),
            expected_uv_m=_pair(expected_uv_m),
            averaged=averaged,
            centre=centre,
        )
        self._watch(index, tcp_start)

    def _watch(self, index: int, tcp_pose: FloatArray) -> None:
        """The cell's other scanners measure the rod here, where they see it (the arm stands still)."""
        for watcher in self._watchers:
            watch_waypoint(
                watcher, index, tcp_pose, self._rod,
                dwell_s=self._job.dwell_s,
                scan_timeout_s=self._job.acquisition.scan_timeout_s,
                clock=self._clock,
                record=self._event,
                on_scan=lambda scan, name=watcher.name: self._on_scan(scan, name),
            )

    def _check_capture(self, capture: DwellCapture, drift_mm: float) -> None:
        """Raise ``_RetryError`` when the dwell's scans cannot be trusted."""
        if capture.missed_scans > self._job.acquisition.max_missed_scans:
            raise _RetryError(
                f"the scanner stream had a gap ({capture.missed_scans} scans missed, e.g. a reconnect)",
                scanner_fault=True,
            )
        expected = self._job.dwell_s / self._scanner.geometry().scan_period_s
        if len(capture.scans) < self._job.acquisition.min_scan_fraction * expected:
            arrived = len(capture.scans)
            raise _RetryError(f"only {arrived} of ~{expected:.0f} scans arrived", scanner_fault=True)
        if drift_mm > self._job.settle.max_drift_mm:
            raise _RetryError(f"the arm moved {drift_mm:.2f} mm during the dwell", scanner_fault=False)

    def _dwell(self, index: int, attempt: int, settled_s: float, tcp_pose: FloatArray) -> DwellCapture:
        start_s = settled_s + self._job.settle.margin_s
        self._event("dwell_start", index=index, attempt=attempt, tcp_pose=tcp_pose, window_start_s=start_s)
        dwell_started_s = self._clock()
        try:
            return collect_window(
                self._scanner,
                start_host_s=start_s,
                duration_s=self._job.dwell_s,
                scan_timeout_s=self._job.acquisition.scan_timeout_s,
                on_scan=self._on_scan,
            )
        except TransportError as exc:
            self._event("fault", device="scanner", index=index, attempt=attempt, message=str(exc))
            raise _RetryError(f"scanner stream failed: {exc}", scanner_fault=True) from exc
        finally:
            self._timings.dwell_s += self._clock() - dwell_started_s

    # -- motion and bookkeeping ---------------------------------------------------------

    def _go(self, target: int | None, pose: FloatArray, q_rad: FloatArray, *, joint: bool = False) -> float:
        """Move to waypoint ``target`` (None: the retract pose) and wait until the arm is steady;
        returns the host time it settled. A first move to it is timed against the plan."""
        motion_before_s = self._timings.motion_s
        self._move(pose, q_rad, joint=joint)
        settled_s = self._settle()
        if target not in self._moved_to:
            self._moved_to.add(target)
            self._plan_of_time().moved(target, self._timings.motion_s - motion_before_s)
        return settled_s

    def _move(self, pose: FloatArray, q_rad: FloatArray, *, joint: bool = False) -> None:
        """Move to a pose: in joint space when asked (or configured), else on a TCP line."""
        motion = self._job.motion
        started_s = self._clock()
        try:
            if joint or motion.move == "joint":
                self._robot.move_joint(q_rad, motion.joint_speed_rad_s, motion.joint_accel_rad_s2)
            else:
                self._robot.move_linear(pose, motion.speed_m_s, motion.accel_m_s2)
        except ProtectiveStopError:
            raise
        except RobotError as exc:
            self._cancel.raise_if_cancelled()  # a move cut short by a cancel is the cancel
            self._raise_if_safety_stop(exc)
            raise
        finally:
            self._timings.motion_s += self._clock() - started_s
        self._cancel.raise_if_cancelled()

    def _raise_if_safety_stop(self, cause: RobotError) -> None:
        """A failed move may be a safety stop reported late: ask the robot, and say so."""
        try:
            state = self._robot.state()
        except LasercalError as exc:
            logger.warning("could not read the robot state after a failed move: %s", exc)
            return
        if state.protective_stop or state.emergency_stop or state.safety_status.upper() != "NORMAL":
            raise ProtectiveStopError(
                f"{cause} (the robot reports safety status {state.safety_status})"
            ) from cause

    def _settle(self) -> float:
        started_s = self._clock()
        try:
            self._robot.wait_until_steady(self._job.settle.timeout_s)
        finally:
            settled_s = self._clock()
            self._timings.motion_s += settled_s - started_s
        return settled_s

    def _read_tcp(self, host_time_s: float) -> FloatArray:
        pose = np.asarray(self._robot.tcp_pose(), dtype=float)
        self._recorder.write_tcp_pose(host_time_s, pose)
        q_rad = np.asarray(self._robot.joint_positions_rad(), dtype=float)
        self._recorder.write_joint_state(host_time_s, q_rad)
        return pose

    def _nominal_expected_uv(self, tcp_pose: FloatArray) -> FloatArray | None:
        """Where the nominal mounting (if configured), else the run's consensus over its first
        waypoints (once there are enough), says the rod crosses the plane."""
        nominal = self._job.scanner.nominal
        if nominal is not None:
            return predict_rod(nominal.matrix(), tcp_pose, self._rod).expected_uv_m
        first = self._measurements[:CONSENSUS_WAYPOINTS]
        if len(first) < CONSENSUS_WAYPOINTS:
            return None
        key = tuple(m.index for m in first)
        if self._consensus is None or self._consensus[0] != key:
            self._consensus = (key, provisional_pose([m.observation() for m in first], self._rod))
        pose = self._consensus[1]
        return None if pose is None else predict_rod(pose, tcp_pose, self._rod).expected_uv_m

    def _skip(self, index: int, reason: str, averaged: AveragedScan | None = None) -> None:
        self._skipped.append(SkippedWaypoint(index, reason))
        self._event("waypoint_skipped", index=index, reason=reason)
        message = f"waypoint {self._name(index)} skipped: {reason}"
        self._progress("skip", message, waypoint=index, reason=reason, averaged=averaged)

    def _on_scan(self, scan: LaserScan, watcher: str | None = None) -> None:
        """Record every scan (a watcher's on its own topic); a cancel takes effect between two
        scans of a dwell."""
        self._recorder.write_scan(scan, watcher)
        self._cancel.raise_if_cancelled()

    def _stop_arm(self) -> None:
        try:
            self._robot.stop()
        except LasercalError as exc:
            logger.error("could not stop the robot: %s", exc)

    def _halt(self, cause: str, message: str) -> None:
        self._stop_arm()
        self._event("abort", cause=cause, index=self._current, message=message)

    def _stop_streaming(self) -> None:
        try:
            self._scanner.stop_streaming()
        except LasercalError as exc:
            logger.warning("could not stop the scanner stream: %s", exc)

    def _where(self) -> str:
        return f" at waypoint {self._name(self._current)}" if self._current is not None else ""

    def _name(self, index: int) -> int:
        """The number a waypoint goes by in messages (``waypoint_names``; else its position)."""
        return self._waypoint_names[index] if self._waypoint_names is not None else index

    def _event(self, kind: str, **fields: Any) -> None:
        try:
            record_event(self._recorder, self._clock(), kind, **fields)
        except LasercalError as exc:
            logger.error("could not record event %s: %s", kind, exc)

    def _progress(self, stage: str, message: str, **fields: Any) -> None:
        self._cancel.raise_if_cancelled()
        if self._on_progress is None:
            return
        self._on_progress(
            Progress(
                stage=stage,
                message=message,
                waypoint_count=len(self._waypoints),
                completed=len(self._measurements) + len(self._skipped),
                time_left_s=self._time_left_s(),
                **fields,
            )
        )

    def _plan_of_time(self) -> TimeLeft:
        """The visit of the waypoints this run has still to do, planned once (``run.time_left``)."""
        if self._time_plan is None:
            self._time_plan = TimeLeft.plan(self._job, self._waypoints, self._pending_at_start())
        return self._time_plan

    def _pending_at_start(self) -> list[int]:
        """The waypoints this run set out to measure, in order: those its resume had not finished."""
        done = self._resume.finished_indices
        return [i for i in range(len(self._waypoints)) if i not in done]

    def _time_left_s(self) -> float:
        """The plan's moves, background and dwells still ahead, the moves scaled by how long the
        arm's moves took against the plan so far (``run.time_left``)."""
        finished = {m.index for m in self._measurements} | {s.index for s in self._skipped}
        ahead = [i for i in range(len(self._waypoints)) if i not in finished]
        background_ahead = self._background is None
        return self._plan_of_time().seconds(
            retract_ahead=background_ahead and None not in self._moved_to,
            background_ahead=background_ahead,
            moves_ahead=[i for i in ahead if i not in self._moved_to],
            dwells_ahead=len(ahead),
        )
