"""The one way to run a calibration: ``calibrate(RunRequest) -> RunReport``.

The CLI, the daemon and Python scripts all call this. It prepares the output folder,
starts the dry-run fake cell when asked, connects the scanner and then the robot,
records everything to ``session.mcap``, runs the sequencer, writes every output file and
reports what happens as ``RunEvent``s to one callback (a terminal view, a JSON printer,
an HTTP event stream or a test). It never prints and never asks: the caller renders the
events and, through ``confirm``, asks the operator.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from lasercal_hw import __version__
from lasercal_hw.config import JobConfig, ScannerConfig, with_overrides
from lasercal_hw.errors import ConfigError, InterruptedRunError, LasercalError
from lasercal_hw.models import FloatArray, RobotCalibration
from lasercal_hw.run.adaptive import run_second_design
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.dry_run_cell import DryRunCell, start_fake_cell
from lasercal_hw.run.events import EventSink, RunEvent, Stage
from lasercal_hw.run.flute_spin import SPIN_TURNS_DEG, run_turned_waypoints
from lasercal_hw.run.outcome import solve_run
from lasercal_hw.run.outputs import SESSION_FILE, transform_error, write_outputs
from lasercal_hw.run.preflight import PreflightReport
from lasercal_hw.run.records import ProgressCallback, ResumeState, RunOutcome, RunRecorder
from lasercal_hw.run.resume import (
    META_JOB,
    META_PROCEDURE,
    META_WAYPOINTS,
    Procedure,
    recorded_job,
    recorded_procedure,
    resume_state,
)
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.watchers import Watcher
from lasercal_hw.run.waypoints import job_waypoints, listed_waypoints
from lasercal_hw.session.format import META_SCANNER_NAME
from lasercal_hw.session.reader import SessionRecording, read_session
from lasercal_hw.session.recorder import SessionRecorder
from lasercal_hw.ur_kinematics import offline_model

__all__ = [
    "CancelToken", "JobRecording", "MotionPlan", "ProcedureReport", "RunEvent", "RunReport", "RunRequest",
    "SequencerSession", "calibrate", "default_out_dir", "open_sequencer",
]

DRY_RUN_SCENE_FILE = "dry_run_scene.toml"
#: Recording meta: whether the run was a dry run, and the fake cell's scene (TOML text), so a
#: dry run's recording resumes against a new fake cell of the same world.
META_DRY_RUN = "dry_run"
META_SCENE = "dry_run_scene_toml"
#: Recording meta: the robot's own kinematics calibration (``RobotCalibration.as_dict``, or None: unknown).
META_ROBOT_CALIBRATION = "robot_calibration"


@dataclass(frozen=True)
class JobRecording:
    """A cell job's one recording (docs/recorder.md), opened by the job: each scanner's run
    writes to it through ``recorder.for_scanner(NAME)``; ``previous`` is what the file held
    before the job was resumed (None: a new file)."""

    recorder: SessionRecorder
    previous: SessionRecording | None = None

    def earlier_run(self, name: str) -> SessionRecording | None:
        """Scanner ``name``'s run as the file held it before the resume (None: not started)."""
        if self.previous is None or name not in self.previous.scanner_names:
            return None
        return self.previous.for_scanner(name)


@dataclass(frozen=True)
class RunRequest:
    """What to run. ``job`` is resolved (command-line or request overrides applied); a
    resumed run takes its job and waypoints from the recording instead. ``robot_host``
    and ``scanner_url``, when given, say where the devices are (for a resumed run too)."""

    job: JobConfig
    out_dir: Path
    robot_host: str | None = None
    scanner_url: str | None = None
    dry_run: bool = False
    scene: Path | None = None
    resume: Path | None = None
    waypoints: FloatArray | None = None
    #: The number each waypoint goes by in messages (default: its position in ``waypoints``).
    waypoint_names: tuple[int, ...] | None = None
    title: str = "lasercal run"
    #: What the run is for, recorded with it: only a calibration's recording is resumed.
    procedure: Procedure = Procedure.CALIBRATION
    #: Which of the cell's scanners this run calibrates (a dry run picks it from the scene's
    #: ``[scanners.NAME]``); None: the one scanner.
    scanner_name: str | None = None
    #: A dry run's fake cell already running (a cell job starts one for all its scanners);
    #: None: a dry run starts its own.
    fake_cell: DryRunCell | None = None
    #: The cell's other scanners that measure the rod at this run's waypoints where they see it
    #: (``run/watchers``): name and settings (url, nominal pose; a dry run's url is its fake cell's).
    watch: tuple[tuple[str, ScannerConfig], ...] = ()
    #: A cell job's one recording this run writes to, as scanner ``scanner_name`` (continuing that
    #: scanner's run where the file holds one); None: the run's own ``session.mcap``.
    recording: JobRecording | None = None


