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

DATA_SHEET_RANGE_ERROR_MM = 30.0
"""UTM-30LX-EW data sheet: range accuracy +-30 mm from 0.1 to 10 m (the rod's distances)."""


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


def _worst_range_error_mm(summary: dict[str, Any]) -> float | None:
    curve = summary.get("range_offset") or {}
    worst = curve.get("worst_mm")
    return None if worst is None else float(worst)


def range_error_health(active: dict[str, Any], earlier: list[dict[str, Any]]) -> dict[str, Any]:
    """The scanner's range error as a health figure: the largest |error| of the active
    calibration's curve over the distances its crossings spanned, against the data sheet and
    against the newest earlier calibration of the same scanner that estimated one (``earlier``:
    that scanner's older summaries, newest first). A unit whose range error grows from one
    calibration to the next is one to check or replace."""
    worst_mm = _worst_range_error_mm(active)
    if worst_mm is None:
        return {
            "state": "unknown", "worst_mm": None, "limit_mm": DATA_SHEET_RANGE_ERROR_MM,
            "previous": None, "note": "the active calibration estimated no range-error curve",
        }
    state = "within_data_sheet" if worst_mm <= DATA_SHEET_RANGE_ERROR_MM else "beyond_data_sheet"
    where = "within" if state == "within_data_sheet" else "BEYOND"
    note = (
        f"largest range error {worst_mm:.1f} mm over the crossings' distances, "
        f"{where} the data sheet's {DATA_SHEET_RANGE_ERROR_MM:.0f} mm"
    )
    previous = next(
        (
            {"calibration_id": s["id"], "worst_mm": w, "change_mm": worst_mm - w}
            for s in earlier
            if (w := _worst_range_error_mm(s)) is not None
        ),
        None,
    )
    if previous is not None:
        note += f"; {previous['change_mm']:+.1f} mm since {previous['calibration_id']}"
    if state == "beyond_data_sheet":
        note += ": check the scanner's window and mounting, or replace the unit"
    return {"state": state, "worst_mm": worst_mm, "limit_mm": DATA_SHEET_RANGE_ERROR_MM,
            "previous": previous, "note": note}


def scanner_health(
    name: str,
    url: str | None,
    active: dict[str, Any] | None,
    last_verify: dict[str, Any] | None,
    robot_reading: dict[str, Any],
    now: datetime,
    earlier: list[dict[str, Any]],
) -> dict[str, Any]:
    """One scanner's health from its active calibration summary, that calibration's newest
    verify, the monitor's robot calibration reading and the scanner's earlier calibrations
    (newest first, for the range error's change)."""
    entry: dict[str, Any] = {"name": name, "url": url, "active_calibration": active is not None}
    if active is None:
        return entry | {
            "calibration_id": None, "passed": None, "age_s": None, "created_utc": None,
            "last_verify": None, "robot_calibration_matches": "unknown",
            "robot_calibration_note": "no active calibration", "range_error": None,
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
        "range_error": range_error_health(active, earlier),
    }
