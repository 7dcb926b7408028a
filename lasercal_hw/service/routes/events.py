"""``/v1/events`` and ``/v1/jobs/{id}/events``: Server-Sent Events, resumable with
``Last-Event-ID`` (or ``?last_event_id=``, which wins, for clients that cannot set headers).

A job's stream tells the job's story from its start; the daemon's stream starts at the
present unless asked for history (``Last-Event-ID``, ``last_event_id`` or ``since``)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime
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
SinceQuery = Annotated[
    str | None,
    Query(description="ISO 8601 time (UTC unless it names its offset): the events from then on"),
]


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


def _since_id(id_before: Callable[[str], int], since: str) -> int:
    try:
        when = datetime.fromisoformat(since)
    except ValueError:
        raise InvalidRequestError(
            f"since must be an ISO 8601 time such as 2026-11-25T17:01:50Z, not {since!r}", "since"
        ) from None
    when = when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)
    return id_before(when.isoformat(timespec="milliseconds"))


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
    daemon: DaemonDep,
    last_event_id: LastEventIdHeader = None,
    after: AfterQuery = None,
    since: SinceQuery = None,
) -> StreamingResponse:
    """Every job's and the daemon's events (SSE), from now on; with ``Last-Event-ID`` or
    ``last_event_id`` the events after that one, with ``since`` those from that time on."""
    if last_event_id or after is not None:
        after_id = _after_id(last_event_id, after)
    elif since is not None:
        after_id = _since_id(daemon.bus.id_before, since)
    else:
        after_id = daemon.bus.latest_id()
    return _event_stream(daemon.bus.stream(after_id))
