"""``/v1/events`` and ``/v1/jobs/{id}/events``: Server-Sent Events, resumable with
``Last-Event-ID`` (or ``?last_event_id=``, which wins, for clients that cannot set headers)."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Header, Query
from fastapi.responses import StreamingResponse

from lasercal_hw.service.errors import InvalidRequestError
from lasercal_hw.service.routes.deps import DaemonDep

router = APIRouter()

SSE_HEADERS = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
LastEventIdHeader = Annotated[str | None, Header()]
MAX_EVENT_ID = 2**63 - 1  # SQLite's largest integer
AfterQuery = Annotated[int | None, Query(alias="last_event_id", ge=0, le=MAX_EVENT_ID)]


def _after_id(last_event_id: str | None, query_id: int | None) -> int:
    if query_id is not None:
        return query_id
    try:
        after_id = int(last_event_id) if last_event_id else 0
    except ValueError:
        after_id = -1
    if not 0 <= after_id <= MAX_EVENT_ID:
        raise InvalidRequestError(
            f"Last-Event-ID must be an event id (an integer from 0 to {MAX_EVENT_ID})", "Last-Event-ID"
        )
    return after_id


def _event_stream(events: AsyncIterator[bytes]) -> StreamingResponse:
    """An SSE response that no proxy buffers or caches."""
    return StreamingResponse(events, media_type="text/event-stream", headers=SSE_HEADERS)


@router.get("/v1/jobs/{job_id}/events")
def job_events(
    job_id: str, daemon: DaemonDep, last_event_id: LastEventIdHeader = None, after: AfterQuery = None
) -> StreamingResponse:
    """The job's events (SSE); ends after its final state."""
    daemon.jobs.get(job_id)
    after_id = _after_id(last_event_id, after)
    return _event_stream(daemon.bus.stream(after_id, job_id, lambda: daemon.jobs.finished(job_id)))


@router.get("/v1/events")
def all_events(
    daemon: DaemonDep, last_event_id: LastEventIdHeader = None, after: AfterQuery = None
) -> StreamingResponse:
    """Every job's and the daemon's events (SSE)."""
    return _event_stream(daemon.bus.stream(_after_id(last_event_id, after)))
