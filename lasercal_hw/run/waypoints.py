"""The waypoints of a job: a named preset (``trajectories.presets``) with optional
parameter overrides, or a waypoint file (``trajectories.waypoint_file``: CSV or TOML)."""

from __future__ import annotations

from lasercal_hw.config import JobConfig
from lasercal_hw.geometry import matrix_to_pose
from lasercal_hw.models import FloatArray
from trajectories.presets import get_preset
from trajectories.semicircles import parse_semicircle_parameters, semicircle_waypoints
from trajectories.waypoint import Waypoint, waypoint_matrices
from trajectories.waypoint_file import load_waypoints


def job_waypoint_list(job: JobConfig) -> list[Waypoint]:
    """The waypoints the job visits, in order, with their labels.

    ``trajectory.parameters`` override the preset's semicircle parameters field by field;
    the preset's plane-crossing check uses the job's rod.
    """
    trajectory = job.trajectory
    if trajectory.waypoints_file is not None:
        return load_waypoints(trajectory.waypoints_file)
    assert trajectory.preset is not None
    preset = get_preset(trajectory.preset)
    parameters = parse_semicircle_parameters(
        preset.parameters.model_dump() | trajectory.parameters, source=f"trajectory preset {preset.name!r}"
    )
    return semicircle_waypoints(parameters, job.rod.rod_line())


def job_waypoints(job: JobConfig) -> FloatArray:
    """The job's waypoints as UR pose vectors (N, 6)."""
    return matrix_to_pose(waypoint_matrices(job_waypoint_list(job)))
