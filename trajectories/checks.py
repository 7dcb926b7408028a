"""Preflight of waypoints before any motion: reachable, inside the safety limits, inside
the workspace box (TCP and, when a rod is given, both rod ends).

The reachability and safety tests are callables so the same check runs against the
robot controller on a real cell (``getInverseKinematics``, ``isPoseWithinSafetyLimits``
through the driver) and offline against ``lasercal_hw.ur_kinematics``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import FloatArray, transform_points
from lasercal_hw.models import RodLine
from trajectories.waypoint import Waypoint

logger = logging.getLogger(__name__)

#: ``inverse_kinematics(pose) -> q or None``: joint angles reaching the UR pose vector.
InverseKinematics = Callable[[FloatArray], FloatArray | Sequence[float] | None]
#: ``within_safety_limits(pose) -> bool``: the controller's (or a model's) safety verdict.
SafetyCheck = Callable[[FloatArray], bool]


class WorkspaceBox(BaseModel):
    """Axis-aligned box in the robot base frame that the TCP and the rod must stay inside.

    The default suits a UR5 (reach 0.85 m) standing on a table at z = 0: nothing below
    the table top, nothing higher than 0.9 m above the base.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    min_m: tuple[float, float, float] = (-0.9, -0.9, 0.0)
    max_m: tuple[float, float, float] = (0.9, 0.9, 0.9)

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceBox:
        for axis, low, high in zip("xyz", self.min_m, self.max_m, strict=True):
            if not low < high:
                raise ValueError(f"workspace box {axis}: min {low} m must be below max {high} m")
        return self

    def violations(self, point_m: Sequence[float] | FloatArray, what: str) -> list[str]:
        """Human-readable reasons the point is outside (empty when inside)."""
        reasons = []
        for axis, value, low, high in zip("xyz", point_m, self.min_m, self.max_m, strict=True):
            if value < low:
                reasons.append(f"{what} {axis} = {value:.3f} m is below the workspace minimum {low:.3f} m")
            elif value > high:
                reasons.append(f"{what} {axis} = {value:.3f} m is above the workspace maximum {high:.3f} m")
        return reasons


@dataclass(frozen=True)
class WaypointProblem:
    """One reason one waypoint must not be visited."""

    index: int
    label: str
    reason: str

    def __str__(self) -> str:
        label = f" ({self.label})" if self.label else ""
        return f"waypoint {self.index}{label}: {self.reason}"


@dataclass(frozen=True)
class CheckReport:
    """Outcome of :func:`check_waypoints`: the problems found and the joint solutions."""

    checked: int
    problems: list[WaypointProblem] = field(default_factory=list)
    joint_solutions_rad: dict[int, FloatArray] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when no waypoint has a problem."""
        return not self.problems

    @property
    def failing_indices(self) -> list[int]:
        """Indices of the waypoints with at least one problem, in order."""
        return sorted({p.index for p in self.problems})

    def summary(self) -> str:
        """One line per problem, or a one-line all-clear."""
        if self.ok:
            return f"all {self.checked} waypoints are reachable and inside the limits"
        lines = [f"{len(self.failing_indices)} of {self.checked} waypoints fail the preflight check:"]
        lines += [f"  {p}" for p in self.problems]
        return "\n".join(lines)


def check_waypoints(
    waypoints: Sequence[Waypoint],
    *,
    inverse_kinematics: InverseKinematics,
    within_safety_limits: SafetyCheck | None = None,
    workspace: WorkspaceBox | None = None,
    rod: RodLine | None = None,
) -> CheckReport:
    """Check every waypoint and list every problem (it does not stop at the first one)."""
    box = workspace or WorkspaceBox()
    problems: list[WaypointProblem] = []
    solutions: dict[int, FloatArray] = {}
    seen: set[int] = set()
    for waypoint in waypoints:

        def problem(reason: str, w: Waypoint = waypoint) -> None:
            problems.append(WaypointProblem(w.index, w.label, reason))

        if waypoint.index in seen:
            problem("duplicate waypoint index")
        seen.add(waypoint.index)
        pose = waypoint.pose_array()
        for reason in box.violations(pose[:3], "TCP"):
            problem(reason)
        if rod is not None:
            ends_base = transform_points(waypoint.matrix(), rod.end_points_m())
            for name, end in zip(("rod start", "rod end"), ends_base, strict=True):
                for reason in box.violations(end, name):
                    problem(reason)
        q = inverse_kinematics(pose)
        if q is None or len(q) == 0:
            problem("not reachable: no inverse kinematics solution")
        else:
            solutions[waypoint.index] = np.asarray(q, dtype=float)
        if within_safety_limits is not None and not within_safety_limits(pose):
            problem("outside the robot's safety limits")
    report = CheckReport(checked=len(waypoints), problems=problems, joint_solutions_rad=solutions)
    logger.info("preflight: %s", report.summary().splitlines()[0])
    return report


def require_waypoints_ok(
    waypoints: Sequence[Waypoint],
    *,
    inverse_kinematics: InverseKinematics,
    within_safety_limits: SafetyCheck | None = None,
    workspace: WorkspaceBox | None = None,
    rod: RodLine | None = None,
) -> CheckReport:
    """:func:`check_waypoints`, raising ConfigError with every failure listed if any."""
    report = check_waypoints(
        waypoints,
        inverse_kinematics=inverse_kinematics,
        within_safety_limits=within_safety_limits,
        workspace=workspace,
        rod=rod,
    )
    if not report.ok:
        raise ConfigError(
            report.summary() + "\nchange the trajectory (preset, waypoint file or workspace box) and retry"
        )
    return report
