"""The centre along the bearing from a fit against the beam's spot, or the ray fit kept, and the
variance of that choice from dwell to dwell."""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.extraction.fit import _fit_residuals, _gauss_newton, _residual_sigma
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _along_the_spot(
    points: FloatArray,
    sigma: FloatArray,
    centre: FloatArray,
    normal: FloatArray,
    ray_whitened: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
) -> tuple[FloatArray, FloatArray, bool, float, float]:
    """The ray fit's centre and normal matrix (``ray_whitened``: its whitened residuals) with
    their part along the bearing taken from a fit against what each beam's spot returns
    (``_fit_residuals``), started there, unless the rays fit the beams better; whether the
    spot's was taken; how far along the bearing the spot fit lies from the ray fit (m; 0
    where it failed); and the variance along the bearing (m^2) of that choice from dwell to
    dwell (``_choice_variance_m2``).

    Along the bearing the spot's blur is one-sided: on a rod's curved front the spot's sides
    meet the surface deeper than its middle, so the middle beams read long and the silhouette's
    edge beams short, and a ray fit's centre lay long by more than its std (a 45 mm matte rod at
    1.5 m: 1.3 mm against 0.29 mm; docs/lab/extraction-log.md, "The fit against the spot"). Across
    the bearing the blur is
    symmetric about the rod and the ray fit's edges pin the centre well; the spot model's own
    sideways hold, the ranges' curvature under the blur, is weak where the rod is not much
    wider than the spot (a 10 mm rod at 0.3 m wandered 16 mm sideways), so the ray fit keeps it.
    The spot fit's centre is moved sideways to the ray fit's and along by what its normal
    matrix couples to that move; the covariance is the spot fit's along the bearing given the
    side, the ray fit's across it, and their coupling. A spot fit that wanders sideways past the
    rod's semi-axis is fitted again along the bearing only (``_spot_fit_along``); a spot of no
    width, or a spot fit that fails both ways, leaves the ray fit.

    A scanner whose beams are rays (the ideal fake's exact ray casts) shows it: its edge beams
    read the grazing surface, where a spot's read several millimetres short, and the rays fit
    with the smaller chi-square; the ray fit is kept then (each beam's noise is the same in both
    fits, so their chi-squares compare)."""
    spot_shows = settings.spot_width_at_scanner_m + settings.spot_divergence_rad > 0.0
    if not (settings.fit_along_the_spot and spot_shows):
        return centre, normal, False, 0.0, 0.0
    bearing = centre / float(np.linalg.norm(centre))
    solved = _gauss_newton(points, sigma, centre, section, settings, free_radius=False)
    if solved is None or float(np.linalg.norm(solved[0] - centre)) > section.semi_major_m:
        solved = _spot_fit_along(points, sigma, centre, bearing, section, settings)
    if solved is None or abs(float(bearing @ (solved[0] - centre))) > section.semi_major_m:
        return centre, normal, False, 0.0, 0.0
    along_m = float(bearing @ (solved[0] - centre))
    choice_m2 = _choice_variance_m2(ray_whitened, solved[2], along_m)
    if float(solved[2] @ solved[2]) > float(ray_whitened @ ray_whitened):
        return centre, normal, False, along_m, choice_m2
    side = np.array([-bearing[1], bearing[0]])
    spot_normal = solved[1]
    information = float(bearing @ spot_normal @ bearing)
    try:
        side_m2 = float(side @ np.linalg.inv(normal) @ side)
    except np.linalg.LinAlgError:
        return centre, normal, False, along_m, choice_m2
    if not information > 0.0:
        return centre, normal, False, along_m, choice_m2
    # The spot fit's centre moved sideways to the ray fit's, and along by what that move
    # costs it (its normal matrix's coupling); the ray fit's sideways variance carried along.
    coupling = float(bearing @ spot_normal @ side) / information
    sideways_m = float(side @ (centre - solved[0]))
    moved = solved[0] + sideways_m * (side - coupling * bearing)
    basis = np.column_stack([bearing, side])
    covariance = basis @ np.array([
        [1.0 / information + coupling**2 * side_m2, -coupling * side_m2],
        [-coupling * side_m2, side_m2],
    ]) @ basis.T
    return moved, np.linalg.inv(covariance), True, along_m, choice_m2


def _spot_fit_along(
    points: FloatArray,
    sigma: FloatArray,
    centre: FloatArray,
    bearing: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """The spot fit moved along ``bearing`` only, from the ray fit's ``centre``: (centre,
    normal matrix (2, 2) there, whitened residuals) as ``_gauss_newton`` gives, or None.

    Where the rod is not much wider than the spot, the free spot fit wanders sideways (a 10 mm
    rod at 0.3-0.6 m: 6-60 mm, where the ray fit's edges hold the side to a millimetre) and was
    refused, leaving the ray fit's range about 1 mm long; whether it wandered changed from dwell
    to dwell at one pose, and the centre with it. The side is the ray fit's in either case."""
    t_m = 0.0
    for _ in range(settings.max_iterations):
        residuals, normals, jac = _fit_residuals(points, centre + t_m * bearing, section, settings)
        res_sigma = _residual_sigma(points, sigma, normals, section.radius_m, settings)
        slope = (jac @ bearing) / res_sigma
        information = float(slope @ slope)
        if not information > 0.0:
            return None
        step_m = -float(slope @ (residuals / res_sigma)) / information
        t_m += step_m
        if abs(step_m) < 1e-10:
            break
    if not np.isfinite(t_m):
        return None
    moved = centre + t_m * bearing
    residuals, normals, jac = _fit_residuals(points, moved, section, settings)
    res_sigma = _residual_sigma(points, sigma, normals, section.radius_m, settings)
    whitened_jac = jac / res_sigma[:, None]
    return moved, whitened_jac.T @ whitened_jac, residuals / res_sigma


def _choice_variance_m2(ray_whitened: FloatArray, spot_whitened: FloatArray, along_m: float) -> float:
    """Variance (m^2) along the bearing of the choice between the ray fit and the spot fit
    ``along_m`` from it, as another dwell at the same pose makes it anew.

    The spot's is taken when its chi-square is not the larger; a dwell's noise (whitened: unit
    variance per beam) moves the two chi-squares' gap by twice its projection on the
    difference of the two fits' whitened residuals, so the spot is taken with probability
    ``p = Phi(-gap / (2 |w_spot - w_ray|))``, and the centre along the bearing is a two-point
    draw ``along_m`` apart: variance ``p (1 - p) along_m^2``. A 10 mm rod at 0.3-0.6 m (the
    drill job): the fits 0.9-1.5 mm apart, the choice changing from dwell to dwell at one
    pose, while each fit's own noise said 0.15-0.5 mm (docs/lab/verify-log.md, 2026-11-27,
    ``drillverify``)."""
    gap = float(spot_whitened @ spot_whitened) - float(ray_whitened @ ray_whitened)
    spread = 2.0 * float(np.linalg.norm(spot_whitened - ray_whitened))
    if not spread > 0.0:
        return 0.0
    p_spot = float(ndtr(-gap / spread))
    return p_spot * (1.0 - p_spot) * along_m**2
