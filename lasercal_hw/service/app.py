"""The HTTP API (``/v1``), built on FastAPI: see docs/daemon.md for every endpoint."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Header, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict
from starlette.exceptions import HTTPException as StarletteHTTPException

from lasercal_hw import __version__
from lasercal_hw.service.auth import check_bearer
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.events import TERMINAL_STATES
from lasercal_hw.service.problems import ApiError
from lasercal_hw.service.requests import JobBody, ResumeBody, require_confirmation, resolve_job
from lasercal_hw.service.scene_toml import scene_toml
from lasercal_hw.service.sd_notify import notify, watchdog_interval_s

logger = logging.getLogger(__name__)

SSE_HEADERS = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
# Where an event stream starts: the Last-Event-ID header a reconnecting EventSource sends,
# or ?last_event_id= (which wins) for clients that cannot set headers.
LastEventIdHeader = Annotated[str | None, Header()]
AfterQuery = Annotated[int | None, Query(alias="last_event_id", ge=0)]


class ActivateBody(BaseModel):
    """Optional body of an activation."""

    model_config = ConfigDict(extra="forbid")

    reason: str = "activated by request"
    force: bool = False


def _problem(error: ApiError) -> JSONResponse:
    return JSONResponse(error.body(), status_code=error.status)


def _validation_problem(exc: RequestValidationError) -> JSONResponse:
    errors = exc.errors()
    first = errors[0] if errors else {"loc": (), "msg": "invalid request"}
    field = ".".join(str(p) for p in first["loc"] if p not in ("body", "query", "path", "header"))
    message = "; ".join(
        f"{'.'.join(str(p) for p in e['loc'] if p != 'body') or 'body'}: "
        + ("unknown field" if e.get("type") == "extra_forbidden" else str(e["msg"]))
        for e in errors
    )
    return _problem(ApiError(422, "invalid_request", f"{message} (see /v1/docs)", {"field": field or "body"}))


def _after_id(last_event_id: str | None, query_id: int | None) -> int:
    if query_id is not None:
        return query_id
    try:
        return int(last_event_id) if last_event_id else 0
    except ValueError:
        raise ApiError(
            422,
            "invalid_request",
            "Last-Event-ID must be an event id (an integer)",
            {"field": "Last-Event-ID"},
        ) from None


def _event_stream(events: AsyncIterator[bytes]) -> StreamingResponse:
    """An SSE response that no proxy buffers or caches."""
    return StreamingResponse(events, media_type="text/event-stream", headers=SSE_HEADERS)


def create_app(daemon: Daemon) -> FastAPI:
    """The FastAPI application serving ``daemon``."""

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        daemon.bus.attach(asyncio.get_running_loop())
        await asyncio.to_thread(daemon.start)
        daemon.state_listeners.append(lambda job_id, state: notify(f"STATUS=job {job_id}: {state}"))
        watchdog = asyncio.create_task(_watchdog()) if watchdog_interval_s() else None
        try:
            yield
        finally:
            if watchdog is not None:
                watchdog.cancel()
            daemon.bus.close_streams()
            await asyncio.to_thread(daemon.stop)

    async def _watchdog() -> None:
        interval_s = watchdog_interval_s() or 1.0
        while True:  # pings only while the event loop runs: a hung loop gets restarted
            notify("WATCHDOG=1")
            await asyncio.sleep(interval_s)

    app = FastAPI(
        title="lasercal daemon",
        version=__version__,
        lifespan=lifespan,
        openapi_url="/v1/openapi.json",
        docs_url="/v1/docs",
        redoc_url=None,
    )

    @app.exception_handler(ApiError)
    async def _api_problem(_request: Request, exc: ApiError) -> JSONResponse:
        return _problem(exc)

    @app.exception_handler(RequestValidationError)
    async def _request_problem(_request: Request, exc: RequestValidationError) -> JSONResponse:
        return _validation_problem(exc)

    @app.exception_handler(StarletteHTTPException)
    async def _http_problem(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
        return _problem(ApiError(exc.status_code, code, str(exc.detail)))

    def token(authorization: Annotated[str | None, Header()] = None) -> None:
        check_bearer(authorization, daemon.token)

    Authorized = Depends(token)

    @app.get("/v1/health")
    def health() -> dict[str, Any]:
        """Liveness without device I/O."""
        return {"ok": True, "version": __version__}

    @app.get("/v1/status")
    def status() -> dict[str, Any]:
        """Daemon, devices, active calibration and the running (or last) job."""
        return daemon.status()

    @app.post("/v1/jobs", status_code=202, dependencies=[Authorized])
    def start_job(body: JobBody) -> dict[str, Any]:
        """Start a calibrate, verify or dry_run job (409 while one runs)."""
        require_confirmation(body.confirm_motion)
        daemon.jobs.require_kind(body.kind)
        devices = daemon.devices() if body.kind != "dry_run" else {}
        job = resolve_job(body, daemon.config.default_job, devices)
        if body.kind != "dry_run" and job.robot.host is None:
            raise ApiError(
                422,
                "invalid_request",
                "no robot configured: set robot_host in the daemon configuration or robot.host in the job",
                {"field": "job.robot.host"},
            )
        if body.scene is not None and body.kind != "dry_run":
            raise ApiError(422, "invalid_request", "scene applies to dry_run jobs only", {"field": "scene"})
        scene = scene_toml(body.scene) if body.scene is not None else None
        return daemon.jobs.start(
            body.kind,
            job,
            body.model_dump(mode="json"),
            scene_toml=scene,
            activate_on_pass=body.activate_on_pass,
            restore_robot=body.restore_robot,
        )

    @app.get("/v1/jobs")
    def list_jobs(limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> dict[str, Any]:
        """Jobs, newest first."""
        return {"jobs": daemon.store.jobs(limit)}

    @app.get("/v1/jobs/{job_id}")
    def get_job(job_id: str) -> dict[str, Any]:
        """One job."""
        return daemon.jobs.get(job_id)

    @app.get("/v1/jobs/{job_id}/files/{name}")
    def job_file(job_id: str, name: str) -> FileResponse:
        """A file in the job's folder (session.mcap, result.json, ...), finished or not."""
        return FileResponse(daemon.jobs.file(job_id, name))

    @app.post("/v1/jobs/{job_id}/cancel", dependencies=[Authorized])
    def cancel_job(job_id: str) -> dict[str, Any]:
        """Stop the job's arm as Ctrl-C does; the recording is kept, the active calibration untouched."""
        return daemon.jobs.cancel(job_id)

    @app.post("/v1/jobs/{job_id}/resume", dependencies=[Authorized])
    def resume_job(job_id: str, body: ResumeBody) -> dict[str, Any]:
        """Continue a cancelled or interrupted job from its recording."""
        require_confirmation(body.confirm_motion)
        return daemon.jobs.resume(job_id, body.restore_robot)

    @app.get("/v1/jobs/{job_id}/events")
    def job_events(
        job_id: str, last_event_id: LastEventIdHeader = None, after: AfterQuery = None
    ) -> StreamingResponse:
        """The job's events (SSE); ends after its final state."""
        daemon.jobs.get(job_id)
        finished = lambda: daemon.jobs.get(job_id)["state"] in TERMINAL_STATES  # noqa: E731
        return _event_stream(daemon.bus.stream(_after_id(last_event_id, after), job_id, finished))

    @app.get("/v1/events")
    def all_events(last_event_id: LastEventIdHeader = None, after: AfterQuery = None) -> StreamingResponse:
        """Every job's and the daemon's events (SSE)."""
        return _event_stream(daemon.bus.stream(_after_id(last_event_id, after)))

    @app.get("/v1/calibration")
    def active_calibration() -> dict[str, Any]:
        """The active calibration with its exports."""
        active = daemon.history.active()
        if active is None:
            raise ApiError(
                404,
                "no_active_calibration",
                "no calibration is active yet; run a calibrate job "
                "with activate_on_pass or activate one with POST /v1/calibrations/{id}/activate",
            )
        return active

    @app.get("/v1/calibrations")
    def calibrations() -> dict[str, Any]:
        """Every calibration, newest first."""
        return {"calibrations": daemon.history.all(), "activations": daemon.store.activations()}

    @app.get("/v1/calibrations/{calibration_id}")
    def calibration(calibration_id: str) -> dict[str, Any]:
        """One calibration."""
        return daemon.history.summary(calibration_id)

    @app.get("/v1/calibrations/{calibration_id}/files/{name}")
    def calibration_file(calibration_id: str, name: str) -> FileResponse:
        """A file of a calibration (result.json, report.png, session.mcap, ...)."""
        return FileResponse(daemon.history.file(calibration_id, name))

    @app.post("/v1/calibrations/{calibration_id}/activate", dependencies=[Authorized])
    def activate(calibration_id: str, body: ActivateBody | None = None) -> dict[str, Any]:
        """Make a calibration active (also a rollback); recorded in the activation log."""
        body = body or ActivateBody()
        return daemon.history.activate(calibration_id, body.reason, force=body.force)

    @app.get("/v1/calibrations/{a}/diff/{b}")
    def diff(a: str, b: str) -> dict[str, Any]:
        """The change from calibration a to b (mm, degrees) and whether it is significant."""
        return daemon.history.diff(a, b)

    @app.get("/v1/verifies")
    def verifies() -> dict[str, Any]:
        """Verify results, newest first."""
        return {"verifies": daemon.store.verifies()}

    static = Path(str(resources.files("lasercal_hw.service"))) / "static"
    if static.is_dir():
        app.mount("/", StaticFiles(directory=static, html=True), name="page")
    return app
