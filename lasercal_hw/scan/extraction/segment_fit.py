"""One candidate segment fitted as the rod, by steps: too few beams refused, mixed edges dropped,
a tail pull taken out, the blend of rod and background bound in the fit, doubts added, the
misfit judged (retried without blended flanks), the ``RodCentre`` with its quality and
warnings."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

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
from lasercal_hw.scan.extraction.centre_fit import _arc_span_deg, _drop_mixed_edges, _Fit
from lasercal_hw.scan.extraction.doubts import (
    _arc_bias_m,
    _with_arc_bias,
    _with_edge_doubt,
    _with_shared_push,
    _with_spot_disagreement,
    _with_symmetry_doubt,
    _with_tail_pull_doubt,
    _with_uneven_background,
)
from lasercal_hw.scan.extraction.fit import _gauss_newton
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError, RodQuality
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.size import _size_mismatch
from lasercal_hw.scan.extraction.spot import _narrower_than_spot

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Segment:
    """A candidate between the steps of its fit: the scan as fitted (less any tail pull taken
    out), the candidate's beams with their points and range sigmas, which of them the fit
    keeps (indices into ``beams``) and the fit, and per beam its blend bound and its tail pull
    (estimated, and taken out), with the depth of the surface that pulls."""

    scan: AveragedScan
    beams: NDArray[np.int64]
    points: FloatArray
    sigma: FloatArray
    keep: NDArray[np.int64]
    fit: _Fit
    bound_m: FloatArray
    pull_m: FloatArray
    taken_m: FloatArray
    tail_depth_m: float = float("nan")
    #: The blend bound is in the fit's sigmas (``_with_blend_bound``).
    bound_in_fit: bool = False

    @property
    def kept(self) -> NDArray[np.int64]:
        """The scan's indices of the kept beams."""
        return self.beams[self.keep]

    @property
    def used(self) -> FloatArray:
        """The kept beams' points."""
        return self.points[self.keep]

    @property
    def rms_m(self) -> float:
        """The fit's RMS residual."""
        return float(np.sqrt(np.mean(self.fit.residuals_m**2)))


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
    ``behind``: what lies behind each beam, for the blend of rod and background. A misfit is
    given a second chance without the blended flanks, whose beams then count as ramp."""
    _refuse_too_few_beams(scan, beams, settings)
    segment = _with_mixed_edges_dropped(scan, sigma_all[beams], beams, section, settings)
    spot_shown = False
    if behind is not None:
        spot_shown = (
            max(ramp_beams, _steady_beams_beside(scan, sigma_all, beams, behind, settings))
            >= settings.spot_shown_ramp_beams
        )
        segment = _without_tail_pull(segment, sigma_all, section, behind, settings, ramp_beams)
        if settings.spot_width_at_scanner_m + settings.spot_divergence_rad > 0.0:
            segment = _with_blend_bound(segment, section, behind, settings, spot_shown)
    segment = replace(segment, fit=_with_doubts(segment, section, behind, settings, spot_shown))
    keep = segment.keep
    refusal = _misfit_refusal(segment, section, settings)
    if refusal is not None:
        inner = _without_blended_flanks(
            segment.kept, segment.bound_m[keep], segment.sigma[keep], section, settings
        )
        if inner.size == keep.size:
            raise refusal
        try:
            return _fit_segment(
                scan,
                sigma_all,
                inner,
                section,
                settings,
                ramp_beams=ramp_beams + beams.size - inner.size,
                behind=behind,
            )
        except RodNotFoundError:
            raise refusal from None
    taken_shift_m, pull_shift_m = _tail_pull_shifts_m(segment, section, settings)
    segment = replace(segment, fit=_with_tail_pull_doubt(segment.fit, taken_shift_m, settings))
    # The warning judges the whole estimated pull, taken out or not: the correction is only as
    # good as the estimate (the pulse row of the extraction benchmark: judged on what was left,
    # a bit 2.6 mm off went silent).
    warnings = _warnings(segment, taken_shift_m, pull_shift_m, settings)
    return _rod_centre(segment, ramp_beams, warnings, section, settings)


def _refuse_too_few_beams(scan: AveragedScan, beams: NDArray[np.int64], settings: ExtractionSettings) -> None:
    """Raise ``RodNotFoundError`` where the candidate has fewer than ``min_beams`` beams."""
    if beams.size < settings.min_beams:
        range_m = float(np.min(scan.ranges_m[beams]))
        raise RodNotFoundError(
            f"too few beams on the rod: {beams.size} at {range_m:.2f} m (need {settings.min_beams}); "
            "move the rod closer or use a thicker rod"
        )


def _with_mixed_edges_dropped(
    scan: AveragedScan,
    sigma: FloatArray,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
) -> _Segment:
    """The candidate in ``scan`` fitted with its mixed edge beams dropped (no blend bound, no
    pull)."""
    points = scan.points_m()[beams]
    keep, fit = _drop_mixed_edges(points, sigma, section, settings)
    none_m = np.zeros(beams.size)
    return _Segment(scan, beams, points, sigma, keep, fit, bound_m=none_m, pull_m=none_m, taken_m=none_m)


def _without_tail_pull(
    segment: _Segment,
    sigma_all: FloatArray,
    section: _Section,
    behind: _Behind,
    settings: ExtractionSettings,
    ramp_beams: int,
) -> _Segment:
    """The segment with the pull of a surface a pulse length behind estimated on each beam and
    taken out where the beam's share of its power is low enough for the estimate to hold (the
    rest left to the warning), refitted if any was; unchanged where the rod is not narrower than
    the spot or too few steady beams beside it show the pull."""
    scan, beams = segment.scan, segment.beams
    shown = _narrower_than_spot(scan, beams, section, settings) and (
        max(ramp_beams, _steady_beams_beside(scan, sigma_all, beams, behind, settings, over_flips=True))
        >= settings.tail_pull_shown_beams
    )
    if not shown:
        return segment
    pull_m, tail_share = _tail_pulls_m(scan, beams, segment.fit.centre_uv_m, section, behind, settings)
    tail_depth_m = float("nan")
    if np.any(pull_m > 0.0):
        tail_depth_m = float(np.median((behind.ranges_m[beams] - scan.ranges_m[beams])[pull_m > 0.0]))
    vouched = tail_share <= settings.max_tail_share_taken_out
    taken_m = np.where(vouched, settings.tail_pull_taken_out * pull_m, 0.0)
    if np.any(taken_m > 0.0):
        ranges = scan.ranges_m.copy()
        ranges[beams] -= taken_m
        segment = _with_mixed_edges_dropped(
            replace(scan, ranges_m=ranges), segment.sigma, beams, section, settings
        )
    return replace(segment, pull_m=pull_m, taken_m=taken_m, tail_depth_m=tail_depth_m)


def _with_blend_bound(
    segment: _Segment, section: _Section, behind: _Behind, settings: ExtractionSettings, spot_shown: bool
) -> _Segment:
    """The segment with each beam's bound on its blend of rod and background, its blended edge
    beams dropped, and the bound in the fit's sigmas where no kept beam reads the rod cleanly
    and the scan shows the spot; ``RodNotFoundError`` where even the cleanest kept beam is more
    than ``max_blend_share`` background.

    Where no beam reads the rod cleanly the echo may be merged and still look like an arc: the
    covariance takes every beam's whole bound. Where some do, the blended edge beams show as
    residuals (the misfit test allows them their bound). Only where the scan shows the spot:
    without that sign (the ideal scanner's exact rays) the spot model's share is no evidence of
    a blend."""
    points, sigma = segment.points, segment.sigma
    keep, fit, share, bound_m = _drop_blended_edges(
        segment.scan, segment.beams, points, sigma, segment.keep, segment.fit, section, behind, settings
    )
    bound_in_fit = spot_shown and float(np.min(share[keep])) > settings.doubtful_blend_share_spot_shown
    if bound_in_fit:
        inner, fit = _drop_mixed_edges(points[keep], sigma[keep], section, settings, bound_m[keep])
        keep = keep[inner]
    if float(np.min(share[keep])) > settings.max_blend_share:
        raise RodNotFoundError(_blend_refusal(segment.scan, segment.beams[keep], section, behind, settings))
    return replace(segment, keep=keep, fit=fit, bound_m=bound_m, bound_in_fit=bound_in_fit)


def _with_doubts(
    segment: _Segment,
    section: _Section,
    behind: _Behind | None,
    settings: ExtractionSettings,
    spot_shown: bool,
) -> _Fit:
    """The segment's fit with what its covariance adds beyond the fit's own (``doubts``), in
    this order: the range error across the arc, the edge check, the profile's symmetry (few or
    narrow beams), an uneven background, and where the scan shows the spot, the spot and ray
    fits' disagreement and a few beams' shared push."""
    scan, kept, used = segment.scan, segment.kept, segment.used
    sigma, bound_m = segment.sigma[segment.keep], segment.bound_m[segment.keep]
    fit = _with_arc_bias(scan, kept, used, sigma, bound_m, segment.fit, section, settings)
    fit = _with_edge_doubt(used, sigma, fit, section, settings)
    # Beams narrower than the rod (a dark rod before a far wall shows only its middle; a core
    # whose blended flanks were dropped) give their sideways position from a flat arc too: the
    # profile's symmetry checks it likewise.
    narrow = _size_mismatch(scan, kept, section, settings) is None
    if kept.size <= settings.symmetry_check_max_beams or narrow:
        fit = _with_symmetry_doubt(scan, kept, fit, section)
    if behind is not None:
        fit = _with_uneven_background(scan, kept, fit, behind, settings)
    if spot_shown:
        fit = _with_spot_disagreement(fit)
    if spot_shown and not segment.bound_in_fit and kept.size <= settings.few_beams_push_max_beams:
        # A fit of few beams takes its range from its edge beams too, whose spots reach past
        # the rod onto the surface close behind: the blend pushes them long, and the fit's one
        # or two spare beams cannot show it (a 45 mm rod at 2-3 m before a wall 0.3 m behind,
        # 3-5 beams: 1.6-3.1 mm long against 0.45-0.7 mm std). Added after the sideways checks,
        # which measure their excess against the covariance before it: added before, it took
        # their share away across and left a 20 mm rod at 0.75 m 5.9 std off, 1.1 before.
        fit = _with_shared_push(used, sigma, np.zeros(kept.size), bound_m, fit, section, settings)
    return fit


def _tail_pull_shifts_m(
    segment: _Segment, section: _Section, settings: ExtractionSettings
) -> tuple[FloatArray, FloatArray]:
    """How far the centre moves with the tail pull taken out of the kept beams' ranges, and
    with the whole estimated pull (taken out and left)."""
    keep = segment.keep
    taken_shift_m, left_shift_m = _pull_shifts_m(
        segment.used,
        segment.sigma[keep],
        (segment.taken_m[keep], (segment.pull_m - segment.taken_m)[keep]),
        section,
        settings,
    )
    return taken_shift_m, taken_shift_m + left_shift_m


def _misfit_refusal(
    segment: _Segment, section: _Section, settings: ExtractionSettings
) -> RodNotFoundError | None:
    """The refusal where the kept beams miss the section by more than ``max_rms_radius_fraction``
    of its radius plus three of their median sigma (RMS over the beams), None where they do not.
    A blended beam lies off the surface by up to its bound, and the arc's range error by up to
    its own: that part is no misfit."""
    allowed_m = segment.bound_m[segment.keep] + _arc_bias_m(segment.scan, segment.kept, settings)
    misfit = np.fmax(np.abs(segment.fit.residuals_m) - allowed_m, 0.0)
    misfit_rms = float(np.sqrt(np.mean(misfit**2)))
    limit_m = settings.max_rms_radius_fraction * section.radius_m + 3.0 * float(
        np.median(segment.sigma[segment.keep])
    )
    if misfit_rms > limit_m:
        return RodNotFoundError(
            f"segment of {segment.keep.size} beams is not a rod of radius {section.radius_m * 1000:.1f} mm "
            f"(fit RMS {segment.rms_m * 1000:.1f} mm)"
        )
    return None


def _warnings(
    segment: _Segment, taken_shift_m: FloatArray, pull_shift_m: FloatArray, settings: ExtractionSettings
) -> tuple[str, ...]:
    """The centre's warnings: a blend with the background beyond ``warn_blend_std_m``, and a
    tail pull (``pull_shift_m``, of which ``taken_shift_m`` was taken out) beyond
    ``warn_tail_pull_std`` of the centre's covariance."""
    fit = segment.fit
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
            f"the surface {segment.tail_depth_m:.2f} m behind the rod pulls its echo long through the laser "
            f"pulse: centre about {np.linalg.norm(pull_shift_m) * 1000:.0f} mm long ({pull_std:.1f} std, "
            f"{np.linalg.norm(taken_shift_m) * 1000:.0f} mm of it taken out); "
            f"a background farther than {2.5 * settings.pulse_fwhm_m:g} m behind the rod, or a brighter "
            "rod, helps",
        )
    return warnings


