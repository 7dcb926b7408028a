"""A daemon job as the job layer keeps it: its state, progress, error and results (the
JSON of ``GET /v1/jobs/{id}``), typed.

A job's state is kept apart from the devices' state and from the verdict: queued ->
preflight -> running -> solving -> succeeded | failed | cancelled | interrupted; while it
runs, its state is the phase of the run's latest stage (``lasercal_hw.run.events.Stage``).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from pydantic import BaseModel

from lasercal_hw.run.events import Phase, RunEvent


class JobState(StrEnum):
    """Where a job is."""

    QUEUED = "queued"
    PREFLIGHT = Phase.PREFLIGHT.value
    RUNNING = Phase.RUNNING.value
    SOLVING = Phase.SOLVING.value
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"

    @property
    def finished(self) -> bool:
        """True once the job has ended (it changes again only by a resume)."""
        return self in FINISHED_STATES

    @classmethod
    def of_phase(cls, phase: Phase) -> JobState:
        """The state of a job whose run is in ``phase``."""
        return cls(phase.value)


FINISHED_STATES = (JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED, JobState.INTERRUPTED)
UNFINISHED_STATES = (JobState.QUEUED, JobState.PREFLIGHT, JobState.RUNNING, JobState.SOLVING)
#: What a stopped verify job says to do: it is never resumed, a new one is started.
VERIFY_ANEW = (
    "a verify is not resumed from its recording: start a new verify (POST /v1/jobs with kind verify; "
    "lasercal remote verify --yes)"
)


def next_step_after_stop(kind: str) -> str:
    """What an interrupted job of ``kind`` says to do next: resume it, or for a verify start anew."""
    return VERIFY_ANEW if kind == "verify" else "resume it with POST /v1/jobs/{id}/resume"


class JobProgress(BaseModel):
    """How far a job is: the waypoint it is at, how many are done of how many, the time
    left and the latest progress message."""

    waypoint: int | None = None
    completed: int = 0
    waypoint_count: int = 0
    time_left_s: float | None = None
    message: str = "starting"

    def after(self, event: RunEvent) -> JobProgress:
        """The progress a ``progress`` event reports."""
        data = event.data
        return JobProgress(
            waypoint=data.get("waypoint"),
            completed=int(data.get("completed") or 0),
            waypoint_count=int(data.get("waypoint_count") or 0),
            time_left_s=data.get("time_left_s"),
            message=event.message,
        )


class JobError(BaseModel):
    """Why a job did not succeed: a stable code and one line."""

    code: str
    message: str


class Job(BaseModel):
    """One job, as stored and as answered."""

    id: str
    kind: str
    state: JobState
    created_utc: str
    started_utc: str | None = None
    finished_utc: str | None = None
    request: dict[str, Any]
    """The request as sent, with ``activate_on_pass``, ``restore_robot`` and ``resolved_job``."""
    progress: JobProgress
    verdict: dict[str, Any] | None = None
    error: JobError | None = None
    calibration_id: str | None = None
    verify_id: str | None = None
    out_dir: str
    document: dict[str, Any] | None = None
    """The run's document as ``lasercal run --json`` prints it (or the verify's)."""

    def as_json(self) -> dict[str, Any]:
        """The job as JSON."""
        return self.model_dump(mode="json")


def verify_verdict(document: dict[str, Any]) -> dict[str, Any]:
    """A verify job's verdict from its ``verify.json`` document: passed only when ``ok``."""
    status = document["verdict"]
    return {"passed": status == "ok", "status": status, "reason": document["reason"]}
