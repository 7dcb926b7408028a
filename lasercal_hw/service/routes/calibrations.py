"""``/v1/calibration`` and ``/v1/calibrations``: the active calibration, the history, its
files, activation (and rollback) and the difference between two."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field, StrictBool, field_validator

from lasercal_hw.config import SCANNER_NAME_PATTERN
from lasercal_hw.service.errors import NotFoundError
from lasercal_hw.service.job_request import unknown_scanner
from lasercal_hw.service.routes.deps import Authorized, DaemonDep

router = APIRouter()

MAX_REASON_CHARS = 500
"""An activation's reason is one line for the log and the page."""
MAX_NAME_CHARS = 100
"""Who marked a calibration bad: a name or an address."""


def _encodable(text: str) -> str:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("must be text (a lone surrogate such as \\ud800 is not)") from None
    return text


class ActivateBody(BaseModel):
    """Optional body of an activation."""

    model_config = ConfigDict(extra="forbid")

    reason: str = Field("activated by request", max_length=MAX_REASON_CHARS)
    force: StrictBool = False

    @field_validator("reason")
    @classmethod
    def _text(cls, reason: str) -> str:
        return _encodable(reason)


class MarkBadBody(BaseModel):
    """Who found a calibration bad, and why."""

    model_config = ConfigDict(extra="forbid")

    by: str = Field(min_length=1, max_length=MAX_NAME_CHARS)
    reason: str = Field(min_length=1, max_length=MAX_REASON_CHARS)

    @field_validator("by", "reason")
    @classmethod
    def _text(cls, value: str) -> str:
        return _encodable(value)


ScannerQuery = Annotated[
    str | None,
    Query(pattern=SCANNER_NAME_PATTERN, description="a scanner of the cell ([scanners.NAME]; default: any)"),
]


@router.get("/v1/calibration")
def active_calibration(daemon: DaemonDep, scanner: ScannerQuery = None) -> dict[str, Any]:
    """The active calibration (of ``scanner``; without it the newest activation, a one-scanner
    daemon's one) with its exports; 404 ``unknown_scanner`` for a scanner the daemon does not
    have and has no calibration of."""
    unknown = unknown_scanner(scanner, daemon.devices, daemon.store)
    if unknown is not None:
        raise NotFoundError(unknown, code="unknown_scanner")
    return daemon.history.active(scanner)


@router.get("/v1/calibrations")
def calibrations(daemon: DaemonDep, scanner: ScannerQuery = None) -> dict[str, Any]:
    """Every calibration (of ``scanner``, or of all), newest first."""
    return {"calibrations": daemon.history.all(scanner), "activations": daemon.history.activations()}


@router.get("/v1/calibrations/{calibration_id}")
def calibration(calibration_id: str, daemon: DaemonDep) -> dict[str, Any]:
    """One calibration."""
    return daemon.history.summary(calibration_id)


@router.get("/v1/calibrations/{calibration_id}/files/{name}")
def calibration_file(calibration_id: str, name: str, daemon: DaemonDep) -> FileResponse:
    """A file of a calibration (result.json, report.png, session.mcap, ...)."""
    return FileResponse(daemon.history.file(calibration_id, name))


@router.post("/v1/calibrations/{calibration_id}/activate", dependencies=[Authorized])
def activate(calibration_id: str, daemon: DaemonDep, body: ActivateBody | None = None) -> dict[str, Any]:
    """Make a calibration active (also a rollback); recorded in the activation log."""
    body = body or ActivateBody()
    return daemon.history.activate(calibration_id, body.reason, force=body.force)


@router.post("/v1/calibrations/{calibration_id}/mark-bad", dependencies=[Authorized])
def mark_bad(calibration_id: str, body: MarkBadBody, daemon: DaemonDep) -> dict[str, Any]:
    """Record who found a calibration bad, when and why. A bad calibration is never active:
    marking the active one deactivates it (the ``deactivation`` event says so), and
    activating a bad one is a 409."""
    return daemon.history.mark_bad(calibration_id, body.by, body.reason)


@router.get("/v1/calibrations/{a}/diff/{b}")
def diff(a: str, b: str, daemon: DaemonDep) -> dict[str, Any]:
    """The change from calibration a to b (mm, degrees) and whether it is significant."""
    return daemon.history.diff(a, b)

