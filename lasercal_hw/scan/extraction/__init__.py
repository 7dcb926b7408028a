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

import logging
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import (
    _beam_step_rad,
    _range_sigma,
    _runs,
    _trim_unstable,
    _unstable_beams,
)
from lasercal_hw.scan.extraction.blend import (
    _Behind,
    _behind,
    _blend_refusal,
    _drop_blended_edges,
    _pull_shifts_m,
    _steady_beams_beside,
    _tail_pulls_m,
    _without_blended_flanks,
)
from lasercal_hw.scan.extraction.centre_fit import (
    _arc_span_deg,
    _drop_mixed_edges,
    _fit_centre,
    seed_centre_pi4,
)
from lasercal_hw.scan.extraction.doubts import (
    _arc_bias_m,
    _with_arc_bias,
    _with_edge_doubt,
    _with_shared_push,
    _with_symmetry_doubt,
    _with_uneven_background,
)
from lasercal_hw.scan.extraction.fit import _gauss_newton, _residuals
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError, RodQuality
from lasercal_hw.scan.extraction.section import _across_bearing, _Section, _unit_axis
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _narrower_than_spot, _spot_parts, _spot_sigma_m

__all__ = [
    "ExtractionSettings",
    "RodCentre",
    "RodNotFoundError",
    "RodQuality",
    "find_rod_centre",
    "seed_centre_pi4",
]


logger = logging.getLogger(__name__)


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


def _jump_threshold_m(section: _Section, sigma: FloatArray, settings: ExtractionSettings) -> FloatArray:
    """Largest range step between neighbouring beams that stays inside one rod."""
    pair_sigma = np.sqrt(sigma[:-1] ** 2 + sigma[1:] ** 2)
    return section.widest_semi_axis_m + settings.min_jump_m + 5.0 * pair_sigma


def _candidate_segments(
    scan: AveragedScan,
    sigma: FloatArray,
    section: _Section,
    background: AveragedScan | None,
    settings: ExtractionSettings,
) -> tuple[list[tuple[NDArray[np.int64], int]], list[str]]:
    """Beam index runs that could be the rod, best first (size match), each with how many
    mixed-pixel beams of a ramp were cut off it, and why rod-sized runs were refused (cut by
    the field of view, partly hidden)."""
    ranges = scan.ranges_m
    valid = np.isfinite(ranges)
    if background is None:
        foreground = valid
    else:
        bg_sigma = _range_sigma(background, settings)
        margin = np.fmax(
            settings.min_depth_below_background_m,
            settings.background_sigmas * np.sqrt(sigma**2 + bg_sigma**2),
        )
        bg_valid = np.isfinite(background.ranges_m)
        with np.errstate(invalid="ignore"):
            foreground = valid & (~bg_valid | (background.ranges_m - ranges > margin))
    with np.errstate(invalid="ignore"):  # inf - inf where a caller passed inf for no return
        jumps = np.abs(np.diff(ranges)) > _jump_threshold_m(section, sigma, settings)
    split = np.concatenate([[False], jumps])
    unstable = _unstable_beams(scan, settings)
    segments: list[NDArray[np.int64]] = []
    for run in _runs(foreground):
        cuts = np.flatnonzero(split[run[1:]]) + 1
        segments.extend(_trim_unstable(part, unstable) for part in np.split(run, cuts))
    scored, notes = [], []
    last_beam, min_beams = ranges.size - 1, settings.min_beams
    for part in segments:
        if part.size == 0:
            continue
        visible = _visible_fraction(scan, part, background, settings)
        rod_sized = [c for c in _rod_cores(scan, sigma, part, section, settings) if c.size >= min_beams]
        cores = [c for c in rod_sized if _size_mismatch(scan, c, section, settings, visible) is not None]
        narrow_part = _size_mismatch(scan, part, section, settings, visible) is None
        if background is not None and not cores and narrow_part and _in_front(scan, part, sigma):
            # The whole segment is too narrow too: its steps into a wall close behind split
            # the rod's blended flanks off, and the middle that reads the rod is all that is
            # left (a bare-metal 20 mm rod at 0.2 m: 14 of its 46 beams, "no segment matching
            # a rod"). Its core may span what a dark rod's middle may; whether its beams are
            # the rod's own or blends the blend bound then says (``_fit_segment``). Only a segment
            # standing in front of its neighbours, and a middle that is a clean arc of the rod
            # without any blend allowance: a 10 mm steel rod at 0.3 m whose every beam blends
            # with the wall showed a jagged middle 35 mm behind the rod, taken for it 40 mm
            # long. Without a background scan a narrow core may be any thin object (a post
            # hiding the rod).
            middle = settings.min_visible_fraction_far_background
            cores = [
                c
                for c in rod_sized
                if _size_mismatch(scan, c, section, settings, middle) is not None
                and _clean_arc(scan, sigma, c, section, settings)
            ]
            visible = middle if cores else visible
        # Without a rod-sized core the segment is judged whole, so that its fit says why.
        for beams in cores or [part]:
            if beams[0] == 0 or beams[-1] == last_beam:
                if _size_mismatch(scan, beams, section, settings, partial=True) is not None:
                    problem = "is cut by the edge of the field of view; move the rod inward"
                    _note_if_rod(scan, sigma, beams, section, settings, notes, problem)
                continue
            fit = _size_mismatch(scan, beams, section, settings, visible)
            if fit is None:
                continue
            if not _in_front(scan, beams, sigma):
                problem = "is partly hidden behind a nearer object; clear the line of sight"
                _note_if_rod(scan, sigma, beams, section, settings, notes, problem)
                continue
            ramps = min(part.size - beams.size, 2 * settings.max_ramp_beams)
            scored.append((fit, beams, ramps))
    scored.sort(key=lambda item: item[0])
    return [(beams, ramp) for _, beams, ramp in scored], notes


