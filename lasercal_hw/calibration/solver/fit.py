"""The robust fit: least-squares refinement of the pose (and of the extras) from a start, iterated
outlier rejection with re-admission, the plain fit on the inliers, the outliers in words, and the
refusal of a fit that diverged (a pose or prediction not finite, a range error no scanner has).

Outlier test: a waypoint is rejected when its squared whitened residual exceeds the
chi-square quantile with 2 degrees of freedom at ``outlier_confidence`` (99.9 %: 13.8),
times ``s^2 = max(1, median(m^2) / (2 ln 2))`` (the data's robust noise scale, never below
the stated noise model); repeated with re-admission until the set is stable."""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from lasercal_hw.calibration.model import (
    effective_covariance,
    extended_residuals_and_jacobian,
    left_jacobian_so3,
    moved_rod,
    range_error_m,
    whiten,
    whitening,
)
from lasercal_hw.calibration.result import Outlier
from lasercal_hw.calibration.solver.axis import _axis_prior_weight, axis_deviation
from lasercal_hw.calibration.solver.data import MIN_WAYPOINTS, _Data
from lasercal_hw.calibration.solver.extras import _Extras
from lasercal_hw.calibration.solver.formatting import _finite
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.residuals import _MEDIAN_CHI2_2DOF, _chi2_2dof_quantile, _whitened
from lasercal_hw.errors import CalibrationError
from lasercal_hw.geometry import FloatArray, rotvec_to_matrix
from lasercal_hw.models import RodLine

logger = logging.getLogger(__name__)

MAX_RANGE_ERROR_M = 0.3
"""Ten times a UTM-30LX-EW's data-sheet range accuracy (+-30 mm to 10 m): a fit whose range
error curve needs more at a used crossing has diverged, not found the scanner's error."""


def _fit(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    start: np.ndarray,
    robust: bool,
    opts: SolverOptions,
    extras: _Extras,
) -> tuple[FloatArray, FloatArray, _Data, np.ndarray, int]:
    """Robust refinement with iterated rejection (from the ``start`` rows; any usable row
    may be re-admitted), then plain least squares on the inliers (weights re-evaluated at
    the robust estimate, so the answer does not depend on the path)."""
    used = start.copy()
    evaluations = 0
    threshold = _chi2_2dof_quantile(opts.outlier_confidence)
    knee = opts.loss_scale or float(np.sqrt(threshold))
    if robust:
        for _ in range(opts.max_rejection_rounds):
            rotation, translation, data, nfev = _refine(
                rotation, translation, data, used, opts.loss, knee, opts, extras
            )
            evaluations += nfev
            m2 = (_whitened(rotation, translation, data, opts) ** 2).sum(axis=1)
            scale2 = max(1.0, float(np.median(m2[used])) / _MEDIAN_CHI2_2DOF)
            accepted = usable & (m2 <= threshold * scale2)
            logger.debug(
                "rejection round: %d of %d accepted (robust scale %.2f)",
                accepted.sum(),
                usable.sum(),
                np.sqrt(scale2),
            )
            if np.array_equal(accepted, used):
                break
            used = accepted
        rejected = int(usable.sum() - used.sum())
        limit = opts.max_outlier_fraction * usable.sum()
        if rejected > limit or used.sum() < MIN_WAYPOINTS:
            raise CalibrationError(
                f"{rejected} of {int(usable.sum())} waypoints fail the outlier test (limit "
                f"{opts.max_outlier_fraction:.0%}): the centres or TCP poses are inconsistent; check the rod "
                "definition (--axis-origin/--axis-direction) and the centre noise (sigma_u, sigma_v)"
            )
    rotation, translation, data, nfev = _refine(
        rotation, translation, data, used, "linear", knee, opts, extras
    )
    return rotation, translation, data, used, evaluations + nfev


