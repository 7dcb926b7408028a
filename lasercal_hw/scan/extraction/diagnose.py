"""Why no rod was found, in the operator's words: a place as one reads it and the sentence that
says what to do."""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _place(centre_uv_m: FloatArray) -> str:
    """A centre as an operator reads it: position, range and bearing."""
    u, v = (float(c) for c in centre_uv_m)
    return f"({u:+.3f}, {v:+.3f}) m, {np.hypot(u, v):.2f} m at {np.degrees(np.arctan2(v, u)):+.0f} deg"


def _diagnose(
    scan: AveragedScan,
    section: _Section,
    background: AveragedScan | None,
    expected: FloatArray | None,
    settings: ExtractionSettings,
    notes: list[str],
) -> str:
    """A sentence saying why no rod-like segment was found, and what to do."""
    valid = np.isfinite(scan.ranges_m)
    if not valid.any():
        return "the scan has no valid beam; check the scanner (window, power) and its stream"
    size = f"radius {section.radius_m * 1000:.1f} mm"
    if expected is not None:
        bearing = float(np.arctan2(expected[1], expected[0]))
        low, high = float(scan.angles_rad.min()), float(scan.angles_rad.max())
        if not low <= bearing <= high:
            return (
                f"expected rod at bearing {np.degrees(bearing):.1f} deg is outside the field of view "
                f"[{np.degrees(low):.1f}, {np.degrees(high):.1f}] deg; move the waypoint into view"
            )
        beam = int(np.argmin(np.abs(scan.angles_rad - bearing)))
        expected_range = float(np.linalg.norm(expected)) - section.semi_major_m
        seen = scan.ranges_m[beam]
        if np.isfinite(seen) and seen < expected_range - settings.search_radius_m:
            return (
                f"rod ({size}) occluded: the beam towards its expected position at {expected_range:.3f} m "
                f"returns {seen:.3f} m; clear the line of sight"
            )
        if np.isfinite(seen) and seen > expected_range + settings.search_radius_m + section.semi_major_m:
            return (
                f"no rod ({size}) near the expected position ({expected[0]:.3f}, {expected[1]:.3f}) m: "
                f"the beam there returns {seen:.3f} m; check the waypoint and the rod mounting"
            )
    if notes:
        return "; ".join(notes)
    method = "background subtraction" if background is not None else "range discontinuities"
    return (
        f"no segment matching a rod of {size} found by {method} "
        f"({int(valid.sum())} valid beams); check the rod radius, the rod's range "
        "(beams are 0.25 deg apart) and, without a background scan, that nothing touches the rod"
    )
