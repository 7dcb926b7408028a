"""The daemon's expected failures, in its own words: a stable code, one line, details.

The job layer, the history and the token check raise these; they know nothing of HTTP.
The routers (``lasercal_hw.service.routes.problems``) answer each kind with its status and
the body ``{"code": "snake_case", "message": "one line", "detail": {...}}``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lasercal_hw.errors import (
    CalibrationError,
    ConfigError,
    DeviceError,
    InterruptedRunError,
    LasercalError,
    ProtectiveStopError,
)

MAX_FILE_NAME = 255
"""The longest file name a job's folder holds (the file systems' limit)."""


class ServiceError(Exception):
    """An expected failure of a request: ``code``, ``message`` and ``detail``."""

    default_code = "service_error"

    def __init__(
        self, message: str, detail: dict[str, Any] | None = None, *, code: str | None = None
    ) -> None:
        super().__init__(message)
        self.code = code or self.default_code
        self.message = message
        self.detail = detail or {}


class NotFoundError(ServiceError):
    """No such job, calibration or file."""

    default_code = "not_found"


class InvalidRequestError(ServiceError):
    """The request names something wrong; ``detail["field"]`` says where."""

    default_code = "invalid_request"

    def __init__(self, message: str, field: str) -> None:
        super().__init__(message, {"field": field})


class ConfirmationRequiredError(ServiceError):
    """The request would move the arm without saying it may."""

    default_code = "confirmation_required"


class ConflictError(ServiceError):
    """The request does not fit the current state (a job runs, a job cannot resume, a
    calibration failed its gates)."""


class NotAvailableError(ServiceError):
    """This build cannot do what was asked."""

    default_code = "not_implemented"


class UnauthenticatedError(ServiceError):
    """No usable bearer token."""

    default_code = "unauthorized"


class ForbiddenError(ServiceError):
    """A wrong bearer token."""

    default_code = "forbidden"


class StorageFullError(ServiceError):
    """The data folder has no room for what the request would write."""

    default_code = "storage_full"


class HistoryUnavailableError(ServiceError):
    """The history database cannot be read (damaged since the daemon started)."""

    default_code = "history_unavailable"


class PayloadTooLargeError(ServiceError):
    """A request body larger than the daemon takes."""

    default_code = "payload_too_large"


def not_found(what: str, ident: str) -> NotFoundError:
    """An unknown id."""
    message = f"no {what} with id {ident!r}; list them with GET /v1/{what}s"
    return NotFoundError(message, {what + "_id": ident})


def folder_file(folder: Path, name: str, missing: str) -> Path:
    """The file ``name`` right inside ``folder``; a hidden name, one reaching into another
    folder or a missing file is NotFoundError with the message ``missing``."""
    path = folder / name
    try:
        found = len(name) <= MAX_FILE_NAME and "/" not in name and not name.startswith(".") and path.is_file()
    except OSError:  # a name the file system refuses (too long, bad bytes) names no file
        found = False
    if not found:
        raise NotFoundError(missing, {"file": name[:MAX_FILE_NAME]})
    return path


def error_code(exc: BaseException) -> str:
    """The stable code a job's ``error`` carries for an exception from a run."""
    if isinstance(exc, InterruptedRunError):
        return "interrupted"
    if isinstance(exc, ProtectiveStopError):
        return "protective_stop"
    if isinstance(exc, DeviceError):
        return "device_error"
    if isinstance(exc, CalibrationError):
        return "calibration_failed"
    if isinstance(exc, ConfigError):
        return "invalid_job"
    if isinstance(exc, LasercalError):
        return "run_error"
    return "internal_error"
