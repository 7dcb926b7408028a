"""The weighted Gauss-Newton fit of a section's centre to a segment's points: each beam's residual
against a ray or against what its spot returns, and that residual's noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _spot_readings_m


def _residuals(
    points: FloatArray, centre: FloatArray, section: _Section, radius_m: float
) -> tuple[FloatArray, FloatArray]:
    """Orthogonal distances to the cylinder surface and unit surface normals (N, 3)."""
    rel = np.zeros((points.shape[0], 3))
    rel[:, :2] = points - centre
    w = rel - (rel @ section.axis)[:, None] * section.axis
    dist = np.linalg.norm(w, axis=1)
    normals = w / np.fmax(dist, 1e-15)[:, None]
    return dist - radius_m, normals


def _rays(settings: ExtractionSettings) -> ExtractionSettings:
    """The settings with a spot of no width: the fit against rays (``_fit_residuals``)."""
    return replace(settings, spot_width_at_scanner_m=0.0, spot_divergence_rad=0.0)


def _fit_residuals(
    points: FloatArray,
    params: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
    *,
    free_radius: bool = False,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The fit's residual per beam (m), its "normal" (N, 3: a ray's surface normal; the noise
    model ``_residual_sigma`` and the covariance terms take it) and its Jacobian by the centre
    ``params[:2]`` (and the radius ``params[2]`` when ``free_radius``).

    Against the spot (``_spot_readings_m``): ``kappa (r - r_spot)``, the reading's excess over
    what the beam's spot returns from the rod, scaled by the spot's mean cosine of incidence
    ``kappa`` (a ray's orthogonal distance to the surface, to first order, so the residual and
    its noise stay in those units); positive where the reading lies behind. Its "normal" is
    ``kappa`` times the spot reading's gradient (a ray's: the surface normal). A beam the spot
    does not reach, or a spot of no width, keeps the ray's orthogonal distance (``_residuals``).
    The free radius is fitted against rays: it is reported, not used, and against the spot its
    fit (nearly degenerate with the range) took 20 evaluations of a millisecond each."""
    radius = float(params[2]) if free_radius else section.radius_m
    centre = params[:2]
    ray, normals = _residuals(points, centre, section, radius)
    jacobian = -normals[:, :2]
    if free_radius:
        return ray, normals, np.column_stack([jacobian, -np.ones(points.shape[0])])
    spot = _spot_readings_m(points, centre, section, radius, settings)
    if spot is None:
        return ray, normals, jacobian
    readings, kappa, gradient, kappa_gradient = spot
    seen = np.isfinite(readings)
    excess = np.linalg.norm(points, axis=1) - np.where(seen, readings, 0.0)
    residuals = np.where(seen, kappa * excess, ray)
    spot_normals = np.zeros_like(normals)
    spot_normals[:, :2] = kappa[:, None] * gradient
    normals = np.where(seen[:, None], spot_normals, normals)
    spot_jacobian = excess[:, None] * kappa_gradient - kappa[:, None] * gradient
    usable = seen & np.all(np.isfinite(spot_jacobian), axis=1)
    return residuals, normals, np.where(usable[:, None], spot_jacobian, jacobian)


def _residual_sigma(
    points: FloatArray, sigma: FloatArray, normals: FloatArray, radius_m: float, settings: ExtractionSettings
) -> FloatArray:
    """Sigma of each orthogonal residual from range noise and lateral beam uncertainty
    (``points`` in beam order: the first and last are the silhouette's edge beams).

    The last term is the second-order effect of a range error at grazing incidence
    (``dr**2 / 2R``), which dominates where the beam is nearly tangent to a thin rod.
    """
    ranges = np.linalg.norm(points, axis=1)
    beam = points / ranges[:, None]
    along = normals[:, 0] * beam[:, 0] + normals[:, 1] * beam[:, 1]
    across = -normals[:, 0] * beam[:, 1] + normals[:, 1] * beam[:, 0]
    lateral = ranges * settings.beam_angle_sigma_rad
    # The first and last beam's spots straddle the silhouette: the return comes from anywhere
    # across the covered part of one beam step. (Not the whole spot: that sigma, 5-8 mm, took
    # the silhouette's bearing out of the fit and, in the residuals' mean sigma, cancelled the
    # covariance's systematic term; docs/lab/extraction-log.md, "The beam's spot".)
    edge_rad = float(np.hypot(settings.beam_angle_sigma_rad, settings.beam_footprint_rad / np.sqrt(12.0)))
    lateral[[0, -1]] = ranges[[0, -1]] * edge_rad
    curvature = sigma**2 / (np.sqrt(2.0) * radius_m)
    return np.sqrt((sigma * along) ** 2 + (lateral * across) ** 2 + curvature**2)


def _gauss_newton(
    points: FloatArray,
    sigma: FloatArray,
    seed: FloatArray,
    section: _Section,
    settings: ExtractionSettings,
    *,
    free_radius: bool,
    spot: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Weighted Gauss-Newton on (u, v[, r]); returns (params, normal matrix, whitened) or None.
    ``spot``: against what the beam's spot returns (``_fit_residuals``); False: against rays."""
    params = np.concatenate([seed, [section.radius_m]]) if free_radius else seed.copy()
    spot = spot and not free_radius  # the free radius is fitted against rays (``_fit_residuals``)
    model = settings if spot else _rays(settings)

    def evaluate(p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        res, normals, jac = _fit_residuals(points, p, section, model, free_radius=free_radius)
        res_sigma = _residual_sigma(points, sigma, normals, section.radius_m, settings)
        return res / res_sigma, jac / res_sigma[:, None], res

    whitened, jac, _ = evaluate(params)
    cost = float(whitened @ whitened)
    for _ in range(settings.max_iterations):
        normal = jac.T @ jac
        try:
            step = np.linalg.solve(normal, -jac.T @ whitened)
            # Against the spot, done once a step moves the centre less than a small fraction
            # of its std: the weights move with the centre, so the fit converges only
            # linearly, and the spot model (``_spot_readings_m``) costs a millisecond an
            # evaluation. Against rays, to the last 0.1 nm as before.
            tolerance_m = 1e-10
            if spot:
                centre_std_m = float(np.sqrt(np.trace(np.linalg.inv(normal)[:2, :2])))
                tolerance_m = settings.fit_tolerance_std * centre_std_m
        except np.linalg.LinAlgError:
            return None
        scale = 1.0
        while scale > 1e-4 and (not spot or scale * float(np.linalg.norm(step[:2])) > tolerance_m):
            trial = params + scale * step
            trial_whitened, trial_jac, _ = evaluate(trial)
            trial_cost = float(trial_whitened @ trial_whitened)
            if trial_cost <= cost * (1.0 + 1e-12):
                break
            scale *= 0.5
        else:
            break
        params, whitened, jac, cost = trial, trial_whitened, trial_jac, trial_cost
        if float(np.linalg.norm(scale * step[:2])) < tolerance_m:
            break
    if not np.all(np.isfinite(params)):
        return None
    return params, jac.T @ jac, whitened
