"""Solve for ``T_base_laser`` from rod observations.

Pipeline (see docs/solver.md): validate -> closed-form linear start (``solver_init``) ->
robust nonlinear least squares on the whitened in-plane residual (``solver_model``) with
iterated outlier rejection -> plain least squares on the inliers -> covariance, Cramér-Rao
bound and observability check.  ``formulation="paper"`` runs the paper's own problem
(``solver_paper``) instead and reports it with the same diagnostics.

Outlier test: a waypoint is rejected when its squared whitened residual exceeds the
chi-square quantile with 2 degrees of freedom at ``outlier_confidence`` (99.9 %: 13.8),
times ``s^2 = max(1, median(m^2) / (2 ln 2))`` (the data's robust noise scale, never below
the stated noise model); repeated with re-admission until the set is stable.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import numpy as np
from pydantic import TypeAdapter
from scipy import special
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from lasercal_hw import __version__
from lasercal_hw.calibration.initial import linear_initial_pose
from lasercal_hw.calibration.model import (
    RANGE_CURVE_BASIS,
    RANGE_CURVE_REFERENCE_M,
    effective_covariance,
    euler_zyx_axes,
    extended_residuals_and_jacobian,
    fisher_information,
    left_jacobian_so3,
    moved_rod,
    plane_crossing,
    range_curve_variable,
    range_error_basis,
    range_error_m,
    whiten,
    whitening,
)
from lasercal_hw.calibration.paper import solve_paper
from lasercal_hw.calibration.plausible import check_physical
from lasercal_hw.calibration.result import (
    CalibrationResult,
    Observability,
    Outlier,
    Provenance,
    RangeErrorPoint,
    RangeOffset,
    WaypointResidual,
)
from lasercal_hw.calibration.solver.axis import (
    _axis_advice,
    _axis_crb_std,
    _axis_estimate,
    _axis_prior_weight,
    _mean_crossing_along_m,
    axis_deviation,
)
from lasercal_hw.calibration.solver.data import (
    MIN_WAYPOINTS,
    _arrays,
    _check_rod_directions,
    _Data,
    _usable_by_incidence,
)
from lasercal_hw.calibration.solver.extras import _crb_std, _extended_fisher, _Extras
from lasercal_hw.calibration.solver.formatting import _finite, _fmt, _list
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.residuals import (
    _MEDIAN_CHI2_2DOF,
    _chi2_2dof_quantile,
    _degrees_of_freedom,
    _reduced_chi_square,
    _residual_scale,
    _whitened,
)
from lasercal_hw.errors import CalibrationError, ConfigError, DegenerateDataError
from lasercal_hw.geometry import (
    FloatArray,
    invert_transform,
    make_transform,
    matrix_to_euler_zyx,
    matrix_to_quat,
    matrix_to_rotvec,
    rotvec_to_matrix,
)
from lasercal_hw.models import Observation, RodLine

logger = logging.getLogger(__name__)

_RESIDUALS = TypeAdapter(list[WaypointResidual])

MAX_RANGE_ERROR_M = 0.3
"""Ten times a UTM-30LX-EW's data-sheet range accuracy (+-30 mm to 10 m): a fit whose range
error curve needs more at a used crossing has diverged, not found the scanner's error."""


