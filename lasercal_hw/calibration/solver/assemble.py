"""The ``CalibrationResult`` of a fit: covariance (the Cramér-Rao bound scaled by the reduced
chi-square), std, residuals per waypoint, observability, provenance, rod axis and range curve."""

from __future__ import annotations

import numpy as np
from pydantic import TypeAdapter

from lasercal_hw import __version__
from lasercal_hw.calibration.model import euler_zyx_axes
from lasercal_hw.calibration.result import CalibrationResult, Outlier, Provenance, WaypointResidual
from lasercal_hw.calibration.solver.axis import _axis_estimate, _axis_prior_weight, _mean_crossing_along_m
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _extended_fisher, _Extras
from lasercal_hw.calibration.solver.formatting import _list
from lasercal_hw.calibration.solver.observability import _check_observability
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.range_curve import _range_offset
from lasercal_hw.calibration.solver.residuals import _reduced_chi_square, _whitened
from lasercal_hw.geometry import (
    FloatArray,
    invert_transform,
    make_transform,
    matrix_to_euler_zyx,
    matrix_to_quat,
    matrix_to_rotvec,
)

_RESIDUALS = TypeAdapter(list[WaypointResidual])


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
