"""The calibration a verify checks: read from its ``result.json`` (``run.outputs``
writes and reads it), with what the run recorded beside the transform: the identities of the
devices, the job (rod and trajectory) and the residual at every waypoint."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.calibration.result import WaypointResidual
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.flute_phase import FluteShift
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
        """How the calibration fitted its solved centres of the rod ``nominal``: its second pass
        (its first pass's transform, the rod line it fitted with, the range offset it took out of
        every range) or, where its flute phase pass was kept, the pass's plain fits and their move
        (``run.first_pass.flute_phase``); what a file does not record: the calibrated transform,
        ``nominal``'s line and the raw ranges (``rod_note`` says which rod), the fluted section's
        mean offset (``flute_note`` says so)."""
        applied_m = float(self.result.provenance.solver_options.get("range_offset_applied_m") or 0.0)
        kept = self._kept_flute_phase()
        if kept is not None:
            plain_fit, offsets = self._fit_table(kept, "plain_fit"), self._fit_table(kept, "offsets")
            shift = FluteShift(
                self._matrix(offsets, "offsets"),
                self._recorded_line(nominal, offsets.get("rod"), "flute_phase.offsets.rod"),
                float(np.radians(self._number(kept, "phase_deg"))),
                float(np.radians(self._number(kept, "phase_std_deg"))),
            )
            plain_rod = self._recorded_line(nominal, plain_fit.get("rod"), "flute_phase.plain_fit.rod")
            return SecondPassRefit(
                self._matrix(plain_fit, "plain_fit"), replace(plain_rod, fluted=False), applied_m, shift
            )
        T = self.T_base_laser if self.first_pass_transform is None else self.first_pass_transform
        rod = nominal
        if self.first_pass_rod is not None:
            rod = self._recorded_line(nominal, self.first_pass_rod, "rod")
        return SecondPassRefit(np.asarray(T, dtype=float), rod, applied_m)

    def flute_note(self) -> str | None:
        """How the verify fits a fluted bit's centres (``verify.json``; None: the job's rod has no
        flutes)."""
        if self.job is None or not self.job.rod.fluted:
            return None
        if self.flute_phase is None:
            return (
                "result.json does not record its flute phase pass (written before 2026-11-27): centres "
                "fitted with the fluted section's mean offset, which may stay in residuals where the pass "
                "was kept"
            )
        kept = self._kept_flute_phase()
        if kept is None:
            return "the calibration's flute phase pass was not kept: centres fitted with the mean offset"
        return (
            "centres fitted as the calibration's flute phase pass did (run.first_pass.flute_phase): "
            f"plain fits moved by the section's offset at {self._number(kept, 'phase_deg'):.0f} "
            f"+- {self._number(kept, 'phase_std_deg'):.0f} deg"
        )

    def _kept_flute_phase(self) -> dict[str, Any] | None:
        """``run.first_pass.flute_phase`` where it says the pass was kept (a fluted job's), else None."""
        if self.flute_phase is None or self.job is None or not self.job.rod.fluted:
            return None
        kept = self.flute_phase.get("kept")
        if not isinstance(kept, bool):
            raise self._malformed("flute_phase.kept is not true or false")
        return self.flute_phase if kept else None

    def _malformed(self, what: str) -> ConfigError:
        """A one-line error naming the malformed field of ``run.first_pass``."""
        return ConfigError(
            f"{self.path}: run.first_pass.{what}; pass the result.json that `lasercal run` wrote"
        )

    def _number(self, table: dict[str, Any], key: str) -> float:
        """``run.first_pass.flute_phase.<key>``, a finite number."""
        value = table.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise self._malformed(f"flute_phase.{key} is not a finite number")
        return float(value)

    def _fit_table(self, kept: dict[str, Any], key: str) -> dict[str, Any]:
        """``run.first_pass.flute_phase.<key>``: a transform and a rod line."""
        table = kept.get(key)
        if not isinstance(table, dict):
            raise self._malformed(f"flute_phase.{key} is missing (T_base_laser and rod)")
        return table

    def _matrix(self, table: dict[str, Any], key: str) -> FloatArray:
        """``run.first_pass.flute_phase.<key>.T_base_laser``, a finite 4x4 transform."""
        try:
            matrix = np.asarray(table.get("T_base_laser"), dtype=float).reshape(4, 4)
        except (TypeError, ValueError):
            raise self._malformed(f"flute_phase.{key}.T_base_laser is not a 4x4 transform") from None
        if not np.isfinite(matrix).all():
            raise self._malformed(f"flute_phase.{key}.T_base_laser is not finite")
        return matrix

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

    def _recorded_line(self, nominal: RodLine, line: Any, name: str) -> RodLine:
        """``nominal`` on a recorded line (``run.first_pass.<name>``: origin_m, direction)."""
        try:
            origin_m = np.asarray(line["origin_m"], dtype=float).reshape(3)
            direction = np.asarray(line["direction"], dtype=float).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise self._malformed(
                f"{name} is not a rod line (origin_m and direction, 3 numbers each)"
            ) from None
        finite = np.isfinite(origin_m).all() and np.isfinite(direction).all()
        if not finite or np.linalg.norm(direction) == 0.0:
            raise self._malformed(f"{name} has a non-finite origin or a zero direction")
        return replace(nominal, origin_m=origin_m, direction=direction)

    def waypoints_note(self) -> str:
        """Where ``waypoints`` come from, for ``verify.json``."""
        if self.run_waypoints is not None:
            count = len(self.run_waypoints)
            return f"result.json run.waypoints: the {count} waypoints the calibration planned"
        return (
            "the job's waypoints as listed (result.json records no run.waypoints, written before "
            "2026-11-28 or by `lasercal solve` of a CSV): an adaptive run's second design or a spun run's "
            "turned waypoints are not among them"
        )

    @property
    def rod(self) -> RodLine | None:
        """The rod the calibration was made with, if recorded."""
        return self.job.rod.rod_line() if self.job is not None else None

    def waypoints(self) -> FloatArray | None:
        """The calibration's waypoints (UR poses) by the residuals' index: every one its run
        planned (``run.waypoints``: an adaptive run's second design and a spun run's turned
        waypoints too) or, in a file without that record, as its job lists them (``waypoints_note``);
        None without either."""
        if self.run_waypoints is not None:
            return self.run_waypoints
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
    by_index = {r.index: r for r in residuals if r.used or not used_only}
    return [
        next((by_index[j] for j in same if j in by_index), None)
        for same in _same_poses(recorded_waypoints, waypoints)
    ]


def _same_poses(recorded_waypoints: FloatArray | None, waypoints: FloatArray) -> list[NDArray[np.int64]]:
    """For each of ``waypoints``, the indices of the calibration's waypoints at that pose (none
    when they were not recorded)."""
    poses = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    if recorded_waypoints is None:
        return [np.zeros(0, dtype=np.int64)] * len(poses)
    recorded = np.asarray(recorded_waypoints, dtype=float).reshape(-1, 6)
    return [np.flatnonzero(np.max(np.abs(recorded - pose), axis=1) <= SAME_POSE_TOLERANCE) for pose in poses]


def unusable_waypoints(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> NDArray[np.bool_]:
    """True at each of ``waypoints`` (N,) that the calibration visited without a re-fitted centre
    it used: the rod was not found there, its centre was left out of the fit as an outlier, or
    the second pass could not fit it again and the solve took the first pass's. A verify meets
    there what the calibration did (fluted drill job, seeds 100-109: every false alarm was an
    outlier waypoint the choice took, its centre 8-12 mm off the prediction at every dwell), or
    compares its re-fit with a fit of another kind (seed 46: 2.4 mm apart at every dwell;
    docs/lab/verify-log.md). False everywhere when the file records no waypoints or no residuals."""
    if not residuals:
        return np.zeros(len(np.asarray(waypoints).reshape(-1, 6)), dtype=bool)
    used = {r.index for r in residuals if r.used and r.first_pass_kept is None}
    visits = _same_poses(recorded_waypoints, waypoints)
    return np.array([same.size > 0 and not used.intersection(same.tolist()) for same in visits], dtype=bool)


def repeated_poses(waypoints: FloatArray) -> NDArray[np.bool_]:
    """True at each of ``waypoints`` (N,) whose pose an earlier one already has (a spun drill's
    spin and its turned waypoints can share one): a second visit there adds no candidate, and
    a verify that took both would count one pose's noise twice as independent."""
    each_pose = _same_poses(waypoints, waypoints)  # a pose's first index: its own or an earlier one
    return np.array([int(same[0]) < k for k, same in enumerate(each_pose)], dtype=bool)


def recorded_residuals(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """The calibration's residual (measured minus predicted, m; (N, 2)) at each of
    ``waypoints``, NaN where it did not visit that pose or left it out of its fit."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=True)
    pairs = [(np.nan, np.nan) if r is None else (r.du_mm / 1e3, r.dv_mm / 1e3) for r in rows]
    return np.array(pairs, dtype=float).reshape(-1, 2)


def recorded_echo_middles(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """A twist drill's echo middle as the calibration recorded it at each of ``waypoints`` in its
    fit: (N, 3), the middle's offset from the centre (u, v; m) and its dwell noise across the
    bearing (m^2); NaN where none is recorded (``WaypointResidual.echo_middle_uv_mm``)."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=True)
    values = [
        (np.nan, np.nan, np.nan)
        if r is None or r.echo_middle_uv_mm is None or r.echo_middle_noise_mm2 is None
        else (r.echo_middle_uv_mm[0] / 1e3, r.echo_middle_uv_mm[1] / 1e3, r.echo_middle_noise_mm2 / 1e6)
        for r in rows
    ]
    return np.array(values, dtype=float).reshape(-1, 3)


def recorded_echo_middle_moves(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> FloatArray:
    """How far the middle of a plain rod's echo moved the calibration's centre across its bearing
    at each of ``waypoints`` in its fit (m, (N, 2); zero where the fit placed it), NaN where none
    is recorded (``WaypointResidual.echo_middle_move_uv_mm``)."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=True)
    values = [
        (np.nan, np.nan)
        if r is None or r.echo_middle_move_uv_mm is None
        else (r.echo_middle_move_uv_mm[0] / 1e3, r.echo_middle_move_uv_mm[1] / 1e3)
        for r in rows
    ]
    return np.array(values, dtype=float).reshape(-1, 2)


def recorded_centre_covariances(
    residuals: Sequence[WaypointResidual], recorded_waypoints: FloatArray | None, waypoints: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The centre covariance (m^2, (N, 2, 2), scanner frame) the calibration's solver weighed
    each of ``waypoints`` with, outliers too, and the part of it another dwell draws anew; NaN
    where it did not measure that pose or its ``result.json`` predates the record
    (``WaypointResidual.covariance_uv_mm2``, ``noise_covariance_uv_mm2``)."""
    rows = _recorded_at(residuals, recorded_waypoints, waypoints, used_only=False)
    unknown = np.full((2, 2), np.nan)

    def blocks(matrices: list[list[list[float]] | None]) -> FloatArray:
        known = [unknown if m is None else np.array(m) / 1e6 for m in matrices]
        return np.array(known, dtype=float).reshape(-1, 2, 2)

    return (
        blocks([None if r is None else r.covariance_uv_mm2 for r in rows]),
        blocks([None if r is None else r.noise_covariance_uv_mm2 for r in rows]),
    )