def solve(
    observations: Sequence[Observation],
    rod: RodLine,
    *,
    robust: bool = True,
    options: SolverOptions | None = None,
    formulation: Literal["ours", "paper"] | None = None,
) -> CalibrationResult:
    """Estimate ``T_base_laser`` from rod observations; see the module docstring.

    Raises ``DegenerateDataError`` when the data cannot determine all six degrees of
    freedom, ``ConfigError`` for invalid covariances, ``CalibrationError`` when too many
    waypoints are outliers.
    """
    started = time.perf_counter()
    opts = options or SolverOptions()
    if formulation is not None:
        opts = opts.model_copy(update={"formulation": formulation})
    data = _arrays(observations, check_physical(observations), rod, opts)
    _check_rod_directions(data.directions, opts)
    weights = 1.0 / np.sqrt(0.5 * np.trace(data.covariance, axis1=1, axis2=2))
    initial = linear_initial_pose(data.origins, data.directions, data.centres, weights)
    rotation, translation = initial.rotation, initial.translation
    usable, outliers = _usable_by_incidence(rotation, translation, data, opts)
    _check_observability(rotation, translation, data, usable, opts, stage="initial")
    extras = _extras(rotation, translation, data, usable, opts)

    if opts.formulation == "paper":
        paper = solve_paper(data.origins[usable], data.directions[usable], data.centres[usable])
        rotation, translation = paper.rotation, paper.translation_m
        used, converged, evaluations, message = usable, paper.converged, paper.evaluations, paper.message
    else:
        agreeing = usable & initial.agreeing
        # The linear start knows no range error: with a curve to estimate, waypoints that a
        # range error moves along their bearings disagree with it, and a robust fit started
        # without them extrapolates the curve to them (a default run on the physical scanner
        # model: 8 of 20 near waypoints then failed the outlier test by 7-200 sigma).
        agreed = robust and agreeing.sum() >= MIN_WAYPOINTS and not extras.offset
        start = agreeing if agreed else usable
        if robust and 0 < extras.range_terms < opts.max_range_terms:
            scale = _fullest_fit_scale(rotation, translation, data, usable, start, opts, extras)
            extras = _extras(rotation, translation, data, usable, opts, scale)
        rotation, translation, data, used, evaluations = _fit(
            rotation, translation, data, usable, start, robust, opts, extras
        )
        while extras.offset:
            kept, extras = _significant_terms(rotation, translation, data, used, opts, extras)
            if kept:
                break
            curve = _lower_curve(rotation, translation, data, used, extras.range_terms)
            rotation, translation, data, used, more = _fit(
                rotation, translation, data.with_line(data.rod, curve), usable, used, robust, opts, extras
            )
            evaluations += more
        outliers += _rejected(rotation, translation, data, usable & ~used, opts)
        converged, message = True, "converged"
    _check_not_diverged(rotation, translation, data, used)
    try:
        result = _result(rotation, translation, data, used, outliers, opts, robust, extras)
    except DegenerateDataError as exc:
        if opts.formulation != "paper":
            raise
        raise CalibrationError(
            f"the paper formulation ended at an unusable pose ({message}; {evaluations} evaluations): {exc}"
        ) from exc
    result.provenance.converged = converged
    result.provenance.iterations = evaluations
    result.provenance.message = message
    result.provenance.solve_time_s = time.perf_counter() - started
    logger.info(
        "solved (%s): %d of %d waypoints used, RMS residual %.2f mm, %d evaluations, %.1f ms",
        opts.formulation,
        result.waypoints_used,
        len(observations),
        result.rms_residual_mm,
        evaluations,
        result.provenance.solve_time_s * 1e3,
    )
    return result


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


def _check_observability(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    *,
    stage: str,
) -> tuple[FloatArray, Observability]:
    """Fisher information of the used waypoints; refuse if a direction is not observable."""
    origins, directions = data.origins[used], data.directions[used]
    fisher = fisher_information(
        rotation, translation, origins, directions, data.covariance[used], opts.robot_sigma_m
    )
    crossing, _, _ = plane_crossing(rotation, translation, origins, directions)
    lever_m = max(0.1, float(np.sqrt(np.mean(np.sum(crossing**2, axis=1)))))
    scale = np.array([1.0, 1.0, 1.0, 1.0 / lever_m, 1.0 / lever_m, 1.0 / lever_m])
    eigenvalues, vectors = np.linalg.eigh(fisher * np.outer(scale, scale))
    singular = np.sqrt(np.clip(eigenvalues, 0.0, None))[::-1]
    vectors = vectors[:, ::-1]
    ratio = float(singular[-1] / singular[0]) if singular[0] > 0 else 0.0
    if not np.isfinite(ratio) or ratio < opts.min_condition_ratio:
        lost = [
            _describe_direction(vectors[:, k], lever_m, translation)
            for k in range(6)
            if not singular[k] > opts.min_condition_ratio * singular[0]
        ]
        what = f"{lost[0]} is" if len(lost) == 1 else f"{len(lost)} directions ({'; '.join(lost)}) are"
        raise DegenerateDataError(
            f"{what} not observable from these waypoints ({stage} singular-value ratio {ratio:.1e}); "
            f"{_advice(vectors[:, -1], rotation, directions, crossing)}"
        )
    notes = [
        f"weakly observable ({singular[k] / singular[0]:.1e} of the strongest): "
        f"{_describe_direction(vectors[:, k], lever_m, translation)}"
        for k in range(6)
        if singular[k] / singular[0] < opts.weak_condition_ratio
    ]
    observability = Observability(
        lever_m=lever_m,
        singular_values=[float(s) for s in singular],
        condition_ratio=ratio,
        weakest_direction=_describe_direction(vectors[:, -1], lever_m, translation),
        notes=notes,
    )
    return fisher, observability


