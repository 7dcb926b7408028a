"""A centre fit's covariances: the noise's, what its residuals leave unexplained, a range error's
move against the solver's model, an unknown tilt's bias."""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.extraction.fit import _fit_residuals, _residual_sigma
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _fit_covariances_m2(
    points: FloatArray,
    sigma: FloatArray,
    centre: FloatArray,
    normal: FloatArray,
    section: _Section,
    model: ExtractionSettings,
) -> tuple[FloatArray, FloatArray]:
    """A fit's noise covariance (its normal matrix's, scaled up by the reduced chi-square
    above 1) and that plus what its residuals leave unexplained (``_systematic_covariance_m2``),
    against the spot or rays as ``model`` says."""
    residuals, normals, _ = _fit_residuals(points, centre, section, model)
    residual_sigma = _residual_sigma(points, sigma, normals, section.radius_m, model)
    whitened = residuals / residual_sigma
    variance_factor = max(1.0, float(whitened @ whitened) / max(points.shape[0] - 2, 1))
    noise = np.linalg.inv(normal) * variance_factor
    return noise, noise + _systematic_covariance_m2(residuals, residual_sigma, normals, normal)


def _along_and_across_m2(along_m2: FloatArray, across_m2: FloatArray, bearing: FloatArray) -> FloatArray:
    """A covariance with ``along_m2``'s variance along the bearing, ``across_m2``'s across it,
    and ``along_m2``'s correlation between the two."""
    side = np.array([-bearing[1], bearing[0]])
    along, across = float(bearing @ along_m2 @ bearing), float(side @ across_m2 @ side)
    both_m2 = max(along * float(side @ along_m2 @ side), 1e-300)
    correlation = float(bearing @ along_m2 @ side) / np.sqrt(both_m2)
    basis = np.column_stack([bearing, side])
    cross = correlation * np.sqrt(along * across)
    return basis @ np.array([[along, cross], [cross, across]]) @ basis.T


def _centre_shift(
    points: FloatArray,
    normals: FloatArray,
    residual_sigma: FloatArray,
    normal: FloatArray,
    push_m: FloatArray,
) -> FloatArray:
    """How the fitted centre moves when every point is pushed ``push_m`` along its beam."""
    beams = points / np.linalg.norm(points, axis=1)[:, None]
    push = np.einsum("ij,ij->i", beams, normals[:, :2]) * push_m / residual_sigma
    return np.linalg.solve(normal, (normals[:, :2] / residual_sigma[:, None]).T @ push)


def _range_error_mismatch(
    points: FloatArray,
    centre: FloatArray,
    normals: FloatArray,
    residual_sigma: FloatArray,
    normal: FloatArray,
) -> FloatArray:
    """How the fitted centre moves for a range error of 1 (every point pushed 1 along its
    beam) minus how the solver's model moves it (1 along its bearing): zero for a far rod
    whose beams are parallel, a few per cent for a thick rod near the scanner."""
    moved = _centre_shift(points, normals, residual_sigma, normal, np.ones(points.shape[0]))
    return moved - centre / np.linalg.norm(centre)


def _systematic_covariance_m2(
    residuals: FloatArray, residual_sigma: FloatArray, normals: FloatArray, normal: FloatArray
) -> FloatArray:
    """Covariance (2, 2) of what the dwell does not average away: the part of the fit's mean
    squared residual the noise does not explain (the rod's shape, edge effects, a range error
    that changes across the arc), carried through the fit's gain as an error shared by
    neighbouring beams.

    Its parts symmetric and antisymmetric about the arc's middle are sized apart (a symmetric
    error, such as one that grows with the incidence angle, moves the centre along its bearing,
    an antisymmetric one across it), each by its own excess over the noise, with the
    correlation between neighbours the residuals show (their lag-1 covariance over the
    excess; the noise is independent beam to beam)."""
    count = residuals.size
    excess_m2 = float(np.mean(residuals**2) - np.mean(residual_sigma**2))
    if excess_m2 <= 0.0 or count < 3:
        return np.zeros((2, 2))
    correlation = float(np.clip(np.mean(residuals[:-1] * residuals[1:]) / excess_m2, 0.0, 1.0))
    shared = correlation ** np.abs(np.subtract.outer(np.arange(count), np.arange(count)))
    mirror = np.eye(count)[::-1]
    gain = np.linalg.solve(normal, (normals[:, :2] / residual_sigma[:, None] ** 2).T)
    covariance = np.zeros((2, 2))
    for sign in (1.0, -1.0):
        part = 0.5 * (np.eye(count) + sign * mirror)
        part_excess_m2 = float(np.mean((part @ residuals) ** 2) - 0.5 * np.mean(residual_sigma**2))
        pattern = part @ shared @ part
        scale = float(np.mean(np.diag(pattern)))
        if part_excess_m2 > 0.0 and scale > 0.0:
            covariance += part_excess_m2 / scale * gain @ pattern @ gain.T
    return covariance


def _unknown_tilt_variance_m2(section: _Section, settings: ExtractionSettings) -> float:
    """Variance per axis of the bias of fitting a circle to a rod whose axis is unknown."""
    if section.unknown_tilt_cos >= 1.0:
        return 0.0
    cos_typical = float(np.cos(np.radians(settings.unknown_axis_typical_tilt_deg)))
    return 0.5 * (section.radius_m * (1.0 / cos_typical**2 - 1.0)) ** 2
