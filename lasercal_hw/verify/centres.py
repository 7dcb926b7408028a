"""The rod centres a verify compares: each averaged scan fitted again as the ellipse the
rod axis predicted by the active calibration cuts from the plane, exactly as the
calibration's own second pass fitted its centres (``run.sequencer.solve_two_pass``), so
that both sides of the comparison carry the same extraction."""

from __future__ import annotations

from collections.abc import Sequence

from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.sequencer import WaypointMeasurement, predict_rod
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre


def refit_centres(
    measurements: Sequence[WaypointMeasurement],
    T_base_laser: FloatArray,
    rod: RodLine,
    background: AveragedScan | None,
) -> tuple[list[WaypointMeasurement], list[tuple[int, str]]]:
    """The measurements with centres re-fitted for the predicted rod axis, and the
    waypoints (index, reason) whose first centre was kept because the re-fit failed."""
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
            )
        except RodNotFoundError as exc:
            kept.append((m.index, str(exc)))
            refitted.append(m)
            continue
        refitted.append(WaypointMeasurement(m.index, m.tcp_pose, m.averaged, centre))
    return refitted, kept