OutcomeT = TypeVar("OutcomeT")


@dataclass(frozen=True)
class ProcedureReport(Generic[OutcomeT]):
    """A finished procedure on the engine's machinery (a run, a verify): its outcome, the
    files written, the dry run's ground truth and fake cell, and the whole call's time."""

    outcome: OutcomeT
    files: dict[str, Path]
    out_dir: Path
    ground_truth: FloatArray | None
    fake_cell: dict[str, Any] | None
    command_s: float

    def with_outputs(self, document: dict[str, Any]) -> dict[str, Any]:
        """``document`` with the files written, whether it was a dry run and the fake cell."""
        document["outputs"] = {name: str(path) for name, path in self.files.items()}
        document["dry_run"] = self.fake_cell is not None
        if self.fake_cell is not None:
            document["fake_cell"] = self.fake_cell
        return document


@dataclass(frozen=True)
class RunReport(ProcedureReport[RunOutcome]):
    """A finished run: the sequencer's outcome and the files written."""

    @property
    def overhead_fraction_with_io(self) -> float:
        """Overhead share counting connecting and writing the outputs too."""
        busy_s = self.outcome.timings.motion_s + self.outcome.timings.dwell_s
        return (self.command_s - busy_s) / busy_s if busy_s > 0 else 0.0

    def truth_error(self) -> dict[str, float] | None:
        """Dry run: the error of both passes against the fake cell's ground truth."""
        if self.ground_truth is None:
            return None
        first = transform_error(self.outcome.first_pass.matrix(), self.ground_truth)
        return transform_error(self.outcome.result.matrix(), self.ground_truth) | {
            f"first_pass_{key}": value for key, value in first.items()
        }

    def document(self) -> dict[str, Any]:
        """The JSON document of the run (what ``lasercal run --json`` prints)."""
        outcome, result = self.outcome, self.outcome.result
        document: dict[str, Any] = {
            "passed": outcome.verdict.passed,
            "verdict": outcome.verdict.as_dict(),
            "T_base_laser": result.T_base_laser,
            "translation_m": result.translation_m,
            "euler_zyx_deg": result.euler_zyx_deg,
            "quaternion_xyzw": result.quaternion_xyzw,
            "std_translation_mm": result.std_translation_mm,
            "std_rotation_deg": result.std_rotation_deg,
            "rms_residual_mm": result.rms_residual_mm,
            "observations": len(outcome.observations),
            "skipped": [{"index": s.index, "reason": s.reason} for s in outcome.skipped],
            "refinement": outcome.refinement,
            "timings": {
                "wall_s": outcome.timings.wall_s,
                "motion_s": outcome.timings.motion_s,
                "dwell_s": outcome.timings.dwell_s,
                "overhead_fraction": outcome.timings.overhead_fraction,
                "command_s": self.command_s,
                "overhead_fraction_with_io": self.overhead_fraction_with_io,
            },
        }
        self.with_outputs(document)
        if self.ground_truth is not None:
            document["ground_truth"] = {
                "T_base_laser": np.asarray(self.ground_truth).tolist(),
                "error": transform_error(result.matrix(), self.ground_truth),
                "first_pass_error": transform_error(outcome.first_pass.matrix(), self.ground_truth),
            }
        return document


