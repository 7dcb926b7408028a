"""The pose checks of every waypoint before any motion: reachable, inside the safety
limits, inside the workspace box (TCP and, when a rod is given, both rod ends).

One set of checks, one message style: ``lasercal run``'s preflight runs ``check_pose``
against the robot controller (``getInverseKinematics``, ``isPoseWithinSafetyLimits``
through the driver), ``lasercal trajectory check`` runs it offline against
``lasercal_hw.ur5_kinematics``; the reachability and safety tests are callables for that.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from lasercal_hw.config import WorkspaceConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import FloatArray, pose_to_matrix, transform_points
from lasercal_hw.models import RodLine
from trajectories.waypoint import Waypoint

logger = logging.getLogger(__name__)

#: ``inverse_kinematics(pose) -> q or None``: joint angles reaching the UR pose vector.
InverseKinematics = Callable[[FloatArray], FloatArray | Sequence[float] | None]
#: ``within_safety_limits(pose) -> bool``: the controller's (or a model's) safety verdict.
SafetyCheck = Callable[[FloatArray], bool]


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


def check_pose(
    pose: FloatArray,
    *,
    inverse_kinematics: InverseKinematics,
    within_safety_limits: SafetyCheck | None = None,
    workspace: WorkspaceConfig | None = None,
    rod: RodLine | None = None,
) -> tuple[list[str], FloatArray | None]:
    """Every reason one UR pose must not be visited, and its joint solution (None when
    unreachable)."""
    box = workspace or WorkspaceConfig()
    pose = np.asarray(pose, dtype=float).reshape(6)
    reasons = box.violations(pose[:3], "TCP")
    if rod is not None:
        ends_base = transform_points(pose_to_matrix(pose)[None], rod.end_points_m())
        for name, end in zip(("rod start", "rod end"), ends_base, strict=True):
            reasons += box.violations(end, name)
    q = inverse_kinematics(pose)
    solution = None if q is None or len(q) == 0 else np.asarray(q, dtype=float)
    if solution is None:
        reasons.append("not reachable: no inverse kinematics solution")
    if within_safety_limits is not None and not within_safety_limits(pose):
        reasons.append("outside the robot's safety limits")
    return reasons, solution


def check_waypoints(
    waypoints: Sequence[Waypoint],
    *,
    inverse_kinematics: InverseKinematics,
    within_safety_limits: SafetyCheck | None = None,
    workspace: WorkspaceConfig | None = None,
    rod: RodLine | None = None,
) -> CheckReport:
    """Check every waypoint and list every problem (it does not stop at the first one)."""
    problems: list[WaypointProblem] = []
    solutions: dict[int, FloatArray] = {}
    seen: set[int] = set()
    for waypoint in waypoints:
        reasons, q = check_pose(
            waypoint.pose_array(),
            inverse_kinematics=inverse_kinematics,
            within_safety_limits=within_safety_limits,
            workspace=workspace,
            rod=rod,
        )
        if waypoint.index in seen:
            reasons.insert(0, "duplicate waypoint index")
        seen.add(waypoint.index)
        problems += [WaypointProblem(waypoint.index, waypoint.label, reason) for reason in reasons]
        if q is not None:
            solutions[waypoint.index] = q
    report = CheckReport(checked=len(waypoints), problems=problems, joint_solutions_rad=solutions)
    logger.info("preflight: %s", report.summary().splitlines()[0])
    return report


def require_waypoints_ok(
    waypoints: Sequence[Waypoint],
    *,
    inverse_kinematics: InverseKinematics,
    within_safety_limits: SafetyCheck | None = None,
    workspace: WorkspaceConfig | None = None,
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
