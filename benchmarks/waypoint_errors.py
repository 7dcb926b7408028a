"""A dry run's solved centres judged waypoint by waypoint over many seeds (``--per-waypoint``
of ``benchmarks.accuracy_conditions``).

Each centre the final solve took is compared with where the rod really crossed the scan plane
(the world's true transform and the TCP where the robot really was: the robot's own error is
taken out), along and across the bearing, beside the covariance it was reported with. Over the
seeds a waypoint whose error has a mean much larger than its scatter repeats at the pose: an
error of the extraction there, which every run through that pose carries into its solve.
Along the bearing the error includes the scanner's range error, which the solver's range curve
takes; across it, nothing in the solve does.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fakes.world import World
from lasercal_hw.calibration.model import plane_crossing, rod_lines_of_transforms
from lasercal_hw.geometry import pose_to_matrix
from lasercal_hw.models import FloatArray, Observation, RodLine


@dataclass(frozen=True)
class WaypointError:
    """One solved centre against the true crossing: the crossing's range (m), the error and
    the reported std along and across the bearing (m, in that order)."""

    index: int
    range_m: float
    error_m: FloatArray
    std_m: FloatArray


def waypoint_errors(
    observations: Sequence[Observation], world: World, true_rod: RodLine
) -> list[WaypointError]:
    """Each observation's centre against the crossing of ``true_rod`` (the rod the world's
    robot holds) at the TCP where the world's robot really was."""
    truth = world.ground_truth_T_base_laser
    rows = []
    for observation in observations:
        tcp_true = world.robot_error.true_pose(pose_to_matrix(np.asarray(observation.tcp_pose, dtype=float)))
        origins, directions = rod_lines_of_transforms(tcp_true[None], true_rod)
        crossing = plane_crossing(truth[:3, :3], truth[:3, 3], origins, directions)[0][0]
        range_m = float(np.linalg.norm(crossing))
        bearing = crossing / range_m
        basis = np.array([bearing, [-bearing[1], bearing[0]]])
        covariance = np.asarray(observation.covariance_uv_m2, dtype=float)
        rows.append(
            WaypointError(
                observation.index,
                range_m,
                basis @ (np.asarray(observation.centre_uv_m, dtype=float) - crossing),
                np.sqrt(np.diag(basis @ covariance @ basis.T)),
            )
        )
    return rows


def print_waypoint_errors(runs: Sequence[Sequence[WaypointError]]) -> None:
    """Per waypoint over the runs: the error's mean and scatter along and across the bearing,
    the median reported std, and the RMS of error over std (about 1 when the std is honest)."""
    by_index: dict[int, list[WaypointError]] = defaultdict(list)
    for run in runs:
        for row in run:
            by_index[row.index].append(row)
    print(
        "  per waypoint over the seeds, error against the true crossing (mm; along includes the range "
        "error the solver's curve takes):"
    )
    print(
        "    waypoint  range    along: mean  std  reported   across: mean  std  reported   "
        "RMS error/std along, across"
    )
    for index in sorted(by_index):
        rows = by_index[index]
        error_mm = 1e3 * np.array([r.error_m for r in rows])
        std_mm = 1e3 * np.array([r.std_m for r in rows])
        mean, scatter, reported = error_mm.mean(axis=0), error_mm.std(axis=0), np.median(std_mm, axis=0)
        rms_z = np.sqrt(np.mean((error_mm / std_mm) ** 2, axis=0))
        range_m = float(np.median([r.range_m for r in rows]))
        print(
            f"    {index:8d}  {range_m:4.2f} m  {mean[0]:+11.2f} {scatter[0]:5.2f} "
            f"{reported[0]:8.2f}   {mean[1]:+12.2f} {scatter[1]:5.2f} {reported[1]:8.2f}   "
            f"{rms_z[0]:.2f}, {rms_z[1]:.2f}"
        )
