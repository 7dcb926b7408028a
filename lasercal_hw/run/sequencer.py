"""The calibration run: preflight, background, move-settle-dwell at every waypoint, rod
centres, solve, quality gates, and a second extraction pass with the solved rod axes.

The sequencer talks to the ``Robot`` and ``Scanner`` protocols and to a recorder; it never
prints (progress goes to a callback the CLI renders) and never imports a driver or a fake.
Everything it sees is written to the recorder as it happens, so an interrupted run keeps
its data and can be resumed (``ResumeState``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, TypeVar

import numpy as np

from lasercal_hw.calibration.consensus import CONSENSUS_WAYPOINTS, provisional_pose
from lasercal_hw.calibration.model import lines_in_scanner, plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.quality import Verdict, evaluate_gates
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.config import JobConfig
from lasercal_hw.errors import (
    DeviceError,
    InterruptedRunError,
    LasercalError,
    ProtectiveStopError,
    RobotError,
    TransportError,
)
from lasercal_hw.models import FloatArray, LaserScan, Observation, RodLine
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.dwell import DwellCapture, collect_count, collect_window
from lasercal_hw.run.preflight import PreflightReport, first_clear_pose, rod_end_points_m, run_preflight
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodCentre, RodNotFoundError, find_rod_centre

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

RETRACT = "retract pose (for the background; see background.pose)"
NOMINAL_CLEARANCE_M = 0.08


class RunRecorder(Protocol):
    """The part of ``SessionRecorder`` the sequencer writes to."""

    def write_scan(self, scan: LaserScan) -> None: ...

    def write_tcp_pose(self, host_time_s: float, pose: FloatArray) -> None: ...

    def write_joint_state(self, host_time_s: float, q_rad: FloatArray) -> None: ...

    def write_event(self, host_time_s: float, kind: str, **fields: Any) -> None: ...


@dataclass(frozen=True)
class Progress:
    """One step of the run, for a live display. ``waypoint`` indexes the waypoint list."""

    stage: str
    message: str
    waypoint: int | None = None
    waypoint_count: int = 0
    completed: int = 0
    scans_averaged: int | None = None
    centre_uv_m: tuple[float, float] | None = None
    #: Where the nominal mounting said the rod would be (None without ``scanner.nominal``).
    expected_uv_m: tuple[float, float] | None = None
    time_left_s: float | None = None
    reason: str | None = None
    averaged: AveragedScan | None = field(default=None, repr=False)
    centre: RodCentre | None = field(default=None, repr=False)


ProgressCallback = Callable[[Progress], None]


@dataclass(frozen=True)
class WaypointMeasurement:
    """A waypoint where the rod was found: the TCP pose, the averaged scan and the centre."""

    index: int
    tcp_pose: FloatArray
    averaged: AveragedScan
    centre: RodCentre

    def observation(self) -> Observation:
        """The solver's view of this waypoint."""
        return Observation(
            index=self.index,
            tcp_pose=np.asarray(self.tcp_pose, dtype=float),
            centre_uv_m=np.asarray(self.centre.centre_uv_m, dtype=float),
            covariance_uv_m2=np.asarray(self.centre.covariance_uv_m2, dtype=float),
        )


@dataclass(frozen=True)
class SkippedWaypoint:
    """A waypoint that gave no observation, and why."""

    index: int
    reason: str


@dataclass
class Timings:
    """Where the run's time went (seconds)."""

    wall_s: float = 0.0
    motion_s: float = 0.0
    dwell_s: float = 0.0

    @property
    def overhead_s(self) -> float:
        """Time spent neither moving nor dwelling (checks, averaging, fitting, solving)."""
        return self.wall_s - self.motion_s - self.dwell_s

    @property
    def overhead_fraction(self) -> float:
        """Overhead relative to the motion and dwell time (the target is under 0.10)."""
        busy_s = self.motion_s + self.dwell_s
        return self.overhead_s / busy_s if busy_s > 0 else 0.0


