"""The solve of a run, live or replayed: the first pass on the circle-fit centres, then the
second pass on centres re-fitted as the ellipse each waypoint's solved rod axis cuts from
the plane (``solve_two_pass``); where a transform predicts the rod (``predict_rod``).

No motion and no devices: ``lasercal solve session.mcap`` and verify use it as the live run does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from lasercal_hw.calibration.model import lines_in_scanner, plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.observations import SolveSettings
from lasercal_hw.calibration.result import CalibrationResult, RangeOffset
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.config import JobConfig
from lasercal_hw.models import FloatArray, Observation, RodLine
from lasercal_hw.run.flute_phase import PLAIN_EXTRACTION, FluteShift, estimate_flute_phase
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import (
    EchoMiddle,
    ExtractionSettings,
    RodNotFoundError,
    echo_middle,
    find_rod_centre,
)


@dataclass(frozen=True)
class RodPrediction:
    """Where a transform says the rod should be in the scanner: its axis direction and,
    when the rod actually reaches the scan plane, the crossing point."""

    axis_in_scanner: FloatArray
    expected_uv_m: FloatArray | None


def predict_rod(T_base_laser: FloatArray, tcp_pose: FloatArray, rod: RodLine) -> RodPrediction:
    """The rod axis direction and plane crossing in the scanner frame for one TCP pose."""
    rotation = np.asarray(T_base_laser, dtype=float)[:3, :3]
    translation_m = np.asarray(T_base_laser, dtype=float)[:3, 3]
    origins, directions = rod_lines_in_base(np.asarray(tcp_pose, dtype=float)[None, :], rod)
    _, axes = lines_in_scanner(rotation, translation_m, origins, directions)
    axis = axes[0] if axes[0, 2] >= 0.0 else -axes[0]
    if abs(axes[0, 2]) < 1e-9:
        return RodPrediction(axis, None)
    crossing, _, line_s = plane_crossing(rotation, translation_m, origins, directions)
    on_rod = 0.0 <= line_s[0] <= rod.length_m
    return RodPrediction(axis, crossing[0] if on_rod else None)


def _typical_range_error_m(range_offset: RangeOffset | None) -> float:
    """The first pass's range error where the crossings are (the median of its curve over
    their span; its offset when it has no curve): what the second pass takes out of every
    range. Not the offset itself, the error at 1 m, which lies outside the span of waypoints
    that all cross nearer (designed ones: 0.3-0.6 m) and is then an extrapolation."""
    if range_offset is None:
        return 0.0
    if not range_offset.curve:
        return range_offset.offset_mm / 1000.0
    return float(np.median([point.error_mm for point in range_offset.curve])) / 1000.0


def _moved_back(centre_uv_m: FloatArray, range_offset_m: float) -> FloatArray:
    """A centre moved back along its bearing by the range offset (the solver's first-order
    model of what the offset does to a centre)."""
    centre = np.asarray(centre_uv_m, dtype=float)
    return centre * (1.0 - range_offset_m / float(np.linalg.norm(centre)))


@dataclass(frozen=True)
class SecondPassRefit:
    """How the second pass fits every centre again: as the ellipse the axis of ``rod`` (the
    first pass's estimate of it when the job estimates the axis) cuts from the plane as
    ``T_base_laser`` (the first pass's transform) predicts it, with ``range_offset_m`` (the
    first pass's typical range error) taken out of every range before the fit; the solver's
    range error curve, less that offset, models the rest. The verify fits its centres with the
    calibration's recorded refit, so the same averaged scan gives it the calibration's centre
    to the last bit.

    Where a twist drill's flute phase pass was kept (``flutes``), the centres are the pass's:
    plain fits (``PLAIN_EXTRACTION``) of ``rod`` (then the second pass's estimate, made plain,
    as the second pass's solution ``T_base_laser`` predicts it), moved by the section's offset at
    each waypoint's turn (``FluteShift``)."""

    T_base_laser: FloatArray
    rod: RodLine
    range_offset_m: float = 0.0
    #: The flute phase pass's move of the plain fits, where the pass was kept; None: the fits as
    #: ``rod`` says (a fluted one with the section's mean offset).
    flutes: FluteShift | None = None

    def centres(
        self,
        measurements: Sequence[WaypointMeasurement],
        background: AveragedScan | None,
        settings: ExtractionSettings | None = None,
    ) -> tuple[list[WaypointMeasurement], list[tuple[int, str]]]:
        """The measurements with their centres fitted again (by ``settings``, None: the
        extraction's defaults) and freed of the range offset (a centre the re-fit could not
        replace moved back along its bearing by it), and the waypoints (index, reason) that
        kept their first centre (the flute phase pass moves those too, as it did)."""
        if self.flutes is not None:
            plain, kept = replace(self, flutes=None).centres(measurements, background, PLAIN_EXTRACTION)
            moved = self.flutes.moved(
                np.array([m.tcp_pose for m in plain], dtype=float),
                [m.centre.centre_uv_m for m in plain],
                [m.centre.covariance_uv_m2 for m in plain],
            )
            return [
                replace(m, centre=replace(m.centre, centre_uv_m=centre, covariance_uv_m2=covariance))
                for m, (centre, covariance) in zip(plain, moved, strict=True)
            ], kept
        refitted, kept = refit_centres(
            measurements,
            self.T_base_laser,
            self.rod,
            background,
            range_offset_m=self.range_offset_m,
            settings=settings,
        )
        if not self.range_offset_m:
            return refitted, kept
        kept_indices = {index for index, _ in kept}
        return [self._moved_back(m) if m.index in kept_indices else m for m in refitted], kept

    def echo_middle(
        self, averaged: AveragedScan, tcp_pose: FloatArray, centre_uv_m: FloatArray
    ) -> EchoMiddle | None:
        """Where the middle of the rod's echo strength lies across the bearing of ``centre_uv_m``
        in ``averaged`` (the extraction's ``echo_middle`` at its default levels, over the section
        the rod's axis cuts at ``tcp_pose`` as ``T_base_laser`` predicts it); None where there is
        none. A twist drill's verify compares these (``verify/echo_reference``)."""
        axis = predict_rod(self.T_base_laser, tcp_pose, self.rod).axis_in_scanner
        semi_major_m = self.rod.radius_m / max(abs(float(axis[2])), 1e-6)
        return echo_middle(averaged, centre_uv_m, semi_major_m, ExtractionSettings().echo_middle_levels)

    def _moved_back(self, measurement: WaypointMeasurement) -> WaypointMeasurement:
        """A first centre moved back along its bearing by the range offset."""
        centre = _moved_back(measurement.centre.centre_uv_m, self.range_offset_m)
        return replace(measurement, centre=replace(measurement.centre, centre_uv_m=centre))


@dataclass(frozen=True)
class TwoPassSolution:
    """The solve of a run: first pass on the circle-fit centres, then the second pass on
    centres re-fitted as the ellipse each waypoint's solved rod axis cuts from the plane."""

    first_pass: CalibrationResult
    result: CalibrationResult
    observations: list[Observation]
    refinement: str
    kept_first_pass: list[tuple[int, str]]
    #: The second pass's rod, solver settings and gates: ``observations`` solved with them
    #: give ``result`` again (``observations.csv`` carries them).
    settings: SolveSettings
    #: (waypoint, warning) for each solved centre that may be off by more than its covariance.
    centre_warnings: list[tuple[int, str]]
    #: How the solved centres were fitted (``result.json`` records it: the verify fits so): the
    #: second pass's re-fit, or where the flute phase pass was kept, its plain fits and move.
    refit: SecondPassRefit


def solve_two_pass(
    measurements: Sequence[WaypointMeasurement],
    job: JobConfig,
    background: AveragedScan | None,
    on_second_pass: Callable[[], None] | None = None,
) -> TwoPassSolution:
    """Solve a run's measurements as a live run does; ``lasercal solve session.mcap`` calls
    this too, so a replay of the recording gives the live result to the last bit.
    ``on_second_pass`` is called between the passes (progress display)."""
    rod = job.rod.rod_line()
    options = SolverOptions(
        robot_sigma_m=job.robot.position_accuracy_mm / 1000.0,
        estimate_axis=job.rod.estimate_axis,
        axis_prior_std_m=job.rod.axis_std_mm / 1000.0,
        axis_prior_std_deg=job.rod.axis_std_deg,
        estimate_range_offset=job.scanner.estimate_range_offset,
        max_range_terms=job.scanner.range_error_terms,
    )
    first = solve([m.observation() for m in measurements], rod, options=options)
    if on_second_pass is not None:
        on_second_pass()
    refit = SecondPassRefit(
        first.matrix(), first.estimated_rod(rod), _typical_range_error_m(first.range_offset)
    )
    range_offset_m = refit.range_offset_m
    refitted, kept = refit.centres(measurements, background)
    observations = [m.observation() for m in refitted]
    # The second pass keeps estimating an offset the first one estimated (and removed above).
    estimate_offset = True if first.range_offset is not None else options.estimate_range_offset
    applied = options.model_copy(
        update={"range_offset_applied_m": range_offset_m, "estimate_range_offset": estimate_offset}
    )
    result = solve(observations, rod, options=applied)
    phase_note = ""
    if rod.fluted:
        # The plain fits take the offset out of the ranges as the second pass did (only a
        # centre the re-fit kept is moved back): once, not twice.
        plain_refit = SecondPassRefit(
            result.matrix(), replace(result.estimated_rod(rod), fluted=False), range_offset_m
        )
        plain, plain_kept = plain_refit.centres(measurements, background, PLAIN_EXTRACTION)
        plain_observations = [m.observation() for m in plain]
        phase = estimate_flute_phase(plain_observations, result, rod, applied)
        if phase is None:
            phase_note = (
                "; the flute phase was not told by the turns (its centres keep the widened allowance)"
            )
        else:
            result, observations = phase.result, phase.observations
            refit = replace(plain_refit, flutes=phase.shift)
            kept = plain_kept  # the solved centres are the plain fits'
            phase_note = f"; {phase.note}"
    refinement = (
        f"second pass: {len(measurements) - len(kept)} of {len(measurements)} centres re-extracted with the "
        "rod axis predicted by the first solution (elliptical cross-section) and the transform re-solved"
        + phase_note
    )
    result = _with_first_pass_kept(result, kept)
    if rod.fluted:
        result = _with_echo_middles(result, observations, measurements, refit)
    else:
        result = _with_echo_middle_moves(result, refitted, kept)
    settings = SolveSettings(rod, applied, job.quality)
    warnings = [(m.index, warning) for m in refitted for warning in m.centre.warnings]
    return TwoPassSolution(first, result, observations, refinement, kept, settings, warnings, refit)


def _with_first_pass_kept(result: CalibrationResult, kept: Sequence[tuple[int, str]]) -> CalibrationResult:
    """``result`` with the reason recorded in each residual whose centre the second pass could
    not fit again (``WaypointResidual.first_pass_kept``): a verify leaves those poses out."""
    reasons = dict(kept)
    residuals = [
        r.model_copy(update={"first_pass_kept": reasons[r.index]}) if r.index in reasons else r
        for r in result.residuals
    ]
    return result.model_copy(update={"residuals": residuals})


def _with_echo_middles(
    result: CalibrationResult,
    observations: Sequence[Observation],
    measurements: Sequence[WaypointMeasurement],
    refit: SecondPassRefit,
) -> CalibrationResult:
    """``result`` with each solved centre's echo middle recorded in its residual
    (``WaypointResidual.echo_middle_uv_mm``): a twist drill's verify compares middles."""
    scans = {m.index: m.averaged for m in measurements}
    centres = {o.index: o for o in observations}
    residuals = []
    for residual in result.residuals:
        observation = centres.get(residual.index)
        averaged = scans.get(residual.index)
        middle = None
        if observation is not None and averaged is not None:
            middle = refit.echo_middle(averaged, observation.tcp_pose, observation.centre_uv_m)
        if middle is not None:
            shift_mm = (middle.turned_onto(observation.centre_uv_m) - observation.centre_uv_m) * 1e3
            residual = residual.model_copy(
                update={
                    "echo_middle_uv_mm": shift_mm.tolist(),
                    "echo_middle_noise_mm2": middle.noise_m2 * 1e6,
                }
            )
        residuals.append(residual)
    return result.model_copy(update={"residuals": residuals})


def _with_echo_middle_moves(
    result: CalibrationResult, refitted: Sequence[WaypointMeasurement], kept: Sequence[tuple[int, str]]
) -> CalibrationResult:
    """``result`` with how far the middle of the rod's echo moved each re-fitted centre across its
    bearing ([0, 0]: none was read) recorded in its residual (``WaypointResidual.
    echo_middle_move_uv_mm``): a plain rod's verify compares centres placed alike."""
    kept_indices = {index for index, _ in kept}
    moves = {
        m.index: np.zeros(2) if m.centre.echo_middle_move_uv_m is None else m.centre.echo_middle_move_uv_m
        for m in refitted
        if m.index not in kept_indices
    }
    residuals = [
        r.model_copy(update={"echo_middle_move_uv_mm": (moves[r.index] * 1e3).tolist()})
        if r.index in moves
        else r
        for r in result.residuals
    ]
    return result.model_copy(update={"residuals": residuals})


def refit_centres(
    measurements: Sequence[WaypointMeasurement],
    T_base_laser: FloatArray,
    rod: RodLine,
    background: AveragedScan | None,
    *,
    range_offset_m: float = 0.0,
    settings: ExtractionSettings | None = None,
) -> tuple[list[WaypointMeasurement], list[tuple[int, str]]]:
    """The measurements with each centre fitted again as the ellipse the rod axis predicted
    by ``T_base_laser`` cuts from the plane (the second pass; ``lasercal verify`` with the
    active calibration), the scanner's ``range_offset_m`` removed, and the waypoints
    (index, reason) that kept their first centre because the re-fit failed."""
    refitted: list[WaypointMeasurement] = []
    kept: list[tuple[int, str]] = []
    for m in measurements:
        predicted = predict_rod(T_base_laser, m.tcp_pose, rod)
        try:
            centre = find_rod_centre(
                m.averaged,
                radius_m=rod.radius_m,
                background=background,
                axis_in_scanner=predicted.axis_in_scanner,
                expected_uv_m=predicted.expected_uv_m,
                range_offset_m=range_offset_m,
                fluted=rod.fluted,
                settings=settings,
            )
        except RodNotFoundError as exc:
            kept.append((m.index, str(exc)))
            refitted.append(m)
            continue
        refitted.append(WaypointMeasurement(m.index, m.tcp_pose, m.averaged, centre))
    return refitted, kept