def _clean_arc(
    scan: AveragedScan,
    sigma: FloatArray,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
) -> bool:
    """True when a known-radius fit of the beams has no more misfit than a rod's (the misfit
    test of ``_fit_segment`` without any blend allowance) and every beam lies on the rod's
    half facing the scanner (three jagged blends fit a circle through its far side)."""
    points = scan.points_m()[beams]
    try:
        fit = _fit_centre(points, sigma[beams], section, settings)
    except RodNotFoundError:
        return False
    rms_m = float(np.sqrt(np.mean(fit.residuals_m**2)))
    towards_m = float(np.linalg.norm(fit.centre_uv_m))
    behind_m = points @ (fit.centre_uv_m / towards_m) - towards_m
    noise_m = 3.0 * float(np.median(sigma[beams]))
    return rms_m <= settings.max_rms_radius_fraction * section.radius_m + noise_m and bool(
        np.all(behind_m <= noise_m)
    )


def _visible_fraction(
    scan: AveragedScan, part: NDArray[np.int64], background: AveragedScan | None, settings: ExtractionSettings
) -> float:
    """The least fraction of the rod's angle a candidate in ``part`` must span: lower where the
    background scan shows a surface behind it too far to merge into the rod's echo."""
    if background is None:
        return settings.min_visible_fraction
    behind_m = background.ranges_m[part]
    behind_m = behind_m[np.isfinite(behind_m)]
    if behind_m.size == 0:
        return settings.min_visible_fraction
    depth_m = float(np.median(behind_m)) - float(np.nanmin(scan.ranges_m[part]))
    if depth_m > settings.echo_merge_m:
        return settings.min_visible_fraction_far_background
    return settings.min_visible_fraction


def _rod_cores(
    scan: AveragedScan,
    sigma: FloatArray,
    part: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
) -> list[NDArray[np.int64]]:
    """The runs of beams in a segment that lie on a rod, without the steady mixed-pixel ramps
    that may join it to its background (``_rod_core`` from each of the segment's fronts)."""
    if part.size < settings.min_beams:
        return []
    fronts = _fronts(scan, part, section, settings)
    cores = (_rod_core(scan, sigma, part, front, section, settings) for front in fronts)
    return [_centred_in_halo(scan, part, core, section) for core in cores if core.size]