@dataclass(frozen=True)
class ResumeState:
    """What an interrupted run already measured (see ``lasercal_hw.run.resume``)."""

    measurements: list[WaypointMeasurement] = field(default_factory=list)
    skipped: list[SkippedWaypoint] = field(default_factory=list)
    background: AveragedScan | None = None

    @property
    def finished_indices(self) -> set[int]:
        """Waypoints that need no further visit."""
        return {m.index for m in self.measurements} | {s.index for s in self.skipped}


@dataclass(frozen=True)
class RunOutcome:
    """Everything a finished run produced."""

    preflight: PreflightReport
    measurements: list[WaypointMeasurement]
    skipped: list[SkippedWaypoint]
    observations: list[Observation]
    first_pass: CalibrationResult
    result: CalibrationResult
    refinement: str
    verdict: Verdict
    timings: Timings
    resumed_from: int
    background: AveragedScan | None


@dataclass(frozen=True)
class Measured:
    """What ``Sequencer.measure`` gathered (no solve)."""

    preflight: PreflightReport
    measurements: list[WaypointMeasurement]
    skipped: list[SkippedWaypoint]
    background: AveragedScan | None
    timings: Timings


@dataclass(frozen=True)
class RodPrediction:
    """Where a transform says the rod should be in the scanner: its axis direction and,
    when the rod actually reaches the scan plane, the crossing point."""

    axis_in_scanner: FloatArray
    expected_uv_m: FloatArray | None


def predict_rod(T_base_laser: FloatArray, tcp_pose: FloatArray, rod: RodLine) -> RodPrediction:
    """The rod axis direction and plane crossing in the scanner frame for one TCP pose."""
    rotation = np.asarray(T_base_laser, dtype=float)[:3, :3]
    translation_m = np.asarray(T_base_laser, dtype=float)[:3, 3]
    origins, directions = rod_lines_in_base(np.asarray(tcp_pose, dtype=float)[None, :], rod)
    _, axes = lines_in_scanner(rotation, translation_m, origins, directions)
    axis = axes[0] if axes[0, 2] >= 0.0 else -axes[0]
    if abs(axes[0, 2]) < 1e-9:
        return RodPrediction(axis, None)
    crossing, _, line_s = plane_crossing(rotation, translation_m, origins, directions)
    on_rod = 0.0 <= line_s[0] <= rod.length_m
    return RodPrediction(axis, crossing[0] if on_rod else None)


def _without_range_offset(observation: Observation, range_offset_m: float) -> Observation:
    """A first-pass centre moved back along its bearing by the range offset (the solver's
    first-order model of what the offset does to a centre)."""
    if not range_offset_m:
        return observation
    centre = np.asarray(observation.centre_uv_m, dtype=float)
    moved = centre * (1.0 - range_offset_m / float(np.linalg.norm(centre)))
    return replace(observation, centre_uv_m=moved)


def _pair(point: FloatArray | None) -> tuple[float, float] | None:
    """A 2-vector as plain floats (None stays None)."""
    return None if point is None else (float(point[0]), float(point[1]))


def estimated_rod(result: CalibrationResult, nominal: RodLine) -> RodLine:
    """The rod line a result estimated (the nominal one when it did not estimate it)."""
    axis = result.rod_axis
    if axis is None or not axis.estimated:
        return nominal
    return replace(nominal, origin_m=np.asarray(axis.origin_m), direction=np.asarray(axis.direction))


def background_lift_m(job: JobConfig, pose: FloatArray) -> float:
    """How far to lift a waypoint along base z so that the whole rod is above the scan plane.

    The configured ``background.lift_m`` if any; else, with a nominal scanner mounting, just
    enough for both rod ends to clear its plane by ``NOMINAL_CLEARANCE_M``; else the rod
    length plus 5 cm (enough wherever the rod crossed the plane).
    """
    nominal = job.scanner.nominal
    if job.background.lift_m is not None or nominal is None:
        return job.background_lift_m()
    T_base_laser = nominal.matrix()
    normal = T_base_laser[:3, 2]
    if normal[2] < 0.5:  # a scanner on its side: its plane is steep, lifting does not clear it
        return job.background_lift_m()
    heights_m = (rod_end_points_m(pose, job.rod.rod_line()) - T_base_laser[:3, 3]) @ normal
    return max(0.0, (NOMINAL_CLEARANCE_M - float(heights_m.min())) / float(normal[2]))