@dataclass(frozen=True)
class MotionPlan:
    """What is about to move, for the question asked before the first motion."""

    preflight: PreflightReport
    job: JobConfig
    waypoint_count: int
    #: A fake cell's arm (a resumed dry run's recording decides it, not the command line).
    dry_run: bool = False
    #: The robot's own kinematics calibration (None: its primary interface could not be read).
    robot_calibration: RobotCalibration | None = None

    def summary(self) -> str:
        """One paragraph for the operator."""
        robot, motion = self.preflight.robot, self.job.motion
        return (
            f"About to move the {robot.model} at {self.job.robot.host} (serial {robot.serial_number}) to its "
            f"retract pose and through {self.waypoint_count} waypoints{self._then()}, {motion.move} "
            f"moves capped at {motion.speed_m_s} m/s and {motion.accel_m_s2} m/s^2, dwelling "
            f"{self.job.dwell_s:g} s each."
        )

    def _then(self) -> str:
        """What a spun drill's run visits after its spin, when the plan's waypoints are the spin's."""
        if self.job.trajectory.flute_phase_deg is None or self.waypoint_count != len(SPIN_TURNS_DEG):
            return ""
        listed = len(listed_waypoints(self.job))
        return f" (the bit's spin), then the job's {listed} turned about the bit to its phase if told"


def default_out_dir() -> Path:
    """``./lasercal-out/<UTC time>``."""
    return Path("lasercal-out") / datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")


def calibrate(
    request: RunRequest,
    *,
    on_event: Callable[[RunEvent], None] | None = None,
    cancel: CancelToken | None = None,
    confirm: Callable[[MotionPlan], None] | None = None,
) -> RunReport:
    """Run one calibration to the end (see the module docstring). Blocking; any thread.

    ``confirm`` is called once preflight passed, before the first motion; raising
    InterruptedRunError from it ends the run with nothing moved.
    Raises the LasercalError of what stopped it (InterruptedRunError for a cancel or
    Ctrl-C: the arm was stopped and the recording kept). A failed quality gate is not an
    error: ``report.outcome.verdict.passed`` is False and every file is written.
    """
    sink = EventSink(on_event)
    cancel = cancel or CancelToken()
    started_s = time.monotonic()
    with open_sequencer(request, sink, cancel, confirm) as session:
        measured = session.sequencer.measure()
        if session.job.trajectory.flute_phase_deg is not None:  # the rest turned to the spin's phase
            outcome = run_turned_waypoints(
                session.robot, session.scanner, session.recorder, session.job, session.waypoints, measured,
                on_progress=session.on_progress, cancel=cancel, resumed_turn_note=session.resumed_turn_note,
            )
        else:
            outcome = solve_run(
                measured, session.job, session.recorder,
                on_progress=session.on_progress, cancel=cancel,
            )
        if session.job.trajectory.adaptive:  # design the rest from this estimate, measure it, solve all
            outcome = run_second_design(
                session.robot, session.scanner, session.recorder, session.job, session.waypoints, outcome,
                on_progress=session.on_progress, cancel=cancel,
                model=offline_model(session.robot_calibration, named=session.job.robot.model),
            )
        sink.emit("stage", "writing the outputs", stage=Stage.OUTPUTS)
        files = {"session": session.session_path} | write_outputs(
            session.out_dir, outcome, session.job, ground_truth=session.ground_truth, title=request.title,
            scanner=request.scanner_name,
            robot_calibration=session.robot_calibration,
        )
    ground_truth, fake_cell, out_dir = session.ground_truth, session.fake_cell, session.out_dir
    report = RunReport(outcome, files, out_dir, ground_truth, fake_cell, time.monotonic() - started_s)
    result = outcome.result
    failures = "; ".join(outcome.verdict.failures())
    sink.emit(
        "result",
        "passed" if outcome.verdict.passed else f"quality gate failed: {failures}",
        passed=outcome.verdict.passed,
        T_base_laser=result.T_base_laser,
        std_translation_mm=result.std_translation_mm,
        std_rotation_deg=result.std_rotation_deg,
        rms_residual_mm=result.rms_residual_mm,
    )
    return report


@dataclass(frozen=True)
class SequencerSession:
    """A sequencer connected to the devices (or a dry run's fake cell) and recording to
    ``session_path``: what ``open_sequencer`` hands to a procedure."""

    job: JobConfig
    waypoints: FloatArray
    out_dir: Path
    session_path: Path
    sequencer: Sequencer
    robot: Robot
    scanner: Scanner
    recorder: RunRecorder
    ground_truth: FloatArray | None
    fake_cell: dict[str, Any] | None
    on_progress: ProgressCallback
    #: The robot's own kinematics calibration (None: unknown, and a warning said so).
    robot_calibration: RobotCalibration | None = None
    #: What a resumed spun run had said of its turn (``ResumeState.turn_note``).
    resumed_turn_note: str | None = None