def _centred_in_halo(
    scan: AveragedScan, part: NDArray[np.int64], core: NDArray[np.int64], section: _Section
) -> NDArray[np.int64]:
    """The core moved to the middle of the rod's halo when that is wider than it by two beams
    or more on a side: the beam's spot is wider than a thin rod, so the beams whose spot only
    touches the rod still read about its range (a bright rod before a far wall: a 10 mm rod
    at 0.5 m spans 19 beams where its silhouette has 9), on both sides alike; a known-radius
    fit of that flat top sits anywhere along it, and the core search picked one end (4-7 mm
    off sideways). The halo: the beams of the segment around the core within a radius of its
    nearest range."""
    ranges = scan.ranges_m[part]
    first, last = int(np.searchsorted(part, core[0])), int(np.searchsorted(part, core[-1]))
    nearest = int(np.searchsorted(part, core[int(np.argmin(scan.ranges_m[core]))]))
    with np.errstate(invalid="ignore"):
        near = ranges <= ranges[nearest] + section.semi_major_m
    halo = next(r for r in _runs(near) if r[0] <= nearest <= r[-1])
    left, right = first - int(halo[0]), int(halo[-1]) - last
    if max(left, right) < 2 or halo.size < core.size:
        return core
    start = int(halo[0]) + (halo.size - core.size) // 2
    return part[start : start + core.size]


def _fronts(
    scan: AveragedScan, part: NDArray[np.int64], section: _Section, settings: ExtractionSettings
) -> list[int]:
    """Positions in ``part`` where a rod's front may be: its nearest beam when the segment is
    no wider than a rod with ramps; else every beam nearest within a rod's width that stands
    at least half a radius in front of the segment a rod-and-ramps' width to either side
    (a rod whose ramps run into a background without a range jump, e.g. a wall close behind)."""
    step = _beam_step_rad(scan)
    ranges = scan.ranges_m[part]
    nearest = int(np.argmin(ranges))
    ramps_rad = 2 * (settings.max_ramp_beams + 1) * step
    width = abs(float(scan.angles_rad[part[-1]] - scan.angles_rad[part[0]]))
    if width <= _widest_rad(float(ranges[nearest]), section, settings) + ramps_rad:
        return [_middle_of_front(scan, part, nearest, section, settings)]
    half_beams = np.ceil(0.5 * _widest_rad_array(ranges, section, settings) / max(step, 1e-9)).astype(int) + 1
    reach = half_beams + settings.max_ramp_beams
    positions = np.arange(part.size)
    left = ranges[np.clip(positions - reach, 0, part.size - 1)]
    right = ranges[np.clip(positions + reach, 0, part.size - 1)]
    depth_m = max(0.5 * section.radius_m, settings.min_jump_m)  # a wall's nearest point rises less
    standing = np.flatnonzero((left - ranges >= depth_m) & (right - ranges >= depth_m))
    fronts = []
    for position in standing:
        half = half_beams[position]
        nearest_around = ranges[max(0, position - half) : position + half + 1].min()
        if ranges[position] <= nearest_around and not (fronts and position - fronts[-1] <= half):
            fronts.append(int(position))
    if not fronts and _flat_halo(ranges, _range_sigma(scan, settings)[part], width, section, settings, step):
        fronts = [nearest]
    return [_middle_of_front(scan, part, front, section, settings) for front in fronts]