def _free_radius_m(
    segment: _Segment, span_deg: float, section: _Section, settings: ExtractionSettings
) -> float | None:
    """The radius a free-radius fit gives the kept beams where they are enough
    (``min_beams_for_radius``, ``min_arc_span_for_radius_deg``) and it is plausible (positive,
    under four times the section's); None otherwise."""
    if not (
        segment.keep.size >= settings.min_beams_for_radius
        and span_deg >= settings.min_arc_span_for_radius_deg
    ):
        return None
    free = _gauss_newton(
        segment.used,
        segment.sigma[segment.keep],
        segment.fit.centre_uv_m,
        section,
        settings,
        free_radius=True,
    )
    if free is not None and 0.0 < free[0][2] < 4.0 * section.radius_m:
        return float(free[0][2])
    return None


def _rod_centre(
    segment: _Segment,
    ramp_beams: int,
    warnings: tuple[str, ...],
    section: _Section,
    settings: ExtractionSettings,
) -> RodCentre:
    """The segment's ``RodCentre``: its fit, ``warnings`` and quality (beams used, RMS, arc span,
    free radius, mixed pixels dropped with the ``ramp_beams`` cut off before)."""
    fit, keep = segment.fit, segment.keep
    span = _arc_span_deg(segment.used, fit.centre_uv_m, section)
    dropped = int(segment.beams.size - keep.size) + ramp_beams
    logger.debug(
        "rod centre (%.4f, %.4f) m from %d beams, rms %.2f mm, span %.0f deg, %d edge beams dropped",
        fit.centre_uv_m[0],
        fit.centre_uv_m[1],
        keep.size,
        segment.rms_m * 1000,
        span,
        dropped,
    )
    return RodCentre(
        centre_uv_m=fit.centre_uv_m,
        covariance_uv_m2=fit.covariance_uv_m2,
        warnings=warnings,
        noise_covariance_uv_m2=fit.noise_covariance_uv_m2,
        quality=RodQuality(
            beams_used=int(keep.size),
            fit_rms_m=segment.rms_m,
            arc_span_deg=span,
            estimated_radius_m=_free_radius_m(segment, span, section, settings),
            mixed_pixels_dropped=dropped,
        ),
        beam_indices=segment.kept.astype(np.int64),
    )
