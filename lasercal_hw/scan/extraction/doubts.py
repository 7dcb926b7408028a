"""What the covariance adds beyond the fit's own: the range error across the arc, a push shared by
neighbouring beams, the sideways checks (the arc without its edge beams, uneven backgrounds,
the range profile's symmetry), the spot and ray fits' disagreement and a tail pull taken out."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _beam_step_rad
from lasercal_hw.scan.extraction.blend import _Behind
from lasercal_hw.scan.extraction.centre_fit import _Fit
from lasercal_hw.scan.extraction.covariance import _centre_shift
from lasercal_hw.scan.extraction.fit import _fit_residuals, _gauss_newton, _rays, _residual_sigma
from lasercal_hw.scan.extraction.section import _across_bearing, _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _spot_sigma_m


def _arc_bias_m(scan: AveragedScan, beams: NDArray[np.int64], settings: ExtractionSettings) -> FloatArray:
    """Per beam, how far its range error may differ from the front beam's: the range walk
    between their intensities and the near-range error's change between their ranges."""
    ranges = scan.ranges_m[beams]
    front = int(np.argmin(ranges))
    near = settings.near_bias_m * np.exp(-(np.fmax(ranges, 0.1) - 0.1) / settings.near_bias_decay_m)
    deeper_efolds = np.log(np.fmax(ranges, 1e-3) / max(float(ranges[front]), 1e-3))
    bias = np.abs(near - near[front]) + settings.range_error_slope_m_per_efold * np.abs(deeper_efolds)
    if scan.intensities is not None:
        intensity = np.fmax(scan.intensities[beams], 1.0)
        bias = bias + settings.range_walk_m_per_efold * np.abs(np.log(intensity / intensity[front]))
    return bias


def _with_arc_bias(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    points: FloatArray,
    sigma: FloatArray,
    blend_m: FloatArray,
    fit: _Fit,
    section: _Section,
    settings: ExtractionSettings,
) -> _Fit:
    """The fit with the arc's range-error variation (``_arc_bias_m``) in its covariance."""
    push_m = _arc_bias_m(scan, beams, settings)
    return _with_shared_push(points, sigma, blend_m, push_m, fit, section, settings)


def _with_shared_push(
    points: FloatArray,
    sigma: FloatArray,
    blend_m: FloatArray,
    push_m: FloatArray,
    fit: _Fit,
    section: _Section,
    settings: ExtractionSettings,
) -> _Fit:
    """The fit with the centre's move were every beam's range off by ``push_m`` in its
    covariance (shared by neighbours, so taken whole); ``blend_m``: blend allowances already
    in the beams' sigmas."""
    if not np.any(push_m > 0.0):
        return fit
    model = settings if fit.spot else _rays(settings)
    _, normals, _ = _fit_residuals(points, fit.centre_uv_m, section, model)
    residual_sigma = _residual_sigma(points, np.hypot(sigma, blend_m), normals, section.radius_m, settings)
    jac = -normals[:, :2] / residual_sigma[:, None]
    try:
        shift = _centre_shift(points, normals, residual_sigma, jac.T @ jac, push_m)
    except np.linalg.LinAlgError:
        return fit
    return replace(fit, covariance_uv_m2=fit.covariance_uv_m2 + np.outer(shift, shift))


def _with_spot_disagreement(fit: _Fit) -> _Fit:
    """The fit with, where the rays fit its beams better than the spot on a scanner whose spot
    shows, the two fits' difference along the bearing in its covariance: the spot model does
    not describe these beams (a wall close behind merged into the edge beams, which then read
    long where the spot says short), and neither fit is vouched for. A 45 mm matte rod at 1.5 m
    before a wall 0.3 m behind: the ray fit 1.25 mm long against 0.29 mm std, the spot fit
    0.68 mm nearer. Unchanged where the spot fit was kept or the two agree."""
    if fit.spot or not fit.spot_disagreement_m:
        return fit
    bearing = fit.centre_uv_m / float(np.linalg.norm(fit.centre_uv_m))
    doubt_m2 = fit.spot_disagreement_m**2 * np.outer(bearing, bearing)
    return replace(fit, covariance_uv_m2=fit.covariance_uv_m2 + doubt_m2)


