"""Hostile and malformed requests for the daemon, as data: each case is a request and the
answer it must get (status and code). Add a case here and both the fault suite
(tests/test_daemon_faults.py) and benchmarks/daemon_faults.py try it.

Paths and bodies may name ``{job}`` (a finished job), ``{cal}`` (its calibration) and
``{outside}`` (a folder outside the daemon's data folder holding ``secret.csv``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import httpx

from tests.daemon_helpers import QUICK_JOB

SECRET = "SECRET_FROM_CSV"
DRY = {"kind": "dry_run", "confirm_motion": True, "job": QUICK_JOB, "dwell_s": 0.5}


@dataclass(frozen=True)
class Hostile:
    """One request and the answer it must get."""

    name: str
    method: str
    path: str
    status: int
    code: str
    json: Any = None
    content: bytes | None = None
    headers: dict[str, str] = field(default_factory=dict)
    token: bool = True


def _job(**changes: Any) -> dict[str, Any]:
    return DRY | changes


CASES: list[Hostile] = [
    # confirm_motion: only JSON true starts motion
    *(
        Hostile(
            f"confirm_motion={value!r}",
            "POST",
            "/v1/jobs",
            422,
            "invalid_request",
            _job(confirm_motion=value),
        )
        for value in ("yes", 1, "true", [True], {"x": 1})
    ),
    Hostile(
        "confirm_motion=false", "POST", "/v1/jobs", 400, "confirmation_required", _job(confirm_motion=False)
    ),
    Hostile("confirm_motion missing", "POST", "/v1/jobs", 400, "confirmation_required", {"kind": "dry_run"}),
    # files outside the data folder are never opened
    *(
        Hostile(
            f"waypoints_file {path}",
            "POST",
            "/v1/jobs",
            422,
            "invalid_request",
            _job(job=QUICK_JOB | {"trajectory": {"preset": None, "waypoints_file": path}}),
        )
        for path in (
            "{outside}/secret.csv",
            "/etc/shadow",
            "/nonexistent/x.csv",
            "../../../etc/passwd",
            "{outside}/../../../../etc/hostname",
        )
    ),
    # sizes and counts
    Hostile(
        "35,000 waypoints by preset parameters",
        "POST",
        "/v1/jobs",
        422,
        "invalid_request",
        _job(job=QUICK_JOB | {"trajectory": {"preset": "quick", "parameters": {"step_deg": 0.005}}}),
    ),
    Hostile(
        "a 1 MB body",
        "POST",
        "/v1/jobs",
        413,
        "payload_too_large",
        _job(job=QUICK_JOB | {"notes": "x" * 1_000_000}),
    ),
    Hostile(
        "a 1 MB body, chunked",
        "POST",
        "/v1/jobs",
        413,
        "payload_too_large",
        content=b"[" + b"1," * 600_000 + b"1]",
        headers={"Content-Type": "application/json"},
    ),
    Hostile(
        "a bad Content-Length",
        "POST",
        "/v1/jobs",
        413,
        "payload_too_large",
        content=b"{}",
        headers={"Content-Length": "-1"},
    ),
    Hostile(
        "a body cut short",
        "POST",
        "/v1/jobs",
        400,
        "invalid_json",
        content=b'{"kind": "dry_run", "confirm_motion": tru',
        headers={"Content-Type": "application/json"},
    ),
    Hostile(
        "a 10,000-character reason",
        "POST",
        "/v1/calibrations/{cal}/activate",
        422,
        "invalid_request",
        {"reason": "r" * 10_000},
    ),
    Hostile(
        "a lone surrogate reason",
        "POST",
        "/v1/calibrations/{cal}/activate",
        422,
        "invalid_request",
        content=b'{"reason": "\\ud800"}',
        headers={"Content-Type": "application/json"},
    ),
    Hostile(
        "force as a string",
        "POST",
        "/v1/calibrations/{cal}/activate",
        422,
        "invalid_request",
        {"force": "yes"},
    ),
    # names and ids
    Hostile(
        "a 5,000-character file name",
        "GET",
        "/v1/jobs/{job}/files/" + "a" * 5000,
        404,
        "not_found",
        token=False,
    ),
    Hostile("a NUL in a file name", "GET", "/v1/jobs/{job}/files/a%00b", 404, "not_found", token=False),
    Hostile("a hidden file name", "GET", "/v1/jobs/{job}/files/.env", 404, "not_found", token=False),
    Hostile(
        "a traversal file name", "GET", "/v1/jobs/{job}/files/..%2F..%2Ftoken", 404, "not_found", token=False
    ),
    Hostile(
        "Last-Event-ID past int64",
        "GET",
        "/v1/events",
        422,
        "invalid_request",
        headers={"Last-Event-ID": "9223372036854775808"},
        token=False,
    ),
    Hostile(
        "Last-Event-ID negative",
        "GET",
        "/v1/jobs/{job}/events",
        422,
        "invalid_request",
        headers={"Last-Event-ID": "-5"},
        token=False,
    ),
    Hostile(
        "last_event_id past int64",
        "GET",
        "/v1/events?last_event_id=99999999999999999999",
        422,
        "invalid_request",
        token=False,
    ),
    # state
    Hostile("cancel a finished job", "POST", "/v1/jobs/{job}/cancel", 409, "not_running"),
    Hostile(
        "resume a finished job",
        "POST",
        "/v1/jobs/{job}/resume",
        409,
        "not_resumable",
        {"confirm_motion": True},
    ),
    Hostile("a job kind that is no kind", "POST", "/v1/jobs", 422, "invalid_request", _job(kind="weld")),
    Hostile(
        "a calibrate job without a scanner pose",
        "POST",
        "/v1/jobs",
        422,
        "invalid_request",
        _job(kind="calibrate"),
    ),
    # DNS rebinding: a page's own name is not this daemon's
    *(
        Hostile(f"Host {host}", "GET", path, 400, "host_not_allowed", headers={"Host": host}, token=False)
        for host in ("evil.example.com", "evil.example.com:8766", "127.0.0.1.nip.io", "")
        for path in ("/v1/status", "/v1/jobs/{job}/files/session.mcap")
    ),
    # tokens
    *(
        Hostile(
            f"token {label}",
            "POST",
            "/v1/jobs/{job}/cancel",
            status,
            code,
            headers={"Authorization": value},
            token=False,
        )
        for label, value, status, code in (
            ("missing scheme", "{token}", 401, "unauthorized"),
            ("basic", "Basic {token}", 401, "unauthorized"),
            ("empty bearer", "Bearer ", 401, "unauthorized"),
            ("wrong", "Bearer nope", 403, "forbidden"),
            ("prefix", "Bearer {token_prefix}", 403, "forbidden"),
            ("with suffix", "Bearer {token}x", 403, "forbidden"),
            ("non-ascii", "Bearer \u00e9t\u00e9", 403, "forbidden"),
        )
    ),
]


def _filled(value: Any, names: dict[str, str]) -> Any:
    if isinstance(value, str):
        for key, text in names.items():
            value = value.replace("{" + key + "}", text)
        return value
    if isinstance(value, dict):
        return {key: _filled(item, names) for key, item in value.items()}
    if isinstance(value, list):
        return [_filled(item, names) for item in value]
    return value


def send(client: httpx.Client, case: Hostile, names: dict[str, str]) -> httpx.Response:
    """Send one hostile case (used by benchmarks/daemon_faults.py too)."""
    headers = _filled(case.headers, names)
    if not case.token and "Authorization" not in headers:
        headers["Authorization"] = ""
    return client.request(
        case.method,
        _filled(case.path, names),
        json=_filled(case.json, names) if case.content is None else None,
        content=case.content,
        headers={key: value.encode("latin-1") for key, value in headers.items()},
    )
