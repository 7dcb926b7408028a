"""The rod's echo blended with the surface behind it: what lies behind each beam, each beam's share
and blend bound, the pull of a surface a pulse length behind, and the blended edge beams and
flanks dropped or refused."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.echo_pull import surface_share, tail_pull_m
from lasercal_hw.scan.extraction.beams import _unstable_beams
from lasercal_hw.scan.extraction.centre_fit import _drop_mixed_edges, _Fit, _fit_centre
from lasercal_hw.scan.extraction.results import RodNotFoundError
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _beside_share, _spot_sigma_m


@dataclass(frozen=True)
class _Behind:
    """What lies behind each beam: its range (m; inf or NaN: nothing) and intensity (None:
    unknown)."""

    ranges_m: FloatArray
    intensities: FloatArray | None


def _behind(scan: AveragedScan, background: AveragedScan | None, settings: ExtractionSettings) -> _Behind:
    """The background scan's view, or without one the farthest reading within
    ``behind_window_beams`` of each beam (the background beside the rod)."""
    if background is not None:
        intensities = background.intensities if scan.intensities is not None else None
        return _Behind(background.ranges_m, intensities)
    ranges = np.where(np.isfinite(scan.ranges_m), scan.ranges_m, -np.inf)
    reach = settings.behind_window_beams
    padded = np.concatenate([np.full(reach, -np.inf), ranges, np.full(reach, -np.inf)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * reach + 1)
    farthest = windows.max(axis=1)
    return _Behind(np.where(np.isfinite(farthest), farthest, np.nan), None)


def _blend(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    centre: FloatArray,
    section: _Section,
    behind: _Behind,
    settings: ExtractionSettings,
    *,
    halo: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Per beam, the background's share of the returned echo and the blend allowance (m);
    ``halo``: with the spot's faint halo (False: its core alone, which tells the edge beams
    apart; the halo adds about the same to every beam).

    The share is the part of the spot passing beside the rod (a gaussian spot across the
    rod's silhouette); with intensities it is weighted by the background's power against
    the beam's (the UTM's intensity grows like the square root of the power).  It counts
    only where the background merges into the rod's echo (less than ``echo_merge_m``
    behind): a surface farther behind returns its own echo, and a beam that reads the rod
    reads the rod alone (a 4 mm rod at 0.1 m before a wall 2.5 m behind was refused as
    "every beam blends it" though each of its 18 beams read the rod's range; its pull on the
    rod's echo peak is ``_tail_pulls_m``'s).  The allowance is the share times the depth
    behind."""
    ranges = scan.ranges_m[beams]
    share = _beside_share(scan, beams, centre, section, settings, halo=halo)
    if behind.intensities is not None and scan.intensities is not None:
        own = np.fmax(scan.intensities[beams], 1.0)
        ratio = np.where(np.isfinite(behind.intensities[beams]), behind.intensities[beams] / own, 1.0)
        share = np.fmin(share * ratio**2, 1.0)
    with np.errstate(invalid="ignore"):
        depth = behind.ranges_m[beams] - ranges
        merged = np.isfinite(depth) & (depth > 0.0) & (depth < settings.echo_merge_m)
    share = np.where(merged, share, 0.0)
    return share, share * np.where(merged, depth, 0.0)


def _tail_pulls_m(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    centre: FloatArray,
    section: _Section,
    behind: _Behind,
    settings: ExtractionSettings,
) -> tuple[FloatArray, FloatArray]:
    """Per beam, how far a surface beyond the merge behind it pulls its reading long and that
    surface's share of the beam's power (``echo_pull``; both 0 where the surface merges,
    nothing lies behind, or either scan has no intensities)."""
    zero = np.zeros(beams.size)
    if behind.intensities is None or scan.intensities is None:
        return zero, zero
    with np.errstate(invalid="ignore"):
        depth = behind.ranges_m[beams] - scan.ranges_m[beams]
        beyond = np.isfinite(depth) & (depth >= settings.echo_merge_m)
    beyond &= np.isfinite(behind.intensities[beams])
    if not np.any(beyond):
        return zero, zero
    depth = np.where(beyond, depth, 0.0)
    share = surface_share(
        _beside_share(scan, beams, centre, section, settings),
        np.fmax(scan.intensities[beams], 1.0),
        np.where(beyond, behind.intensities[beams], 0.0),
        depth,
        settings.pulse_fwhm_m,
    )
    share = np.where(beyond, share, 0.0)
    return np.where(beyond, tail_pull_m(share, depth, settings.pulse_fwhm_m), 0.0), share


def _nearer(points: FloatArray, pull_m: FloatArray) -> FloatArray:
    """The points moved ``pull_m`` nearer the scanner along their beams."""
    return points * (1.0 - pull_m / np.linalg.norm(points, axis=1))[:, None]


def _pull_shifts_m(
    points: FloatArray,
    sigma: FloatArray,
    pulls_m: tuple[FloatArray, ...],
    section: _Section,
    settings: ExtractionSettings,
) -> list[FloatArray]:
    """For each of ``pulls_m``, how far the fitted centre moves when each point's pull is taken
    out of its range (a fit that fails so: about the mean pull along the arc's bearing, towards
    the scanner); the points' own fit is made once, when a shift needs it."""
    base: FloatArray | None = None
    shifts = []
    for pull_m in pulls_m:
        if not np.any(pull_m > 0.0):
            shifts.append(np.zeros(2))
            continue
        try:
            moved = _fit_centre(_nearer(points, pull_m), sigma, section, settings).centre_uv_m
        except RodNotFoundError:
            bearing = np.mean(points, axis=0)
            shifts.append(-float(np.mean(pull_m)) * bearing / float(np.linalg.norm(bearing)))
            continue
        if base is None:
            base = _fit_centre(points, sigma, section, settings).centre_uv_m
        shifts.append(moved - base)
    return shifts


