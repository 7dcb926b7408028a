"""Shared crossings for a cell: waypoints of one scanner where the rod also crosses another
scanner's plane, at distances that other scanner is calibrated at (docs/cell.md).

A cell job tests whether two scanners agree where both saw the rod at one waypoint
(``lasercal_hw/calibration/agreement.py``). The other scanner (the *watcher*) corrects its
centre there with the range error curve its own run estimated, which holds only over the
distances its own waypoints span; a waypoint designed for one plane alone puts the rod far
outside that span in the other plane. ``design_with_shared`` therefore draws the scanner's
candidates (``trajectories.candidates``) and keeps those whose rod also crosses the watcher's
plane:

- between the rod's ends with ``END_MARGIN_M`` to spare wherever inside the pose uncertainty
  the watcher's plane really is (``crossing_window_m``, as for the scanner's own plane);
- inside the watcher's field of view (with the same margin as a design's), its beam clear of
  the robot's base column, and at a distance inside ``watcher_span_m`` (the distances its own
  waypoints cross at).

Of those it takes ``count``, spread in the watcher's plane (farthest-point choice among the
nearer half for the scanner, ``MIN_SEPARATION_M`` apart), adds their Fisher information as
a prior to the scanner's own design (``trajectories.design.design``: the rest of the
waypoints are chosen knowing them) and orders all in one tour with the design's own
visiting order and walk check. The module only calls ``trajectories.design``; it changes
nothing there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lasercal_hw.geometry import FloatArray, matrix_to_pose
from trajectories.candidates import (
    AXIS_TOOL_TURN_SPREAD_DEG,
    COLUMN_CLEARANCE_M,
    FIELD_OF_VIEW_MARGIN_DEG,
    HALF_FIELD_OF_VIEW_DEG,
    HOME_Q_RAD,
    TOOL_TURN_SPREAD_DEG,
    CandidatePool,
    PoseUncertainty,
    column_distance_m,
    crossing_window_m,
    draw_candidates,
)
from trajectories.design import (
    MIN_SEPARATION_M,
    Design,
    DesignRequest,
    InformationModel,
    design,
    information_blocks,
    visited_crossings,
    visiting_order,
    walk_problem,
)
from trajectories.plane_crossing import rod_plane_crossings
from trajectories.waypoint import Waypoint, waypoint_matrices

#: Candidates drawn to find shared crossings, per candidate of the scanner's own design (they
#: are rare: a thin lens of the workspace).
SHARED_CANDIDATES_PER_CANDIDATE = 10
#: The pose uncertainty shared crossings are designed for by default: 3 cm and 3 deg.
SHARED_UNCERTAINTY = PoseUncertainty(0.03, 3.0)
#: Tries at a choice of shared crossings that the tour with the rest can walk.
_SHARED_ROUNDS = 6


@dataclass(frozen=True)
class SharedRequest:
    """Where the watcher is roughly (``T_base_laser``), its name for the labels, the distances
    its own waypoints span (``span_m``: min, max), how many shared crossings to add, and the
    pose uncertainty both planes' rod windows must hold for at them (shared crossings lie in a
    thin lens between the scanners: a tape measure's 5 cm / 5 deg leaves none on the example
    cell; the scanner's own waypoints keep the design request's)."""

    name: str
    T_base_laser: FloatArray
    span_m: tuple[float, float]
    count: int
    uncertainty: PoseUncertainty = SHARED_UNCERTAINTY


@dataclass(frozen=True)
class SharedCandidates:
    """The candidates of a pool whose rod crosses the watcher's plane usably: their indices in
    the pool and the crossing there (range and bearing from the watcher, base-frame point)."""

    index: np.ndarray
    range_m: FloatArray
    bearing_rad: FloatArray
    point_base_m: FloatArray


def shared_candidates(pool: CandidatePool, request: DesignRequest, shared: SharedRequest) -> SharedCandidates:
    """The candidates of ``pool`` (drawn for the request's scanner) that the watcher sees too."""
    rod, uncertainty = request.rules.rod, shared.uncertainty
    T_other = np.asarray(shared.T_base_laser, dtype=float)
    crossings = rod_plane_crossings(pool.T_base_tcp, rod, T_other)
    direction = pool.T_base_tcp[:, :3, :3] @ rod.unit_direction()
    cos_tilt = np.abs(direction @ T_other[:3, 2])
    low, high = crossing_window_m(rod, crossings.range_m, np.maximum(cos_tilt, 1e-9), uncertainty)
    with np.errstate(invalid="ignore"):
        ok = (crossings.along_rod_m >= low) & (crossings.along_rod_m <= high)
        margin_deg = (
            FIELD_OF_VIEW_MARGIN_DEG + uncertainty.rotation_deg
            + np.degrees(uncertainty.translation_m / np.maximum(crossings.range_m, 1e-9))
        )
        ok &= np.abs(np.degrees(crossings.bearing_rad)) <= HALF_FIELD_OF_VIEW_DEG - margin_deg
        ok &= (crossings.range_m >= shared.span_m[0]) & (crossings.range_m <= shared.span_m[1])
    in_plane = np.column_stack([crossings.uv_m, np.zeros(len(crossings.uv_m))])
    point = in_plane @ T_other[:3, :3].T + T_other[:3, 3]
    ok &= column_distance_m(T_other[:2, 3], point[:, :2]) >= COLUMN_CLEARANCE_M + uncertainty.translation_m
    index = np.flatnonzero(ok)
    return SharedCandidates(index, crossings.range_m[index], crossings.bearing_rad[index], point[index])


def spread_choice(
    found: SharedCandidates, own_range_m: FloatArray, count: int, excluded: set[int]
) -> list[int]:
    """``count`` positions into ``found``: the nearest to the scanner first, then each farthest
    from those chosen in the watcher's plane, among the nearer half for the scanner (its centres
    there join its own solve, and the rod extraction's error grows with distance) and at
    least ``MIN_SEPARATION_M`` apart (fewer when fewer qualify)."""
    allowed = np.array([k not in excluded for k in range(len(found.index))], dtype=bool)
    if not allowed.any():
        return []
    near = own_range_m <= np.median(own_range_m[allowed])
    pool = np.flatnonzero(allowed & near) if (allowed & near).sum() >= count else np.flatnonzero(allowed)
    chosen = [int(pool[np.argmin(own_range_m[pool])])]
    while len(chosen) < count:
        distance = np.linalg.norm(
            found.point_base_m[pool][:, None, :] - found.point_base_m[chosen][None, :, :], axis=2
        ).min(axis=1)
        best = int(np.argmax(distance))
        if distance[best] < MIN_SEPARATION_M:
            break
        chosen.append(int(pool[best]))
    return chosen


def design_with_shared(
    request: DesignRequest, shared: SharedRequest, information: InformationModel
) -> Design:
    """The scanner's design (``request.waypoints`` of its own) with ``shared.count`` shared
    crossings added, all in one visiting order; its notes say how many were found."""
    rng = np.random.default_rng([request.seed, 1])
    turn_deg = AXIS_TOOL_TURN_SPREAD_DEG if request.estimate_axis else TOOL_TURN_SPREAD_DEG
    pool = draw_candidates(
        request.T_base_laser, shared.uncertainty, request.rules,
        SHARED_CANDIDATES_PER_CANDIDATE * request.candidates, rng,
        turn_spread_deg=turn_deg,
    )
    found = shared_candidates(pool, request, shared)
    excluded: set[int] = set()
    notes: list[str] = []
    own_seed = request.seed
    for _ in range(_SHARED_ROUNDS):
        picked = spread_choice(found, pool.crossing_range_m[found.index], shared.count, excluded)
        chosen = found.index[picked]
        T_shared = pool.T_base_tcp[chosen]
        prior = information_blocks(T_shared, pool.crossing_range_m[chosen], request, information).sum(axis=0)
        visited = visited_crossings(T_shared, request)[0]
        own = design(
            replace(request, prior_information=prior, visited_crossings_m=visited, seed=own_seed), information
        )
        transforms = np.concatenate([T_shared, waypoint_matrices(own.waypoints)])
        joints = np.concatenate([pool.joints_rad[chosen], own.joints_rad])
        order = visiting_order(joints, HOME_Q_RAD if request.start_q_rad is None else request.start_q_rad)
        failed_at, walked = walk_problem(transforms[order], joints[order], request.rules, joints[order[0]])
        if failed_at is None:
            break
        if order[failed_at] < len(chosen):
            excluded.add(picked[order[failed_at]])  # a shared one breaks the tour: choose again without it
        else:
            own_seed += 1  # one of its own does: design those again
    labels = [
        f"shared with {shared.name}: crossing {pool.crossing_range_m[i]:.2f} m at "
        f"{np.degrees(pool.crossing_bearing_rad[i]):+.0f} deg, {shared.name}'s {found.range_m[k]:.2f} m at "
        f"{np.degrees(found.bearing_rad[k]):+.0f} deg"
        for k, i in zip(picked, chosen, strict=True)
    ] + [w.label for w in own.waypoints]
    if failed_at is not None:
        notes.append("the visiting order with the shared crossings broke the joint-jump rule; cut short "
                     "there")
        order = order[:failed_at]
    if len(chosen) < shared.count:
        notes.append(
            f"only {len(chosen)} of {shared.count} shared crossings with {shared.name} found "
            f"({len(found.index)} of {len(pool)} candidates cross its plane at {shared.span_m[0]:.2f}-"
            f"{shared.span_m[1]:.2f} m); a smaller --pose-uncertainty or a wider span finds more"
        )
    poses = matrix_to_pose(transforms[order])
    first = request.first_index
    waypoints = [
        Waypoint(index=first + k, tcp_pose=tuple(float(v) for v in pose), label=labels[i])
        for k, (i, pose) in enumerate(zip(order, poses, strict=True))
    ]
    return replace(own, waypoints=waypoints, joints_rad=walked[: len(order)], notes=own.notes + notes)