def retract_candidates(job: JobConfig, waypoints: FloatArray) -> list[FloatArray]:
    """Where the background may be taken, best first: the configured ``background.pose``;
    else each waypoint lifted clear of the plane, the first waypoint first, then the
    others nearest the robot base first (a far waypoint lifted may be out of reach)."""
    if job.background.pose is not None:
        return [np.asarray(job.background.pose, dtype=float)]
    order = sorted(range(len(waypoints)), key=lambda i: (i != 0, float(np.linalg.norm(waypoints[i][:3]))))
    candidates = []
    for i in order:
        pose = np.asarray(waypoints[i], dtype=float).copy()
        pose[2] += background_lift_m(job, pose)
        candidates.append(pose)
    return candidates


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "model_dump"):
        return _jsonable(value.model_dump(mode="json"))
    if hasattr(value, "__dataclass_fields__"):
        return {name: _jsonable(getattr(value, name)) for name in value.__dataclass_fields__}
    return value


class _RetryError(Exception):
    """One attempt at a waypoint failed in a way that repeating it may fix."""

    def __init__(self, reason: str, scanner_fault: bool) -> None:
        super().__init__(reason)
        self.reason = reason
        self.scanner_fault = scanner_fault


@dataclass(frozen=True)
class TwoPassSolution:
    """The solve of a run: first pass on the circle-fit centres, then the second pass on
    centres re-fitted as the ellipse each waypoint's solved rod axis cuts from the plane."""

    first_pass: CalibrationResult
    result: CalibrationResult
    observations: list[Observation]
    refinement: str
    kept_first_pass: list[tuple[int, str]]


def solve_two_pass(
    measurements: Sequence[WaypointMeasurement],
    job: JobConfig,
    background: AveragedScan | None,
    on_second_pass: Callable[[], None] | None = None,
) -> TwoPassSolution:
    """Solve a run's measurements as a live run does; ``lasercal solve session.mcap`` calls
    this too, so a replay of the recording gives the live result to the last bit.
    ``on_second_pass`` is called between the passes (progress display)."""
    rod = job.rod.rod_line()
    options = SolverOptions(
        robot_sigma_m=job.robot.position_accuracy_mm / 1000.0,
        estimate_axis=job.rod.estimate_axis,
        axis_prior_std_m=job.rod.axis_std_mm / 1000.0,
        axis_prior_std_deg=job.rod.axis_std_deg,
        estimate_range_offset=job.scanner.estimate_range_offset,
        max_range_terms=job.scanner.range_error_terms,
    )
    first = solve([m.observation() for m in measurements], rod, options=options)
    if on_second_pass is not None:
        on_second_pass()
    range_offset_m = first.range_offset.offset_mm / 1000.0 if first.range_offset is not None else 0.0
    refitted, kept = refit_centres(
        measurements, first.matrix(), estimated_rod(first, rod), background, range_offset_m=range_offset_m
    )
    kept_indices = {index for index, _ in kept}
    observations = [
        _without_range_offset(m.observation(), range_offset_m) if m.index in kept_indices else m.observation()
        for m in refitted
    ]
    # The second pass keeps estimating an offset the first one estimated (and removed above).
    estimate_offset = True if first.range_offset is not None else options.estimate_range_offset
    applied = options.model_copy(
        update={"range_offset_applied_m": range_offset_m, "estimate_range_offset": estimate_offset}
    )
    result = solve(observations, rod, options=applied)
    refinement = (
        f"second pass: {len(measurements) - len(kept)} of {len(measurements)} centres re-extracted with the "
        "rod axis predicted by the first solution (elliptical cross-section) and the transform re-solved"
    )
    return TwoPassSolution(first, result, observations, refinement, kept)