def _drop_blended_edges(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    points: FloatArray,
    sigma: FloatArray,
    keep: NDArray[np.int64],
    fit: _Fit,
    section: _Section,
    behind: _Behind,
    settings: ExtractionSettings,
) -> tuple[NDArray[np.int64], _Fit, FloatArray, FloatArray]:
    """The fit without an edge beam that is more background than rod by its centre (its spot
    passes mostly beside the rod and the surface behind merges into its echo) while the other
    edge beam reads the rod cleanly, refitted until the two edges agree; with every beam's
    blend share and bound by the last centre.

    Such a beam reads well behind the rod's surface, and a known-radius fit bends towards it:
    a dark 45 mm rod at 1 m before a wall 0.3 m behind kept two blends (+14 and +49 mm) on one
    side of its core and none on the other, and its centre sat 13.6 mm sideways (3.1 std);
    a 20 mm rod at 0.3 m was "not a rod" for the same reason. Edges blended alike on both
    sides are left to the blend bounds (the ideal scanner's silhouette edges, which read the
    rod's own surface: dropping them cost its median error 0.40 -> 0.47 mm)."""
    while True:
        share, bound_m = _blend(scan, beams, fit.centre_uv_m, section, behind, settings)
        if keep.size <= settings.min_beams:
            return keep, fit, share, bound_m
        # The edges compared by the spot's core: its halo, much the same on both sides, lifted
        # the clean edge of a dark 45 mm rod at 0.1 m before a bright wall over 5 %, and the
        # blends kept on the other side pulled it 10.9 mm sideways.
        core, _ = _blend(scan, beams, fit.centre_uv_m, section, behind, settings, halo=False)
        first, last = core[keep[0]], core[keep[-1]]
        if max(first, last) <= settings.max_blend_share or min(first, last) > settings.doubtful_blend_share:
            return keep, fit, share, bound_m
        kept = keep[1:] if first > last else keep[:-1]
        if kept.size < settings.min_beams:
            return keep, fit, share, bound_m
        inner, fit = _drop_mixed_edges(points[kept], sigma[kept], section, settings)
        keep = kept[inner]


def _steady_beams_beside(
    scan: AveragedScan,
    sigma: FloatArray,
    beams: NDArray[np.int64],
    behind: _Behind,
    settings: ExtractionSettings,
    *,
    over_flips: bool = False,
) -> int:
    """How many beams beside the rod (both sides, up to ``max_ramp_beams`` each) read
    steadily between its edge and the surface behind: the beam's spot straddling the two
    (a far rod's ramps, split off its segment by their range jumps). An exact ray reads one
    surface or flips between them (unstable: ``_unstable_beams``), so it counts none.
    ``over_flips``: the count steps over flipping beams (a polished bit's flanks flip between
    it and the wall, and the steady beams beyond read the wall pulled towards it)."""
    ranges = scan.ranges_m
    unstable = _unstable_beams(scan, settings)
    count = 0
    for edge, step in ((int(beams[0]), -1), (int(beams[-1]), 1)):
        i = edge + step
        while 0 <= i < ranges.size and abs(i - edge) <= settings.max_ramp_beams:
            if unstable[i]:
                if not over_flips:
                    break
                i += step
                continue
            margin = max(settings.min_depth_below_background_m, settings.background_sigmas * float(sigma[i]))
            if not ranges[edge] < ranges[i] < behind.ranges_m[i] - margin:  # NaN: False
                break
            count += 1
            i += step
    return count


def _without_blended_flanks(
    beams: NDArray[np.int64],
    bound_m: FloatArray,
    sigma: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
) -> NDArray[np.int64]:
    """The beams without the runs at either end whose blend bound exceeds what a beam of the
    rod may lie off its surface (its noise and the shape tolerance, as in ``_rod_core``): a
    segment whose flanks merged with a wall close behind on both sides, which the fit could
    not take as a rod (20 mm painted rods at 0.2-0.3 m before a wall 0.3 m behind: "not a
    rod, fit RMS 7-8 mm"), is tried again on its middle (fewer than ``min_beams``: unchanged)."""
    tolerance = settings.shape_tolerance_m(section.radius_m)
    clean = np.flatnonzero(bound_m <= settings.edge_residual_sigmas * sigma + tolerance)
    if clean.size < settings.min_beams:
        return beams
    return beams[clean[0] : clean[-1] + 1]


def _blend_refusal(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    section: _Section,
    behind: _Behind,
    settings: ExtractionSettings,
) -> str:
    """Why a rod whose every beam is mostly background is refused."""
    range_m = float(np.min(scan.ranges_m[beams]))
    depth_m = float(np.nanmedian(behind.ranges_m[beams])) - range_m
    spot_mm = 4000.0 * float(_spot_sigma_m(np.array([range_m]), settings)[0])
    return (
        f"every beam on the rod at {range_m:.2f} m blends it with the surface {depth_m:.2f} m behind it "
        f"(a {2000 * section.radius_m:.0f} mm rod against the beam's {spot_mm:.0f} mm spot): no reading is "
        f"the rod's own; use a thicker or retro-reflective rod, or clear the background to more than "
        f"{settings.echo_merge_m:g} m behind the rod"
    )
