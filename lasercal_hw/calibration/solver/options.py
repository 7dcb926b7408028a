"""The solver's settings (``SolverOptions``), recorded in the result's provenance."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field


class SolverOptions(BaseModel):
    """Settings of the solver (recorded in the result's provenance)."""

    formulation: Literal["ours", "paper"] = "ours"
    loss: Literal["huber", "soft_l1", "cauchy"] = Field("huber", description="robust loss in robust mode")
    loss_scale: float | None = Field(
        None, gt=0, description="robust loss knee in sigmas; default: the outlier limit (3.7 at 99.9 %)"
    )
    outlier_confidence: float = Field(0.999, gt=0.5, lt=1.0)
    max_rejection_rounds: int = Field(10, ge=1)
    max_outlier_fraction: float = Field(0.3, ge=0.0, lt=1.0)
    default_sigma_uv_m: float = Field(0.005, gt=0, description="centre noise when none is given")
    robot_sigma_m: float = Field(0.0005, ge=0, description="robot TCP position noise per axis")
    min_incidence_deg: float = Field(
        5.0, ge=0, lt=90, description="rod-to-plane angle below which a waypoint is unusable"
    )
    parallel_tolerance_deg: float = Field(0.5, ge=0, description="all rod axes within this are 'parallel'")
    min_condition_ratio: float = Field(1e-6, gt=0, description="refuse below this singular-value ratio")
    weak_condition_ratio: float = Field(1e-2, gt=0, description="note directions below this ratio")
    estimate_axis: bool | Literal["auto"] = Field(
        False,
        description="estimate the rod line in the TCP frame (2 offsets, 2 tilts); auto: when observable",
    )
    estimate_range_offset: bool | Literal["auto"] = Field(
        False,
        description="estimate the scanner's range error curve over distance (an offset, then powers of "
        "ln(distance) where the waypoints pin them down); auto: the offset too only when observable",
    )
    max_range_terms: int = Field(
        5,
        ge=1,
        le=5,
        description="most terms of the range error curve: 1 an offset, each more a power of ln(d / 1 m)",
    )
    auto_range_offset_max_std_m: float = Field(
        0.002,
        gt=0,
        description="estimate a term of the range error curve when the Cramér-Rao std of what it adds to the "
        "error over the crossings' span (its coefficient's std times half the span in ln d, to its power) is "
        "below this",
    )
    auto_range_offset_min_sigmas: float = Field(
        3.3, gt=0, description="auto: ... and keep it only when it is this many std from zero"
    )
    range_offset_applied_m: float = Field(
        0.0, description="range offset already removed from the centres (added to the reported offset)"
    )
    auto_axis_max_offset_std_m: float = Field(
        0.001,
        gt=0,
        description="auto: estimate the axis when the Cramér-Rao std of its offset where the rod crosses "
        "the plane is below this",
    )
    axis_prior_std_m: float = Field(
        0.005,
        gt=0,
        description="how far the given rod axis may be off across itself (one std): an estimated axis is "
        "held to it where the waypoints cannot see it",
    )
    axis_prior_std_deg: float = Field(3.0, gt=0, description="... and how far it may be tilted (one std)")
    weak_axis_tilt_std_deg: float = Field(
        0.5, gt=0, description="note a rod-axis tilt whose Cramér-Rao std is above this as weakly determined"
    )