@contextlib.contextmanager
def open_sequencer(
    request: RunRequest,
    sink: EventSink,
    cancel: CancelToken,
    confirm: Callable[[MotionPlan], None] | None = None,
) -> Iterator[SequencerSession]:
    """Everything a run does around its sequencer, for ``calibrate`` and for other
    procedures on the same machinery (``lasercal verify`` measures without solving):
    output folder, fake cell, devices, recording, and on failure where the recording is
    (and that the run can be resumed from it, for a calibration: ``request.procedure``)."""
    request, job, waypoints, out_dir, state, created = _prepare(request)
    session_path = _recording_path(request)
    try:
        with contextlib.ExitStack() as stack:
            ground_truth: FloatArray | None = None
            fake_cell: dict[str, Any] | None = None
            watch_urls = {name: config.url for name, config in request.watch}
            if request.dry_run:
                job, ground_truth, fake_cell, watch_urls = _start_fake_cell(
                    request, job, out_dir, stack, sink, cancel
                )
            cancel.raise_if_cancelled()
            if job.robot.host is None:
                raise ConfigError("no robot given: say where the robot is (robot.host in the job file)")
            sink.emit("stage", "connecting to the scanner and the robot", stage=Stage.CONNECT)
            from drivers.access import DeviceAccess  # the connect step: nothing above needs a driver

            devices = DeviceAccess()
            watchers = _connect_watchers(request, watch_urls, devices, stack)  # scanners before the robot
            robot, scanner = devices.connect(job, stack)
            robot_calibration = _read_robot_calibration(devices, job.robot.host, sink)
            recorder = _open_recorder(request, job, waypoints, robot, scanner, fake_cell, ground_truth,
                                      session_path, robot_calibration)
            if isinstance(recorder, SessionRecorder):  # a cell job's one recording is closed by the job
                stack.callback(recorder.close)
            on_progress = sink.progress_listener(job.rod.radius_m)
            sequencer = Sequencer(
                robot,
                scanner,
                recorder,
                job,
                waypoints,
                on_progress=on_progress,
                before_motion=None if confirm is None else lambda report: confirm(
                    MotionPlan(report, job, len(waypoints), dry_run=request.dry_run,
                               robot_calibration=robot_calibration)
                ),
                resume=state,
                cancel=cancel,
                waypoint_names=request.waypoint_names,
                watchers=watchers,
            )
            yield SequencerSession(
                job, waypoints, out_dir, session_path, sequencer, robot, scanner, recorder, ground_truth,
                fake_cell, on_progress, robot_calibration, None if state is None else state.turn_note,
            )
    except (LasercalError, KeyboardInterrupt, OSError) as exc:  # OSError: a full disk, say
        _after_failure(
            out_dir, session_path, created, sink, exc,
            resumable=request.procedure.resumable, dry_run=request.dry_run
        )
        raise


def _prepare(
    request: RunRequest,
) -> tuple[RunRequest, JobConfig, FloatArray, Path, ResumeState | None, bool]:
    """The request as the recording says for a resumed run (a dry run's recording goes on as
    a dry run), the job, its waypoints, the output folder (made here), what a resumed run
    already has, and whether this call created the folder."""
    devices = {"robot.host": request.robot_host, "scanner.url": request.scanner_url}
    previous = _earlier_run(request)
    if previous is not None:
        request = _as_recorded(request, previous.meta)
        recorded, waypoints = recorded_job(previous)
        job = with_overrides(recorded, devices)  # the recording decides all but where the devices are
        out_dir = request.out_dir if request.resume is None else request.resume.parent
        _make_folder(out_dir)
        return request, job, waypoints, out_dir, resume_state(previous), False
    job = with_overrides(request.job, devices)
    waypoints = (
        request.waypoints if request.waypoints is not None else job_waypoints(job, live=not request.dry_run)
    )
    out_dir = request.out_dir
    created = not out_dir.exists()
    _make_folder(out_dir)
    if (out_dir / SESSION_FILE).exists():
        raise ConfigError(
            f"{out_dir / SESSION_FILE} already exists: choose another output folder, "
            "or resume that run from its recording"
        )
    return request, job, np.asarray(waypoints, dtype=float).reshape(-1, 6), out_dir, None, created