def refit_centres(
    measurements: Sequence[WaypointMeasurement],
    T_base_laser: FloatArray,
    rod: RodLine,
    background: AveragedScan | None,
    *,
    range_offset_m: float = 0.0,
) -> tuple[list[WaypointMeasurement], list[tuple[int, str]]]:
    """The measurements with each centre fitted again as the ellipse the rod axis predicted
    by ``T_base_laser`` cuts from the plane (the second pass; ``lasercal verify`` with the
    active calibration), the scanner's ``range_offset_m`` removed, and the waypoints
    (index, reason) that kept their first centre because the re-fit failed."""
    refitted: list[WaypointMeasurement] = []
    kept: list[tuple[int, str]] = []
    for m in measurements:
        predicted = predict_rod(T_base_laser, m.tcp_pose, rod)
        try:
            centre = find_rod_centre(
                m.averaged,
                radius_m=rod.radius_m,
                background=background,
                axis_in_scanner=predicted.axis_in_scanner,
                expected_uv_m=predicted.expected_uv_m,
                range_offset_m=range_offset_m,
            )
        except RodNotFoundError as exc:
            kept.append((m.index, str(exc)))
            refitted.append(m)
            continue
        refitted.append(WaypointMeasurement(m.index, m.tcp_pose, m.averaged, centre))
    return refitted, kept


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
    ) -> None:
        """``before_motion`` is called once preflight passed and before the first motion
        (the CLI asks the operator there; raising from it aborts with nothing moved).
        ``cancel`` stops the run from another thread as Ctrl-C does: the arm is told to
        stop at once, the run raises InterruptedRunError at its next checkpoint."""
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
        self._background: AveragedScan | None = self._resume.background
        self._measurements: list[WaypointMeasurement] = list(self._resume.measurements)
        self._skipped: list[SkippedWaypoint] = list(self._resume.skipped)
        self._timings = Timings()
        self._joint_targets: dict[int, FloatArray] = {}
        self._current: int | None = None
        self._moves = 0
        self._consensus: tuple[tuple[int, ...], FloatArray | None] | None = None

    # -- public -------------------------------------------------------------------------

    def run(self) -> RunOutcome:
        """Run the whole job; see the module docstring. Raises on abort, never hangs the arm."""
        started_s = self._clock()
        outcome = self._guarded(lambda: self._solve(self._measure_all()))
        outcome.timings.wall_s = self._clock() - started_s
        self._event(
            "run_end",
            passed=outcome.verdict.passed,
            wall_s=outcome.timings.wall_s,
            motion_s=outcome.timings.motion_s,
            dwell_s=outcome.timings.dwell_s,
            overhead_fraction=outcome.timings.overhead_fraction,
        )
        return outcome

    def measure(self) -> Measured:
        """Preflight, background and every waypoint as ``run`` does them, but no solve
        (``lasercal verify`` compares the centres with a calibration instead)."""
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
                "continue later with --resume"
            ) from None
        except ProtectiveStopError as exc:
            # The controller already stopped the arm; no command is sent to it any more.
            self._event("abort", cause="protective_stop", index=self._current, message=str(exc))
            raise ProtectiveStopError(
                f"protective stop{self._where()}: {exc}. The run is aborted and will not resume by "
                "itself: find the cause, clear the stop on the teach pendant, then continue with --resume"
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
        poses = {RETRACT: retract} | {f"waypoint {i}": w for i, w in enumerate(self._waypoints)}
        report = run_preflight(self._robot, self._scanner, poses, self._rod, self._job.workspace)
        retract_q, *waypoint_q = report.joint_solutions_rad
        self._joint_targets = dict(enumerate(waypoint_q))
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

    def _capture_background(self, pose: FloatArray, q_rad: FloatArray) -> None:
        self._progress("background", "moving to the retract pose for the background")
        attempts = self._job.acquisition.max_attempts
        for attempt in range(1, attempts + 1):
            # The arm may start anywhere: reach the retract pose in joint space (the preflight
            # solution nearest the current joints), which no singularity can stop.
            self._move(pose, q_rad, joint=True)
            settled_s = self._settle()
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
                self._progress("retry", f"waypoint {index}: {retry.reason}; repeating", waypoint=index)
        assert last is not None
        if last.scanner_fault:
            raise DeviceError(
                f"waypoint {index}: the scanner failed {attempts} times ({last.reason}); "
                "check its cable and power, then continue with --resume"
            )
        self._skip(index, f"{last.reason} ({attempts} attempts)")

    def _attempt_waypoint(self, index: int, attempt: int) -> None:
        count = len(self._waypoints)
        self._progress("move", f"moving to waypoint {index} ({index + 1} of {count})", waypoint=index)
        self._move(self._waypoints[index], self._joint_targets[index])
        settled_s = self._settle()
        tcp_start = self._read_tcp(settled_s)
        self._progress("dwell", f"dwelling {self._job.dwell_s:g} s at waypoint {index}", waypoint=index)
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
            )
        except RodNotFoundError as exc:
            self._skip(index, str(exc), averaged)
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
            scans=len(capture.scans),
            window_start_s=capture.window_start_host_s,
            window_end_s=capture.window_end_host_s,
        )
        self._progress(
            "centre",
            f"waypoint {index}: rod at ({u:+.4f}, {v:+.4f}) m from {len(capture.scans)} scans",
            waypoint=index,
            scans_averaged=len(capture.scans),
            centre_uv_m=(u, v),
            expected_uv_m=_pair(expected_uv_m),
            averaged=averaged,
            centre=centre,
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

    # -- solving ------------------------------------------------------------------------

    def _solve(self, report: PreflightReport) -> RunOutcome:
        measurements = sorted(self._measurements, key=lambda m: m.index)
        self._progress("solve", f"solving from {len(measurements)} observations")
        solution = solve_two_pass(
            measurements, self._job, self._background,
            on_second_pass=lambda: self._progress("refine", "second pass: centres from the solved rod axes"),
        )
        self._event("solve", pass_number=1, result=_summary(solution.first_pass))
        for index, reason in solution.kept_first_pass:
            self._event("refine_kept_first_pass", index=index, reason=reason)
        self._event("solve", pass_number=2, result=_summary(solution.result), refinement=solution.refinement)
        verdict = evaluate_gates(solution.result, self._job.quality, len(self._waypoints))
        self._event("verdict", **verdict.as_dict())
        self._progress("done", "passed" if verdict.passed else "quality gate failed")
        return RunOutcome(
            preflight=report,
            measurements=measurements,
            skipped=sorted(self._skipped, key=lambda s: s.index),
            observations=solution.observations,
            first_pass=solution.first_pass,
            result=solution.result,
            refinement=solution.refinement,
            verdict=verdict,
            timings=self._timings,
            resumed_from=len(self._resume.measurements) + len(self._resume.skipped),
            background=self._background,
        )

    # -- motion and bookkeeping ---------------------------------------------------------

    def _move(self, pose: FloatArray, q_rad: FloatArray, *, joint: bool = False) -> None:
        """Move to a pose: in joint space when asked (or configured), else on a TCP line."""
        motion = self._job.motion
        self._moves += 1
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
        self._progress("skip", f"waypoint {index} skipped: {reason}", waypoint=index, reason=reason,
                       averaged=averaged)

    def _on_scan(self, scan: LaserScan) -> None:
        """Record every scan; a cancel takes effect between two scans of a dwell."""
        self._recorder.write_scan(scan)
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
        return f" at waypoint {self._current}" if self._current is not None else ""

    def _event(self, kind: str, **fields: Any) -> None:
        try:
            self._recorder.write_event(self._clock(), kind, **_jsonable(fields))
        except LasercalError as exc:
            logger.error("could not record event %s: %s", kind, exc)

    def _progress(self, stage: str, message: str, **fields: Any) -> None:
        self._cancel.raise_if_cancelled()
        if self._on_progress is None:
            return
        done = len(self._measurements) + len(self._skipped)
        remaining = len(self._waypoints) - done
        per_waypoint_s = self._job.dwell_s + self._job.settle.margin_s + self._mean_motion_s()
        self._on_progress(
            Progress(
                stage=stage,
                message=message,
                waypoint_count=len(self._waypoints),
                completed=done,
                time_left_s=remaining * per_waypoint_s,
                **fields,
            )
        )

    def _mean_motion_s(self) -> float:
        return self._timings.motion_s / max(self._moves, 1)


def _summary(result: CalibrationResult) -> dict[str, Any]:
    return {
        "T_base_laser": result.T_base_laser,
        "rms_residual_mm": result.rms_residual_mm,
        "std_translation_mm": result.std_translation_mm,
        "std_rotation_deg": result.std_rotation_deg,
        "outliers": len(result.outliers),
    }
