"""The daemon's Python client over a real loopback socket, against a minimal HTTP server that
plays the daemon's order of things at a job's end: the final state event is sent (and the
stream closed) before the job's record says so."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from lasercal_hw.service.client import DaemonClient


class _LaggingDaemon(BaseHTTPRequestHandler):
    """``/v1/jobs/J/events`` ends with ``succeeded``; ``/v1/jobs/J`` says ``solving`` for its
    first ``lag_reads`` reads, then ``succeeded``."""

    lag_reads = 3
    reads = 0

    def log_message(self, *_args: object) -> None:
        """Quiet."""

    def _send(self, body: bytes, content_type: str) -> None:
        self.send_response(200)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        if self.path == "/v1/jobs/J/events":
            events = [("state", {"state": "solving"}), ("state", {"state": "succeeded"})]
            body = "".join(
                f"id: {n}\nevent: {kind}\ndata: {json.dumps(data)}\n\n"
                for n, (kind, data) in enumerate(events, 1)
            )
            self._send(body.encode(), "text/event-stream")
            return
        type(self).reads += 1
        state = "solving" if type(self).reads <= self.lag_reads else "succeeded"
        self._send(json.dumps({"id": "J", "state": state}).encode(), "application/json")


@pytest.fixture
def lagging_daemon() -> Iterator[str]:
    _LaggingDaemon.reads = 0
    server = ThreadingHTTPServer(("127.0.0.1", 0), _LaggingDaemon)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def test_wait_returns_the_end_its_events_announced_though_the_record_lags(lagging_daemon: str) -> None:
    seen: list[str] = []
    client = DaemonClient(lagging_daemon, timeout_s=5.0)
    final = client.wait("J", on_event=lambda _kind, data: seen.append(data["state"]))
    assert seen == ["solving", "succeeded"]
    assert final["state"] == "succeeded" and _LaggingDaemon.reads == _LaggingDaemon.lag_reads + 1
