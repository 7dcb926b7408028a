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

from lasercal_hw import __version__
from lasercal_hw.calibration.initial import linear_initial_pose
from lasercal_hw.calibration.model import euler_zyx_axes
from lasercal_hw.calibration.paper import solve_paper
from lasercal_hw.calibration.plausible import check_physical
from lasercal_hw.calibration.result import CalibrationResult, Outlier, Provenance, WaypointResidual
from lasercal_hw.calibration.solver.axis import (
    _axis_advice,
    _axis_crb_std,
    _axis_estimate,
    _axis_prior_weight,
    _mean_crossing_along_m,
)
from lasercal_hw.calibration.solver.data import (
    MIN_WAYPOINTS,
    _arrays,
    _check_rod_directions,
    _Data,
    _usable_by_incidence,
)
from lasercal_hw.calibration.solver.extras import _extended_fisher, _Extras
from lasercal_hw.calibration.solver.fit import _check_not_diverged, _fit, _rejected
from lasercal_hw.calibration.solver.formatting import _list
from lasercal_hw.calibration.solver.observability import _check_observability, _require_observable
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.range_curve import (
    _fullest_fit_scale,
    _lower_curve,
    _range_offset,
    _range_terms_wanted,
    _significant_terms,
)
from lasercal_hw.calibration.solver.residuals import _reduced_chi_square, _whitened
from lasercal_hw.errors import CalibrationError, ConfigError, DegenerateDataError
from lasercal_hw.geometry import (
    FloatArray,
    invert_transform,
    make_transform,
    matrix_to_euler_zyx,
    matrix_to_quat,
    matrix_to_rotvec,
)
from lasercal_hw.models import Observation, RodLine

logger = logging.getLogger(__name__)

_RESIDUALS = TypeAdapter(list[WaypointResidual])


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
