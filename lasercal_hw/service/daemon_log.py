"""The daemon's log: one line per job state, activation, calibration filed or marked bad,
deactivation, cancel request, fault and device change, each with its ids, on stderr (what
``journalctl -u lasercal`` shows).

``text`` lines are for a person (``2026-11-25T16:59:56Z INFO job job-... running``);
``json`` lines are one JSON object each (``time_utc``, ``level``, ``event``, ``message`` and
the event's ids and fields) for a log collector. The bus calls ``log_event`` for every event;
the device monitor calls ``log_device`` when a device's state changes.
"""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime
from typing import Any, Literal, TextIO

LogFormat = Literal["text", "json"]
LOGGER_NAME = "lasercal.daemon"
logger = logging.getLogger(LOGGER_NAME)

# What a device's status line is made of: a change in one of these is logged.
_DEVICE_KEYS = ("connected", "mode", "safety", "remote_control", "identity", "error")


def _event_line(kind: str, data: dict[str, Any], job_id: str | None) -> str | None:
    if kind == "state":
        error = data.get("error") or {}
        detail = f": {error.get('code')}: {error.get('message')}" if error else ""
        note = f" ({data['message']})" if data.get("message") and not error else ""
        return f"job {job_id} {data['state']}{detail}{note}"
    if kind == "calibration":
        passed = "passed its gates" if data.get("passed") else "failed its gates"
        return f"job {job_id} filed calibration {data.get('calibration_id')} ({passed})"
    if kind == "cancel_requested":
        return f"job {job_id} cancel requested: {data.get('reason')}"
    if kind == "fault":
        return f"job {job_id} fault of the {data.get('device', 'device')}: {data.get('message')}"
    if kind == "robot_restored":
        return f"job {job_id} robot program: {data.get('message')}"
    if kind == "activation":
        return f"calibration {data.get('calibration_id')} activated: {data.get('reason')}"
    if kind == "calibration_marked_bad":
        who = data.get("by")
        return f"calibration {data.get('calibration_id')} marked bad by {who}: {data.get('reason')}"
    if kind == "deactivation":
        return f"calibration {data.get('calibration_id')} deactivated: {data.get('reason')}"
    if kind == "daemon":
        return str(data.get("message"))
    return None


def log_event(kind: str, data: dict[str, Any], job_id: str | None) -> None:
    """Log one bus event if it is one a person follows (progress, scans and centres are not)."""
    line = _event_line(kind, data, job_id)
    if line is None:
        return
    failed = kind in ("fault", "calibration_marked_bad", "deactivation") or (
        kind == "state" and data.get("state") == "failed"
    )
    fields = {"event": kind, **({"job_id": job_id} if job_id else {}), **data}
    logger.log(logging.WARNING if failed else logging.INFO, line, extra={"fields": fields})


def device_summary(status: dict[str, Any]) -> tuple[Any, ...]:
    """The part of a device's status whose change is worth a line."""
    return tuple(json.dumps(status.get(key), sort_keys=True) for key in _DEVICE_KEYS)


def log_device(device: Literal["robot", "scanner"], status: dict[str, Any]) -> None:
    """One line for a device whose state changed (connected, lost, mode, safety)."""
    where = status.get("host") or status.get("url") or "?"
    if status.get("connected"):
        parts = [f"{device} {where} connected"]
        if device == "robot":
            parts.append(
                f"mode {status.get('mode')}, safety {status.get('safety')}, "
                f"remote control {'on' if status.get('remote_control') else 'off'}"
            )
        elif status.get("identity"):
            parts.append(f"serial {status['identity'].get('serial')}")
        line, level = ", ".join(parts), logging.INFO
    else:
        line, level = f"{device} {where} not reachable: {status.get('error')}", logging.WARNING
    logger.log(level, line, extra={"fields": {"event": "device", "device": device, **status}})


class _TextFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        when = datetime.fromtimestamp(record.created, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        return f"{when} {record.levelname} {record.getMessage()}"


class _JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        document = {
            "time_utc": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname.lower(),
            "message": record.getMessage(),
            **getattr(record, "fields", {}),
        }
        return json.dumps(document, default=str)


_LOGGERS = (LOGGER_NAME, "lasercal_hw.service")


def configure(log_format: LogFormat, stream: TextIO | None = None) -> logging.Handler:
    """Send the daemon's log (and the service's own warnings) to ``stream`` (stderr) as
    ``text`` or ``json`` lines; returns the handler for ``unconfigure``."""
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(_JsonFormatter() if log_format == "json" else _TextFormatter())
    for name in _LOGGERS:
        target = logging.getLogger(name)
        target.setLevel(logging.INFO)
        target.addHandler(handler)
        target.propagate = False
    return handler


def unconfigure(handler: logging.Handler) -> None:
    """Undo ``configure``: the loggers propagate to the root logger again."""
    for name in _LOGGERS:
        target = logging.getLogger(name)
        target.removeHandler(handler)
        target.setLevel(logging.NOTSET)
        target.propagate = True
