"""``/v1/jobs``: start, list, read, cancel and resume jobs, and their files."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import FileResponse

from lasercal_hw.service.job_request import JobBody, ResumeBody
from lasercal_hw.service.routes.deps import Authorized, DaemonDep
from lasercal_hw.service.routes.problems import documented

router = APIRouter()


@router.post("/v1/jobs", status_code=202, dependencies=[Authorized], responses=documented(409, 413, 507))
def start_job(body: JobBody, daemon: DaemonDep) -> dict[str, Any]:
    """Start a calibrate, verify or dry_run job (409 while one runs)."""
    return daemon.jobs.start(body).as_json()


@router.get("/v1/jobs")
def list_jobs(daemon: DaemonDep, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> dict[str, Any]:
    """Jobs, newest first."""
    return {"jobs": [job.as_json() for job in daemon.jobs.list(limit)]}


@router.get("/v1/jobs/{job_id}")
def get_job(job_id: str, daemon: DaemonDep) -> dict[str, Any]:
    """One job."""
    return daemon.jobs.get(job_id).as_json()


@router.get("/v1/jobs/{job_id}/files/{name}")
def job_file(job_id: str, name: str, daemon: DaemonDep) -> FileResponse:
    """A file in the job's folder (session.mcap, result.json, ...), finished or not."""
    return FileResponse(daemon.jobs.file(job_id, name))


@router.post("/v1/jobs/{job_id}/cancel", dependencies=[Authorized], responses=documented(409))
def cancel_job(job_id: str, daemon: DaemonDep) -> dict[str, Any]:
    """Stop the job's arm as Ctrl-C does; the recording is kept, the active calibration untouched."""
    return daemon.jobs.cancel(job_id).as_json()


@router.post("/v1/jobs/{job_id}/resume", dependencies=[Authorized], responses=documented(409, 507))
def resume_job(job_id: str, body: ResumeBody, daemon: DaemonDep) -> dict[str, Any]:
    """Continue a cancelled or interrupted job from its recording."""
    return daemon.jobs.resume(job_id, body).as_json()
