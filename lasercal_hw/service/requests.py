"""The body of ``POST /v1/jobs`` and how it becomes a resolved job."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from lasercal_hw.config import JobConfig, job_from_mapping, load_job
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.service.problems import ApiError

MOTION_KINDS = ("calibrate", "verify", "dry_run")


class JobBody(BaseModel):
    """A request to start a job (every kind moves an arm, the dry run a fake one)."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["calibrate", "verify", "dry_run"]
    confirm_motion: bool = Field(False, description="must be true: the arm moves")
    job: dict[str, Any] | None = Field(
        None, description="job file (TOML) as a JSON object, merged over the daemon's default job"
    )
    activate_on_pass: bool = Field(False, description="make the result active when it passes the gates")
    restore_robot: bool = Field(True, description="reload (and replay) the robot's program afterwards")
    dwell_s: float | None = Field(None, gt=0.0, le=60.0, description="dwell per waypoint in s")
    scene: dict[str, Any] | None = Field(
        None, description="dry_run only: the fake cell's scene (TOML tables as JSON)"
    )


class ResumeBody(BaseModel):
    """A request to continue a cancelled or interrupted job from its recording."""

    model_config = ConfigDict(extra="forbid")

    confirm_motion: bool = False
    restore_robot: bool = True


def require_confirmation(confirm_motion: bool) -> None:
    """400 unless the request says the arm may move."""
    if not confirm_motion:
        raise ApiError(
            400,
            "confirmation_required",
            'this job moves the arm: send "confirm_motion": true once the cell is clear',
            {"field": "confirm_motion"},
        )


def _merged(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merged(merged[key], value)
        else:
            merged[key] = value
    return merged


def resolve_job(body: JobBody, default_job: Path | None, devices: dict[str, str | None]) -> JobConfig:
    """The job to run: the request's job over the default job, the dwell override, the
    daemon's devices (``{"robot.host": ..., "scanner.url": ...}``, None: keep the job's).
    An invalid job or an unknown preset is a 422 naming the field."""
    try:
        base = load_job(default_job).model_dump(mode="json", exclude_none=True)
        data = _merged(base, body.job or {})
        if body.dwell_s is not None:
            data["dwell_s"] = body.dwell_s
        for dotted, value in devices.items():
            if value is not None:
                table, field = dotted.split(".")
                data.setdefault(table, {})[field] = value
        job = job_from_mapping(data, "job")
        job_waypoints(job)
    except ConfigError as exc:
        raise ApiError(422, "invalid_request", str(exc).replace("\n ", ""), {"field": "job"}) from None
    return job
