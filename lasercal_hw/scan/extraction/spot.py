"""The beam's spot: its core and halo, its width at a range, what it reads on a rod's curved front
(``_spot_readings_m``) and how much of it passes beside the rod."""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _spot_readings_m(
    points: FloatArray, centre: FloatArray, section: _Section, radius_m: float, settings: ExtractionSettings
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """Per beam, the range its spot reads on the rod (NaN: the spot misses it), the
    power-weighted mean cosine of incidence over the part on the rod (``kappa``), and the
    derivatives of both by the centre (N, 2 each); None for a spot of no width.

    As the scanner's echo makes it: the spot's rays parallel to the beam (a gaussian core
    ``spot_width_at_scanner_m + spot_divergence_rad * range`` wide at 1/e^2, and its faint
    halo), each returning from where it meets the rod the power the spot's profile gives it
    times the cosine of its incidence (a diffuse surface: Lambert), the echo's range their
    power-weighted mean. Where part of the spot passes beside the rod, that part is not in
    the rod's echo (a surface close behind merging into it: ``_blend``).

    On a rod's curved front the spot's sides meet the surface deeper than its middle (a
    sagitta of ``x^2 / 2r``): a beam across the middle reads long, by about ``sigma^2 / 2r``
    (0.9 mm for a 45 mm rod at 1.5 m), and one at the silhouette short (the spot's part on
    the rod is nearer than the grazing ray's hit: 10-20 mm for that rod); a ray fit's centre
    was off by more than its std (docs/lab/extraction-log.md, "The fit against the spot").

    The integral runs over the visible half of the section by the angle ``phi`` about its
    centre (in the squeezed frame, where it is a circle and the rays stay parallel): the ray
    meeting the surface there lies ``m + x(phi)`` beside the beam (``m``: the rod's middle)
    and reads ``b.c + tau(phi)``, both ``x`` and ``tau`` fixed by the section's shape, so the
    reading moves with the centre as ``b + d(mean tau)/dm across``. Gauss-Legendre nodes over
    the part each of the spot's core and halo covers (to twice its 1/e^2 half-width, where it
    is 3e-4 of its peak: the moving limits add nothing worth keeping to the derivative).

    The power each spot takes from the rod (the readings' weight, ``total`` below) is the
    quantity ``intensity._gloss_ratio`` integrates too, its own way and only relative to the
    brightest beam: here the section as this beam sees it (an ellipse for a tilted rod, the
    cosine of incidence in 3D), each beam's spot as wide as at its own reading, Gauss-Legendre
    nodes within twice each part's half-width; there an upright circle, one spot width at the
    rod's front, 201 angles across the whole visible half. Their predicted profiles differ by up
    to 0.4 % of the peak (10-45 mm rods at 0.75-3 m), so each keeps its own."""
    ranges = np.linalg.norm(points, axis=1)
    core_m = 2.0 * _spot_sigma_m(ranges, settings)  # the core's 1/e^2 half-width
    if not np.any(core_m > 0.0):
        return None
    beams = points / ranges[:, None]
    across = np.column_stack([-beams[:, 1], beams[:, 0]])
    squeeze, unsqueeze = section.to_circle(np.eye(2)), section.from_circle(np.eye(2))  # symmetric maps
    beams_c = beams @ squeeze
    beams_c /= np.linalg.norm(beams_c, axis=1)[:, None]
    # The surface point at phi, from the centre: cos(phi) front + sin(phi) side (the real frame).
    front = -radius_m * (beams_c @ unsqueeze)
    side = radius_m * (np.column_stack([-beams_c[:, 1], beams_c[:, 0]]) @ unsqueeze)
    half_width = np.einsum("ij,ij->i", side, across)  # the silhouette's half-width
    side *= np.where(half_width < 0.0, -1.0, 1.0)[:, None]
    half_width = np.fmax(np.abs(half_width), 1e-12)
    front_b, side_b = np.einsum("ij,ij->i", front, beams), np.einsum("ij,ij->i", side, beams)
    axis_xy, axis_b = section.axis[:2], beams @ section.axis[:2]
    front_a, side_a = front @ axis_xy, side @ axis_xy
    front2, side2, front_side = (front**2).sum(1), (side**2).sum(1), np.einsum("ij,ij->i", front, side)
    beside_m = across @ centre
    shares, scales = zip(*_spot_parts(settings), strict=True)
    nodes, weights = _gauss_legendre(settings.spot_quadrature_nodes)
    count = nodes.size
    half_m = np.repeat(np.fmax(core_m, 1e-12)[:, None] * np.array(scales)[None, :], count, axis=1)
    share = np.repeat(np.array(shares), count)[None, :]
    col = lambda v: v[:, None]  # noqa: E731 (per beam, broadcast over the nodes)
    low = np.arcsin(np.clip((-2.0 * half_m - col(beside_m)) / col(half_width), -1.0, 1.0))
    high = np.arcsin(np.clip((2.0 * half_m - col(beside_m)) / col(half_width), -1.0, 1.0))
    phi = 0.5 * (low + high) + 0.5 * (high - low) * np.tile(nodes, len(shares))[None, :]
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    tau = cos_phi * col(front_b) + sin_phi * col(side_b)  # the ray's reading less b.c
    along_axis = cos_phi * col(front_a) + sin_phi * col(side_a)
    length2 = cos_phi**2 * col(front2) + 2.0 * cos_phi * sin_phi * col(front_side) + sin_phi**2 * col(side2)
    cosine = np.abs(tau - along_axis * col(axis_b)) / np.sqrt(np.fmax(length2 - along_axis**2, 1e-30))
    spread = np.abs(col(half_width) * cos_phi) * 0.5 * (high - low) * np.tile(weights, len(shares))[None, :]
    beside = (col(beside_m) + col(half_width) * sin_phi) / half_m
    power = share / (half_m * np.sqrt(np.pi / 2.0)) * np.exp(-2.0 * beside**2) * cosine * spread
    slope = power * (-4.0 * beside / half_m)  # d power / d m
    total, moment = power.sum(axis=1), (power * tau).sum(axis=1)
    d_total, d_moment = slope.sum(axis=1), (slope * tau).sum(axis=1)
    found = total > 1e-12 * np.max(total, initial=0.0)
    safe = np.where(found, total, 1.0)
    mean_tau = moment / safe
    readings = np.where(found, beams @ centre + mean_tau, np.nan)
    gradient = beams + ((d_moment - mean_tau * d_total) / safe)[:, None] * across
    lit, d_lit = (power * cosine).sum(axis=1), (slope * cosine).sum(axis=1)
    kappa = np.where(found, lit / safe, 1.0)
    kappa_gradient = ((d_lit - kappa * d_total) / safe)[:, None] * across
    return readings, kappa, gradient, kappa_gradient


@functools.cache
def _gauss_legendre(count: int) -> tuple[FloatArray, FloatArray]:
    """Gauss-Legendre nodes and weights on [-1, 1]."""
    return np.polynomial.legendre.leggauss(count)


def _spot_parts(settings: ExtractionSettings) -> tuple[tuple[float, float], ...]:
    """The spot's core and, where it has one, its halo: (share of the power, width over the
    core's) each."""
    halo = settings.spot_halo_fraction
    core = ((1.0 - halo, 1.0),)
    return (*core, (halo, settings.spot_halo_scale)) if halo > 0.0 else core


def _spot_sigma_m(range_m: FloatArray, settings: ExtractionSettings) -> FloatArray:
    """Gaussian sigma across the beam's spot at these ranges (a quarter of its 1/e^2 width)."""
    return 0.25 * (settings.spot_width_at_scanner_m + settings.spot_divergence_rad * range_m)


def _beside_share(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    centre: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
    *,
    halo: bool = True,
) -> FloatArray:
    """Per beam, the part of its spot passing beside the rod (a gaussian spot across the rod's
    silhouette, with its faint halo where ``halo``)."""
    ranges = scan.ranges_m[beams]
    angles = scan.angles_rad[beams]
    offset = np.sin(angles) * centre[0] - np.cos(angles) * centre[1]
    spot = np.fmax(_spot_sigma_m(ranges, settings), 1e-9)  # a thin ray: all or nothing
    half = section.radius_m

    def beside(sigma_m: FloatArray) -> FloatArray:
        return 1.0 - (ndtr((half - offset) / sigma_m) - ndtr((-half - offset) / sigma_m))

    halo_fraction = settings.spot_halo_fraction if halo else 0.0
    return (1.0 - halo_fraction) * beside(spot) + halo_fraction * beside(settings.spot_halo_scale * spot)


def _narrower_than_spot(
    scan: AveragedScan, beams: NDArray[np.int64], section: _Section, settings: ExtractionSettings
) -> bool:
    """Whether the rod is narrower than the beam's spot (1/e^2) at its range: every beam's spot
    passes partly beside it."""
    range_m = float(np.min(scan.ranges_m[beams]))
    return 2.0 * section.radius_m < settings.spot_width_at_scanner_m + settings.spot_divergence_rad * range_m