def _with_tail_pull_doubt(fit: _Fit, taken_shift_m: FloatArray, settings: ExtractionSettings) -> _Fit:
    """The fit with ``tail_pull_doubt`` of the centre's move by the tail pull taken out of its
    ranges (``taken_shift_m``) in its covariance: the correction is only as good as the pull's
    estimate."""
    doubt_m = settings.tail_pull_doubt * taken_shift_m
    return replace(fit, covariance_uv_m2=fit.covariance_uv_m2 + np.outer(doubt_m, doubt_m))


def _with_sideways_doubt(fit: _Fit, doubt_m2: FloatArray, noise_doubt_m2: FloatArray | None = None) -> _Fit:
    """The fit with a sideways check's variance in its covariance (``doubt_m2``) and in its
    noise (``noise_doubt_m2``, default the same): which beams are the silhouette's edges
    changes from dwell to dwell (a far rod's 3-7 beams: its centre moved 5-7 mm sideways
    between two dwells at one pose), so another dwell draws that part anew too."""
    noise = fit.noise_covariance_uv_m2
    noise_doubt_m2 = doubt_m2 if noise_doubt_m2 is None else noise_doubt_m2
    return replace(
        fit,
        covariance_uv_m2=fit.covariance_uv_m2 + doubt_m2,
        noise_covariance_uv_m2=None if noise is None else noise + noise_doubt_m2,
    )


def _with_edge_doubt(
    points: FloatArray, sigma: FloatArray, fit: _Fit, section: _Section, settings: ExtractionSettings
) -> _Fit:
    """The fit with a sideways variance where its two edge beams pull it away from what the
    rest of the arc says.

    The silhouette's edge beams fix the centre sideways far better than the arc's ranges do
    (on the ideal scanner they are exact to a beam step). On a real one the spot blurs the
    edges, speckle holds an edge beam off for the whole dwell, or an edge beam is trimmed
    on one side only, and the known-radius fit moves sideways by half a beam or more (a 45
    mm rod at 1-2 m: 2-4 mm against 0.5-0.9 mm std). The arc without its edge beams is
    fitted too; the part of the two centres' sideways difference that their covariances do
    not explain (the difference of two nested fits has the variance of the smaller one less
    the larger one's) joins the covariance across the bearing."""
    if points.shape[0] < settings.min_beams + 2:
        return fit
    # Ray fits: the sideways position is the ray fit's (``_along_the_spot``).
    full = _gauss_newton(points, sigma, fit.centre_uv_m, section, settings, free_radius=False, spot=False)
    inner = _gauss_newton(
        points[1:-1], sigma[1:-1], fit.centre_uv_m, section, settings, free_radius=False, spot=False
    )
    if full is None or inner is None:
        return fit
    try:
        difference_m2 = np.linalg.inv(inner[1]) - np.linalg.inv(full[1])
    except np.linalg.LinAlgError:
        return fit
    across = _across_bearing(fit.centre_uv_m)
    sideways_m = float(across @ (inner[0][:2] - full[0][:2]))
    excess_m2 = sideways_m**2 - max(float(across @ difference_m2 @ across), 0.0)
    if excess_m2 <= 0.0:
        return fit
    return _with_sideways_doubt(fit, excess_m2 * np.outer(across, across))


def _with_uneven_background(
    scan: AveragedScan, beams: NDArray[np.int64], fit: _Fit, behind: _Behind, settings: ExtractionSettings
) -> _Fit:
    """The fit with a sideways variance where the backgrounds just outside its two edges (the
    beams within the spot's halo of each edge, what ``behind`` says lies there) reach into the
    rod's echo unequally (``uneven_background_doubt``), where that exceeds the fit's sideways std
    (smaller, it left the dry runs' p95 0.001-0.005 mm worse). It repeats at the pose, so it stays
    out of the noise."""
    range_m = float(np.min(scan.ranges_m[beams]))
    spot_m = float(_spot_sigma_m(np.array([range_m]), settings)[0])
    pulse_sigma_m = settings.pulse_fwhm_m / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    reach = max(int(np.ceil(settings.spot_halo_scale * spot_m / (range_m * _beam_step_rad(scan)))), 1)
    reaches_m = []
    for edge, step in ((int(beams[0]), -1), (int(beams[-1]), 1)):
        outside = edge + step * np.arange(1, reach + 1)
        outside = outside[(outside >= 0) & (outside < scan.ranges_m.size)]
        depth_m = behind.ranges_m[outside] - range_m
        depth_m = depth_m[np.isfinite(depth_m) & (depth_m > 0.0)]
        if depth_m.size == 0:
            return fit
        depth = float(np.median(depth_m))
        reaches_m.append(depth * np.exp(-0.5 * (depth / pulse_sigma_m) ** 2))
    std_m = settings.uneven_background_doubt * spot_m * abs(reaches_m[0] - reaches_m[1]) / pulse_sigma_m
    across = _across_bearing(fit.centre_uv_m)
    if std_m**2 <= float(across @ fit.covariance_uv_m2 @ across):
        return fit
    return _with_sideways_doubt(fit, std_m**2 * np.outer(across, across), np.zeros((2, 2)))