def _refine(
    rotation0: FloatArray,
    translation0: FloatArray,
    data: _Data,
    mask: np.ndarray,
    loss: str,
    knee: float,
    opts: SolverOptions,
    extras: _Extras,
) -> tuple[FloatArray, FloatArray, _Data, int]:
    """One least-squares run on the masked waypoints, parameterised as a translation
    increment, a base-frame rotation vector increment from the given pose and, with
    ``extras``, increments of the rod line (``moved_rod``) and of the range offset."""
    tcp, centres, covariance = data.tcp_transforms[mask], data.centres[mask], data.covariance[mask]
    _, slope = data.predicted(rotation0, translation0)
    white = whitening(effective_covariance(covariance, slope[mask], opts.robot_sigma_m))
    cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def line(x: FloatArray) -> tuple[RodLine, FloatArray]:
        rod = moved_rod(data.rod, x[6:10]) if extras.axis else data.rod
        curve = np.zeros(max(extras.range_terms, data.range_curve_m.size))
        curve[: data.range_curve_m.size] = data.range_curve_m
        if extras.range_terms:
            curve[: extras.range_terms] += x[x.size - extras.range_terms :]
        return rod, curve

    prior_weight = _axis_prior_weight(opts)

    def evaluate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            rotation = Rotation.from_rotvec(x[3:6]).as_matrix() @ rotation0  # 3x faster than geometry's
            translation = translation0 + x[:3]
            rod, offset = line(x)
            residual, jac, _ = extended_residuals_and_jacobian(
                rotation,
                translation,
                tcp,
                rod,
                centres,
                offset,
                with_axis=extras.axis,
                with_offset=extras.range_terms,
            )
            jac[:, :, 3:6] = (jac[:, :, 3:6].reshape(-1, 3) @ left_jacobian_so3(x[3:6])).reshape(-1, 2, 3)
            residual_white, jac_white = whiten(white, residual, jac)
            if extras.axis:
                # The axis prior: four more residuals, the line's deviation from the job's in std.
                prior_jac = np.zeros((4, jac_white.shape[1]))
                prior_jac[:, 6:10] = np.diag(prior_weight)
                deviation = axis_deviation(data.nominal_rod, rod)
                residual_white = np.concatenate([residual_white, prior_weight * deviation])
                jac_white = np.vstack([jac_white, prior_jac])
            cache[key] = residual_white, jac_white
        return cache[key]

    fit = least_squares(
        lambda x: evaluate(x)[0],
        np.zeros(6 + extras.count),
        jac=lambda x: evaluate(x)[1],
        method="lm" if loss == "linear" else "trf",
        loss=loss,
        f_scale=knee,
        x_scale="jac",
        xtol=1e-12 if loss == "linear" else 1e-8,
        ftol=1e-12 if loss == "linear" else 1e-8,
    )
    rod, offset = line(fit.x)
    moved = data.with_line(rod, offset) if extras.count else data
    return rotvec_to_matrix(fit.x[3:6]) @ rotation0, translation0 + fit.x[:3], moved, int(fit.nfev)


def _check_not_diverged(rotation: FloatArray, translation: FloatArray, data: _Data, used: np.ndarray) -> None:
    """``CalibrationError`` when the fit ended where no working cell can be: a pose or a
    prediction that is not finite, or a range error beyond any working scanner's at a used
    crossing (seen: a range error curve that ran away with the pose on a fluted bit's centres
    under a wrong section model, -16 m, which then failed inside LAPACK)."""
    advice = (
        "the centres do not fit one rod line seen by one scanner; check the rod definition "
        "(--axis-origin/--axis-direction) and the centres' noise (sigma_u, sigma_v)"
    )
    with np.errstate(all="ignore"):
        crossing, slope = data.predicted(rotation, translation)
    if not (np.isfinite(rotation).all() and np.isfinite(translation).all()):
        raise CalibrationError(f"the fit diverged to a pose that is not finite: {advice}")
    if not (np.isfinite(crossing[used]).all() and np.isfinite(slope[used]).all()):
        raise CalibrationError(f"the fit diverged: its predicted crossings are not finite; {advice}")
    if not data.range_curve_m.any():
        return
    distance_m = np.linalg.norm(crossing[used], axis=1)
    with np.errstate(all="ignore"):
        error_m = range_error_m(data.range_curve_m, distance_m)[0]
    worst = int(np.argmax(np.nan_to_num(np.abs(error_m), nan=np.inf)))
    if not abs(error_m[worst]) <= MAX_RANGE_ERROR_M:
        raise CalibrationError(
            f"the fit's range error curve reads {error_m[worst] * 1e3:+.0f} mm at {distance_m[worst]:.2f} m, "
            f"beyond any working scanner's ({MAX_RANGE_ERROR_M * 1e3:.0f} mm): the fit ran away with the "
            f"pose, or the scanner is faulty (compare a tape-measured distance with its reading); {advice}"
        )


def _rejected(
    rotation: FloatArray, translation: FloatArray, data: _Data, rejected: np.ndarray, opts: SolverOptions
) -> list[Outlier]:
    if not rejected.any():
        return []
    m2 = (_whitened(rotation, translation, data, opts) ** 2).sum(axis=1)
    crossing, _ = data.predicted(rotation, translation)
    norm_mm = np.linalg.norm(crossing - data.centres, axis=1) * 1e3
    threshold = _chi2_2dof_quantile(opts.outlier_confidence)
    return [
        Outlier(
            index=int(data.index[i]),
            residual_mm=_finite(norm_mm[i]),
            reason=f"whitened residual {np.sqrt(m2[i]):.1f} sigma exceeds the chi-square(2) "
            f"{opts.outlier_confidence:.1%} limit {np.sqrt(threshold):.2f} sigma (robust scale applied)",
        )
        for i in np.flatnonzero(rejected)
    ]
