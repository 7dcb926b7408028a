"""A small Python client of the daemon (standard library only), for scripts and
``lasercal remote``::

    client = DaemonClient("http://127.0.0.1:8766", token=read_token())
    job = client.start_job({"kind": "dry_run", "confirm_motion": True})
    final = client.wait(job["id"], on_event=print)
"""

from __future__ import annotations

import json
import os
import re
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from lasercal_hw.errors import ConfigError, ExitCode, LasercalError

DEFAULT_URL = "http://127.0.0.1:8766"
TOKEN_ENV = "LASERCAL_TOKEN"
_RECONNECT_TRIES = 5
_FINISHED_STATES = frozenset({"succeeded", "failed", "cancelled", "interrupted"})
_STORED_END_WAIT_S = 10.0
"""How long ``wait`` reads the job again after its event stream ended: the daemon announces a
job's end before it stores it (so that a job read as finished has all its events stored)."""


class DaemonRequestError(LasercalError):
    """The daemon refused a request (4xx: exit 2; busy with another job: exit 5) or could not
    be reached (exit 3)."""

    def __init__(
        self,
        message: str,
        *,
        status: int | None = None,
        code: str | None = None,
        detail: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(message)
        self.status, self.code, self.detail = status, code, detail or {}
        self.exit_code = ExitCode.DEVICE_ERROR if status is None or status >= 500 else ExitCode.BAD_INPUT
        if code == "job_running":
            self.exit_code = ExitCode.BUSY


def check_daemon_url(url: str) -> str:
    """``url`` if it is an http(s) URL with a host and a valid port, else a ``ConfigError`` saying
    what to give (a bare ``host:port`` is told to add ``http://``)."""
    parts = urlsplit(url)
    if "://" not in url and re.fullmatch(r"[\w.-]+:\d+/?", url):
        raise ConfigError(f"{url!r} is not a URL: add http://, as in http://{url}")
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ConfigError(f"{url!r} is not an http:// URL: give one such as {DEFAULT_URL}")
    try:
        _ = parts.port  # urlsplit checks the port only when it is read
    except ValueError:
        raise ConfigError(f"{url!r} has no valid port (1-65535): give one such as {DEFAULT_URL}") from None
    return url


def read_token(token_file: Path | None = None) -> str | None:
    """``$LASERCAL_TOKEN``, else the token file (default: the daemon's default data folder), else
    None when the default file is missing; a ``token_file`` given that does not exist is a
    ``ConfigError`` naming it."""
    if os.environ.get(TOKEN_ENV):
        return os.environ[TOKEN_ENV].strip()
    given = token_file is not None
    if token_file is None:
        from lasercal_hw.service.config import default_data_dir

        token_file = default_data_dir() / "token"
    try:
        return token_file.read_text(encoding="utf-8").strip()
    except FileNotFoundError:
        if given:  # a file named on purpose: say so before a request goes out without a token
            raise ConfigError(
                f"token file {token_file} does not exist: give the daemon's token file (the file "
                f"'token' in its data folder) with --token-file, or the token itself in ${TOKEN_ENV}"
            ) from None
        return None
    except OSError as exc:
        raise DaemonRequestError(f"cannot read the token file {token_file}: {exc.strerror or exc}") from None


class DaemonClient:
    """Calls the daemon's ``/v1`` API; every failure is a ``DaemonRequestError``."""

    def __init__(
        self,
        url: str = DEFAULT_URL,
        token: str | None = None,
        timeout_s: float = 30.0,
        token_file: Path | None = None,
    ) -> None:
        self.url = check_daemon_url(url).rstrip("/")
        self.token = token
        self.timeout_s = timeout_s
        #: The file the token was read from when one was named (commands shown to the user name it).
        self.token_file = token_file

    def _open(
        self,
        method: str,
        path: str,
        body: Any = None,
        headers: dict[str, str] | None = None,
        timeout_s: float | None = None,
    ) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method=method, headers=headers or {})
        if data is not None:
            request.add_header("Content-Type", "application/json")
        if self.token:
            request.add_header("Authorization", f"Bearer {self.token}")
        try:
            return urllib.request.urlopen(request, timeout=timeout_s or self.timeout_s)
        except urllib.error.HTTPError as exc:
            raise _refusal(exc) from None
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise DaemonRequestError(
                f"cannot reach the lasercal daemon at {self.url}: {reason}; is "
                "'lasercal serve' running there?"
            ) from None

    def call(self, method: str, path: str, body: Any = None) -> Any:
        """One JSON request; the decoded JSON answer."""
        with self._open(method, path, body) as response:
            return json.loads(response.read() or b"null")

    def status(self) -> dict[str, Any]:
        """``GET /v1/status``."""
        return self.call("GET", "/v1/status")

    def jobs(self) -> list[dict[str, Any]]:
        """Jobs, newest first."""
        return self.call("GET", "/v1/jobs")["jobs"]

    def job(self, job_id: str) -> dict[str, Any]:
        """One job."""
        return self.call("GET", f"/v1/jobs/{job_id}")

    def start_job(self, body: dict[str, Any]) -> dict[str, Any]:
        """Start a job (``POST /v1/jobs``)."""
        return self.call("POST", "/v1/jobs", body)

    def cancel(self, job_id: str) -> dict[str, Any]:
        """Cancel a running job."""
        return self.call("POST", f"/v1/jobs/{job_id}/cancel")

    def resume(self, job_id: str) -> dict[str, Any]:
        """Resume a cancelled or interrupted job (the request confirms motion)."""
        return self.call("POST", f"/v1/jobs/{job_id}/resume", {"confirm_motion": True})

    def calibrations(self) -> list[dict[str, Any]]:
        """Every calibration, newest first."""
        return self.call("GET", "/v1/calibrations")["calibrations"]

    def calibration(self, calibration_id: str) -> dict[str, Any]:
        """One calibration's summary."""
        return self.call("GET", f"/v1/calibrations/{calibration_id}")

    def activate(self, calibration_id: str, reason: str, force: bool = False) -> dict[str, Any]:
        """Make a calibration active (rollback included)."""
        return self.call(
            "POST", f"/v1/calibrations/{calibration_id}/activate", {"reason": reason, "force": force}
        )

    def mark_bad(self, calibration_id: str, by: str, reason: str) -> dict[str, Any]:
        """Record who found a calibration bad and why (the active one is deactivated)."""
        return self.call("POST", f"/v1/calibrations/{calibration_id}/mark-bad", {"by": by, "reason": reason})

    def health(self) -> dict[str, Any]:
        """``GET /v1/health``: every scanner's calibration health."""
        return self.call("GET", "/v1/health")

    def diff(self, a: str, b: str) -> dict[str, Any]:
        """The change between two calibrations."""
        return self.call("GET", f"/v1/calibrations/{a}/diff/{b}")

    def events(
        self, job_id: str | None = None, after_id: int = 0
    ) -> Iterator[tuple[int, str, dict[str, Any]]]:
        """``(id, kind, data)`` of a job's SSE stream (or the daemon's), reconnecting with
        ``Last-Event-ID`` when the connection drops; ends with the job's final state."""
        path = f"/v1/jobs/{job_id}/events" if job_id else "/v1/events"
        last_id, failures = after_id, 0
        while True:
            try:
                with self._open(
                    "GET", path, headers={"Last-Event-ID": str(last_id)}, timeout_s=60.0
                ) as stream:
                    for event_id, kind, data in _parse_sse(stream):
                        last_id, failures = event_id, 0
                        yield event_id, kind, data
                return
            except (DaemonRequestError, OSError) as exc:
                failures += 1
                if failures >= _RECONNECT_TRIES or (isinstance(exc, DaemonRequestError) and exc.status):
                    raise
                time.sleep(0.5 * failures)

    def wait(
        self, job_id: str, on_event: Callable[[str, dict[str, Any]], None] | None = None
    ) -> dict[str, Any]:
        """Follow a job's events to its end; returns the finished job (read again until the
        daemon has stored the end its events announced)."""
        for _, kind, data in self.events(job_id):
            if on_event is not None:
                on_event(kind, data)
        deadline = time.monotonic() + _STORED_END_WAIT_S
        job = self.job(job_id)
        while job["state"] not in _FINISHED_STATES and time.monotonic() < deadline:
            time.sleep(0.05)
            job = self.job(job_id)
        return job


def _parse_sse(stream: Any) -> Iterator[tuple[int, str, dict[str, Any]]]:
    event_id, kind, data = 0, "message", []
    for raw in stream:
        line = raw.decode("utf-8").rstrip("\r\n")
        if not line:
            if data:
                yield event_id, kind, json.loads("\n".join(data))
            kind, data = "message", []
        elif line.startswith("id:"):
            event_id = int(line[3:].strip())
        elif line.startswith("event:"):
            kind = line[6:].strip()
        elif line.startswith("data:"):
            data.append(line[5:].strip())


def _refusal(exc: urllib.error.HTTPError) -> DaemonRequestError:
    try:
        body = json.loads(exc.read() or b"{}")
    except ValueError:
        body = {}
    message = body.get("message") or f"HTTP {exc.code} {exc.reason}"
    return DaemonRequestError(
        f"daemon refused ({exc.code} {body.get('code', '')}): {message}",
        status=exc.code,
        code=body.get("code"),
        detail=body.get("detail"),
    )
