"""The calibration result: the document written to ``result.json``.

Units are in the field names.  Rotation uncertainties are given twice: as small
rotations about the base x, y, z axes (``*_rotation_deg``, the left perturbation
``R' = exp([e]x) R``) and as ZYX Euler angle uncertainties (``*_euler_zyx_deg``, yaw,
pitch, roll).  ``std_*`` come from the Jacobian at the solution scaled by the reduced
chi-square (a posteriori); ``crb_*`` are the Cramér-Rao bound of the same waypoints
under the stated noise model (a priori).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, Field

from lasercal_hw.calibration.model import RangeCurveBasis, range_error_m
from lasercal_hw.geometry import FloatArray
from lasercal_hw.models import RodLine


class WaypointResidual(BaseModel):
    """Measured minus predicted rod centre of one waypoint, in the scanner plane."""

    index: int
    du_mm: float
    dv_mm: float
    norm_mm: float
    whitened_norm: float = Field(description="Mahalanobis length under the noise model")
    used: bool
    covariance_uv_mm2: list[list[float]] | None = Field(
        default=None,
        description="the centre covariance (2x2, mm^2) the solver weighed this waypoint with, robot "
        "noise not included, in the scanner's frame (u along its x axis, v along its y axis, in the "
        "scan plane); None in a file written before it was recorded",
    )
    noise_covariance_uv_mm2: list[list[float]] | None = Field(
        default=None,
        description="the part of that centre covariance (2x2, mm^2, same frame) another dwell at this "
        "pose draws anew: the dwell's noise through the fit (all of it where the extraction warned of "
        "the centre); the verify weighs the waypoint with it. None where unknown (centres read from a "
        "CSV, or a file written before it was recorded)",
    )
    echo_middle_uv_mm: list[float] | None = Field(
        default=None,
        description="a twist drill's: where the middle of the rod's echo strength lies from this centre, "
        "across its bearing (u, v; mm, same frame): its section's glint places it off the axis, by "
        "the same at every dwell of this pose, while the fitted centre jumps with the beams its fit "
        "keeps; the verify compares middles. None: not fluted, no intensities, or no middle found",
    )
    echo_middle_noise_mm2: float | None = Field(
        default=None,
        description="what another dwell draws anew of echo_middle_uv_mm's length across the bearing (mm^2)",
    )
    echo_middle_move_uv_mm: list[float] | None = Field(
        default=None,
        description="a plain rod's: how far the middle of the rod's echo moved the fitted centre across "
        "its bearing (u, v; mm, same frame); [0, 0] where no middle was read and the fit placed it. At "
        "a pose where the middle is read at some dwells and not at others, the two kinds of centre lie "
        "up to 2 mm apart, so the verify compares a centre with one placed alike. None: a fluted rod "
        "(echo_middle_uv_mm), the first pass's centre kept, or a file written before it was recorded",
    )
    first_pass_kept: str | None = Field(
        default=None,
        description="why the second pass could not fit this centre again, so that the solve took "
        "the first pass's centre (a fit of another kind: the verify does not compare a re-fitted "
        "centre with it). None: re-fitted, or a file written before it was recorded",
    )


class Outlier(BaseModel):
    """A waypoint left out of the final fit, and why."""

    index: int
    residual_mm: float
    reason: str


class Observability(BaseModel):
    """How well the waypoints pin down each direction of the transform."""

    lever_m: float = Field(description="length that converts rotation (rad) to metres for comparison")
    singular_values: list[float] = Field(description="of the whitened Jacobian, rotations scaled by lever_m")
    condition_ratio: float = Field(description="smallest over largest singular value")
    weakest_direction: str
    notes: list[str] = Field(default_factory=list)


class Provenance(BaseModel):
    """What produced the result."""

    software: str = "lasercal"
    software_version: str
    formulation: Literal["ours", "paper"]
    solver_options: dict[str, Any]
    converged: bool
    iterations: int
    solve_time_s: float
    message: str = ""


class RodAxisEstimate(BaseModel):
    """The rod's line in the TCP frame: the job's nominal one and the one estimated with the
    transform (or the nominal one again, with the reason, when it was not estimated)."""

    estimated: bool
    nominal_origin_m: list[float]
    nominal_direction: list[float]
    origin_m: list[float] = Field(
        description="point of the estimated line level with the nominal origin along the nominal axis"
    )
    direction: list[float] = Field(description="unit direction of the estimated line")
    basis_tcp: list[list[float]] = Field(description="e1, e2: TCP-frame unit vectors across the nominal axis")
    offset_mm: list[float] = Field(description="line moved along e1, e2")
    offset_std_mm: list[float]
    tilt_deg: list[float] = Field(description="line tilted towards e1, e2")
    tilt_std_deg: list[float]
    crossing_along_mm: float = Field(
        0.0, description="mean distance along the rod, from the nominal origin, where it crossed the plane"
    )
    crossing_offset_mm: list[float] = Field(
        default_factory=lambda: [0.0, 0.0], description="line moved along e1, e2 at crossing_along_mm"
    )
    crossing_offset_std_mm: list[float] = Field(default_factory=lambda: [0.0, 0.0])
    note: str = ""


class RangeErrorPoint(BaseModel):
    """The range error curve at one distance."""

    distance_m: float
    error_mm: float
    std_mm: float


class RangeOffset(BaseModel):
    """The scanner's range error (measured minus true range) over distance, estimated with the
    transform: a polynomial in ``ln(d / reference_m)`` (``terms_mm``, basis ``log_distance``)
    with as many terms as the waypoints pin down and the data show. Calibrations solved before
    kept ``offset + scale (d - reference) + curvature (d - reference)^2`` (basis ``distance``:
    ``scale_mm_per_m`` and ``curvature_mm_per_m2``); both are read."""

    offset_mm: float = Field(description="the error at reference_m (with one term: at every distance)")
    std_mm: float
    reference_m: float = 1.0
    basis: RangeCurveBasis = Field(
        "distance", description="log_distance: powers of ln(d / reference_m); distance: of d - reference_m"
    )
    terms_mm: list[float] = Field(
        default_factory=list,
        description="log_distance: every term (mm per ln(d / reference_m)^k), the offset first",
    )
    terms_std_mm: list[float] = Field(default_factory=list, description="their std")
    scale_mm_per_m: float | None = None
    scale_std_mm_per_m: float | None = None
    curvature_mm_per_m2: float | None = None
    curvature_std_mm_per_m2: float | None = None
    curve: list[RangeErrorPoint] = Field(
        default_factory=list, description="the curve over the distances the crossings span"
    )
    worst_mm: float | None = Field(
        None,
        description="health figure: the largest |error| over those distances (UTM-30LX-EW data sheet: 30 mm; "
        "one that grows between calibrations marks a unit to replace)",
    )

    def coefficients_m(self) -> list[float]:
        """The curve's terms in metres in its ``basis`` (as many as were estimated), for
        ``calibration.model.range_error_m``."""
        if self.terms_mm:
            return [float(term) / 1000.0 for term in self.terms_mm]
        terms = [self.offset_mm, self.scale_mm_per_m, self.curvature_mm_per_m2]
        count = 1 + sum(1 for term in terms[1:] if term is not None)
        return [float(term or 0.0) / 1000.0 for term in terms[:count]]

    def error_m(self, distance_m: FloatArray) -> FloatArray:
        """The range error (m) this curve gives at the distances."""
        return range_error_m(np.asarray(self.coefficients_m()), distance_m, self.basis)[0]


class CalibrationResult(BaseModel):
    """Pose of the scanner in the robot base frame, with its uncertainty and diagnostics."""

    T_base_laser: list[list[float]] = Field(description="4x4, p_base = T @ p_laser, row-major")
    T_laser_base: list[list[float]] = Field(description="inverse of T_base_laser")
    translation_m: list[float]
    quaternion_xyzw: list[float]
    euler_zyx_deg: list[float] = Field(description="yaw, pitch, roll; R = Rz Ry Rx")
    rotvec: list[float] = Field(description="rotation vector in radians")
    covariance: list[list[float]] = Field(
        description="6x6 a-posteriori covariance of (tx, ty, tz [m], rot x, y, z about base axes [rad])"
    )
    std_translation_mm: list[float]
    std_rotation_deg: list[float] = Field(description="about base x, y, z")
    std_euler_zyx_deg: list[float] = Field(description="yaw, pitch, roll")
    crb_translation_mm: list[float]
    crb_rotation_deg: list[float] = Field(description="about base x, y, z")
    crb_euler_zyx_deg: list[float] = Field(description="yaw, pitch, roll")
    reduced_chi_square: float
    residuals: list[WaypointResidual]
    outliers: list[Outlier]
    rms_residual_mm: float
    waypoints_used: int
    observability: Observability
    provenance: Provenance
    rod_axis: RodAxisEstimate | None = None
    range_offset: RangeOffset | None = None

    def matrix(self) -> FloatArray:
        """``T_base_laser`` as a 4x4 numpy array."""
        return np.asarray(self.T_base_laser, dtype=float)

    def estimated_rod(self, nominal: RodLine) -> RodLine:
        """The rod line this result estimated (``nominal`` when it did not estimate it)."""
        axis = self.rod_axis
        if axis is None or not axis.estimated:
            return nominal
        return replace(nominal, origin_m=np.asarray(axis.origin_m), direction=np.asarray(axis.direction))

    def inverse_matrix(self) -> FloatArray:
        """``T_laser_base`` as a 4x4 numpy array."""
        return np.asarray(self.T_laser_base, dtype=float)

    def estimate_lines(self) -> list[str]:
        """The estimated rod axis next to the nominal one and the range offset, one line each
        (empty when neither was asked for); the CLI and the report print them."""
        lines = []
        axis = self.rod_axis
        if axis is not None and axis.estimated:
            estimated = f"estimated origin {_mm(axis.origin_m)} mm, direction {_vec(axis.direction)}"
            nominal = f"nominal {_mm(axis.nominal_origin_m)} mm, {_vec(axis.nominal_direction)}"
            moved = f"moved {_pm(axis.offset_mm, axis.offset_std_mm, 2)} mm"
            tilted = f"tilted {_pm(axis.tilt_deg, axis.tilt_std_deg, 3)} deg"
            basis = f"{_vec(axis.basis_tcp[0])}, {_vec(axis.basis_tcp[1])}"
            crossing = (
                f"where it crossed the scan plane ({axis.crossing_along_mm:.0f} mm along the rod) moved "
                f"{_pm(axis.crossing_offset_mm, axis.crossing_offset_std_mm, 2)} mm"
            )
            lines.append(
                f"rod axis (TCP frame): {estimated}; {nominal}; {moved} and {tilted} along {basis}; "
                f"{crossing}"
            )
        if axis is not None and axis.note:
            lines.append(axis.note)
        if self.range_offset is not None:
            lines.append(_range_line(self.range_offset))
        return lines

    def to_json_dict(self) -> dict[str, Any]:
        """The ``result.json`` document (plain JSON types, matrices row-major)."""
        return self.model_dump(mode="json")


def _range_line(offset: RangeOffset) -> str:
    """The range error curve in one line."""
    if len(offset.coefficients_m()) == 1:
        return f"scanner range offset (measured - true): {offset.offset_mm:+.2f} ± {offset.std_mm:.2f} mm"
    terms = [f"{offset.offset_mm:+.2f} ± {offset.std_mm:.2f} mm at {offset.reference_m:g} m"]
    if offset.basis == "log_distance":
        terms += [
            f"{value:+.2f} ± {std:.2f} mm x ln(d/{offset.reference_m:g} m)" + (f"^{k}" if k > 1 else "")
            for k, (value, std) in enumerate(zip(offset.terms_mm, offset.terms_std_mm, strict=True))
            if k
        ]
    else:
        terms.append(f"scale {offset.scale_mm_per_m:+.2f} ± {offset.scale_std_mm_per_m:.2f} mm/m")
        if offset.curvature_mm_per_m2 is not None:
            curvature, curvature_std = offset.curvature_mm_per_m2, offset.curvature_std_mm_per_m2
            terms.append(f"curvature {curvature:+.2f} ± {curvature_std:.2f} mm/m²")
    span = f"{offset.curve[0].distance_m:.2f}-{offset.curve[-1].distance_m:.2f} m" if offset.curve else ""
    return (
        f"scanner range error (measured - true): {', '.join(terms)}; largest {offset.worst_mm:.1f} mm over "
        f"{span} (data sheet: 30 mm)"
    )


def _vec(values: list[float]) -> str:
    return "(" + ", ".join(f"{v:+.4f}" for v in values) + ")"


def _mm(values: list[float]) -> str:
    return "(" + ", ".join(f"{v * 1e3:+.2f}" for v in values) + ")"


def _pm(values: list[float], stds: list[float], digits: int) -> str:
    return ", ".join(f"{v:+.{digits}f} ± {s:.{digits}f}" for v, s in zip(values, stds, strict=True))
