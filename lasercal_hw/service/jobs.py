"""The job manager: one motion job at a time, each in its own worker thread.

A job's state is kept apart from the devices' state and from the verdict: queued ->
preflight -> running -> solving -> succeeded | failed | cancelled | interrupted. The run
itself is a *runner* chosen by the job's kind (``lasercal_hw.service.runners``); the
manager turns its events into state and progress, stores them, and files the result.
Nothing resumes by itself: ``resume`` is always a request.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import InterruptedRunError, LasercalError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.service.events import EventBus
from lasercal_hw.service.problems import ApiError, error_code, folder_file, not_found
from lasercal_hw.service.store import HistoryStore, new_id, utc_now

logger = logging.getLogger(__name__)

SESSION_FILE = "session.mcap"
RESUMABLE_STATES = ("cancelled", "interrupted")
RESUMABLE_ERRORS = ("device_error", "protective_stop")
"""A job a device stopped (the arm stopped, the recording kept) resumes as ``lasercal run --resume`` does."""
_STAGE_STATES = {  # the engine's stage events and its progress events' stages -> the job's state
    **dict.fromkeys(("fake_cell", "connect", "preflight"), "preflight"),
    **dict.fromkeys(("background", "waypoints", "move", "dwell", "centre", "skip", "retry"), "running"),
    **dict.fromkeys(("solve", "solving", "refine", "done", "outputs"), "solving"),
}


@dataclass(frozen=True)
class RunContext:
    """What a runner gets: the resolved job, where to write, and the job's channels."""

    job_id: str
    kind: str
    job: JobConfig
    out_dir: Path
    resume_from: Path | None
    scene_file: Path | None
    on_event: Callable[[str, str, dict[str, Any]], None]  # (kind, message, data)
    cancel: CancelToken
    confirm: Callable[[Any], None]  # called once preflight passed


@dataclass(frozen=True)
class RunResult:
    """What a finished run gives back."""

    document: dict[str, Any]  # as ``lasercal run --json`` prints it
    passed: bool
    verdict: dict[str, Any]
    calibration_dir: Path | None = None  # a calibration to file (its result.json is there)
    verify: dict[str, Any] | None = None  # a verify document to file


Runner = Callable[[RunContext], RunResult]


class CalibrationFiler(Protocol):
    """Files a finished calibration into the history (``calibrations.CalibrationHistory``)."""

    def record(self, job_id: str, directory: Path, dry_run: bool) -> str: ...
    def activate(self, calibration_id: str, reason: str) -> dict[str, Any]: ...


class RobotKeeper(Protocol):
    """Notes the robot's program before a job and puts it back afterwards."""

    def snapshot(self, host: str) -> Callable[[], str] | None: ...


@dataclass
class _Active:
    job_id: str
    cancel: CancelToken
    thread: threading.Thread


