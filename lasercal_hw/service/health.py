"""``GET /v1/health``: per scanner, is its calibration there, good, how old, when was it last
verified and with what verdict, and does the robot's own kinematics calibration still match
the one it was made with. From the history and the device monitor's last reading; no
device I/O, so it answers at once whatever the devices do."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.models import RobotCalibration

DEFAULT_SCANNER = DEFAULT_SCANNER_NAME
"""The name of the one scanner a daemon configuration of today has."""


def _age_s(created_utc: str, now: datetime) -> float:
    return max(0.0, (now - datetime.fromisoformat(created_utc)).total_seconds())


def robot_calibration_match(recorded: dict[str, Any] | None, reading: dict[str, Any]) -> tuple[Any, str]:
    """``True``, ``False`` or ``"unknown"``, and one line saying why."""
    if recorded is None:
        return "unknown", "the calibration did not record the robot's kinematics calibration"
    if not reading.get("known"):
        why = reading.get("error") or "not read yet"
        return "unknown", f"the robot's primary interface has not been read: {why}"
    try:
        then, now = RobotCalibration.from_dict(recorded), RobotCalibration.from_dict(reading["calibration"])
    except (KeyError, TypeError, ValueError):
        return "unknown", "the recorded robot kinematics calibration cannot be read"
    change = now.change_from(then)
    if change is None:
        return True, f"checksum {now.checksum}, as when calibrated (read {reading['read_utc']})"
    return False, f"the robot's kinematics calibration changed since the calibration: {change}"


def scanner_health(
    name: str,
    url: str | None,
    active: dict[str, Any] | None,
    last_verify: dict[str, Any] | None,
    robot_reading: dict[str, Any],
    now: datetime,
) -> dict[str, Any]:
    """One scanner's health from its active calibration summary, that calibration's newest
    verify and the monitor's robot calibration reading."""
    entry: dict[str, Any] = {"name": name, "url": url, "active_calibration": active is not None}
    if active is None:
        return entry | {
            "calibration_id": None, "passed": None, "age_s": None, "created_utc": None,
            "last_verify": None, "robot_calibration_matches": "unknown",
            "robot_calibration_note": "no active calibration",
        }
    recorded = (active.get("devices") or {}).get("robot_calibration")
    matches, note = robot_calibration_match(recorded, robot_reading)
    verify = None if last_verify is None else {
        "id": last_verify.get("id"), "time_utc": last_verify["created_utc"],
        "verdict": last_verify["verdict"], "reason": last_verify.get("reason"),
        "age_s": _age_s(last_verify["created_utc"], now),
    }
    return entry | {
        "calibration_id": active["id"], "passed": bool(active["passed"]),
        "created_utc": active["created_utc"], "age_s": _age_s(active["created_utc"], now),
        "last_verify": verify,
        "robot_calibration_matches": matches, "robot_calibration_note": note,
    }
