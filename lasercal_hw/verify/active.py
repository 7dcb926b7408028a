"""The calibration a verify checks: read from its ``result.json`` (``run.outputs``
writes and reads it), with what the run recorded beside the transform: the identities of the
devices, the job (rod and trajectory) and the residual at every waypoint."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from lasercal_hw.calibration.result import WaypointResidual
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.outputs import ResultFile, read_result_file
from lasercal_hw.run.two_pass import SecondPassRefit
from lasercal_hw.run.waypoints import job_waypoints, listed_waypoints

#: Two waypoints are the same pose when they agree this closely (m, and rad of the rotation vector).
SAME_POSE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class ActiveCalibration(ResultFile):
    """A calibration result and its run's records (None where the file has none)."""

    @property
    def T_base_laser(self) -> FloatArray:  # noqa: N802 (the transform's name everywhere)
        """The calibrated transform (4x4)."""
        return self.result.matrix()

    @property
    def covariance(self) -> FloatArray:
        """The calibration's 6x6 covariance of (dt, e)."""
        return np.asarray(self.result.covariance, dtype=float)

    def refit(self, nominal: RodLine) -> SecondPassRefit:
        """How the calibration's second pass fitted its centres of the rod ``nominal`` (its first
        pass's transform, the rod line it fitted with, the range offset it took out of every
        range); what a file does not record: the calibrated transform, ``nominal``'s line and the
        raw ranges (``rod_note`` says which rod)."""
        T = self.T_base_laser if self.first_pass_transform is None else self.first_pass_transform
        applied_m = self.result.provenance.solver_options.get("range_offset_applied_m") or 0.0
        return SecondPassRefit(np.asarray(T, dtype=float), self._refit_rod(nominal), float(applied_m))

    def rod_note(self) -> str:
        """Which rod line the verify fits its centres with and which predicts them (``verify.json``)."""
        axis = self.result.rod_axis
        estimated = axis is not None and axis.estimated
        predicted = "the rod the calibration estimated (rod_axis)" if estimated else "the job's rod"
        if self.first_pass_rod is not None:
            return (
                "centres fitted again with the rod line the calibration's second pass used "
                f"(run.first_pass.rod), predicted with {predicted}"
            )
        note = (
            "result.json does not record the rod line its second pass used (written before 2026-11-27): "
            f"centres fitted again with the job's nominal rod, predicted with {predicted}"
        )
        if estimated:
            offset_mm = float(np.linalg.norm(axis.crossing_offset_mm))
            note += f"; the estimate is {offset_mm:.1f} mm off it at the plane, which may stay in residuals"
        return note

    def _refit_rod(self, nominal: RodLine) -> RodLine:
        """``nominal`` on the recorded line of the second pass (``run.first_pass.rod``), if any."""
        if self.first_pass_rod is None:
            return nominal
        try:
            origin_m = np.asarray(self.first_pass_rod["origin_m"], dtype=float).reshape(3)
            direction = np.asarray(self.first_pass_rod["direction"], dtype=float).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise ConfigError(
                f"{self.path}: run.first_pass.rod is not a rod line (origin_m and direction, 3 numbers "
                "each); pass the result.json that `lasercal run` wrote"
            ) from None
        finite = np.isfinite(origin_m).all() and np.isfinite(direction).all()
        if not finite or np.linalg.norm(direction) == 0.0:
            raise ConfigError(
                f"{self.path}: run.first_pass.rod has a non-finite origin or a zero direction; pass the "
                "result.json that `lasercal run` wrote"
            )
        return replace(nominal, origin_m=origin_m, direction=direction)

    @property
    def rod(self) -> RodLine | None:
        """The rod the calibration was made with, if recorded."""
        return self.job.rod.rod_line() if self.job is not None else None

    def waypoints(self) -> FloatArray | None:
        """The calibration's waypoints (UR poses) as its job lists them, if its job was recorded."""
        if self.job is None:
            return None
        if self.job.trajectory.flute_phase_deg is not None:  # the waypoints, not the spin before them
            return listed_waypoints(self.job)
        return job_waypoints(self.job)


def load_active_calibration(path: Path) -> ActiveCalibration:
    """Read ``result.json`` (``run.outputs.read_result_file``); a missing or malformed file
    raises ``ConfigError``."""
    read = read_result_file(path)
    return ActiveCalibration(**{field.name: getattr(read, field.name) for field in fields(read)})


def _recorded_at(
    residuals: Sequence[WaypointResidual],
    recorded_waypoints: FloatArray | None,
    waypoints: FloatArray,
    *,
    used_only: bool,
) -> list[WaypointResidual | None]:
    """The calibration's residual row at each of ``waypoints`` (matched by pose), None where it
    did not visit that pose (or, ``used_only``, left it out of its fit)."""
    poses = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    if recorded_waypoints is None:
        return [None] * len(poses)
    recorded = np.asarray(recorded_waypoints, dtype=float).reshape(-1, 6)
    by_index = {r.index: r for r in residuals if r.used or not used_only}
    rows: list[WaypointResidual | None] = []
    for pose in poses:
        same = np.flatnonzero(np.max(np.abs(recorded - pose), axis=1) <= SAME_POSE_TOLERANCE)
        rows.append(next((by_index[j] for j in same if j in by_index), None))
    return rows


def recorded_residuals(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """The calibration's residual (measured minus predicted, m; (N, 2)) at each of
    ``waypoints``, NaN where it did not visit that pose or left it out of its fit."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=True)
    pairs = [(np.nan, np.nan) if r is None else (r.du_mm / 1e3, r.dv_mm / 1e3) for r in rows]
    return np.array(pairs, dtype=float).reshape(-1, 2)


def recorded_centre_covariances(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """The centre covariance (m^2, (N, 2, 2), scanner frame) the calibration's solver weighed
    each of ``waypoints`` with, outliers too, NaN where it did not measure that pose or its
    ``result.json`` predates the record (``WaypointResidual.covariance_uv_mm2``)."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=False)
    unknown = np.full((2, 2), np.nan)
    blocks = [
        unknown if r is None or r.covariance_uv_mm2 is None else np.array(r.covariance_uv_mm2) / 1e6
        for r in rows
    ]
    return np.array(blocks, dtype=float).reshape(-1, 2, 2)
