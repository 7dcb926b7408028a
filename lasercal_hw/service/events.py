"""The event bus: every event carries the time it happened (``time_utc``), gets an increasing
id, is stored (so a client that reconnects with ``Last-Event-ID`` continues where it left off,
even across a daemon restart) and is pushed to the live subscribers of the event loop.

Two kinds of event are bounded: a ``scan`` (a whole averaged scan, kilobytes) is live only,
never stored and sent without an id, and the stored history keeps the newest
``HISTORY_EVENTS`` events.

``publish`` may be called from any thread (the job's worker thread publishes the engine's
events); subscribers live on the event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Any

from lasercal_hw.service.daemon_log import log_event
from lasercal_hw.service.job_record import FINISHED_STATES
from lasercal_hw.service.store import HistoryStore, utc_now

QUEUE_LIMIT = 1000
KEEPALIVE_S = 15.0
LIVE_ONLY_KINDS = frozenset({"scan"})
HISTORY_EVENTS = 20_000
PRUNE_EVERY = 500


@dataclass(frozen=True)
class StoredEvent:
    """One event as it goes out: id (None: a live-only event), kind, job (None: a daemon
    event) and its data as JSON."""

    id: int | None
    kind: str
    job_id: str | None
    data_json: str

    def sse(self) -> bytes:
        """The Server-Sent Events message (no ``id:`` line for a live-only event, so a
        browser's ``Last-Event-ID`` stays on the last stored one)."""
        head = "" if self.id is None else f"id: {self.id}\n"
        return f"{head}event: {self.kind}\ndata: {self.data_json}\n\n".encode()

    @property
    def ends_job(self) -> bool:
        """True for a state event announcing a terminal state."""
        return self.kind == "state" and json.loads(self.data_json).get("state") in FINISHED_STATES


class _Subscriber:
    def __init__(self, job_id: str | None) -> None:
        self.job_id = job_id
        self.queue: asyncio.Queue[StoredEvent | None] = asyncio.Queue()


class EventBus:
    """Stores events and fans them out to the subscribers on ``loop``."""

    def __init__(self, store: HistoryStore) -> None:
        self._store = store
        store.prune_events(HISTORY_EVENTS)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subscribers: set[_Subscriber] = set()
        self._publish_lock = threading.Lock()

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver live events on ``loop`` (called once the server runs)."""
        self._loop = loop

    def publish(self, kind: str, data: dict[str, Any], job_id: str | None = None) -> int | None:
        """Store an event (not a live-only one) and push it to the live subscribers; returns
        its id (None for a live-only event)."""
        time_utc = utc_now()
        payload = data | ({"job_id": job_id} if job_id is not None else {}) | {"time_utc": time_utc}
        with self._publish_lock:  # ids reach the subscribers in order
            event_id = None
            if kind not in LIVE_ONLY_KINDS:
                event_id = self._store.add_event(job_id, kind, payload, time_utc)
                if event_id % PRUNE_EVERY == 0:
                    self._store.prune_events(HISTORY_EVENTS)
            event = StoredEvent(event_id, kind, job_id, json.dumps(payload, allow_nan=False))
            loop = self._loop
            if loop is not None and not loop.is_closed():
                with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                    loop.call_soon_threadsafe(self._deliver, event)
        log_event(kind, payload, job_id)
        return event_id

    def _deliver(self, event: StoredEvent) -> None:
        for subscriber in list(self._subscribers):
            if subscriber.job_id is not None and subscriber.job_id != event.job_id:
                continue
            if subscriber.queue.qsize() >= QUEUE_LIMIT:  # too slow: end its stream, it reconnects
                self._subscribers.discard(subscriber)
                subscriber.queue.put_nowait(None)
            else:
                subscriber.queue.put_nowait(event)

    def close_streams_soon(self) -> None:
        """``close_streams`` on the loop, from any thread or a signal handler."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.close_streams)

    def close_streams(self) -> None:
        """End every live stream (at shutdown); call on the loop."""
        for subscriber in list(self._subscribers):
            subscriber.queue.put_nowait(None)
        self._subscribers.clear()

    @property
    def subscribers(self) -> int:
        """How many live streams are open."""
        return len(self._subscribers)

    def latest_id(self) -> int:
        """The id of the newest stored event (0: none): where a stream "from now" starts."""
        return self._store.latest_event_id()

    def id_before(self, time_utc: str) -> int:
        """The id after which the events at or after ``time_utc`` (ISO 8601, UTC) begin."""
        return self._store.event_id_before(time_utc)

    def _stored_after(self, after_id: int, job_id: str | None) -> Iterator[StoredEvent]:
        while True:
            rows = self._store.events_after(after_id, job_id)
            if not rows:
                return
            for event_id, kind, data_json in rows:
                yield StoredEvent(event_id, kind, job_id, data_json)
                after_id = event_id

    async def stream(
        self,
        after_id: int,
        job_id: str | None = None,
        job_finished: Callable[[], bool] = lambda: False,
        keepalive_s: float = KEEPALIVE_S,
    ) -> AsyncIterator[bytes]:
        """SSE bytes: the stored events after ``after_id``, then live ones. A job's stream
        ends after the job's final state event (at once when a client reconnects after it:
        ``job_finished()``); the daemon stream runs until shutdown."""
        subscriber = _Subscriber(job_id)
        self._subscribers.add(subscriber)
        try:
            last_id = after_id
            finished = job_id is not None and job_finished()  # its final event is stored by now
            ended = False
            for event in self._stored_after(after_id, job_id):
                yield event.sse()
                last_id = event.id
                ended = event.ends_job
            if job_id is not None and (ended or finished):
                return
            while True:
                try:
                    event = await asyncio.wait_for(subscriber.queue.get(), keepalive_s)
                except TimeoutError:
                    yield b": keep-alive\n\n"
                    continue
                if event is None:
                    return
                if event.id is not None:
                    if event.id <= last_id:
                        continue
                    last_id = event.id
                yield event.sse()
                if job_id is not None and event.ends_job:
                    return
        finally:
            self._subscribers.discard(subscriber)
