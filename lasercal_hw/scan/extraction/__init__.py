"""Rod centre from an averaged scan: segment the rod, drop mixed pixels, fit its centre.

Steps (docs/extraction.md has the reasoning):

1. Segment: with a background scan, beams significantly nearer than the background (per-
   beam noise of both scans); without one, runs of valid beams split at range jumps.
   The rod's own beams are picked out of each run (steady mixed-pixel ramps beside it cut
   off: ``_rod_core``). A candidate must stand in front of its neighbours and span the
   angle a rod of the known radius covers at its range. Every candidate is fitted: the
   fit nearest ``expected_uv_m`` wins if within the search radius (others are refused by
   name); without an expected position two rod-like fits are a refusal naming both.
2. Seed: mean of the arc points plus the paper's ``R*pi/4`` correction away from the
   scanner (exact for a far rod whose beams sample the half circle evenly across).
3. Fit: Gauss-Newton on the orthogonal distance of each point to the rod's surface,
   ``dist(point, axis line) - r``, with the axis through the unknown centre (u, v, 0).
   With ``axis_in_scanner`` the line is tilted and the cross-section is the ellipse
   (semi-minor r, semi-major r/|cos tilt|); without it the line is the scanner z axis
   and the cross-section a circle.  Each residual is weighted by the range noise
   projected on the surface normal plus a small lateral (beam-angle) term.  The
   covariance adds what the dwell does not average away (residuals beyond the noise) and
   how far the solver's range-error model is from this fit's response to a range error.
   Then the same fit against what each beam's spot returns from the rod (its power-weighted
   mean over the curved front: ``_spot_readings_m``) gives the centre along the bearing,
   the ray fit across it (``_along_the_spot``), unless the rays fit the beams better.
4. Mixed pixels: unstable beams (their readings flipped between rod and background
   during the dwell: a low inlier count or a reading spread far above the scan's) are
   trimmed off the ends of every segment before it is judged; after the fit, edge beams
   lying significantly behind the fitted surface are dropped and the fit repeated.
5. Radius: a free-radius fit when enough beams over a wide enough arc hit the rod.
6. The beam's spot (wider than a thin rod): a near rod looks up to a spot wider (allowed in
   the size check; the core is centred in that halo, and a flat bright blot's middle is its
   front); a background close behind merges into the echo, bounded per beam by its share of the spot
   (and intensities) times the depth: a rod no beam reads alone is refused, one whose
   cleanest beam is still partly background gets the bound in its covariance and a warning.
   What the range-error curve leaves across the arc (range walk, near-range error) joins
   the covariance too, and so does what two sideways checks find (the arc without its edge
   beams; for a fit of few beams, the range profile's symmetry).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _range_sigma
from lasercal_hw.scan.extraction.blend import _behind
from lasercal_hw.scan.extraction.candidates import _candidate_segments
from lasercal_hw.scan.extraction.centre_fit import seed_centre_pi4
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError, RodQuality
from lasercal_hw.scan.extraction.section import _across_bearing, _Section, _unit_axis
from lasercal_hw.scan.extraction.segment_fit import _fit_segment
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _spot_parts, _spot_sigma_m

__all__ = [
    "ExtractionSettings",
    "RodCentre",
    "RodNotFoundError",
    "RodQuality",
    "find_rod_centre",
    "seed_centre_pi4",
]


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


def _place(centre_uv_m: FloatArray) -> str:
    """A centre as an operator reads it: position, range and bearing."""
    u, v = (float(c) for c in centre_uv_m)
    return f"({u:+.3f}, {v:+.3f}) m, {np.hypot(u, v):.2f} m at {np.degrees(np.arctan2(v, u)):+.0f} deg"


def _distinct(found: list[RodCentre], section: _Section) -> list[RodCentre]:
    """The fits with one per object: fits of parts of one rod (a segment split by a lost
    beam) have centres within a radius of each other; the one with most beams is kept."""
    kept: list[RodCentre] = []
    for fit in sorted(found, key=lambda f: -f.quality.beams_used):
        if all(np.linalg.norm(fit.centre_uv_m - k.centre_uv_m) > section.radius_m for k in kept):
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


#: The fewest of ``echo_middle_levels`` whose middle must be read on the rod's beams (a far rod's
#: lobe, wider than the rod, does not fall to the lowest levels on them).
MIN_ECHO_MIDDLE_LEVELS = 2


def _across_from_echo_middle(
    scan: AveragedScan, fit: RodCentre, section: _Section, settings: ExtractionSettings
) -> RodCentre:
    """The centre with its position across the bearing from the middle of the rod's echo
    strength: at each of ``echo_middle_levels`` of the brightest beam on the rod, the middle of
    where the intensity falls through that level on either side (interpolated between beams
    that read the rod), averaged over the levels. Along the bearing the centre is kept; across,
    the dwell noise takes the levels' scatter (a lopsided lobe's middles move with the level)
    and the mean's (all of it: which beams cross a level changes from dwell to dwell), the
    covariance that and a beam step's quantisation besides (the beams' angles repeat at the
    pose). Unchanged without intensities, for a fluted rod (its
    glint is no symmetric lobe), or where a level is not crossed on the rod's beams on both
    sides (the background's echo won there).

    The spot's power on the rod falls off alike on both sides of its centre; which echo wins
    at the rod's edges moves the segment's ends, not the lobe's middle (the dry run's waypoints
    1, 3, 17 and 18: within 0.2 mm of the true bearing, where the fits lay -0.75 to +1.32 mm)."""
    if scan.intensities is None or not settings.echo_middle_levels:
        return fit
    intensities, ranges = scan.intensities, scan.ranges_m
    distance_m = float(np.linalg.norm(fit.centre_uv_m))
    bearing_rad = float(np.arctan2(fit.centre_uv_m[1], fit.centre_uv_m[0]))
    half_rad = float(np.arcsin(min(section.semi_major_m / distance_m, 1.0)))
    within = np.abs(scan.angles_rad - bearing_rad) <= half_rad
    on_rod = within & (ranges < distance_m) & np.isfinite(intensities)
    if not np.any(on_rod):
        return fit
    brightest = int(np.flatnonzero(on_rod)[int(np.argmax(intensities[on_rod]))])
    on_rod_m = float(ranges[brightest]) + 2.0 * section.semi_major_m
    middles_rad = []
    for level in settings.echo_middle_levels:
        threshold = level * float(intensities[brightest])
        sides: list[float] = []
        for direction in (-1, 1):
            i = brightest
            while 0 <= i + direction < ranges.size and ranges[i + direction] < on_rod_m and (
                intensities[i + direction] > threshold
            ):  # NaN: False
                i += direction
            j = i + direction
            if not (0 <= j < ranges.size and ranges[j] < on_rod_m and np.isfinite(intensities[j])):
                break
            share = (intensities[i] - threshold) / (intensities[i] - intensities[j])
            sides.append(scan.angles_rad[i] + share * (scan.angles_rad[j] - scan.angles_rad[i]))
        if len(sides) == 2:
            middles_rad.append(0.5 * (sides[0] + sides[1]))
    if len(middles_rad) < MIN_ECHO_MIDDLE_LEVELS:
        return fit
    middles_m = distance_m * (np.asarray(middles_rad) - bearing_rad)
    across = _across_bearing(fit.centre_uv_m)
    shift_m = float(np.mean(middles_m))  # the fit's own centre lies on its bearing
    # A flat-topped lobe (every level crossed between the same two beams) fixes its middle only
    # to a beam step: each side anywhere within one, the middle their mean.
    step_m = distance_m * float(np.median(np.abs(np.diff(scan.angles_rad))))
    noise_m2 = float(np.var(middles_m)) * (1.0 + 1.0 / middles_m.size)
    along = np.outer(fit.centre_uv_m, fit.centre_uv_m) / distance_m**2
    noise = fit.noise_covariance_uv_m2

    def across_replaced(covariance_uv_m2: FloatArray, across_m2: float) -> FloatArray:
        """The covariance's part along the bearing with ``across_m2`` across."""
        return along @ covariance_uv_m2 @ along + across_m2 * np.outer(across, across)

    return replace(
        fit,
        centre_uv_m=fit.centre_uv_m + shift_m * across,
        covariance_uv_m2=across_replaced(fit.covariance_uv_m2, noise_m2 + step_m**2 / 24.0),
        noise_covariance_uv_m2=None if noise is None else across_replaced(noise, noise_m2),
    )


