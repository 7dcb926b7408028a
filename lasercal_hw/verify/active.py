"""The calibration a verify checks: read from its ``result.json`` (as ``lasercal run``
writes it), with what the run recorded beside the transform: the identities of the
devices, the job (rod and trajectory) and the residual at every waypoint."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from lasercal_hw.calibration.result import CalibrationResult, WaypointResidual
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.waypoints import job_waypoints

#: Two waypoints are the same pose when they agree this closely (m, and rad of the rotation vector).
SAME_POSE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class ActiveCalibration:
    """A calibration result and its run's records (None where the file has none)."""

    path: Path
    result: CalibrationResult
    robot: dict[str, Any] | None
    scanner: dict[str, Any] | None
    job: JobConfig | None
    motion_and_dwell_s: float | None

    @property
    def T_base_laser(self) -> FloatArray:  # noqa: N802 (the transform's name everywhere)
        """The calibrated transform (4x4)."""
        return self.result.matrix()

    @property
    def covariance(self) -> FloatArray:
        """The calibration's 6x6 covariance of (dt, e)."""
        return np.asarray(self.result.covariance, dtype=float)

    @property
    def rod(self) -> RodLine | None:
        """The rod the calibration was made with, if recorded."""
        return self.job.rod.rod_line() if self.job is not None else None

    def waypoints(self) -> FloatArray | None:
        """The calibration's waypoints (UR poses), if its job was recorded."""
        return job_waypoints(self.job) if self.job is not None else None


def load_active_calibration(path: Path) -> ActiveCalibration:
    """Read ``result.json``; a missing or malformed file raises ``ConfigError``."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(
            f"calibration file {path} does not exist; pass the result.json of a calibration"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read calibration file {path}: {exc}") from None
    if not isinstance(document, dict):
        raise ConfigError(f"{path} is not a calibration result (expected a JSON object)")
    try:
        result = CalibrationResult.model_validate(document)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(
            f"{path} is not a lasercal calibration result ({where}: {first['msg']}); pass the result.json "
            "that `lasercal run` or `lasercal solve` wrote"
        ) from None
    run = document.get("run") if isinstance(document.get("run"), dict) else {}
    job = job_from_mapping(run["job"], f"{path} (run.job)") if isinstance(run.get("job"), dict) else None
    timings = run.get("timings") if isinstance(run.get("timings"), dict) else {}
    busy_s = (timings.get("motion_s") or 0.0) + (timings.get("dwell_s") or 0.0)
    return ActiveCalibration(
        path=Path(path),
        result=result,
        robot=run.get("robot") if isinstance(run.get("robot"), dict) else None,
        scanner=run.get("scanner") if isinstance(run.get("scanner"), dict) else None,
        job=job,
        motion_and_dwell_s=float(busy_s) if busy_s > 0 else None,
    )


def recorded_residuals(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """The calibration's residual (measured minus predicted, m; (N, 2)) at each of
    ``waypoints``, NaN where it did not visit that pose or left it out of its fit."""
    poses = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    out = np.full((len(poses), 2), np.nan)
    if recorded_waypoints is None:
        return out
    recorded = np.asarray(recorded_waypoints, dtype=float).reshape(-1, 6)
    by_index = {r.index: r for r in residuals if r.used}
    for i, pose in enumerate(poses):
        same = np.flatnonzero(np.max(np.abs(recorded - pose), axis=1) <= SAME_POSE_TOLERANCE)
        hit = next((by_index[j] for j in same if j in by_index), None)
        if hit is not None:
            out[i] = (hit.du_mm / 1e3, hit.dv_mm / 1e3)
    return out
