"""The rod's own beams in a segment: its fronts, the core around each without the steady
mixed-pixel ramps beside it, centred in the halo of a rod thinner than the spot."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _beam_step_rad, _range_sigma, _runs
from lasercal_hw.scan.extraction.fit import _gauss_newton, _residuals
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.size import _widest_rad, _widest_rad_array
from lasercal_hw.scan.extraction.spot import _spot_sigma_m


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
    tolerance = settings.shape_tolerance_m(section.radius_m)
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
    tolerance = settings.shape_tolerance_m(section.radius_m)
    with np.errstate(invalid="ignore"):
        level = ranges <= ranges[position] + 3.0 * np.hypot(sigma, sigma[position]) + tolerance
    run = next(r for r in _runs(level) if r[0] <= position <= r[-1])
    return int(run[run.size // 2])


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
    tolerance = settings.shape_tolerance_m(section.radius_m)
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