def _make_folder(out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the output folder {out_dir}: {exc.strerror or exc}") from exc


def _recording_path(request: RunRequest) -> Path:
    """Where the run records: the recording it resumes, a cell job's one recording, or its own."""
    if request.resume is not None:
        return request.resume
    if request.recording is not None:
        return request.recording.recorder.path
    return request.out_dir / SESSION_FILE


def _earlier_run(request: RunRequest) -> SessionRecording | None:
    """What the run continues: the recording it resumes, or this scanner's run in a resumed cell
    job's one recording (``SessionRecording.for_scanner``); None: a new run."""
    if request.resume is not None:
        recording = read_session(request.resume)
        if recording.is_job_recording:  # continued as a whole, by its job (run/cell.py)
            names = ", ".join(recording.scanner_names)
            raise ConfigError(
                f"{request.resume} is a cell job's recording of scanners {names}: it is continued by "
                f"resuming the job, its folder {request.resume.parent}, not one scanner's run"
            )
        procedure = recorded_procedure(recording)
        if not procedure.resumable:
            raise ConfigError(
                f"{request.resume} is a {procedure.value}'s recording, which is not resumed: start a "
                f"new {procedure.value} (lasercal {procedure.value})"
            )
        return recording
    if request.recording is not None and request.scanner_name is not None:
        return request.recording.earlier_run(request.scanner_name)
    return None


def _as_recorded(request: RunRequest, meta: dict[str, Any]) -> RunRequest:
    """A resumed run continues on what it was recorded on: a dry run's recording against a
    new fake cell of the recorded scene (the recording alone is enough), a live recording
    only against hardware."""
    recorded_at = _recording_path(request)
    if not meta.get(META_DRY_RUN):
        if request.dry_run:
            raise ConfigError(
                f"{recorded_at} was recorded on hardware: a dry run cannot continue it; resume it "
                "against the robot and scanner it was recorded with"
            )
        return request
    if request.robot_host is not None or request.scanner_url is not None:
        raise ConfigError(
            f"{recorded_at} is a dry run's recording: it continues against a new fake cell, not "
            "against a robot or scanner"
        )
    scene = request.scene
    scene_toml = meta.get(META_SCENE)
    if scene is None and scene_toml is not None:
        scene = recorded_at.parent / DRY_RUN_SCENE_FILE
        if not scene.is_file() or scene.read_text(encoding="utf-8") != scene_toml:
            scene.write_text(scene_toml, encoding="utf-8")
    return replace(request, dry_run=True, scene=scene, scanner_name=meta.get(META_SCANNER_NAME))


def _start_fake_cell(
    request: RunRequest,
    job: JobConfig,
    out_dir: Path,
    stack: contextlib.ExitStack,
    sink: EventSink,
    cancel: CancelToken,
) -> tuple[JobConfig, FloatArray, dict[str, Any], dict[str, str]]:
    """Start the dry run's fake cell (or take the one a cell job started: ``request.fake_cell``)
    and point the job at its scanner (``request.scanner_name``); the urls of the scanners it
    watches (``request.watch``) there."""
    from lasercal_hw.run.dry_run_scene import rods_differ, write_rod_scene

    cell = request.fake_cell
    if cell is None:  # the fake cell holds the rod the job describes, unless a scene is given
        scene = request.scene or write_rod_scene(job.rod.rod_line(), out_dir / DRY_RUN_SCENE_FILE)
        cell = start_fake_cell(scene, stack, sink, cancel)
    process = cell.process
    scanner_url, ground_truth = process.scanner(request.scanner_name)
    job = with_overrides(job, {"robot.host": process.robot_host, "scanner.url": scanner_url})
    sink.emit(
        "stage",
        f"fake cell on {process.address} (pid {process.pid}): scanner {scanner_url}",
        stage=Stage.FAKE_CELL,
        address=process.address,
        pid=process.pid,
        robot_host=process.robot_host,
        scanner_url=scanner_url,
        scanner_name=request.scanner_name,
    )
    difference = rods_differ(process.info.get("rod"), job.rod.rod_line())
    if difference is not None:
        sink.emit("warning", difference)
    watch_urls = {name: process.scanner(name)[0] for name, _ in request.watch}
    started = {"address": process.address, "pid": process.pid, "scene": str(cell.scene)}
    return job, ground_truth, started, watch_urls


def _connect_watchers(
    request: RunRequest, urls: dict[str, str], devices: Any, stack: contextlib.ExitStack
) -> list[Watcher]:
    """The cell's other scanners of ``request.watch``, connected (closed by ``stack``)."""
    watchers = []
    for name, config in request.watch:
        assert config.nominal is not None, "a cell watches its scanners with a nominal pose only"
        scanner = devices.open_scanner(urls[name], timeout_s=config.timeout_s)
        stack.callback(scanner.close)
        watchers.append(Watcher(name, scanner, config.nominal.matrix()))
    return watchers


def _read_robot_calibration(devices: Any, host: str, sink: EventSink) -> RobotCalibration | None:
    """The robot's own kinematics calibration from its primary interface; when it cannot be
    read, a warning says so and the run goes on with it unknown."""
    try:
        calibration: RobotCalibration = devices.read_robot_calibration(host)
    except LasercalError as exc:
        sink.emit("warning", f"the robot's kinematics calibration is unknown and recorded as unknown: {exc}")
        return None
    sink.emit(
        "stage", f"robot kinematics calibration: {calibration.model}, checksum {calibration.checksum}",
        stage=Stage.CONNECT, robot_calibration_checksum=calibration.checksum,
    )
    return calibration


def _open_recorder(
    request: RunRequest,
    job: JobConfig,
    waypoints: FloatArray,
    robot: Robot,
    scanner: Scanner,
    fake_cell: dict[str, Any] | None,
    ground_truth: FloatArray | None,
    session_path: Path,
    robot_calibration: RobotCalibration | None,
) -> RunRecorder:
    """A new ``session.mcap``, or the interrupted one continued, with the run's meta; in a cell
    job's one recording, the scanner's part of it (``SessionRecorder.for_scanner``)."""
    meta = {
        META_JOB: job.model_dump(mode="json"),
        META_WAYPOINTS: np.asarray(waypoints).tolist(),
        META_PROCEDURE: request.procedure.value,
        "software_version": __version__,
        META_DRY_RUN: request.dry_run,
        "started_utc": datetime.now(UTC).isoformat(),
        "robot": asdict(robot.identity()) | {"host": job.robot.host},
        "scanner": asdict(scanner.identity()) | {"url": job.scanner.url},
        META_ROBOT_CALIBRATION: None if robot_calibration is None else robot_calibration.as_dict(),
    }
    if request.scanner_name is not None:
        meta[META_SCANNER_NAME] = request.scanner_name
    if ground_truth is not None:
        meta["ground_truth_T_base_laser"] = np.asarray(ground_truth).tolist()
    if fake_cell is not None:
        meta[META_SCENE] = Path(fake_cell["scene"]).read_text(encoding="utf-8")
    if request.recording is not None and request.scanner_name is not None:
        recorder = request.recording.recorder.for_scanner(request.scanner_name)
        recorder.write_meta(meta)
        return recorder
    if request.resume is not None:
        return SessionRecorder.resume(request.resume, meta)
    return SessionRecorder(session_path, meta)


def _after_failure(
    out_dir: Path, session_path: Path, created: bool, sink: EventSink, exc: BaseException, *,
    resumable: bool, dry_run: bool,
) -> None:
    """Say where the recording is (the ``stopped`` event: ``session``, ``resumable``,
    ``interrupted``, ``dry_run``, so each front end can say how to resume in its own words),
    or remove an output folder the run left empty."""
    if session_path.exists():
        interrupted = isinstance(exc, InterruptedRunError | KeyboardInterrupt)
        action = "resume this run from its recording" if resumable else "start again"
        when = "" if interrupted else "once the cause is fixed, "
        sink.emit(
            "stopped",
            f"recording kept in {session_path}; {when}{action}",
            session=str(session_path),
            error=str(exc),
            resumable=resumable,
            interrupted=interrupted,
            dry_run=dry_run,
        )
        return
    leftovers = [p for p in out_dir.iterdir() if p.name != DRY_RUN_SCENE_FILE]
    if created and not leftovers:
        for path in out_dir.iterdir():
            path.unlink()
        out_dir.rmdir()
        sink.emit("stopped", f"nothing was recorded; removed the empty output folder {out_dir}",
                  error=str(exc))