def _flat_halo(
    ranges: FloatArray,
    sigma: FloatArray,
    width_rad: float,
    section: _Section,
    settings: ExtractionSettings,
    step_rad: float,
) -> bool:
    """True for a segment that is one flat bright blot: every beam within a semi-major axis
    (the shape tolerance, and the noise of the nearest and farthest of its averaged ranges)
    of the nearest range and no wider than a rod with twice its ramps. A retro-reflective
    rod lights up the spot's faint skirt far beside it, so every beam whose skirt touches it
    reads the rod's range (a 4 mm taped rod at 0.15 m: 13 deg of beams at 152-157 mm; at
    0.1 m 19 deg at 113-119 mm, its extremes 6.4 mm apart where a 4 mm rod and its shape
    tolerance allow 6, which left it "no segment matching a rod"); no beam stands in front of
    the rest, so the search for fronts found none. Its middle is then the front."""
    nearest = float(np.nanmin(ranges))
    reach_rad = 4 * (settings.max_ramp_beams + 1) * step_rad
    tolerance = max(settings.shape_tolerance_fraction * section.radius_m, settings.min_shape_tolerance_m)
    extremes_sigma = 2.0 * settings.edge_residual_sigmas * float(np.nanmedian(sigma))
    flat = float(np.nanmax(ranges)) - nearest <= section.semi_major_m + tolerance + extremes_sigma
    return flat and width_rad <= _widest_rad(nearest, section, settings) + reach_rad


