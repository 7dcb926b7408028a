"""One candidate segment fitted as the rod: mixed, blended and pulled beams handled, doubts added,
the misfit judged, the ``RodCentre`` with its quality and warnings."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.blend import (
    _Behind,
    _blend_refusal,
    _drop_blended_edges,
    _pull_shifts_m,
    _steady_beams_beside,
    _tail_pulls_m,
    _without_blended_flanks,
)
from lasercal_hw.scan.extraction.centre_fit import _arc_span_deg, _drop_mixed_edges
from lasercal_hw.scan.extraction.doubts import (
    _arc_bias_m,
    _with_arc_bias,
    _with_edge_doubt,
    _with_shared_push,
    _with_symmetry_doubt,
    _with_uneven_background,
)
from lasercal_hw.scan.extraction.fit import _gauss_newton
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError, RodQuality
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.size import _size_mismatch
from lasercal_hw.scan.extraction.spot import _narrower_than_spot

logger = logging.getLogger(__name__)


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