def _symmetry_bearing_rad(scan: AveragedScan, beams: NDArray[np.int64], section: _Section) -> float | None:
    """The bearing the rod's range profile is symmetric about: at depths of 0.2-0.8 radius
    behind its nearest beam, the middle of where the profile crosses that depth on either
    side (interpolated between beams), median over the depths; None where it cannot tell.

    A rod's own arc is symmetric about its centre's bearing, and so is what the beam's spot
    adds on both sides (a halo of near readings, ramps of blends into a wall close behind),
    which a known-radius fit of the few beams left may not be."""
    ranges = scan.ranges_m
    front = int(beams[int(np.argmin(ranges[beams]))])
    nearest = float(ranges[front])
    middles = []
    for depth in (0.2, 0.4, 0.6, 0.8):
        level = nearest + depth * section.radius_m
        sides = []
        for direction in (-1, 1):
            i = front
            while 0 <= i + direction < ranges.size and ranges[i + direction] < level:  # NaN: False
                i += direction
            j = i + direction
            if not (0 <= j < ranges.size and np.isfinite(ranges[j])):
                break
            share = (level - ranges[i]) / (ranges[j] - ranges[i])
            sides.append(scan.angles_rad[i] + share * (scan.angles_rad[j] - scan.angles_rad[i]))
        if len(sides) == 2:
            middles.append(0.5 * (sides[0] + sides[1]))
    return float(np.median(middles)) if middles else None


def _with_symmetry_doubt(
    scan: AveragedScan, beams: NDArray[np.int64], fit: _Fit, section: _Section
) -> _Fit:
    """The fit with a sideways variance where its centre's bearing and the profile's symmetry
    disagree (``_symmetry_bearing_rad``) by more than the fit's own sideways variance and a
    beam step's quantisation: a rod merged with a wall close behind keeps 5 beams whose fit
    sat 10 mm sideways against 1 mm std (a 20 mm rod at 0.75 m, the wall 0.3 m behind)."""
    bearing = _symmetry_bearing_rad(scan, beams, section)
    if bearing is None:
        return fit
    distance_m = float(np.linalg.norm(fit.centre_uv_m))
    across = _across_bearing(fit.centre_uv_m)
    fitted = float(np.arctan2(fit.centre_uv_m[1], fit.centre_uv_m[0]))
    sideways_m = distance_m * float(np.angle(np.exp(1j * (bearing - fitted))))
    quantisation_m2 = (distance_m * _beam_step_rad(scan)) ** 2 / 12.0
    noise = fit.covariance_uv_m2 if fit.noise_covariance_uv_m2 is None else fit.noise_covariance_uv_m2
    # Against the whole covariance for the covariance, against the noise for the noise: a
    # blend bound that covers the disagreement repeats at the pose, while which beams the
    # core keeps is drawn anew by every dwell (verify seed 6: a 20 mm rod at 1.2 m, 3 beams,
    # 192-194 at the calibration and 191-193 at the verify, 11.7 mm apart sideways against
    # 2-3 mm of noise std, its 59-188 mm blend std having swallowed the check).
    excess_m2, noise_excess_m2 = (
        max(sideways_m**2 - float(across @ covariance @ across) - quantisation_m2, 0.0)
        for covariance in (fit.covariance_uv_m2, noise)
    )
    if noise_excess_m2 <= 0.0:
        return fit
    doubt = np.outer(across, across)
    return _with_sideways_doubt(fit, excess_m2 * doubt, noise_excess_m2 * doubt)