def _middle_of_front(
    scan: AveragedScan,
    part: NDArray[np.int64],
    position: int,
    section: _Section,
    settings: ExtractionSettings,
) -> int:
    """The middle of the run of beams around ``position`` (a nearest beam) that lie as near
    as it, within their noise and the rod's shape tolerance: a rod's front is flat over a few
    beams, and its single nearest beam is off to one side by noise (the rod-core search then
    placed its circle off-centre and kept one flank's ramp: 20 mm off sideways for a 45 mm rod
    at 0.1 m)."""
    ranges = scan.ranges_m[part]
    sigma = _range_sigma(scan, settings)[part]
    tolerance = max(settings.shape_tolerance_fraction * section.radius_m, settings.min_shape_tolerance_m)
    with np.errstate(invalid="ignore"):
        level = ranges <= ranges[position] + 3.0 * np.hypot(sigma, sigma[position]) + tolerance
    run = next(r for r in _runs(level) if r[0] <= position <= r[-1])
    return int(run[run.size // 2])


def _widest_rad(range_m: float, section: _Section, settings: ExtractionSettings) -> float:
    """Widest angle a rod whose nearest point is at ``range_m`` may cover (range error allowed)."""
    return float(_widest_rad_array(np.array([range_m]), section, settings)[0])


def _widest_rad_array(range_m: FloatArray, section: _Section, settings: ExtractionSettings) -> FloatArray:
    """``_widest_rad`` for each of several nearest ranges."""
    nearest_centre_m = range_m + section.radius_m - settings.range_bias_allowance_m
    centre_m = np.fmax(nearest_centre_m, section.widest_semi_axis_m)
    return 2.0 * np.arcsin(np.fmin(1.0, section.widest_semi_axis_m / centre_m))


def _rod_core(
    scan: AveragedScan,
    sigma: FloatArray,
    part: NDArray[np.int64],
    front: int,
    section: _Section,
    settings: ExtractionSettings,
) -> NDArray[np.int64]:
    """The rod's own beams around position ``front`` of a segment that may carry steady
    mixed-pixel ramps on its sides.

    A ramp beam steps from the rod's edge out towards the background and does not lie on the
    rod: its ray passes beside the rod, or its range is well behind the surface. A circle of
    the rod's radius is placed behind the front beam (the rod's front faces the scanner),
    and the run of beams whose rays hit it and whose points lie on its surface (noise, shape
    and range bias allowed) is fitted; repeated until the run is stable. With intensities,
    beams at the background's level beside a bright rod are no rod beams either."""
    step = _beam_step_rad(scan)
    centre_range = float(scan.ranges_m[part[front]]) + section.radius_m
    bearing = float(scan.angles_rad[part[front]])
    centre = centre_range * np.array([np.cos(bearing), np.sin(bearing)])
    points = scan.points_m()[part]
    tolerance = max(settings.shape_tolerance_fraction * section.radius_m, settings.min_shape_tolerance_m)
    run = part[:0]
    for _ in range(4):
        residuals, _ = _residuals(points, centre, section, section.radius_m)
        on_surface = np.abs(residuals) <= settings.edge_residual_sigmas * sigma[part] + tolerance
        spot_sigma_m = float(_spot_sigma_m(np.array([float(np.linalg.norm(centre))]), settings)[0])
        hits = on_surface & _rays_hit(points, centre, section, step, sigma[part], spot_sigma_m)
        hits &= _bright(scan, part, run, settings)
        runs = [r for r in _runs(hits) if r.size]
        if not runs:
            return part[:0]
        best = max(runs, key=lambda r: (r.size, -abs(int(r[0]) + int(r[-1]) - 2 * front)))
        if np.array_equal(part[best], run) or best.size < settings.min_beams:
            return part[best]
        run = part[best]
        # Against rays, as the surface test above: which beams lie on the rod (the spot's
        # centre lies a sagitta further, and the edge beams' ray residuals would cut them).
        solved = _gauss_newton(
            points[best], sigma[part][best], centre, section, settings, free_radius=False, spot=False
        )
        if solved is None:
            return run
        centre = solved[0]
    return run


def _bright(
    scan: AveragedScan, part: NDArray[np.int64], run: NDArray[np.int64], settings: ExtractionSettings
) -> NDArray[np.bool_]:
    """With intensities (SCIP ME) and a rod clearly brighter than what surrounds it (the rest
    of its segment and ``max_ramp_beams`` beyond each end: retro-reflective tape against a
    wall; a mixed pixel returns at the background's level), the beams of ``part`` brighter
    than that level (1.5 times it, or the geometric mean of the two if lower); else every
    beam."""
    everything = np.ones(part.size, dtype=bool)
    if scan.intensities is None or run.size == 0:
        return everything
    intensity = scan.intensities
    reach = settings.max_ramp_beams
    around = np.concatenate([
        np.setdiff1d(part, run),
        np.arange(max(0, part[0] - reach), part[0]),
        np.arange(part[-1] + 1, min(intensity.size, part[-1] + 1 + reach)),
    ])
    with np.errstate(invalid="ignore"):
        rod_level = np.nanmedian(intensity[run])
        rest_level = np.nanmedian(intensity[around]) if around.size else np.nan
    if not (np.isfinite(rod_level) and np.isfinite(rest_level)) or rod_level < 2.0 * max(rest_level, 1.0):
        return everything
    # At the background's level, not merely darker than the rod's middle: the rod's own edge
    # beams meet it at grazing incidence and return less than its front.
    level = min(np.sqrt(rod_level * max(rest_level, 1.0)), 1.5 * max(rest_level, 1.0))
    return ~(intensity[part] < level)


def _rays_hit(
    points: FloatArray,
    centre: FloatArray,
    section: _Section,
    step_rad: float,
    sigma: FloatArray,
    spot_sigma_m: float,
) -> NDArray[np.bool_]:
    """Which beams' rays (through the points, from the scanner) pass through the rod's
    cross-section centred at ``centre`` (squeezed frame, where the ellipse is a circle of the
    radius; rays stay rays), with a beam's spot and three noise sigmas of grace (a thin rod's
    centre is uncertain by a fair part of its radius; the surface test then sorts the beams)."""
    squeezed = section.to_circle(points)
    c = section.to_circle(centre[None, :])[0]
    directions = squeezed / np.linalg.norm(squeezed, axis=1)[:, None]
    miss = np.abs(directions[:, 0] * c[1] - directions[:, 1] * c[0])
    grace = step_rad * float(np.linalg.norm(c)) + 3.0 * float(np.median(sigma)) + 2.0 * spot_sigma_m
    radius = section.radius_m / section.unknown_tilt_cos
    return (miss <= radius + grace) & (directions @ c > 0.0)


def _note_if_rod(
    scan: AveragedScan,
    sigma: FloatArray,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
    notes: list[str],
    problem: str,
) -> None:
    """Record why a refused segment was refused, if it really looks like (part of) a rod."""
    if beams.size < settings.min_beams:
        return
    try:
        _fit_segment(scan, sigma, beams, section, settings)
    except RodNotFoundError:
        return
    notes.append(f"a rod at {float(np.min(scan.ranges_m[beams])):.2f} m {problem}")


def _size_mismatch(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
    visible_fraction: float | None = None,
    *,
    partial: bool = False,
) -> float | None:
    """How far the segment's angular width is from the rod's (in beams); None if implausible.

    It must span ``visible_fraction`` (default ``settings.min_visible_fraction``) of the rod's
    angle; ``partial`` accepts any width up to the rod's (a rod cut by the field of view)."""
    step = _beam_step_rad(scan)
    centre_range = float(np.min(scan.ranges_m[beams])) + section.radius_m
    if centre_range <= section.widest_semi_axis_m:
        return None
    width_min = 2.0 * np.arcsin(min(1.0, section.radius_m / (centre_range + settings.range_bias_allowance_m)))
    width_max = _widest_rad(float(np.min(scan.ranges_m[beams])), section, settings)
    # Each beam stands for one step of angle: n beams cover n steps (a far rod's 3 beams
    # cover 3 steps, not the 2 between their centres).
    width = abs(float(scan.angles_rad[beams[-1]] - scan.angles_rad[beams[0]])) + step
    if visible_fraction is None:
        visible_fraction = settings.min_visible_fraction
    low = 0.0 if partial else visible_fraction * width_min - 2.0 * step
    nearest_m = float(np.min(scan.ranges_m[beams]))
    spot_rad = 4.0 * float(_spot_sigma_m(np.array([nearest_m]), settings)[0]) / max(nearest_m, 1e-3)
    high = width_max + spot_rad + 3.0 * step  # a near rod's echo wins while its spot touches it
    if not low <= width <= high:
        return None
    return abs(width - 0.5 * (width_min + width_max)) / max(step, 1e-9)


def _in_front(scan: AveragedScan, beams: NDArray[np.int64], sigma: FloatArray) -> bool:
    """True unless a neighbour just outside the segment is nearer (the rod would be cut)."""
    nearest = float(np.min(scan.ranges_m[beams]))
    for neighbour in (beams[0] - 1, beams[-1] + 1):
        if 0 <= neighbour < scan.ranges_m.size:
            value = scan.ranges_m[neighbour]
            if np.isfinite(value) and value < nearest - 3.0 * sigma[neighbour]:
                return False
    return True


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


def _fit_segment(
    scan: AveragedScan,
    sigma_all: FloatArray,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
    *,
    ramp_beams: int = 0,
    behind: _Behind | None = None,
) -> RodCentre:
    """Fit one candidate; ``ramp_beams`` mixed pixels were already cut off its sides;
    ``behind``: what lies behind each beam, for the blend of rod and background."""
    if beams.size < settings.min_beams:
        range_m = float(np.min(scan.ranges_m[beams]))
        raise RodNotFoundError(
            f"too few beams on the rod: {beams.size} at {range_m:.2f} m (need {settings.min_beams}); "
            "move the rod closer or use a thicker rod"
        )
    points = scan.points_m()[beams]
    sigma = sigma_all[beams]
    keep, fit = _drop_mixed_edges(points, sigma, section, settings)
    bound_m = np.zeros(beams.size)
    spot_shown = behind is not None and (
        max(ramp_beams, _steady_beams_beside(scan, sigma_all, beams, behind, settings))
        >= settings.spot_shown_ramp_beams
    )
    bound_in_fit = False
    given = scan
    pull_m = taken_m = np.zeros(beams.size)
    tail_depth_m = float("nan")
    if behind is not None and _narrower_than_spot(scan, beams, section, settings) and (
        max(ramp_beams, _steady_beams_beside(scan, sigma_all, beams, behind, settings, over_flips=True))
        >= settings.tail_pull_shown_beams
    ):
        # A surface a pulse length behind pulls each beam long: taken out where the beam's share
        # of its power is low enough for the estimate to hold, the rest left to the warning.
        pull_m, tail_share = _tail_pulls_m(scan, beams, fit.centre_uv_m, section, behind, settings)
        if np.any(pull_m > 0.0):
            tail_depth_m = float(np.median((behind.ranges_m[beams] - scan.ranges_m[beams])[pull_m > 0.0]))
        vouched = tail_share <= settings.max_tail_share_taken_out
        taken_m = np.where(vouched, settings.tail_pull_taken_out * pull_m, 0.0)
        if np.any(taken_m > 0.0):
            ranges = scan.ranges_m.copy()
            ranges[beams] -= taken_m
            scan = replace(scan, ranges_m=ranges)
            points = scan.points_m()[beams]
            keep, fit = _drop_mixed_edges(points, sigma, section, settings)
    if behind is not None and settings.spot_width_at_scanner_m + settings.spot_divergence_rad > 0.0:
        keep, fit, share, bound_m = _drop_blended_edges(
            scan, beams, points, sigma, keep, fit, section, behind, settings
        )
        # Where no beam reads the rod cleanly the echo may be merged and still look like an arc:
        # the covariance takes every beam's whole bound. Where some do, the blended edge beams
        # show as residuals (the misfit test below allows them their bound).
        # Only where the scan shows the spot: without that sign (the ideal scanner's exact rays)
        # the spot model's share is no evidence of a blend.
        bound_in_fit = spot_shown and float(np.min(share[keep])) > settings.doubtful_blend_share_spot_shown
        if bound_in_fit:
            inner, fit = _drop_mixed_edges(points[keep], sigma[keep], section, settings, bound_m[keep])
            keep = keep[inner]
        if float(np.min(share[keep])) > settings.max_blend_share:
            raise RodNotFoundError(_blend_refusal(scan, beams[keep], section, behind, settings))
    used = points[keep]
    fit = _with_arc_bias(scan, beams[keep], used, sigma[keep], bound_m[keep], fit, section, settings)
    fit = _with_edge_doubt(used, sigma[keep], fit, section, settings)
    # Beams narrower than the rod (a dark rod before a far wall shows only its middle; a core
    # whose blended flanks were dropped) give their sideways position from a flat arc too: the
    # profile's symmetry checks it likewise.
    narrow = _size_mismatch(scan, beams[keep], section, settings) is None
    if keep.size <= settings.symmetry_check_max_beams or narrow:
        fit = _with_symmetry_doubt(scan, beams[keep], fit, section)
    if behind is not None:
        fit = _with_uneven_background(scan, beams[keep], fit, behind, settings)
    if spot_shown and not fit.spot and fit.spot_disagreement_m:
        # The rays fit these beams better than the spot on a scanner whose spot shows: the spot
        # model does not describe them (a wall close behind merged into the edge beams, which
        # then read long where the spot says short), and neither fit is vouched for. A 45 mm
        # matte rod at 1.5 m before a wall 0.3 m behind: the ray fit 1.25 mm long against 0.29
        # mm std, the spot fit 0.68 mm nearer. Their difference joins the covariance along the
        # bearing.
        bearing = fit.centre_uv_m / float(np.linalg.norm(fit.centre_uv_m))
        doubt_m2 = fit.spot_disagreement_m**2 * np.outer(bearing, bearing)
        fit = replace(fit, covariance_uv_m2=fit.covariance_uv_m2 + doubt_m2)
    if spot_shown and not bound_in_fit and keep.size <= settings.few_beams_push_max_beams:
        # A fit of few beams takes its range from its edge beams too, whose spots reach past
        # the rod onto the surface close behind: the blend pushes them long, and the fit's one
        # or two spare beams cannot show it (a 45 mm rod at 2-3 m before a wall 0.3 m behind,
        # 3-5 beams: 1.6-3.1 mm long against 0.45-0.7 mm std). Added after the sideways checks,
        # which measure their excess against the covariance before it: added before, it took
        # their share away across and left a 20 mm rod at 0.75 m 5.9 std off, 1.1 before.
        fit = _with_shared_push(used, sigma[keep], np.zeros(keep.size), bound_m[keep], fit, section, settings)
    taken_shift_m, left_shift_m = _pull_shifts_m(
        used, sigma[keep], (taken_m[keep], (pull_m - taken_m)[keep]), section, settings
    )
    doubt_m = settings.tail_pull_doubt * taken_shift_m
    fit = replace(fit, covariance_uv_m2=fit.covariance_uv_m2 + np.outer(doubt_m, doubt_m))
    # The warning judges the whole estimated pull, taken out or not: the correction is only as
    # good as the estimate (the pulse row of the extraction benchmark: judged on what was left,
    # a bit 2.6 mm off went silent).
    pull_shift_m = taken_shift_m + left_shift_m
    rms = float(np.sqrt(np.mean(fit.residuals_m**2)))
    # A blended beam lies off the surface by up to its bound, and the arc's range error by up
    # to its own: that part is no misfit.
    allowed_m = bound_m[keep] + _arc_bias_m(scan, beams[keep], settings)
    misfit = np.fmax(np.abs(fit.residuals_m) - allowed_m, 0.0)
    misfit_rms = float(np.sqrt(np.mean(misfit**2)))
    if misfit_rms > settings.max_rms_radius_fraction * section.radius_m + 3.0 * float(np.median(sigma[keep])):
        refusal = RodNotFoundError(
            f"segment of {keep.size} beams is not a rod of radius {section.radius_m * 1000:.1f} mm "
            f"(fit RMS {rms * 1000:.1f} mm)"
        )
        inner = _without_blended_flanks(beams[keep], bound_m[keep], sigma[keep], section, settings)
        if inner.size == keep.size:
            raise refusal
        try:
            return _fit_segment(
                given, sigma_all, inner, section, settings,
                ramp_beams=ramp_beams + beams.size - inner.size, behind=behind,
            )
        except RodNotFoundError:
            raise refusal from None
    span = _arc_span_deg(used, fit.centre_uv_m, section)
    estimated_radius = None
    if keep.size >= settings.min_beams_for_radius and span >= settings.min_arc_span_for_radius_deg:
        free = _gauss_newton(used, sigma[keep], fit.centre_uv_m, section, settings, free_radius=True)
        if free is not None and 0.0 < free[0][2] < 4.0 * section.radius_m:
            estimated_radius = float(free[0][2])
    dropped = int(beams.size - keep.size) + ramp_beams
    logger.debug(
        "rod centre (%.4f, %.4f) m from %d beams, rms %.2f mm, span %.0f deg, %d edge beams dropped",
        fit.centre_uv_m[0],
        fit.centre_uv_m[1],
        keep.size,
        rms * 1000,
        span,
        dropped,
    )
    warnings: tuple[str, ...] = ()
    if fit.blend_shift_m > settings.warn_blend_std_m:
        warnings = (
            f"the rod's beams blend it with the background behind it: centre uncertain by "
            f"{fit.blend_shift_m * 1000:.0f} mm; a thicker or brighter rod, or a background farther "
            "behind, helps",
        )
    pull_std = float(np.sqrt(pull_shift_m @ np.linalg.solve(fit.covariance_uv_m2, pull_shift_m)))
    if pull_std > settings.warn_tail_pull_std:
        warnings += (
            f"the surface {tail_depth_m:.2f} m behind the rod pulls its echo long through the laser pulse: "
            f"centre about {np.linalg.norm(pull_shift_m) * 1000:.0f} mm long ({pull_std:.1f} std, "
            f"{np.linalg.norm(taken_shift_m) * 1000:.0f} mm of it taken out); "
            f"a background farther than {2.5 * settings.pulse_fwhm_m:g} m behind the rod, or a brighter "
            "rod, helps",
        )
    return RodCentre(
        centre_uv_m=fit.centre_uv_m,
        covariance_uv_m2=fit.covariance_uv_m2,
        warnings=warnings,
        noise_covariance_uv_m2=fit.noise_covariance_uv_m2,
        quality=RodQuality(
            beams_used=int(keep.size),
            fit_rms_m=rms,
            arc_span_deg=span,
            estimated_radius_m=estimated_radius,
            mixed_pixels_dropped=dropped,
        ),
        beam_indices=beams[keep].astype(np.int64),
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
