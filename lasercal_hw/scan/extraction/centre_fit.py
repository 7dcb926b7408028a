"""A rod's centre from one segment's points: the paper's seed, the ray fit, the spot fit along the
bearing, the covariance; edge beams lying behind the fitted surface dropped."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.extraction.covariance import (
    _along_and_across_m2,
    _centre_shift,
    _fit_covariances_m2,
    _range_error_mismatch,
    _unknown_tilt_variance_m2,
)
from lasercal_hw.scan.extraction.fit import _fit_residuals, _gauss_newton, _rays, _residual_sigma
from lasercal_hw.scan.extraction.results import RodNotFoundError
from lasercal_hw.scan.extraction.section import _Section, _unit_axis
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot_fit import _along_the_spot


def seed_centre_pi4(
    points_m: FloatArray, radius_m: float, axis_in_scanner: FloatArray | None = None
) -> FloatArray:
    """The paper's estimate: mean of the arc points moved ``R*pi/4`` away from the scanner.

    For a tilted rod the correction is applied where the ellipse is a circle (the plane
    squeezed along the major axis) and mapped back.
    """
    section = _Section(_unit_axis(axis_in_scanner), radius_m)
    squeezed = section.to_circle(np.asarray(points_m, dtype=float))
    mean = squeezed.mean(axis=0)
    seed = mean + radius_m * np.pi / 4.0 * mean / np.linalg.norm(mean)
    return section.from_circle(seed[None, :])[0]


@dataclass(frozen=True)
class _Fit:
    centre_uv_m: FloatArray
    covariance_uv_m2: FloatArray
    residuals_m: FloatArray
    whitened: FloatArray
    blend_shift_m: float = 0.0
    noise_covariance_uv_m2: FloatArray | None = None
    #: The residuals are against the beam's spot, not rays (``_along_the_spot``).
    spot: bool = False
    #: Where the ray fit was kept: how far along the bearing the fit against the spot put the
    #: centre from it (m; 0 where there was none).
    spot_disagreement_m: float = 0.0


def _fit_centre(
    points: FloatArray,
    sigma: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
    blend_m: FloatArray | None = None,
) -> _Fit:
    """Fit the centre to the points; ``blend_m``: each beam's blend allowance (m, along the
    beam, one-sided: shared by neighbouring beams), which joins the covariance whole."""
    seed = seed_centre_pi4(points, section.radius_m, section.axis)
    solved = _gauss_newton(points, sigma, seed, section, settings, free_radius=False, spot=False)
    limit = 2.0 * section.semi_major_m + 0.01
    if solved is None or float(np.linalg.norm(solved[0] - seed)) > limit:
        raise RodNotFoundError(
            f"circle fit diverged from its seed ({seed[0]:.3f}, {seed[1]:.3f}) m; the segment is not a "
            "clean arc (clutter touching the rod?)"
        )
    centre, normal, ray_whitened = solved
    if float(np.linalg.norm(centre)) <= float(np.min(np.linalg.norm(points, axis=1))):
        raise RodNotFoundError(
            "fitted centre lies in front of the arc (fit diverged); the segment is not a rod"
        )
    ray_noise, ray_covariance = _fit_covariances_m2(points, sigma, centre, normal, section, _rays(settings))
    spot_centre, spot_normal, spot, spot_along_m, choice_m2 = _along_the_spot(
        points, sigma, centre, normal, ray_whitened, section, settings
    )
    model = settings if spot else _rays(settings)
    noise_covariance, covariance = ray_noise, ray_covariance
    if spot:
        # Each direction keeps the covariance of the fit it came from (what that fit's residuals
        # leave unexplained included): along the bearing the spot's, across it the rays'.
        spot_noise, spot_covariance = _fit_covariances_m2(
            points, sigma, spot_centre, spot_normal, section, settings
        )
        bearing = centre / float(np.linalg.norm(centre))
        # The spot's power weighting is a diffuse surface's; a glossy or retro-reflective one
        # weights the spot's middle more (``spot_model_doubt`` of the correction).
        doubt_m = settings.spot_model_doubt * float(bearing @ (spot_centre - centre))
        # No tighter along the bearing than the ray fit: what its residuals showed beyond the
        # noise was the spot's blur, which the spot fit explains, and what else the arc carries
        # (range walk across a bright rod, blends), which it may not.
        along_m2 = float(bearing @ spot_covariance @ bearing) + doubt_m**2
        missing_m2 = max(float(bearing @ ray_covariance @ bearing) - along_m2, 0.0)
        spot_covariance = spot_covariance + (doubt_m**2 + missing_m2) * np.outer(bearing, bearing)
        noise_covariance = _along_and_across_m2(spot_noise, ray_noise, bearing)
        covariance = _along_and_across_m2(spot_covariance, ray_covariance, bearing)
        centre, normal = spot_centre, spot_normal
    # Which of the two fits this dwell keeps is drawn anew by the next (``_along_the_spot``):
    # the covariance holds their difference already (``spot_model_doubt``, or the disagreement
    # where the rays win), the noise did not.
    along = centre / float(np.linalg.norm(centre))
    noise_covariance = noise_covariance + choice_m2 * np.outer(along, along)
    residuals, normals, _ = _fit_residuals(points, centre, section, model)
    residual_sigma = _residual_sigma(points, sigma, normals, section.radius_m, model)
    whitened = residuals / residual_sigma
    covariance = covariance + np.eye(2) * _unknown_tilt_variance_m2(section, settings)
    mismatch = _range_error_mismatch(points, centre, normals, residual_sigma, normal)
    covariance += np.outer(mismatch, mismatch) * settings.typical_range_error_m**2
    blend_shift = np.zeros(2)
    if blend_m is not None:
        blend_shift = _centre_shift(points, normals, residual_sigma, normal, blend_m)
        covariance += np.outer(blend_shift, blend_shift)
    blend_m = float(np.linalg.norm(blend_shift))
    disagreement_m = 0.0 if spot else spot_along_m
    return _Fit(centre, covariance, residuals, whitened, blend_m, noise_covariance, spot, disagreement_m)


def _drop_mixed_edges(
    points: FloatArray,
    sigma: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
    blend_m: FloatArray | None = None,
) -> tuple[NDArray[np.int64], _Fit]:
    """Fit, then drop edge beams lying significantly behind the fitted surface; refit."""
    keep = np.arange(points.shape[0])
    fit = _fit_centre(points, sigma, section, settings, blend_m)
    dropped = {"first": 0, "last": 0}
    while keep.size > settings.min_beams:
        candidates = []
        for side, pos in (("first", 0), ("last", keep.size - 1)):
            if dropped[side] < settings.max_edge_drops_per_side:
                behind = fit.residuals_m[pos] > 0.0
                if behind and fit.whitened[pos] > settings.edge_residual_sigmas:
                    candidates.append((fit.whitened[pos], side, pos))
        if not candidates:
            break
        _, side, pos = max(candidates)
        dropped[side] += 1
        keep = np.delete(keep, pos)
        kept_blend = None if blend_m is None else blend_m[keep]
        fit = _fit_centre(points[keep], sigma[keep], section, settings, kept_blend)
    return keep, fit


def _arc_span_deg(points: FloatArray, centre: FloatArray, section: _Section) -> float:
    """Angle the used points cover as seen from the centre (in the squeezed, circular frame)."""
    squeezed = section.to_circle(points)
    c = section.to_circle(centre[None, :])[0]
    towards_scanner = np.arctan2(-c[1], -c[0])
    rel = squeezed - c
    angles = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - towards_scanner)))
    return float(np.degrees(angles.max() - angles.min()))
