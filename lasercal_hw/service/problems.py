"""The daemon's expected failures: an HTTP status, a stable code, one line, details.

Every 4xx answer has the body ``{"code": "snake_case", "message": "one line", "detail": {...}}``.
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


class ApiError(Exception):
    """An expected failure answered with ``status`` and a JSON body."""

    def __init__(self, status: int, code: str, message: str, detail: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.detail = detail or {}

    def body(self) -> dict[str, Any]:
        """The JSON body of the answer."""
        return {"code": self.code, "message": self.message, "detail": self.detail}


def not_found(what: str, ident: str) -> ApiError:
    """404 for an unknown id."""
    return ApiError(
        404,
        "not_found",
        f"no {what} with id {ident!r}; list them with GET /v1/{what}s",
        {what + "_id": ident},
    )


def folder_file(folder: Path, name: str, missing: str) -> Path:
    """The file ``name`` right inside ``folder``; a hidden name, one reaching into another
    folder or a missing file is a 404 whose message is ``missing``."""
    path = folder / name
    if "/" in name or name.startswith(".") or not path.is_file():
        raise ApiError(404, "not_found", missing, {"file": name})
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