def _gloss_ratio(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    centre_uv_m: FloatArray,
    radius_m: float,
    settings: ExtractionSettings,
) -> float | None:
    """How the rod's echo falls off across it against a diffuse (Lambert) section's: on the
    beams where a diffuse section would return under 0.9 of its brightest beam's, the median
    of each beam's intensity over the brightest, divided by that prediction (intensity goes
    as the square root of the power; the spot's core and halo as ``_spot_readings_m`` takes
    them). About 1 for a diffuse surface, well under for a polished one; None without
    intensities or such beams."""
    if scan.intensities is None:
        return None
    intensity = scan.intensities[beams]
    distance_m = float(np.linalg.norm(centre_uv_m))
    bearing_rad = float(np.arctan2(centre_uv_m[1], centre_uv_m[0]))
    offsets_m = distance_m * np.sin(scan.angles_rad[beams] - bearing_rad)
    half_m = 2.0 * float(_spot_sigma_m(np.array([distance_m - radius_m]), settings)[0])
    across_m = radius_m * np.sin(np.linspace(-np.pi / 2.0, np.pi / 2.0, 201))
    cosine = np.sqrt(np.fmax(1.0 - (across_m / radius_m) ** 2, 0.0))
    power = np.zeros(beams.size)
    for share, scale in _spot_parts(settings):
        width_m = max(half_m * scale, 1e-9)
        profile = np.exp(-2.0 * ((across_m[None, :] - offsets_m[:, None]) / width_m) ** 2)
        power += share / width_m * (profile * cosine * np.gradient(across_m)).sum(axis=1)
    predicted = np.sqrt(power / max(float(power.max()), 1e-300))
    flank = (predicted < 0.9) & np.isfinite(intensity)
    if not np.any(flank) or not np.nanmax(intensity) > 0.0:
        return None
    return float(np.median(intensity[flank] / np.nanmax(intensity) / predicted[flank]))