def _describe_direction(vector: FloatArray, lever_m: float, translation: FloatArray) -> str:
    """Name a parameter direction (dt, lever * e) in words: a translation, or a rotation
    about a base-frame axis through a point (the scanner turning about that axis)."""
    trans, rot = vector[:3], vector[3:] / lever_m
    if np.linalg.norm(vector[3:]) < 0.3:
        return f"translation along base {_fmt(trans / np.linalg.norm(trans))}"
    # A whole-body rotation e about an axis through c moves the scanner origin by e x (t - c).
    axis = rot / np.linalg.norm(rot)
    moment = np.cross(rot, translation) - trans
    foot = np.cross(moment, rot) / (rot @ rot)
    point = foot + ((translation - foot) @ axis) * axis
    text = f"rotation about base axis {_fmt(axis)} through ({', '.join(f'{v:.2f}' for v in point)}) m"
    slide = (trans @ axis) / np.linalg.norm(rot)
    if abs(slide) > 0.1 * lever_m:
        text += f" with {abs(slide):.2f} m/rad translation along it"
    return text


def _advice(vector: FloatArray, rotation: FloatArray, directions: FloatArray, crossing: FloatArray) -> str:
    """What to change in the trajectory so that the given direction becomes observable."""
    spread_mm = 1e3 * float(np.sqrt(np.mean(np.sum((crossing - crossing.mean(axis=0)) ** 2, axis=1))))
    mean_rod = directions.mean(axis=0) / max(np.linalg.norm(directions.mean(axis=0)), 1e-12)
    tilt_deg = float(np.degrees(np.arccos(np.clip(directions @ mean_rod, -1.0, 1.0))).max())
    spread = (
        f"spread the crossing points over the scan plane (now within {spread_mm:.0f} mm RMS; "
        "use different bearings and distances)"
    )
    tilt = (
        f"tilt the rod more between waypoints (now within {tilt_deg:.1f} deg; "
        "use 10-20 deg about two different axes)"
    )
    if spread_mm < 50.0:
        return spread
    if tilt_deg < 5.0:
        return tilt
    trans, rot = vector[:3], vector[3:]
    normal = rotation[:, 2]
    if np.linalg.norm(trans) >= np.linalg.norm(rot):
        unit = trans / np.linalg.norm(trans)
        return tilt if abs(unit @ normal) > 0.7 or abs(unit @ mean_rod) > 0.7 else spread
    unit = rot / np.linalg.norm(rot)
    if abs(unit @ normal) > 0.7:
        return spread
    return "vary both the rod tilt (10-20 deg about two axes) and the crossing position in the scan plane"


