"""Where the background is taken: the retract pose, with the whole rod clear of the scan
plane. Pure planning from the job and the waypoints (verify's timing estimate uses it too).
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.models import FloatArray
from lasercal_hw.run.preflight import rod_end_points_m
from lasercal_hw.run.waypoints import listed_waypoints

NOMINAL_CLEARANCE_M = 0.08


def background_lift_m(job: JobConfig, pose: FloatArray) -> float:
    """How far to lift a waypoint along base z so that the whole rod is above the scan plane.

    The configured ``background.lift_m`` if any; else, with a nominal scanner mounting, just
    enough for both rod ends to clear its plane by ``NOMINAL_CLEARANCE_M``; else the rod
    length plus 5 cm (enough wherever the rod crossed the plane).
    """
    nominal = job.scanner.nominal
    if job.background.lift_m is not None or nominal is None:
        return job.background_lift_m()
    T_base_laser = nominal.matrix()
    normal = T_base_laser[:3, 2]
    if normal[2] < 0.5:  # a scanner on its side: its plane is steep, lifting does not clear it
        return job.background_lift_m()
    heights_m = (rod_end_points_m(pose, job.rod.rod_line()) - T_base_laser[:3, 3]) @ normal
    return max(0.0, (NOMINAL_CLEARANCE_M - float(heights_m.min())) / float(normal[2]))


def retract_candidates(job: JobConfig, waypoints: FloatArray) -> list[FloatArray]:
    """Where the background may be taken, best first: the configured ``background.pose``;
    else each waypoint lifted clear of the plane, the first waypoint first, then the
    others nearest the robot base first (a far waypoint lifted may be out of reach)."""
    if job.background.pose is not None:
        return [np.asarray(job.background.pose, dtype=float)]
    if job.trajectory.flute_phase_deg is not None:  # a spin stays at one crossing: the listed ones too
        waypoints = np.vstack([waypoints, listed_waypoints(job)])
    order = sorted(range(len(waypoints)), key=lambda i: (i != 0, float(np.linalg.norm(waypoints[i][:3]))))
    candidates = []
    for i in order:
        pose = np.asarray(waypoints[i], dtype=float).copy()
        pose[2] += background_lift_m(job, pose)
        candidates.append(pose)
    return candidates