class JobManager:
    """Starts, cancels, resumes and files jobs; holds at most one running job."""

    def __init__(
        self,
        store: HistoryStore,
        bus: EventBus,
        data_dir: Path,
        runners: dict[str, Runner],
        history: CalibrationFiler,
        robot: RobotKeeper | None = None,
        dry_run_daemon: bool = False,
        on_state: Callable[[str, str], None] | None = None,
    ) -> None:
        self._store = store
        self._bus = bus
        self._jobs_dir = data_dir / "jobs"
        self._jobs_dir.mkdir(parents=True, exist_ok=True)
        self._runners = runners
        self._history = history
        self._robot = robot
        self._dry_run_daemon = dry_run_daemon
        self._on_state = on_state or (lambda job_id, state: None)
        self._lock = threading.Lock()
        #: Held while a job takes the devices and while the status monitor probes the
        #: scanner: a UTM-30LX-EW serves one client, so a probe must never overlap a job.
        self.device_lock = threading.Lock()
        self._active: _Active | None = None
        self._last_id: str | None = None

    # -- queries -------------------------------------------------------------------------------

    def get(self, job_id: str) -> dict[str, Any]:
        """A job by id (404 when unknown)."""
        job = self._store.job(job_id)
        if job is None:
            raise not_found("job", job_id)
        return job

    def current(self) -> dict[str, Any] | None:
        """The running job, else the newest one."""
        with self._lock:
            job_id = self._active.job_id if self._active else self._last_id
        if job_id is None:
            jobs = self._store.jobs(limit=1)
            return jobs[0] if jobs else None
        return self._store.job(job_id)

    def file(self, job_id: str, name: str) -> Path:
        """A file in a job's folder (404 when there is no such file)."""
        return folder_file(Path(self.get(job_id)["out_dir"]), name, f"job {job_id} has no file {name!r}")

    def running_id(self) -> str | None:
        """The id of the running job, if any."""
        with self._lock:
            return self._active.job_id if self._active else None

    # -- life cycle ----------------------------------------------------------------------------

    def require_kind(self, kind: str) -> None:
        """501 for a kind this build cannot run yet."""
        if kind not in self._runners:
            raise ApiError(
                501,
                "not_implemented",
                f"jobs of kind {kind!r} are not available in this build",
                {"field": "kind"},
            )

    def recover(self) -> list[str]:
        """At start-up: jobs a killed daemon left running become ``interrupted`` (never resumed)."""
        ids = self._store.mark_unfinished_interrupted()
        for job_id in ids:
            self._bus.publish(
                "state",
                {
                    "state": "interrupted",
                    "message": "the daemon stopped during this job; its recording is kept",
                },
                job_id,
            )
        return ids

    def start(
        self,
        kind: str,
        job: JobConfig,
        request: dict[str, Any],
        *,
        scene_toml: str | None,
        activate_on_pass: bool,
        restore_robot: bool,
    ) -> dict[str, Any]:
        """Create a job and start it (409 while another one runs)."""
        self.require_kind(kind)
        job_id = new_id("job")
        out_dir = self._jobs_dir / job_id
        record = {
            "id": job_id,
            "kind": kind,
            "state": "queued",
            "created_utc": utc_now(),
            "started_utc": None,
            "finished_utc": None,
            "request": request
            | {
                "activate_on_pass": activate_on_pass,
                "restore_robot": restore_robot,
                "resolved_job": job.model_dump(mode="json"),
            },
            "progress": _progress(None, 0, 0, None, "queued"),
            "verdict": None,
            "error": None,
            "calibration_id": None,
            "verify_id": None,
            "out_dir": str(out_dir),
            "document": None,
        }
        with self._lock:
            self._refuse_if_busy()
            out_dir.mkdir(parents=True)
            scene_file = None
            if scene_toml is not None:
                scene_file = out_dir / "request_scene.toml"
                scene_file.write_text(scene_toml, encoding="utf-8")
            self._store.insert_job(record)
            self._bus.publish("state", {"state": "queued"}, job_id)
            self._launch(record, job, resume_from=None, scene_file=scene_file)
        return self.get(job_id)

    def resume(self, job_id: str, restore_robot: bool) -> dict[str, Any]:
        """Continue a cancelled or interrupted job from its recording (409 otherwise)."""
        record = self.get(job_id)
        session = Path(record["out_dir"]) / SESSION_FILE
        device_failure = (
            record["state"] == "failed" and (record["error"] or {}).get("code") in RESUMABLE_ERRORS
        )
        if record["state"] not in RESUMABLE_STATES and not device_failure:
            raise ApiError(
                409,
                "not_resumable",
                f"job {job_id} is {record['state']}; only a cancelled or interrupted job, or one a device "
                "stopped, can be resumed",
                {"job_id": job_id, "state": record["state"]},
            )
        if not session.exists():
            raise ApiError(
                409,
                "not_resumable",
                f"job {job_id} has no recording to resume from (it stopped "
                "before the first waypoint); start a new job",
                {"job_id": job_id},
            )
        job = job_from_mapping(record["request"]["resolved_job"], f"job {job_id}")
        scene_file = Path(record["out_dir"]) / "request_scene.toml"
        with self._lock:
            self._refuse_if_busy()
            record["request"] = record["request"] | {"restore_robot": restore_robot}
            self._set_state(job_id, "queued", finished_utc=None, error=None, request=record["request"])
            self._launch(
                record, job, resume_from=session, scene_file=scene_file if scene_file.exists() else None
            )
        return self.get(job_id)

    def cancel(self, job_id: str, reason: str = "cancelled by request") -> dict[str, Any]:
        """Stop a running job as Ctrl-C does (the arm stops, the recording is kept). A job
        that is not running is returned unchanged."""
        record = self.get(job_id)
        with self._lock:
            active = self._active if self._active and self._active.job_id == job_id else None
        if active is not None:
            active.cancel.cancel(reason)
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

    def _refuse_if_busy(self) -> None:
        if self._active is not None:
            raise ApiError(
                409,
                "job_running",
                f"job {self._active.job_id} is moving the arm; wait for it or cancel it first",
                {"job_id": self._active.job_id},
            )

    def _launch(
        self, record: dict[str, Any], job: JobConfig, *, resume_from: Path | None, scene_file: Path | None
    ) -> None:
        cancel = CancelToken()
        thread = threading.Thread(
            target=self._work,
            name=f"job-{record['id']}",
            daemon=True,
            args=(record, job, cancel, resume_from, scene_file),
        )
        with self.device_lock:  # a status probe of the scanner in progress ends first
            self._active = _Active(record["id"], cancel, thread)
        self._last_id = record["id"]
        thread.start()

    def _set_state(self, job_id: str, state: str, **fields: Any) -> None:
        """Publish the state event, then store the state: a job seen finished has its final event stored."""
        data: dict[str, Any] = {"state": state}
        if "error" in fields and fields["error"] is not None:
            data["error"] = fields["error"]
        self._bus.publish("state", data, job_id)
        self._store.update_job(job_id, state=state, **fields)
        self._on_state(job_id, state)

    def _work(
        self,
        record: dict[str, Any],
        job: JobConfig,
        cancel: CancelToken,
        resume_from: Path | None,
        scene_file: Path | None,
    ) -> None:
        job_id, kind = record["id"], record["kind"]
        state = {"value": "preflight"}
        progress = dict(record["progress"]) if resume_from else _progress(None, 0, 0, None, "starting")

        def on_event(event_kind: str, message: str, data: dict[str, Any]) -> None:
            self._bus.publish(event_kind, data | {"message": message}, job_id)
            new_state = (
                _STAGE_STATES.get(str(data.get("stage"))) if event_kind in ("stage", "progress") else None
            )
            if new_state is not None and new_state != state["value"]:
                state["value"] = new_state
                self._set_state(job_id, new_state)
            if event_kind == "progress":
                progress.update(
                    _progress(
                        data.get("waypoint"),
                        int(data.get("completed") or 0),
                        int(data.get("waypoint_count") or 0),
                        data.get("time_left_s"),
                        message,
                    )
                )
                self._store.update_job(job_id, progress=progress)

        def confirm(_preflight: Any) -> None:
            if cancel.cancelled:
                raise InterruptedRunError(f"{cancel.reason} before the first motion; nothing moved")
            self._bus.publish(
                "confirmed", {"message": "preflight passed; motion confirmed by the request"}, job_id
            )

        restore = None
        try:
            self._set_state(job_id, "preflight", started_utc=record["started_utc"] or utc_now())
            if record["request"].get("restore_robot") and kind != "dry_run" and self._robot is not None:
                restore = self._robot.snapshot(str(job.robot.host))
            context = RunContext(
                job_id, kind, job, Path(record["out_dir"]), resume_from, scene_file, on_event, cancel, confirm
            )
            final, fields = "succeeded", self._file_result(record, self._runners[kind](context))
        except InterruptedRunError as exc:
            stopped = cancel.reason == "daemon shutting down" or not cancel.cancelled
            final = "interrupted" if stopped else "cancelled"
            fields = {"error": {"code": final, "message": str(exc)}}
        except LasercalError as exc:
            final, fields = "failed", {"error": {"code": error_code(exc), "message": str(exc)}}
        except Exception as exc:
            logger.exception("job %s failed unexpectedly", job_id)
            final = "failed"
            fields = {"error": {"code": "internal_error", "message": f"{type(exc).__name__}: {exc}"}}
        if restore is not None:
            self._bus.publish("robot_restored", {"message": restore()}, job_id)
        with self._lock:
            self._active = None
        self._set_state(job_id, final, finished_utc=utc_now(), **fields)

    def _file_result(self, record: dict[str, Any], result: RunResult) -> dict[str, Any]:
        """File a finished run's calibration or verify; the job fields to store with its end."""
        job_id = record["id"]
        fields: dict[str, Any] = {"verdict": result.verdict, "document": result.document}
        if result.calibration_dir is not None:
            dry_run = record["kind"] == "dry_run" or self._dry_run_daemon
            calibration_id = self._history.record(job_id, result.calibration_dir, dry_run)
            fields["calibration_id"] = calibration_id
            self._bus.publish(
                "calibration", {"calibration_id": calibration_id, "passed": result.passed}, job_id
            )
            if result.passed and record["request"].get("activate_on_pass"):
                self._history.activate(calibration_id, f"activated on pass by job {job_id}")
        if result.verify is not None:
            verify_id = new_id("verify")
            self._store.add_verify(verify_id, job_id, result.verify | {"id": verify_id})
            fields["verify_id"] = verify_id
        return fields


def _progress(
    waypoint: int | None, completed: int, count: int, time_left_s: float | None, message: str
) -> dict[str, Any]:
    return {
        "waypoint": waypoint,
        "completed": completed,
        "waypoint_count": count,
        "time_left_s": time_left_s,
        "message": message,
    }