def _result(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    outliers: list[Outlier],
    opts: SolverOptions,
    robust: bool,
    extras: _Extras,
) -> CalibrationResult:
    _, observability = _check_observability(rotation, translation, data, used, opts, stage="final")
    information = _extended_fisher(rotation, translation, data, used, opts, extras)
    if extras.axis:
        information[6:10, 6:10] += np.diag(_axis_prior_weight(opts) ** 2)
    crb_full = np.linalg.inv(information)
    crb = crb_full[:6, :6]
    m2 = (_whitened(rotation, translation, data, opts) ** 2).sum(axis=1)
    reduced = _reduced_chi_square(m2, used, extras)
    # The stated noise model is a floor: residuals smaller than it (a chi-square below 1 by
    # chance, or robot errors that are smooth over the waypoints and partly absorbed by the
    # fit) must not shrink the std below the bound.
    covariance = crb * max(1.0, reduced)
    if extras.offset_note:
        observability.notes.append(extras.offset_note)
    if reduced > 4.0:
        observability.notes.append(
            f"residuals are {np.sqrt(reduced):.1f} times the stated noise (reduced chi-square "
            f"{reduced:.1f}): the centre sigma is too small, or the rod axis definition or TCP poses are off"
        )
    euler_map = np.linalg.inv(euler_zyx_axes(*matrix_to_euler_zyx(rotation)[:2]))

    def std_parts(cov: FloatArray) -> tuple[list[float], list[float], list[float]]:
        rot_cov = cov[3:, 3:]
        return (
            _list(np.sqrt(np.diag(cov[:3, :3])) * 1e3),
            _list(np.degrees(np.sqrt(np.diag(rot_cov)))),
            _list(np.degrees(np.sqrt(np.diag(euler_map @ rot_cov @ euler_map.T)))),
        )

    std_t, std_r, std_e = std_parts(covariance)
    crb_t, crb_r, crb_e = std_parts(crb)
    crossing, _ = data.predicted(rotation, translation)
    delta_mm = np.nan_to_num((data.centres - crossing) * 1e3, nan=1e12, posinf=1e12, neginf=-1e12)
    norm_mm = np.linalg.norm(delta_mm, axis=1)
    whitened_norm = np.nan_to_num(np.sqrt(m2), posinf=1e12)
    columns = zip(
        data.index.tolist(),
        delta_mm[:, 0].tolist(),
        delta_mm[:, 1].tolist(),
        norm_mm.tolist(),
        whitened_norm.tolist(),
        used.tolist(),
        (data.covariance * 1e6).tolist(),
        [None if np.isnan(c).any() else c.tolist() for c in data.noise_covariance * 1e6],
        strict=True,
    )
    residuals = _RESIDUALS.validate_python(  # one validation of plain dicts: twice as fast as
        [  # 10,000 model constructors, and faster than model_construct
            {
                "index": i, "du_mm": du, "dv_mm": dv, "norm_mm": nm, "whitened_norm": wn, "used": u,
                "covariance_uv_mm2": c, "noise_covariance_uv_mm2": noise,
            }
            for i, du, dv, nm, wn, u, c, noise in columns
        ]
    )
    transform = make_transform(rotation, translation)
    options = opts.model_dump()
    options["robust"] = robust and opts.formulation == "ours"  # the paper's problem has no robust mode
    return CalibrationResult(
        T_base_laser=transform.tolist(),
        T_laser_base=invert_transform(transform).tolist(),
        translation_m=_list(translation),
        quaternion_xyzw=_list(matrix_to_quat(rotation)),
        euler_zyx_deg=_list(np.degrees(matrix_to_euler_zyx(rotation))),
        rotvec=_list(matrix_to_rotvec(rotation)),
        covariance=covariance.tolist(),
        std_translation_mm=std_t,
        std_rotation_deg=std_r,
        std_euler_zyx_deg=std_e,
        crb_translation_mm=crb_t,
        crb_rotation_deg=crb_r,
        crb_euler_zyx_deg=crb_e,
        reduced_chi_square=reduced,
        residuals=residuals,
        outliers=outliers,
        rms_residual_mm=float(np.sqrt(np.mean(norm_mm[used] ** 2))),
        waypoints_used=int(used.sum()),
        observability=observability,
        provenance=Provenance(
            software_version=__version__,
            formulation=opts.formulation,
            solver_options=options,
            converged=True,
            iterations=0,
            solve_time_s=0.0,
        ),
        rod_axis=_axis_estimate(
            data,
            extras,
            crb_full * max(1.0, reduced),
            _mean_crossing_along_m(rotation, translation, data, used),
        ),
        range_offset=_range_offset(
            data, extras, crb_full * max(1.0, reduced), opts, np.linalg.norm(crossing[used], axis=1)
        ),
    )


