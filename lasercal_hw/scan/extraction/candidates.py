"""The candidate segments of a scan: beams split by background and range jumps, unstable ends
trimmed, rod cores picked, each judged for size, the field of view's edge and what hides it."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _range_sigma, _runs, _trim_unstable, _unstable_beams
from lasercal_hw.scan.extraction.centre_fit import _fit_centre
from lasercal_hw.scan.extraction.cores import _rod_cores
from lasercal_hw.scan.extraction.results import RodNotFoundError
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.segment_fit import _fit_segment
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.size import _size_mismatch


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


def _in_front(scan: AveragedScan, beams: NDArray[np.int64], sigma: FloatArray) -> bool:
    """True unless a neighbour just outside the segment is nearer (the rod would be cut)."""
    nearest = float(np.min(scan.ranges_m[beams]))
    for neighbour in (beams[0] - 1, beams[-1] + 1):
        if 0 <= neighbour < scan.ranges_m.size:
            value = scan.ranges_m[neighbour]
            if np.isfinite(value) and value < nearest - 3.0 * sigma[neighbour]:
                return False
    return True
