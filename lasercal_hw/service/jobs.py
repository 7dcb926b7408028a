"""The job manager: one motion job at a time, each in its own worker thread.

The run itself is a *runner* chosen by the job's kind (``lasercal_hw.service.runners``);
the manager turns the run's events into the job's state (the phase of each ``Stage``) and
progress, stores them, and files the result. Nothing resumes by itself: ``resume`` is
always a request. Failures are the service's own errors (``lasercal_hw.service.errors``);
the routers decide how HTTP says them.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

from lasercal_hw.config import DEFAULT_SCANNER_NAME, JobConfig, job_from_mapping
from lasercal_hw.errors import ConfigError, InterruptedRunError, LasercalError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.cell import CELL_FILE, SCANNER_RESULT
from lasercal_hw.run.events import RunEvent, Stage
from lasercal_hw.service.errors import (
    ConflictError,
    InvalidRequestError,
    NotAvailableError,
    StorageFullError,
    error_code,
    folder_file,
    not_found,
)
from lasercal_hw.service.events import EventBus
from lasercal_hw.service.job_record import VERIFY_ANEW, Job, JobError, JobProgress, JobState
from lasercal_hw.service.job_request import (
    DeviceAddresses,
    JobBody,
    ResumeBody,
    nothing_to_verify,
    require_confirmation,
    require_fields_of_kind,
    resolve_job,
    scene_file_text,
    unknown_scanner,
)
from lasercal_hw.service.storage import StorageGuard, storage_full_cause
from lasercal_hw.service.store import HistoryStore, new_id, utc_now

logger = logging.getLogger(__name__)

SESSION_FILE = "session.mcap"
SCENE_FILE = "request_scene.toml"
RESUMABLE_STATES = (JobState.CANCELLED, JobState.INTERRUPTED)
RESUMABLE_ERRORS = ("device_error", "protective_stop", "storage_full")
"""A job a device or a full disk stopped (the arm stopped, the recording kept) resumes as a
cancelled one does."""
STORAGE_FULL_REASON = "the data folder is full"


@dataclass(frozen=True)
class RunContext:
    """What a runner gets: the job, where its devices are, where to write, and the job's
    channels (``on_event`` takes the run's events as they come)."""

    job_id: str
    kind: str
    job: JobConfig
    devices: DeviceAddresses
    out_dir: Path
    resume_from: Path | None
    scene_file: Path | None
    on_event: Callable[[RunEvent], None]
    cancel: CancelToken
    confirm: Callable[[Any], None]  # called once preflight passed
    #: A verify job's scanner of the cell (None: the newest activation's).
    scanner: str | None = None
    #: A verify job's calibration: the one active (of ``scanner``) when the verify was requested.
    calibration_id: str | None = None


@dataclass(frozen=True)
class RunResult:
    """What a finished run gives back."""

    document: dict[str, Any]  # as ``lasercal run --json`` prints it
    passed: bool
    verdict: dict[str, Any]
    calibration_dir: Path | None = None  # a calibration to file (its result.json is there)
    #: A cell job's calibrations to file, by scanner (each folder holds its result.json).
    calibration_dirs: dict[str, Path] | None = None
    verify: dict[str, Any] | None = None  # a verify document to file


Runner = Callable[[RunContext], RunResult]


class CalibrationFiler(Protocol):
    """Files a finished calibration or verify into the history (``calibrations.CalibrationHistory``)."""

    def record(self, job_id: str, directory: Path, dry_run: bool, created_utc: str | None = None,
               scanner: str = ...) -> str: ...
    def activate(self, calibration_id: str, reason: str) -> Any: ...
    def filed(self, job_id: str, scanner: str) -> str | None: ...
    def record_verify(self, job_id: str, summary: dict[str, Any]) -> str: ...


class DeviceDoor(Protocol):
    """The daemon's devices (``drivers.access.DeviceAccess``): where they are, who holds
    them, and the robot's program kept across a job."""

    robot_host: str | None
    scanner_url: str | None
    scanner_urls: dict[str, str]

    def claim(self, owner: str, urls: Iterable[str] | None = None) -> None: ...
    def release(self, owner: str) -> None: ...
    def program_snapshot(self, host: str) -> Callable[[], str] | None: ...


@dataclass
class _Active:
    job_id: str
    kind: str
    cancel: CancelToken
    thread: threading.Thread


DRY_RUN_DAEMON_HINT = (
    "this daemon serves a fake cell (serve --dry-run), where a calibrate job is checked as on a real "
    "cell: to try a job there, start a dry run instead (lasercal remote calibrate --dry-run, or kind "
    "dry_run), which knows the fake cell's scanner pose"
)


class JobManager:
    """Starts, cancels, resumes and files jobs; holds at most one running job."""

    def __init__(
        self,
        store: HistoryStore,
        bus: EventBus,
        data_dir: Path,
        runners: dict[str, Runner],
        history: CalibrationFiler,
        devices: DeviceDoor,
        default_job: Path | None = None,
        dry_run_daemon: bool = False,
        on_state: Callable[[str, str], None] | None = None,
        dry_run_scene: Path | None = None,
    ) -> None:
        self._store = store
        self._bus = bus
        self._jobs_dir = data_dir / "jobs"
        self._jobs_dir.mkdir(parents=True, exist_ok=True)
        self._storage = StorageGuard(data_dir)
        self._runners = runners
        self._history = history
        self._devices = devices
        self._default_job = default_job
        self._dry_run_scene = dry_run_scene  # a dry-run daemon's scene, for dry runs that give none
        self._dry_run_daemon = dry_run_daemon
        self._on_state = on_state or (lambda job_id, state: None)
        self._lock = threading.Lock()
        self._active: _Active | None = None
        self._last_id: str | None = None

    # -- queries -------------------------------------------------------------------------------

    def get(self, job_id: str) -> Job:
        """A job by id (NotFoundError when unknown)."""
        record = self._store.job(job_id)
        if record is None:
            raise not_found("job", job_id)
        return Job.model_validate(record)

    def list(self, limit: int) -> list[Job]:
        """The newest ``limit`` jobs, newest first."""
        return [Job.model_validate(record) for record in self._store.jobs(limit)]

    def current(self) -> Job | None:
        """The running job, else the newest one."""
        with self._lock:
            job_id = self._active.job_id if self._active else self._last_id
        if job_id is None:
            jobs = self.list(limit=1)
            return jobs[0] if jobs else None
        record = self._store.job(job_id)
        return Job.model_validate(record) if record is not None else None

    def finished(self, job_id: str) -> bool:
        """True once the job has ended."""
        return self.get(job_id).state.finished

    def file(self, job_id: str, name: str) -> Path:
        """A file in a job's folder (NotFoundError when there is no such file)."""
        return folder_file(Path(self.get(job_id).out_dir), name, f"job {job_id} has no file {name!r}")

    # -- life cycle ----------------------------------------------------------------------------

    def recover(self) -> list[str]:
        """At start-up: jobs a killed daemon left running become ``interrupted`` (never resumed)."""
        ids = self._store.mark_unfinished_interrupted()
        for job_id in ids:
            self._bus.publish(
                "state",
                {
                    "state": JobState.INTERRUPTED.value,
                    "message": "the daemon stopped during this job; its recording is kept",
                },
                job_id,
            )
        return ids

    def start(self, body: JobBody) -> Job:
        """Check the request, create the job and start it (ConflictError while another runs)."""
        require_confirmation(body.confirm_motion)
        self._require_kind(body.kind)
        require_fields_of_kind(body)
        try:
            job = resolve_job(body, self._default_job, self._jobs_dir.parent)
        except InvalidRequestError as exc:
            if not (self._dry_run_daemon and exc.detail["field"] == "job.scanner.nominal"):
                raise
            # the job was checked as a real cell's: say how to try it on this daemon's fake cell
            raise InvalidRequestError(f"{exc.message}; {DRY_RUN_DAEMON_HINT}", exc.detail["field"]) from None
        devices = self._addresses(body.kind)
        checks: dict[str, str] = {}
        if body.kind == "verify":  # the job recorded with the calibration, not the daemon's default
            devices, job, calibration_id = self._verify_job(body.scanner, devices)
            checks = {"active_calibration_id": calibration_id}  # what it checks, whatever is activated next
        elif body.kind != "dry_run" and devices.applied_to(job).robot.host is None:
            raise InvalidRequestError(
                "no robot configured: set robot_host in the daemon configuration or robot.host in the job",
                "job.robot.host",
            )
        scene_text = scene_file_text(body)
        if scene_text is None and body.kind == "dry_run" and self._dry_run_scene is not None:
            scene_text = self._dry_run_scene.read_text(encoding="utf-8")  # the dry-run daemon's own world
        job_id = new_id("job")
        out_dir = self._jobs_dir / job_id
        record = Job(
            id=job_id,
            kind=body.kind,
            state=JobState.QUEUED,
            created_utc=utc_now(),
            request=body.model_dump(mode="json")
            | {
                "activate_on_pass": body.activate_on_pass,
                "restore_robot": body.restore_robot,
                "resolved_job": devices.applied_to(job).model_dump(mode="json"),
            }
            | checks,
            progress=JobProgress(message="queued"),
            out_dir=str(out_dir),
        )
        with self._lock:
            self._refuse_if_busy()
            self._storage.ensure()
            try:
                out_dir.mkdir(parents=True)
                scene_file = None
                if scene_text is not None:
                    scene_file = out_dir / SCENE_FILE
                    scene_file.write_text(scene_text, encoding="utf-8")
                self._store.insert_job(record.as_json())
            except (OSError, StorageFullError) as exc:
                shutil.rmtree(out_dir, ignore_errors=True)  # no empty job folder is left behind
                cause = storage_full_cause(exc)
                if cause is None:
                    raise
                raise StorageFullError(
                    f"cannot create job {job_id}: the data folder is full ({cause}); free some space there, "
                    "then try again",
                    {"data_dir": str(self._jobs_dir.parent)},
                ) from None
            self._bus.publish("state", {"state": JobState.QUEUED.value}, job_id)
            self._launch(record, job, devices, resume_from=None, scene_file=scene_file)
        return self.get(job_id)

    def resume(self, job_id: str, body: ResumeBody) -> Job:
        """Continue a cancelled or interrupted job from its recording (ConflictError otherwise)."""
        require_confirmation(body.confirm_motion)
        record = self.get(job_id)
        # a cell job resumes from its folder (cell.json: the scanners done, the one stopped)
        session = Path(record.out_dir) / SESSION_FILE
        if (Path(record.out_dir) / CELL_FILE).exists():
            session = Path(record.out_dir)
        stopped_by = record.error.code if record.error is not None else None
        device_failure = record.state == JobState.FAILED and stopped_by in RESUMABLE_ERRORS
        if record.state not in RESUMABLE_STATES and not device_failure:
            raise ConflictError(
                f"job {job_id} is {record.state.value}; only a cancelled or interrupted job, or one a device "
                "stopped, can be resumed",
                {"job_id": job_id, "state": record.state.value},
                code="not_resumable",
            )
        if record.kind == "verify":
            raise ConflictError(
                f"job {job_id} is a verify; {VERIFY_ANEW}",
                {"job_id": job_id, "kind": record.kind},
                code="not_resumable",
            )
        if not session.exists():
            raise ConflictError(
                f"job {job_id} has no recording to resume from (it stopped "
                "before the first waypoint); start a new job",
                {"job_id": job_id},
                code="not_resumable",
            )
        job = job_from_mapping(record.request["resolved_job"], f"job {job_id}")
        scene_file = Path(record.out_dir) / SCENE_FILE
        with self._lock:
            self._refuse_if_busy()
            self._storage.ensure()
            record.request = record.request | {"restore_robot": body.restore_robot}
            self._set_state(job_id, JobState.QUEUED, finished_utc=None, error=None, request=record.request)
            self._launch(
                record,
                job,
                self._addresses(record.kind),  # asked again: a restarted dry-run daemon's cell moved
                resume_from=session,
                scene_file=scene_file if scene_file.exists() else None,
            )
        return self.get(job_id)

    def cancel(self, job_id: str, reason: str = "cancelled by request") -> Job:
        """Stop a running job as Ctrl-C does (the arm stops, the recording is kept); a job
        that has ended is a ConflictError."""
        record = self.get(job_id)
        with self._lock:
            active = self._active if self._active and self._active.job_id == job_id else None
        if active is None:
            raise ConflictError(
                f"job {job_id} is not running (it is {record.state.value}); there is nothing to cancel",
                {"job_id": job_id, "state": record.state.value},
                code="not_running",
            )
        active.cancel.cancel(reason)
        with contextlib.suppress(StorageFullError):  # on a full disk the cancel works, untold
            self._bus.publish("cancel_requested", {"reason": reason}, job_id)
        return record

    def shutdown(self, timeout_s: float = 30.0) -> None:
        """Stop the running job (its state becomes ``interrupted``) and wait for its thread."""
        with self._lock:
            active = self._active
        if active is not None:
            active.cancel.cancel("daemon shutting down")
            active.thread.join(timeout_s)

    # -- internals -----------------------------------------------------------------------------

    def _require_kind(self, kind: str) -> None:
        if kind not in self._runners:
            raise NotAvailableError(
                f"jobs of kind {kind!r} are not available in this build", {"field": "kind"}
            )

    def _addresses(self, kind: str) -> DeviceAddresses:
        """The daemon's devices for a job of ``kind`` (a dry run brings its own)."""
        if kind == "dry_run":
            return DeviceAddresses()
        devices = self._devices
        return DeviceAddresses(devices.robot_host, devices.scanner_url, tuple(devices.scanner_urls.items()))

    def _verify_job(
        self, scanner: str | None, devices: DeviceAddresses
    ) -> tuple[DeviceAddresses, JobConfig, str]:
        """What a verify of the active calibration (of ``scanner``) runs: ``devices`` with the
        robot it connects to (the daemon's, else the one of the job recorded with the
        calibration), that recorded job (``verify.procedure.recorded_job``) and the
        calibration's id. ConflictError when there is no active calibration (said first: nothing
        to verify) or it cannot be read or records no job; InvalidRequestError when the scanner
        is not the daemon's or no robot is named."""
        from lasercal_hw.run.outputs import RESULT_FILE
        from lasercal_hw.verify.procedure import recorded_job

        found = self._store.active_calibration(scanner)
        if found is None:
            unknown = unknown_scanner(scanner, self._devices, self._store)
            if unknown is not None:
                raise InvalidRequestError(unknown, "scanner")
            raise ConflictError(nothing_to_verify(scanner), code="no_active_calibration")
        calibration_id, folder = found
        try:
            job = recorded_job(folder / RESULT_FILE)
        except ConfigError as exc:
            raise ConflictError(
                f"the active calibration {calibration_id} cannot be read ({exc}); activate another one or "
                "calibrate again",
                {"calibration_id": calibration_id},
                code="calibration_unreadable",
            ) from None
        if devices.robot_host is not None:
            return devices, job, calibration_id
        if job.robot.host is None:
            raise InvalidRequestError(
                f"no robot configured: set robot_host in the daemon configuration (the job recorded with "
                f"the active calibration {calibration_id}, which a verify runs, names no robot.host)",
                "robot_host",
            )
        return replace(devices, robot_host=job.robot.host), job, calibration_id

    def _scanners_used(self, record: Job, job: JobConfig, devices: DeviceAddresses) -> Iterable[str] | None:
        """The URLs of the daemon's scanners a job talks to, held for it (None: every one): a
        calibration's, the scanner a verify checks; none for a dry run (its own fake cell)."""
        if record.kind == "dry_run":
            return ()
        if record.kind == "calibrate":
            resolved = devices.applied_to(job)
            return [scanner.url for scanner in resolved.scanners.values()] or [resolved.scanner.url]
        checked = record.request.get("active_calibration_id")  # the calibration the verify checks
        found = None if checked is None else self._store.calibration(checked)
        name = found[0]["scanner"] if found is not None else record.request.get("scanner")
        url = self._devices.scanner_urls.get(name or "", None)
        if url is None and name == DEFAULT_SCANNER_NAME:
            url = self._devices.scanner_url
        return None if url is None else [url]

    def _refuse_if_busy(self) -> None:
        if self._active is not None:
            job_id, kind = self._active.job_id, self._active.kind
            raise ConflictError(
                f"job {job_id} ({kind}) is moving the arm; wait for it to end or cancel it "
                f"(POST /v1/jobs/{job_id}/cancel), then try again",
                {"job_id": job_id, "kind": kind},
                code="job_running",
            )

    def _launch(
        self,
        record: Job,
        job: JobConfig,
        devices: DeviceAddresses,
        *,
        resume_from: Path | None,
        scene_file: Path | None,
    ) -> None:
        cancel = CancelToken()
        thread = threading.Thread(
            target=self._work,
            name=f"job-{record.id}",
            daemon=True,
            args=(record, job, devices, cancel, resume_from, scene_file),
        )
        # a status probe of a scanner the job uses, in progress, ends first
        self._devices.claim(record.id, self._scanners_used(record, job, devices))
        self._active = _Active(record.id, record.kind, cancel, thread)
        self._last_id = record.id
        thread.start()

    def _set_state(self, job_id: str, state: JobState, **fields: Any) -> None:
        """Publish the state event, then store the state: a job seen finished has its final event stored."""
        data: dict[str, Any] = {"state": state.value}
        if fields.get("error") is not None:
            data["error"] = fields["error"]
        self._bus.publish("state", data, job_id)
        self._store.update_job(job_id, state=state.value, **fields)
        self._on_state(job_id, state.value)

    def _work(
        self,
        record: Job,
        job: JobConfig,
        devices: DeviceAddresses,
        cancel: CancelToken,
        resume_from: Path | None,
        scene_file: Path | None,
    ) -> None:
        job_id, kind = record.id, record.kind
        current = {"state": JobState.PREFLIGHT, "progress": record.progress if resume_from else JobProgress()}
        storage_full: list[str] = []  # why the history could not store an event, if it could not

        def store_event(event: RunEvent) -> None:
            self._bus.publish(event.kind, event.fields(), job_id)
            if event.stage is not None and JobState.of_phase(event.stage.phase) != current["state"]:
                current["state"] = JobState.of_phase(event.stage.phase)
                self._set_state(job_id, current["state"])
            if event.stage is Stage.FAKE_CELL and "scanner_url" in event.data:
                record.request = record.request | {"resolved_job": _pointed_at_fake_cell(record, event.data)}
                self._store.update_job(job_id, request=record.request)
            if event.kind == SCANNER_RESULT:  # a cell job's scanner finished: in the history at once
                self._file_scanner(record, event.data["scanner"], Path(event.data["folder"]),
                                   bool(event.data["passed"]))
            if event.kind == "progress":
                current["progress"] = current["progress"].after(event)
                self._store.update_job(job_id, progress=current["progress"].model_dump(mode="json"))

        def on_event(event: RunEvent) -> None:
            try:
                store_event(event)
            except StorageFullError as exc:  # the reserve keeps the end (the arm's stop) told
                if not storage_full:
                    storage_full.append(str(storage_full_cause(exc)))
                    self._storage.release()
                    cancel.cancel(STORAGE_FULL_REASON)  # the run stops as a cancel does: the arm first
                with contextlib.suppress(StorageFullError):
                    store_event(event)

        def confirm(_preflight: Any) -> None:
            if cancel.cancelled:
                raise InterruptedRunError(f"{cancel.reason} before the first motion; nothing moved")
            self._bus.publish(
                "confirmed", {"message": "preflight passed; motion confirmed by the request"}, job_id
            )

        restore = None
        try:
            self._set_state(job_id, JobState.PREFLIGHT, started_utc=record.started_utc or utc_now())
            if record.request.get("restore_robot") and kind != "dry_run":
                restore = self._devices.program_snapshot(str(devices.applied_to(job).robot.host))
            out_dir = Path(record.out_dir)
            context = RunContext(
                job_id, kind, job, devices, out_dir, resume_from, scene_file, on_event, cancel, confirm,
                scanner=record.request.get("scanner"),
                calibration_id=record.request.get("active_calibration_id"),
            )
            final, fields = JobState.SUCCEEDED, self._file_result(record, self._runners[kind](context))
        except Exception as exc:
            final, fields = self._ending(job_id, exc, cancel, storage_full[0] if storage_full else None)
        if restore is not None:
            self._bus.publish("robot_restored", {"message": restore()}, job_id)
        with self._lock:
            self._active = None
            self._devices.release(job_id)
        self._store_end(job_id, final, fields)

    def _ending(
        self, job_id: str, exc: Exception, cancel: CancelToken, storage_note: str | None
    ) -> tuple[JobState, dict[str, Any]]:
        """How a run that raised ``exc`` ends: its final state and error."""
        full = storage_note or storage_full_cause(exc)
        if full is not None:
            self._storage.release()  # room to store this end
            message = (
                f"the data folder is full ({full}): the arm was stopped and the recording keeps every "
                "waypoint written; free some space, then resume this job"
            )
            final, code = JobState.FAILED, "storage_full"
        elif isinstance(exc, InterruptedRunError):
            stopped = cancel.reason == "daemon shutting down" or not cancel.cancelled
            final = JobState.INTERRUPTED if stopped else JobState.CANCELLED
            code, message = final.value, str(exc)
        elif isinstance(exc, LasercalError):
            final, code, message = JobState.FAILED, error_code(exc), str(exc)
        else:
            logger.exception("job %s failed unexpectedly", job_id)
            final, code, message = JobState.FAILED, "internal_error", f"{type(exc).__name__}: {exc}"
        return final, {"error": JobError(code=code, message=message).model_dump()}

    def _store_end(self, job_id: str, final: JobState, fields: dict[str, Any]) -> None:
        """Store and announce the job's end; a full disk gives the reserve back and tries once more."""
        for attempt in range(2):
            try:
                self._set_state(job_id, final, finished_utc=utc_now(), **fields)
                return
            except StorageFullError as exc:
                if attempt == 0:
                    self._storage.release()
                    continue
                logger.error("job %s ended %s; the history could not store it: %s", job_id, final.value, exc)

    def _file_result(self, record: Job, result: RunResult) -> dict[str, Any]:
        """File a finished run's calibration or verify; the job fields to store with its end."""
        job_id = record.id
        fields: dict[str, Any] = {"verdict": result.verdict, "document": result.document}
        dry_run = record.kind == "dry_run" or self._dry_run_daemon
        if result.calibration_dir is not None:
            calibration_id = self._history.record(job_id, result.calibration_dir, dry_run)
            fields["calibration_id"] = calibration_id
            self._bus.publish(
                "calibration", {"calibration_id": calibration_id, "passed": result.passed}, job_id
            )
            if result.passed and record.request.get("activate_on_pass"):
                self._history.activate(calibration_id, f"activated on pass by job {job_id}")
        passed = {name: bool(entry["passed"]) for name, entry in result.document.get("scanners", {}).items()}
        filed = {
            scanner: self._file_scanner(record, scanner, directory, passed[scanner])
            for scanner, directory in (result.calibration_dirs or {}).items()
        }
        if filed:  # a cell job: the first scanner's calibration in the job's column, all in its document
            fields["calibration_id"] = next(iter(filed.values()))
            fields["document"] = result.document | {"calibration_ids": filed}
        if result.verify is not None:
            fields["verify_id"] = self._history.record_verify(job_id, result.verify)
        return fields

    def _file_scanner(self, record: Job, scanner: str, directory: Path, passed: bool) -> str:
        """File a cell job's calibration of ``scanner`` (activated when it passed and the job
        asks), once: a scanner filed before (as it finished, before a crash) keeps its id."""
        job_id = record.id
        calibration_id = self._history.filed(job_id, scanner)
        if calibration_id is not None:
            return calibration_id
        dry_run = record.kind == "dry_run" or self._dry_run_daemon
        calibration_id = self._history.record(job_id, directory, dry_run, scanner=scanner)
        self._bus.publish(
            "calibration", {"calibration_id": calibration_id, "passed": passed, "scanner": scanner}, job_id
        )
        if passed and record.request.get("activate_on_pass"):
            self._history.activate(calibration_id, f"activated on pass by job {job_id}")
        return calibration_id


def _pointed_at_fake_cell(record: Job, cell: dict[str, Any]) -> dict[str, Any]:
    """The dry run's resolved job with the addresses of the fake cell it started (until then
    it names the default job's devices, which the dry run never uses): a cell job's scanner
    (``scanner_name``) in its ``scanners`` table, a one-scanner job's in ``scanner``."""
    resolved = record.request["resolved_job"]
    robot = {"robot": resolved["robot"] | {"host": cell["robot_host"]}}
    scanners = resolved.get("scanners") or {}
    name = cell.get("scanner_name")
    if name in scanners:
        pointed = scanners[name] | {"url": cell["scanner_url"]}
        return resolved | robot | {"scanners": scanners | {name: pointed}}
    return resolved | robot | {"scanner": resolved["scanner"] | {"url": cell["scanner_url"]}}