def _extras(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    opts: SolverOptions,
    noise_scale: float = 1.0,
) -> _Extras:
    """Which extra parameters to estimate: refuses a requested one the waypoints cannot
    determine; with ``estimate_axis="auto"`` leaves the axis out (with a note) unless the
    Cramér-Rao bound at the start pins down its offset where the rod crosses the plane. A
    tilt the crossings cannot see (they keep to a short stretch of the rod) is estimated
    with a note: it then hardly moves the line where the waypoints measure it."""
    wanted_axis = opts.estimate_axis is True or opts.estimate_axis == "auto"
    if opts.formulation == "paper" and (opts.estimate_axis is True or opts.estimate_range_offset is True):
        raise ConfigError("the paper formulation cannot estimate the rod axis or the range offset; use ours")
    if opts.formulation == "paper":
        return _Extras()
    terms, offset_note = _range_terms_wanted(rotation, translation, data, usable, opts, noise_scale)
    if not wanted_axis:
        return _Extras(range_terms=terms, offset_note=offset_note)
    extras = _Extras(axis=True, range_terms=terms, offset_note=offset_note)
    fisher = _extended_fisher(rotation, translation, data, usable, opts, extras)
    along_m = _mean_crossing_along_m(rotation, translation, data, usable)
    offset_std_m, tilt_std_deg = _axis_crb_std(fisher, along_m)
    if opts.estimate_axis is True:
        _require_observable(fisher, opts, extras)
    elif not offset_std_m.max() <= opts.auto_axis_max_offset_std_m:
        note = (
            f"rod axis not estimated (auto): the Cramér-Rao std of its offset where it crosses the scan "
            f"plane would be {offset_std_m.max() * 1e3:.2g} mm (limit "
            f"{opts.auto_axis_max_offset_std_m * 1e3:g} mm); {_axis_advice(offset_std_m, tilt_std_deg, opts)}"
        )
        return replace(extras, axis=False, axis_note=note)
    if tilt_std_deg.max() <= opts.weak_axis_tilt_std_deg:
        return extras
    note = (
        f"rod axis tilt weakly determined by the waypoints (Cramér-Rao std {tilt_std_deg.max():.2g} deg), so "
        f"held to the given direction ({opts.axis_prior_std_deg:g} deg std): the crossings keep to a short "
        f"stretch of the rod, where its offset is what the pose relies on; "
        f"{_axis_advice(np.zeros(2), tilt_std_deg, opts)}"
    )
    return replace(extras, axis_note=note)