def _along_from_glint(
    scan: AveragedScan, found: RodCentre, section: _Section, settings: ExtractionSettings
) -> RodCentre:
    """A polished rod on few beams (``glint_gloss_ratio``, ``glint_max_beams``) placed along its
    bearing by its glint: its brightest beam reads the section's front, which lies the
    section's half-width along the bearing (a radius for an upright rod) before the centre.
    The covariance keeps the fit's along the bearing, plus ``spot_model_doubt`` of the move
    (the glint is not a mirror's point: the spot's middle, not its peak) and the beam's own
    noise, which the dwell's noise takes too. Unchanged otherwise."""
    beams = found.beam_indices
    if scan.intensities is None or not 0 < beams.size <= settings.glint_max_beams:
        return found
    gloss = _gloss_ratio(scan, beams, found.centre_uv_m, section.radius_m, settings)
    if gloss is None or gloss >= settings.glint_gloss_ratio:
        return found
    brightest = int(beams[int(np.nanargmax(scan.intensities[beams]))])
    bearing = found.centre_uv_m / float(np.linalg.norm(found.centre_uv_m))
    front_m = section.radius_m * float(np.linalg.norm(section.from_circle(bearing[None, :])[0]))
    shift_m = float(scan.ranges_m[brightest]) + front_m - float(np.linalg.norm(found.centre_uv_m))
    beam_m2 = float(_range_sigma(scan, settings)[brightest]) ** 2
    along = np.outer(bearing, bearing)
    doubt_m2 = (settings.spot_model_doubt * shift_m) ** 2 + beam_m2
    noise = found.noise_covariance_uv_m2
    return replace(
        found,
        centre_uv_m=found.centre_uv_m + shift_m * bearing,
        covariance_uv_m2=found.covariance_uv_m2 + doubt_m2 * along,
        noise_covariance_uv_m2=None if noise is None else noise + beam_m2 * along,
    )


def _flute_moments_m(radius_m: float, settings: ExtractionSettings) -> tuple[float, float, float]:
    """Where a twist drill's axis lies from the centre a circle fit finds on it, over the
    drill's turn about its axis (unknown to the extraction): the mean and variance along the
    bearing (away from the scanner) and the variance across it, in m and m^2.

    The fit puts a circle of the drill's radius behind the surface the echo comes from. A
    land facing the scanner is on that circle; a flute facing it (a share ``2 opening / 360``
    of the turns) sends its echo from its hollow, ``(1 - web) r`` deeper, and aside by ``r
    sin(delta)`` where the flute's middle is turned ``delta`` (uniform over the opening) from
    the scanner. On the physical scanner model's polished 10 mm bit (drill job, seeds
    100-102) the centres lay 0 mm (land facing) to 5.7 mm (flute facing) behind the axis along
    the bearing, 2.4 mm std, and 1.4 mm RMS across it."""
    half_rad = np.radians(settings.flute_opening_deg) / 2.0
    share = 2.0 * half_rad / np.pi
    depth_m = (1.0 - settings.flute_web_fraction) * radius_m
    across_m2 = share * radius_m**2 * (0.5 - np.sin(2.0 * half_rad) / (4.0 * half_rad))
    return share * depth_m, share * (1.0 - share) * depth_m**2, float(across_m2)


def _with_flutes(found: RodCentre, section: _Section, settings: ExtractionSettings) -> RodCentre:
    """A centre fitted on a twist drill moved to where its axis lies on average and its
    covariance widened by how far off that may be (``_flute_moments_m``), both stretched
    along the section's major axis for a tilted drill. The error repeats at the same pose and
    turn, so the noise part of the covariance stays."""
    mean_m, along_m2, across_m2 = _flute_moments_m(section.radius_m, settings)
    bearing = found.centre_uv_m / float(np.linalg.norm(found.centre_uv_m))
    across = np.array([-bearing[1], bearing[0]])
    stretch = section.from_circle(np.eye(2)).T  # the linear map from the circle to the section
    shift = stretch @ (-mean_m * bearing)  # the fit lies behind the axis: move it nearer
    covariance = stretch @ (along_m2 * np.outer(bearing, bearing) + across_m2 * np.outer(across, across))
    return replace(
        found,
        centre_uv_m=found.centre_uv_m + shift,
        covariance_uv_m2=found.covariance_uv_m2 + covariance @ stretch.T,
    )
