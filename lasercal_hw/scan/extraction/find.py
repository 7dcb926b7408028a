"""``find_rod_centre``: the steps in order, and the choice among the fits (one per object, the one
nearest where the rod should be)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _range_sigma
from lasercal_hw.scan.extraction.blend import _behind
from lasercal_hw.scan.extraction.candidates import _candidate_segments
from lasercal_hw.scan.extraction.diagnose import _diagnose, _place
from lasercal_hw.scan.extraction.drill import _with_flutes
from lasercal_hw.scan.extraction.intensity import _across_from_echo_middle, _along_from_glint
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError
from lasercal_hw.scan.extraction.section import _Section, _unit_axis
from lasercal_hw.scan.extraction.segment_fit import _fit_segment
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def find_rod_centre(
    scan: AveragedScan,
    *,
    radius_m: float,
    background: AveragedScan | None = None,
    axis_in_scanner: FloatArray | None = None,
    expected_uv_m: FloatArray | None = None,
    settings: ExtractionSettings | None = None,
    range_offset_m: float = 0.0,
    fluted: bool = False,
) -> RodCentre:
    """Find the rod's centre (u, v) in an averaged scan (scanner frame, metres).

    ``background``: the same view without the rod, for segmentation against clutter;
    ``axis_in_scanner``: the rod axis (unit 3-vector, scanner frame) to fit the tilted
    cross-section; ``expected_uv_m``: where the rod should be, to pick among candidates;
    ``range_offset_m``: the scanner's range offset (measured minus true), removed from every
    range before the fit; ``fluted``: the rod is a twist drill, whose section is no circle
    (``_with_flutes``).
    Raises ``RodNotFoundError`` saying why when there is no usable rod in the scan, and
    ``ConfigError`` for a non-positive radius or a zero axis.
    """
    settings = settings or ExtractionSettings()
    if fluted:
        # A twist drill's centre keeps the ray fit's along the bearing: where its echo comes
        # from is the polished section's glint, not a diffuse circle's spot, and the flutes'
        # offsets (``_with_flutes``; calibration/flutes.py) were measured against ray fits.
        settings = replace(settings, fit_along_the_spot=False)
    if not radius_m > 0.0:
        raise ConfigError(f"rod radius must be positive, got {radius_m} m; set the rod radius")
    unknown_tilt_cos = 1.0
    if axis_in_scanner is None:
        unknown_tilt_cos = float(np.cos(np.radians(settings.unknown_axis_max_tilt_deg)))
    section = _Section(_unit_axis(axis_in_scanner), radius_m, unknown_tilt_cos)
    if section.cos_tilt < settings.min_axis_cos_tilt:
        raise RodNotFoundError(
            f"rod axis is {np.degrees(np.arccos(section.cos_tilt)):.0f} deg from the scan plane normal: "
            "its cross-section is too elongated to fit; tilt the rod less"
        )
    if background is not None and background.ranges_m.shape != scan.ranges_m.shape:
        raise CalibrationError(
            f"background has {background.ranges_m.size} beams but the scan has {scan.ranges_m.size}; "
            "record the background with the same scanner settings"
        )
    if range_offset_m:
        scan = replace(scan, ranges_m=scan.ranges_m - range_offset_m)
    sigma = _range_sigma(scan, settings)
    expected = None if expected_uv_m is None else np.asarray(expected_uv_m, dtype=float)
    candidates, notes = _candidate_segments(scan, sigma, section, background, settings)
    behind = _behind(scan, background, settings)
    found, reasons = [], []
    for beams, ramp_beams in candidates:
        try:
            fit = _fit_segment(scan, sigma, beams, section, settings, ramp_beams=ramp_beams, behind=behind)
            found.append(fit)
        except RodNotFoundError as exc:
            reasons.append(str(exc))
    found = _distinct(found, section)
    if fluted:
        found = [_with_flutes(f, section, settings) for f in found]
    else:
        found = [_across_from_echo_middle(scan, f, section, settings) for f in found]
        found = [_along_from_glint(scan, f, section, settings) for f in found]
    if expected is not None:
        return _nearest_to_expected(scan, found, expected, section, background, settings, notes)
    if len(found) == 1:
        return found[0]
    if len(found) > 1:
        places = ", ".join(_place(f.centre_uv_m) for f in found)
        raise RodNotFoundError(
            f"{len(found)} rod-like objects in view ({places}) and no expected position to tell the rod: "
            "give the scanner's nominal mounting, or record a background scan without the rod"
        )
    if reasons:
        raise RodNotFoundError("; ".join(dict.fromkeys(reasons)))
    raise RodNotFoundError(_diagnose(scan, section, background, expected, settings, notes))


def _distinct(found: list[RodCentre], section: _Section) -> list[RodCentre]:
    """The fits with one per object: two rods of this radius cannot overlap, so fits whose
    centres lie within a diameter of each other are parts of one (a segment split by a lost
    beam, a twist drill's flutes); the one with most beams is kept."""
    kept: list[RodCentre] = []
    for fit in sorted(found, key=lambda f: -f.quality.beams_used):
        if all(np.linalg.norm(fit.centre_uv_m - k.centre_uv_m) > 2.0 * section.radius_m for k in kept):
            kept.append(fit)
    return kept


def _nearest_to_expected(
    scan: AveragedScan,
    found: list[RodCentre],
    expected: FloatArray,
    section: _Section,
    background: AveragedScan | None,
    settings: ExtractionSettings,
    notes: list[str],
) -> RodCentre:
    """The fit nearest the expected centre if within the search radius; otherwise
    ``RodNotFoundError`` naming every rod-like object refused for being elsewhere."""
    distances = [float(np.linalg.norm(f.centre_uv_m - expected)) for f in found]
    if found and min(distances) <= settings.search_radius_m:
        return found[int(np.argmin(distances))]
    reason = _diagnose(scan, section, background, expected, settings, notes)
    refused = [
        f"a rod-like object at {_place(f.centre_uv_m)} was refused: {d:.2f} m from where the rod should be "
        f"(limit {settings.search_radius_m:g} m)"
        for f, d in zip(found, distances, strict=True)
    ]
    raise RodNotFoundError("; ".join([reason, *refused]))