def _significant_terms(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> tuple[bool, _Extras]:
    """Keep the range error curve's highest term only when the data show it: a t-test of its
    coefficient against the std the fit's own residuals give it (the Cramér-Rao std times the
    residuals' scale, ``sqrt(reduced chi-square)``), at the two-sided level of
    ``auto_range_offset_min_sigmas`` normal std, on the fit's degrees of freedom. This is the
    F-test of the chi-square the term removes: it does not depend on the stated noise's level,
    so conservative centre covariances do not drop a term the residuals need (the fit without
    it then gates good waypoints out). Estimating a parameter that is not there costs the pose
    precision. The offset itself is kept when asked for (not ``auto``). Returns whether the
    curve stays as it is, and the extras to go on with (one term fewer)."""
    terms = extras.range_terms
    if terms == 1 and opts.estimate_range_offset is True:
        return True, extras
    std = float(_crb_std(_extended_fisher(rotation, translation, data, used, opts, extras))[-1])
    std *= _residual_scale(rotation, translation, data, used, opts, extras)
    value = float(data.range_curve_m[terms - 1])
    dof = _degrees_of_freedom(used, extras)
    if abs(value) >= _t_quantile(opts.auto_range_offset_min_sigmas, dof) * std:
        return True, extras
    name, unit, scale = _TERM_UNITS[terms - 1]
    note = f"scanner range {name} {value * scale:+.3g} ± {std * scale:.2g} {unit} is not significant (auto): "
    note += "left out"
    notes = "; ".join(n for n in (extras.offset_note, note) if n)
    return False, replace(extras, range_terms=terms - 1, offset_note=notes)


def _lower_curve(
    rotation: FloatArray, translation: FloatArray, data: _Data, used: np.ndarray, terms: int
) -> FloatArray:
    """The start of the fit with ``terms`` terms when a higher one is left out: the curve of
    that many terms closest (least squares) to the fitted one at the used crossings'
    distances. Not the fitted curve cut short: its terms are powers of ``ln(d / 1 m)``, and
    crossings all on one side of 1 m make them large and cancelling (a 7-waypoint job at
    0.3-0.55 m fitted -203, -1092, -2112, -1736, -517 mm), so the cut curve is hundreds of
    mm off where the rod was seen and the robust fit from there rejects good waypoints."""
    if not terms:
        return np.zeros(0)
    crossing, _, _ = plane_crossing(rotation, translation, data.origins[used], data.directions[used])
    distances_m = np.linalg.norm(crossing, axis=1)
    fitted, _ = range_error_m(data.range_curve_m, distances_m)
    lower, *_ = np.linalg.lstsq(range_error_basis(distances_m, terms), fitted, rcond=None)
    return lower


def _fullest_fit_scale(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    start: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> float:
    """The residuals' scale against the stated noise (``_residual_scale``) of the robust fit
    with every term of the range error curve: the fullest model gives the noise's level
    without the bias of a term left out, so the precision gate judges each term by the std
    the data give it, not by the stated (often conservative) noise. 1 when that fit fails."""
    fullest = replace(extras, range_terms=opts.max_range_terms)
    try:
        rotation, translation, fitted, used, _ = _fit(
            rotation, translation, data, usable, start, True, opts, fullest
        )
    except CalibrationError:
        return 1.0
    return _residual_scale(rotation, translation, fitted, used, opts, fullest)


def _t_quantile(normal_sigmas: float, dof: int) -> float:
    """The Student-t quantile on ``dof`` degrees of freedom with the two-sided tail of
    ``normal_sigmas`` normal std (the normal quantile itself when ``dof`` is not positive)."""
    if dof <= 0:
        return normal_sigmas
    return float(special.stdtrit(dof, special.ndtr(normal_sigmas)))


#: Name, unit and scale from SI of each range-curve term in messages (``x = ln(d / 1 m)``).
_TERM_UNITS = tuple(
    (name, "mm" if not k else f"mm/x{'^' + str(k) if k > 1 else ''}", 1e3)
    for k, name in enumerate(("offset", "slope", "curvature", "cubic term", "quartic term"))
)


def _range_terms_wanted(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    opts: SolverOptions,
    noise_scale: float = 1.0,
) -> tuple[int, str]:
    """How many terms of the range error curve to estimate, and the note when one is left
    out: the most terms whose highest term passes, a term passing when the Cramér-Rao std of
    what it adds to the error over the crossings is within ``auto_range_offset_max_std_m``
    (the offset must be observable when asked for: ``DegenerateDataError`` otherwise). A
    term may pass where a lower one does not: the offset trades against the translation
    along the bearings, and a curve whose slope the distances pin down is estimated with its
    offset, the offset's std then carried into the pose's (a 10-waypoint quick run on the
    physical scanner: offset 2.4 mm over the limit, slope within it; without both, its
    +-10 mm range error failed the outlier test). What it adds is its coefficient's std times half the
    crossings' span in ln d to its power: the highest term's coefficient does not depend on
    where the curve's reference lies (the lower terms take the rest), so a trajectory whose
    crossings all lie on one side of 1 m is judged by its own span, not by an extrapolation.
    ``noise_scale``: the residuals' scale against the stated noise (``_fullest_fit_scale``),
    which the std is multiplied by."""
    if opts.estimate_range_offset is False:
        return 0, ""
    crossing, _ = data.predicted(rotation, translation)
    distances_m = np.linalg.norm(crossing[usable], axis=1)
    reach = max(0.5 * float(np.ptp(range_curve_variable(distances_m)[0])), 1e-3)
    terms = 1 if opts.estimate_range_offset is True else 0
    left_out: list[tuple[int, float]] = []
    for wanted in range(1, opts.max_range_terms + 1):
        trial = _Extras(range_terms=wanted)
        fisher = _extended_fisher(rotation, translation, data, usable, opts, trial)
        if wanted == 1 and opts.estimate_range_offset is True:
            _require_observable(fisher, opts, trial)
        effect_std_m = float(_crb_std(fisher)[-1]) * reach ** (wanted - 1) * noise_scale
        if effect_std_m <= opts.auto_range_offset_max_std_m:
            terms = wanted
        else:
            left_out.append((wanted, effect_std_m))
    left_out = [(wanted, std) for wanted, std in left_out if wanted > terms]
    if not left_out:
        return terms, ""
    wanted, effect_std_m = left_out[0]
    name = _TERM_UNITS[wanted - 1][0]
    return terms, (
        f"scanner range {name} not estimated (auto): the Cramér-Rao std of what it adds "
        f"to the range error would be {effect_std_m * 1e3:.2g} mm (limit "
        f"{opts.auto_range_offset_max_std_m * 1e3:g} mm); spread the crossings' distances from the scanner "
        "more widely (0.3 m or more apart, near and far) to see it"
    )


def _require_observable(fisher: FloatArray, opts: SolverOptions, extras: _Extras) -> None:
    """Refuse (``DegenerateDataError``) extra parameters the waypoints cannot separate from the pose."""
    scale = 1.0 / np.sqrt(np.clip(np.diag(fisher), 1e-300, None))
    eigenvalues = np.linalg.eigvalsh(fisher * np.outer(scale, scale))
    ratio = float(np.sqrt(max(eigenvalues[0], 0.0) / eigenvalues[-1])) if eigenvalues[-1] > 0 else 0.0
    if ratio >= opts.min_condition_ratio * 10.0:
        return
    std = _crb_std(fisher)
    parts = []
    if extras.axis:
        parts.append(_axis_advice(std[6:8], np.degrees(std[8:10]), opts))
    if extras.offset:
        parts.append(
            "for the range offset, vary the crossings' distance from the scanner (0.3 m or more apart)"
        )
    raise DegenerateDataError(
        f"the {'rod axis' if extras.axis else 'range offset'} cannot be told apart from the scanner pose "
        f"with these waypoints (singular-value ratio {ratio:.1e}): {'; '.join(parts)}"
    )


def _range_offset(
    data: _Data, extras: _Extras, covariance: FloatArray, opts: SolverOptions, distances_m: FloatArray
) -> RangeOffset | None:
    """The estimated range error curve (the applied offset added back), its std, and its
    values over the distances the crossings span (the scanner's health figure)."""
    if not extras.offset:
        return None
    terms = extras.range_terms
    curve = data.range_curve_m[:terms].copy()
    curve[0] += opts.range_offset_applied_m
    block = covariance[-terms:, -terms:]
    std = np.sqrt(np.clip(np.diag(block), 0.0, None))
    grid = np.linspace(float(distances_m.min()), float(distances_m.max()), 5)
    basis = range_error_basis(grid, terms)
    values = range_error_m(curve, grid)[0]
    value_std = np.sqrt(np.clip(np.einsum("nk,kl,nl->n", basis, block, basis), 0.0, None))
    dense = np.linspace(grid[0], grid[-1], 50)
    return RangeOffset(
        offset_mm=float(curve[0]) * 1e3,
        std_mm=float(std[0]) * 1e3,
        reference_m=RANGE_CURVE_REFERENCE_M,
        basis=RANGE_CURVE_BASIS,
        terms_mm=_list(curve * 1e3),
        terms_std_mm=_list(std * 1e3),
        curve=[
            RangeErrorPoint(distance_m=float(d), error_mm=float(e) * 1e3, std_mm=float(s) * 1e3)
            for d, e, s in zip(grid, values, value_std, strict=True)
        ],
        worst_mm=float(np.max(np.abs(range_error_m(curve, dense)[0]))) * 1e3,
    )
