"""``/v1/health`` and ``/v1/status``: the daemon itself."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter
from pydantic import BaseModel

from lasercal_hw.service.routes.deps import DaemonDep

router = APIRouter()


class RobotCalibrationReading(BaseModel):
    """The device monitor's last reading of the robot's primary interface."""

    known: bool
    calibration: dict[str, Any] | None
    """``checksum``, ``checksums``, ``dh_theta_rad``, ``dh_a_m``, ``dh_d_m``, ``dh_alpha_rad``,
    ``calibration_status``, ``model``, ``software_version`` (docs/ur.md)."""
    read_utc: str | None
    error: str | None


class VerifyHealth(BaseModel):
    """The newest verify of a calibration."""

    id: str | None
    time_utc: str
    verdict: Literal["ok", "inconclusive", "degraded", "recalibrate"]
    reason: str | None
    age_s: float


class PreviousRangeError(BaseModel):
    """The newest earlier calibration of the scanner that estimated a range-error curve."""

    calibration_id: str
    worst_mm: float
    change_mm: float
    """The active calibration's figure minus this one's: a growing range error marks a unit to replace."""


class RangeErrorHealth(BaseModel):
    """The scanner's range error as a health figure (docs/daemon.md, Health)."""

    state: Literal["within_data_sheet", "beyond_data_sheet", "unknown"]
    worst_mm: float | None
    """The largest |range error| of the active calibration's curve over its crossings' distances."""
    limit_mm: float
    """The data sheet's range accuracy (UTM-30LX-EW: 30 mm from 0.1 to 10 m)."""
    previous: PreviousRangeError | None
    note: str


class ScannerHealth(BaseModel):
    """One scanner's calibration at a glance."""

    name: str
    url: str | None
    active_calibration: bool
    calibration_id: str | None
    passed: bool | None
    created_utc: str | None
    age_s: float | None
    last_verify: VerifyHealth | None
    robot_calibration_matches: bool | Literal["unknown"]
    """Whether the robot's kinematics calibration is still the one the calibration was made with."""
    robot_calibration_note: str
    range_error: RangeErrorHealth | None
    """Null when no calibration is active."""


class Health(BaseModel):
    """``GET /v1/health``: liveness and every scanner's calibration health."""

    ok: bool
    version: str
    api_version: int
    time_utc: str
    robot_calibration: RobotCalibrationReading
    scanners: list[ScannerHealth]


@router.get("/v1/health", response_model=Health)
def health(daemon: DaemonDep) -> dict[str, Any]:
    """Liveness, and per scanner: an active calibration or not, passed, its age, the last
    verify's time and verdict, and whether the robot's own kinematics calibration still
    matches (from the history and the device monitor's last reading; no device I/O)."""
    return daemon.health()


@router.get("/v1/status")
def status(daemon: DaemonDep) -> dict[str, Any]:
    """Daemon, devices, active calibration and the running (or last) job."""
    return daemon.status()
