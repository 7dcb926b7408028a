"""Where the run's own first waypoints put the scanner, when no nominal mounting is given.

Without ``scanner.nominal`` the extraction has no expected position, and a rod-sized
object elsewhere in view could pass for the rod. Once ``CONSENSUS_WAYPOINTS`` centres are
measured, the solver's robust solve on them (least-median-of-squares start, outlier
test) gives a provisional ``T_base_laser``; from then on each waypoint's expected centre
is predicted from it, so a candidate far from where the robot put the rod is refused as
with a nominal mounting. The first waypoints themselves are checked by the solver's
outlier test at the end. A run and its replay compute it from the same centres in the
same order, so both see the same expected positions.
"""

from __future__ import annotations

from collections.abc import Sequence

from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.errors import LasercalError
from lasercal_hw.models import FloatArray, Observation, RodLine

CONSENSUS_WAYPOINTS = 6
"""Measured waypoints before a provisional pose is trusted (5 determine it; one more lets
the outlier test see a wrong one)."""
MAX_STD_MM = 20.0
MAX_STD_DEG = 2.0
"""A provisional pose less certain than this (any axis) is not used: its predictions could
miss the rod by more than the extraction's search radius (0.15 m) at 2 m."""


def provisional_pose(
    observations: Sequence[Observation], rod: RodLine, options: SolverOptions | None = None
) -> FloatArray | None:
    """``T_base_laser`` (4x4) from the first ``CONSENSUS_WAYPOINTS`` observations, or None
    while there are fewer or they do not determine a pose (rod directions too alike, too
    many of them disagreeing)."""
    if len(observations) < CONSENSUS_WAYPOINTS:
        return None
    try:
        result = solve(list(observations[:CONSENSUS_WAYPOINTS]), rod, options=options)
    except LasercalError:
        return None
    if max(result.std_translation_mm) > MAX_STD_MM or max(result.std_rotation_deg) > MAX_STD_DEG:
        return None
    return result.matrix()
