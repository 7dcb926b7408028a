"""The rod axis in the TCP frame: its deviation from the job's line, the Cramér-Rao std of its offset
where it crosses the plane and of its tilt, its prior, advice in words when the trajectory cannot see
it, and the estimate reported in the result (``RodAxisEstimate``)."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.model import axis_basis, plane_crossing
from lasercal_hw.calibration.result import RodAxisEstimate
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _Extras
from lasercal_hw.calibration.solver.formatting import _list
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.geometry import FloatArray
from lasercal_hw.models import RodLine


def _axis_crb_std(fisher: FloatArray, crossing_along_m: float) -> tuple[FloatArray, FloatArray]:
    """Cramér-Rao std of the rod axis's offset where it crosses the plane (m, e1 and e2) and
    of its tilt (deg), from the information of the pose, the axis (parameters 6-9) and more."""
    if not np.all(np.isfinite(fisher)):
        return np.full(2, np.inf), np.full(2, np.inf)
    axis_covariance = np.linalg.pinv(fisher, rcond=1e-12, hermitian=True)[6:10, 6:10]
    tilt_std_rad = np.sqrt(np.clip(np.diag(axis_covariance)[2:], 0.0, None))
    return _crossing_offset_std_m(axis_covariance, crossing_along_m), np.degrees(tilt_std_rad)


def _crossing_offset_std_m(axis_covariance: FloatArray, crossing_along_m: float) -> FloatArray:
    """Std (m) of the axis offset ``a + along * b`` where the rod crosses the plane, from the
    covariance (4, 4) of the offset ``a`` and tilt ``b`` at the rod origin."""
    to_crossing = np.hstack([np.eye(2), crossing_along_m * np.eye(2)])
    return np.sqrt(np.clip(np.diag(to_crossing @ axis_covariance @ to_crossing.T), 0.0, None))


def _axis_advice(offset_std_m: FloatArray, tilt_std_deg: FloatArray, opts: SolverOptions) -> str:
    """Which tool motion the trajectory lacks to observe the rod axis."""
    advice = []
    if not offset_std_m.max() <= opts.auto_axis_max_offset_std_m:
        advice.append(
            "to see the axis offset, turn the tool about the rod axis between waypoints (spin it 90 deg or "
            "more) and tilt it about two different axes"
        )
    if not tilt_std_deg.max() <= opts.weak_axis_tilt_std_deg:
        advice.append(
            "to see the axis tilt, vary where along the rod it crosses the scan plane (crossings spread "
            "5 cm or more along the rod)"
        )
    return "; ".join(advice) or "the trajectory is too short"


def _axis_prior_weight(opts: SolverOptions) -> FloatArray:
    """1 / std of the axis prior for (offset e1, e2 (m), tilt e1, e2 (rad))."""
    return 1.0 / np.array([opts.axis_prior_std_m] * 2 + [np.radians(opts.axis_prior_std_deg)] * 2)


def axis_deviation(nominal: RodLine, rod: RodLine) -> FloatArray:
    """How ``rod`` lies off ``nominal``: its offset (m) across the nominal axis at the nominal
    origin and its tilt (the tangent) along ``axis_basis`` of the nominal direction, the
    parameters of ``moved_rod``."""
    basis = axis_basis(nominal.direction)
    direction = rod.unit_direction()
    nominal_direction = nominal.unit_direction()
    along = direction @ nominal_direction
    nominal_origin = np.asarray(nominal.origin_m, dtype=float)
    origin = np.asarray(rod.origin_m, dtype=float)
    level = origin + ((nominal_origin - origin) @ nominal_direction) / along * direction
    offset = (level - nominal_origin) @ basis
    return np.concatenate([offset, (direction @ basis) / along])


def _mean_crossing_along_m(
    rotation: FloatArray, translation: FloatArray, data: _Data, used: np.ndarray
) -> float:
    """Mean distance along the rod, from its origin, at which the used waypoints cross the plane."""
    _, _, along_m = plane_crossing(rotation, translation, data.origins[used], data.directions[used])
    return float(np.mean(along_m))


def _axis_estimate(
    data: _Data, extras: _Extras, covariance: FloatArray, crossing_along_m: float
) -> RodAxisEstimate | None:
    """The estimated rod line next to the nominal one (None when the axis was never asked for),
    with its offset where the rod crossed the plane: the part of the line the waypoints pin
    down best when the crossings keep to a short stretch of the rod."""
    nominal = data.nominal_rod
    if not extras.axis and not extras.axis_note:
        return None
    basis = axis_basis(nominal.direction)
    deviation = axis_deviation(nominal, data.rod)
    offset, tilt = deviation[:2], np.arctan(deviation[2:])
    axis_covariance = covariance[6:10, 6:10] if extras.axis else np.zeros((4, 4))
    std = np.sqrt(np.diag(axis_covariance))
    crossing_std = _crossing_offset_std_m(axis_covariance, crossing_along_m)
    return RodAxisEstimate(
        estimated=extras.axis,
        nominal_origin_m=_list(nominal.origin_m),
        nominal_direction=_list(nominal.unit_direction()),
        origin_m=_list(np.asarray(nominal.origin_m, dtype=float) + basis @ offset),
        direction=_list(data.rod.unit_direction()),
        basis_tcp=basis.T.tolist(),
        offset_mm=_list(offset * 1e3),
        offset_std_mm=_list(std[:2] * 1e3),
        tilt_deg=_list(np.degrees(tilt)),
        tilt_std_deg=_list(np.degrees(std[2:])),
        crossing_along_mm=crossing_along_m * 1e3,
        crossing_offset_mm=_list((offset + crossing_along_m * deviation[2:]) * 1e3),
        crossing_offset_std_mm=_list(crossing_std * 1e3),
        note=extras.axis_note,
    )
