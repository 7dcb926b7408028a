"""How HTTP says the service's errors: each kind's status, and the body
``{"code": "snake_case", "message": "one line", "detail": {...}}`` of every 4xx answer
(request validation and unknown paths included)."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from lasercal_hw.service.errors import (
    ConfirmationRequiredError,
    ConflictError,
    ForbiddenError,
    HistoryUnavailableError,
    InvalidRequestError,
    NotAvailableError,
    NotFoundError,
    PayloadTooLargeError,
    ServiceError,
    StorageFullError,
    UnauthenticatedError,
)

STATUS_OF: dict[type[ServiceError], int] = {
    ConfirmationRequiredError: 400,
    UnauthenticatedError: 401,
    ForbiddenError: 403,
    NotFoundError: 404,
    ConflictError: 409,
    PayloadTooLargeError: 413,
    InvalidRequestError: 422,
    NotAvailableError: 501,
    HistoryUnavailableError: 503,
    StorageFullError: 507,
}
_HTTP_CODES = {404: "not_found", 405: "method_not_allowed"}
_DESCRIPTIONS = {
    409: "the job or calibration is in the wrong state (job_running, not_running, not_resumable, ...)",
    413: "the request body is larger than the daemon takes (payload_too_large)",
    507: "the data folder is full (storage_full); free space and try again, no restart needed",
}


def documented(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """The OpenAPI entries of the problem answers a route may give besides 422."""
    return {status: {"description": _DESCRIPTIONS[status]} for status in statuses}


def problem(status: int, code: str, message: str, detail: dict[str, Any] | None = None) -> JSONResponse:
    """A problem answer."""
    return JSONResponse({"code": code, "message": message, "detail": detail or {}}, status_code=status)


def _json_problem(error: dict[str, Any]) -> JSONResponse:
    """A body that is not JSON: where it stops being JSON (the error's last place is a character
    position, not a field)."""
    position = error["loc"][-1]
    reason = (error.get("ctx") or {}).get("error", "JSON decode error")
    message = f"the request body is not valid JSON: {reason} at character {position} (see /v1/docs)"
    return problem(400, "invalid_json", message, {"position": position})


def _validation_problem(exc: RequestValidationError) -> JSONResponse:
    errors = exc.errors()
    not_json = next((e for e in errors if e.get("type") == "json_invalid"), None)
    if not_json is not None:
        return _json_problem(not_json)
    first = errors[0] if errors else {"loc": (), "msg": "invalid request"}
    field = ".".join(str(p) for p in first["loc"] if p not in ("body", "query", "path", "header"))
    message = "; ".join(
        f"{'.'.join(str(p) for p in e['loc'] if p != 'body') or 'body'}: "
        + ("unknown field" if e.get("type") == "extra_forbidden" else str(e["msg"]))
        for e in errors
    )
    return problem(422, "invalid_request", f"{message} (see /v1/docs)", {"field": field or "body"})


def install_problem_handlers(app: FastAPI) -> None:
    """Answer the service's errors, invalid requests and unknown paths as problems."""

    @app.exception_handler(ServiceError)
    async def _service_problem(_request: Request, exc: ServiceError) -> JSONResponse:
        return problem(STATUS_OF[type(exc)], exc.code, exc.message, exc.detail)

    @app.exception_handler(RequestValidationError)
    async def _request_problem(_request: Request, exc: RequestValidationError) -> JSONResponse:
        return _validation_problem(exc)

    @app.exception_handler(StarletteHTTPException)
    async def _http_problem(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return problem(exc.status_code, _HTTP_CODES.get(exc.status_code, "http_error"), str(exc.detail))
